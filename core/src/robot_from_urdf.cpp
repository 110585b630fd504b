// A robot description from a URDF (read with urdfdom): the serial chain of six revolute joints,
// turned into the standard D-H table the kinematics and the analytic IK work with.
//
// The joint axes at the URDF's zero configuration are lines in the base link's frame. The D-H
// frames follow from them (Spong, Hutchinson, Vidyasagar, "Robot Modeling and Control", 3.2):
// z_{i−1} along joint i's axis, x_i along the common normal of z_{i−1} and z_i, and
//   a_i = length of that normal, d_i = offset along z_{i−1} to it,
//   α_i = angle from z_{i−1} to z_i about x_i, θ_i = angle from x_{i−1} to x_i about z_{i−1}.
// Each axis may be taken along or against the URDF's direction and each normal pointing either
// way; of those choices the first whose table one of the analytic solvers handles is kept (the
// URDF's own directions first). The URDF's joint value q relates to the D-H angle by
// θ = s·q + θ0 (s = ±1: axis direction, θ0: the D-H angle at the URDF's zero), and the URDF's
// convention becomes the controller's axis values: A = s·θ − s·θ0.
#include <spdlog/spdlog.h>
#include <urdf_parser/urdf_parser.h>

#include <cmath>
#include <functional>
#include <optional>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"
#include "flashtwin/core/robot.hpp"

namespace flashtwin {

namespace {

// Snapping: URDFs write π/2 as "1.5708" and tiny offsets as round-off; the D-H table keeps
// exact right angles and zero lengths within these tolerances (1e-5 rad is 10 µm at 1 m).
constexpr double kAngleSnap = 1e-5;   // [rad]
constexpr double kLengthSnap = 1e-7;  // [m]

[[noreturn]] void fail(const std::string& file, const std::string& what) {
  throw ConfigError(file + ": " + what);
}

Pose to_pose(const urdf::Pose& p) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(p.position.x, p.position.y, p.position.z);
  X.linear() = Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z)
                   .normalized()
                   .toRotationMatrix();
  return X;
}

bool movable(const urdf::Joint& j) {
  return j.type == urdf::Joint::REVOLUTE || j.type == urdf::Joint::CONTINUOUS;
}

// One moving joint of the chain, at the URDF's zero configuration, in the base link's frame.
struct AxisLine {
  const urdf::Joint* joint = nullptr;
  Vec3 point = Vec3::Zero();
  Vec3 direction = Vec3::UnitZ();
};

// A link of the chain and its pose at zero; `body` counts the moving joints above it
// (0 = the base, i = moves with joint i).
struct ChainLink {
  urdf::LinkConstSharedPtr link;
  Pose X_BL;
  int body = 0;
};

struct Chain {
  std::vector<AxisLine> axes;
  std::vector<ChainLink> links;
  Pose X_BF = Pose::Identity();  // the flange link (tool0, flange or the last link) at zero
};

bool has_moving_joint_below(const urdf::Link& link) {
  for (const auto& j : link.child_joints)
    if (movable(*j)) return true;
  for (const auto& c : link.child_links)
    if (has_moving_joint_below(*c)) return true;
  return false;
}

// Walks the URDF from its root: one branch may carry moving joints (the arm); fixed side
// branches (frames, sensors, the flange) ride on the body they hang from.
Chain walk_chain(const urdf::ModelInterface& model, const std::string& file) {
  Chain ch;
  std::function<void(const urdf::LinkConstSharedPtr&, const Pose&, int)> visit =
      [&](const urdf::LinkConstSharedPtr& link, const Pose& X_BL, int body) {
        ch.links.push_back({link, X_BL, body});
        int branches = 0;
        for (const auto& j : link->child_joints)
          if (movable(*j) || has_moving_joint_below(*model.getLink(j->child_link_name))) ++branches;
        if (branches > 1)
          fail(file, "link '" + link->name + "' branches into " + std::to_string(branches) +
                         " chains with moving joints; expected one serial arm");
        for (const auto& j : link->child_joints) {
          if (j->type == urdf::Joint::PRISMATIC || j->type == urdf::Joint::FLOATING ||
              j->type == urdf::Joint::PLANAR)
            fail(file, "joint '" + j->name + "': expected revolute, continuous or fixed joints only");
          const Pose X_BJ = X_BL * to_pose(j->parent_to_joint_origin_transform);
          int child_body = body;
          if (movable(*j)) {
            const Vec3 axis(j->axis.x, j->axis.y, j->axis.z);
            if (!(axis.norm() > 0)) fail(file, "joint '" + j->name + "': expected a non-zero axis");
            ch.axes.push_back({j.get(), X_BJ.translation(), X_BJ.linear() * axis.normalized()});
            child_body = static_cast<int>(ch.axes.size());
          }
          visit(model.getLink(j->child_link_name), X_BJ, child_body);
        }
      };
  visit(model.getRoot(), Pose::Identity(), 0);
  if (ch.axes.size() != kNumJoints)
    fail(file, "expected a serial chain of 6 revolute joints, found " +
                   std::to_string(ch.axes.size()));
  // The flange: tool0 (ROS-Industrial's tool mounting frame, z out of the flange), else a link
  // named flange, else the last joint's child link.
  const std::string last_child = ch.axes.back().joint->child_link_name;
  std::optional<ChainLink> pick;
  for (const char* name : {"tool0", "flange"})
    for (const auto& l : ch.links)
      if (!pick && l.body == kNumJoints && l.link->name == name) pick = l;
  for (const auto& l : ch.links)
    if (!pick && l.link->name == last_child) pick = l;
  ch.X_BF = pick->X_BL;
  return ch;
}

// ---- D-H frames from the axis lines.

struct DhFrames {
  std::array<DhRow, kNumJoints> dh;
  std::array<double, kNumJoints> theta0{};  // D-H angle at the URDF's zero
  std::array<double, kNumJoints> sign{};    // θ = sign·q + θ0
  std::array<Pose, kNumJoints + 1> F;       // D-H frames {0}..{6} at the URDF's zero
};

double snap_angle(double a) {
  for (int k = -4; k <= 4; ++k)
    if (std::abs(a - k * M_PI / 2) < kAngleSnap) return k * M_PI / 2;
  return a;
}
double snap_length(double v) { return std::abs(v) < kLengthSnap ? 0.0 : v; }

Pose rot_z(double angle) {
  Pose X = Pose::Identity();
  X.linear() = Eigen::AngleAxisd(angle, Vec3::UnitZ()).toRotationMatrix();
  return X;
}

// Frame {i} (1..5) from frame {i−1} and joint i+1's axis taken along z; `flip_x` turns the
// common normal around.
void next_frame(const Pose& Fp, const Vec3& p, const Vec3& z, bool flip_x, Pose& Fi, DhRow& row,
                double& theta0) {
  const Vec3 op = Fp.translation(), zp = Fp.linear().col(2), xp = Fp.linear().col(0);
  const Vec3 c = zp.cross(z);
  Vec3 foot_prev, foot_next, x;
  if (c.norm() < 1e-9) {
    // Parallel axes: the normal through o_{i−1} (d_i = 0); coincident: keep x.
    const Vec3 w = p - op;
    const Vec3 perp = w - w.dot(zp) * zp;
    foot_prev = op;
    foot_next = op + perp;
    x = perp.norm() < kLengthSnap ? xp : perp.normalized();
  } else {
    // Closest points of the two lines op + t·zp and p + u·z.
    const Vec3 w = op - p;
    const double b = zp.dot(z), dd = zp.dot(w), e = z.dot(w), den = 1 - b * b;
    const double t = (b * e - dd) / den, u = (e - b * dd) / den;
    foot_prev = op + t * zp;
    foot_next = p + u * z;
    const Vec3 n = foot_next - foot_prev;
    x = n.norm() < kLengthSnap ? c.normalized() : n.normalized();
  }
  if (flip_x) x = -x;
  row.a = snap_length((foot_next - foot_prev).dot(x));
  row.d = snap_length((foot_prev - op).dot(zp));
  row.alpha = snap_angle(std::atan2(zp.cross(z).dot(x), zp.dot(z)));
  theta0 = std::atan2(xp.cross(x).dot(zp), xp.dot(x));
  // The frame from the snapped row, so that it chains exactly as the D-H product does.
  Fi = Fp * rot_z(theta0) * dh_constant(row);
}

// D-H frames for one choice of axis directions (bit i: joint i+1 against its URDF direction)
// and normal directions (bit i: x_{i+1} flipped).
DhFrames dh_frames(const Chain& ch, unsigned z_flips, unsigned x_flips) {
  DhFrames out;
  out.F[0] = Pose::Identity();
  for (int i = 0; i < kNumJoints; ++i)
    out.sign[i] = (z_flips >> i & 1u) ? -1.0 : 1.0;
  for (int i = 1; i < kNumJoints; ++i) {
    const Vec3 z = out.sign[i] * ch.axes[i].direction;
    next_frame(out.F[i - 1], ch.axes[i].point, z, (x_flips >> i) & 1u, out.F[i], out.dh[i - 1],
               out.theta0[i - 1]);
  }
  // Frame {6}: on joint 6's axis level with the flange, x as near the flange's x as it goes.
  const Pose& F5 = out.F[5];
  const Vec3 z5 = F5.linear().col(2), o5 = F5.translation(), x5 = F5.linear().col(0);
  DhRow& r6 = out.dh[5];
  r6.alpha = 0;
  r6.a = 0;
  r6.d = snap_length((ch.X_BF.translation() - o5).dot(z5));
  Vec3 xf = ch.X_BF.linear().col(0);
  xf -= xf.dot(z5) * z5;
  if (xf.norm() < 1e-6) xf = x5;
  xf.normalize();
  out.theta0[5] = std::atan2(x5.cross(xf).dot(z5), x5.dot(xf));
  out.F[6] = F5 * rot_z(out.theta0[5]) * dh_constant(r6);
  return out;
}

std::string table_text(const std::array<DhRow, kNumJoints>& dh) {
  std::ostringstream os;
  os << "alpha [";
  for (int i = 0; i < kNumJoints; ++i) os << (i ? ", " : "") << strf("%.4f", dh[i].alpha);
  os << "], a [";
  for (int i = 0; i < kNumJoints; ++i) os << (i ? ", " : "") << strf("%.4f", dh[i].a);
  os << "], d [";
  for (int i = 0; i < kNumJoints; ++i) os << (i ? ", " : "") << strf("%.4f", dh[i].d);
  return os.str() + "]";
}

// ---- Mass properties.

// Inertial of everything riding on body `body`, in that body's D-H frame F (at zero).
std::optional<Inertial> body_inertial(const Chain& ch, int body, const Pose& F) {
  double mass = 0;
  Vec3 moment = Vec3::Zero();
  Mat3 I_F = Mat3::Zero();  // about F's origin
  for (const auto& l : ch.links) {
    if (l.body != body || !l.link->inertial) continue;
    const urdf::Inertial& in = *l.link->inertial;
    if (!(in.mass > 0)) continue;
    const Pose X_FI = F.inverse() * l.X_BL * to_pose(in.origin);
    Mat3 I;
    I << in.ixx, in.ixy, in.ixz, in.ixy, in.iyy, in.iyz, in.ixz, in.iyz, in.izz;
    const Mat3 R = X_FI.linear();
    const Vec3 c = X_FI.translation();
    // Parallel-axis theorem about F's origin.
    I_F += R * I * R.transpose() + in.mass * (c.squaredNorm() * Mat3::Identity() - c * c.transpose());
    moment += in.mass * c;
    mass += in.mass;
  }
  if (!(mass > 0)) return std::nullopt;
  Inertial out;
  out.mass = mass;
  out.com = moment / mass;
  const Vec3 c = out.com;
  const Mat3 I_com = I_F - mass * (c.squaredNorm() * Mat3::Identity() - c * c.transpose());
  // The description holds moments along its frame's axes: the tensor's diagonal in the D-H
  // frame (products of inertia are dropped; the diagonal of a physical tensor keeps the
  // triangle inequality). A floor keeps point masses simulable.
  for (int k = 0; k < 3; ++k) out.inertia[k] = std::max(I_com(k, k), 1e-6);
  return out;
}

}  // namespace

RobotModel robot_from_urdf(const std::string& xml, const std::string& file) {
  const urdf::ModelInterfaceSharedPtr model = urdf::parseURDF(xml);
  if (!model) fail(file, "expected a URDF document urdfdom can read (see its messages above)");
  const Chain ch = walk_chain(*model, file);

  // {B} = {0} is the root link's frame: joint 1 must turn about its z axis through its origin.
  const AxisLine& j1 = ch.axes[0];
  if (std::abs(std::abs(j1.direction.z()) - 1) > 1e-9 || j1.point.head<2>().norm() > 1e-9)
    fail(file, strf("joint '%s': expected the first joint's axis along the z axis of the root "
                    "link '%s' through its origin (the robot base {B} is D-H frame {0}), got "
                    "axis (%.4f, %.4f, %.4f) through (%.4f, %.4f)",
                    j1.joint->name.c_str(), model->getRoot()->name.c_str(), j1.direction.x(),
                    j1.direction.y(), j1.direction.z(), j1.point.x(), j1.point.y()));
  const unsigned z1_flip = j1.direction.z() < 0 ? 1u : 0u;

  RobotModel r;
  r.name = model->getName();
  r.source = file;
  std::optional<DhFrames> chosen;
  for (unsigned zf = 0; zf < 32 && !chosen; ++zf)
    for (unsigned xf = 0; xf < 32 && !chosen; ++xf) {
      const DhFrames f = dh_frames(ch, z1_flip | (zf << 1), xf << 1);
      r.dh = f.dh;
      if (arm_geometry(r) != ArmGeometry::kUnsupported) chosen = f;
    }
  if (!chosen) {
    const DhFrames f = dh_frames(ch, z1_flip, 0);
    fail(file, "the arm's D-H table (" + table_text(f.dh) +
                   ") fits neither analytic IK: a spherical-wrist arm needs joints 4, 5, 6 to "
                   "meet in one point and joints 2, 3 parallel; a UR-type arm needs joints 2, "
                   "3, 4 parallel and joint 5 at right angles to them");
  }
  const DhFrames& f = *chosen;
  r.dh = f.dh;

  static const double kAccel[kNumJoints] = {10, 10, 12, 25, 25, 35};  // as the FT6's [rad/s²]
  for (int i = 0; i < kNumJoints; ++i) {
    const urdf::Joint& j = *ch.axes[i].joint;
    JointLimits& L = r.limits[i];
    const double s = f.sign[i], t0 = f.theta0[i];
    if (!j.limits || !(j.limits->velocity > 0) || !(j.limits->effort > 0))
      fail(file, "joint '" + j.name + "': expected <limit> with velocity > 0 and effort > 0");
    double lo = -2 * M_PI, hi = 2 * M_PI;  // continuous
    if (j.type == urdf::Joint::REVOLUTE) {
      lo = j.limits->lower;
      hi = j.limits->upper;
      if (!(lo < hi))
        fail(file, strf("joint '%s': expected limit lower < upper, got %g and %g", j.name.c_str(),
                        lo, hi));
    }
    L.lower = std::min(s * lo, s * hi) + t0;
    L.upper = std::max(s * lo, s * hi) + t0;
    L.velocity = j.limits->velocity;
    L.torque = j.limits->effort;
    L.acceleration = kAccel[i];
    r.controller.sign[i] = s;
    r.controller.offset[i] = -s * t0;
    r.home[i] = std::clamp(t0, L.lower, L.upper);
  }
  spdlog::info("{}: URDF arm '{}' read as a {} D-H table ({}); joint accelerations are not in "
               "URDF, assumed {:g}, {:g}, {:g}, {:g}, {:g}, {:g} rad/s^2",
               file, r.name,
               arm_geometry(r) == ArmGeometry::kSphericalWrist ? "spherical-wrist" : "UR-type",
               table_text(r.dh), kAccel[0], kAccel[1], kAccel[2], kAccel[3], kAccel[4], kAccel[5]);

  // Mass properties; a body the URDF gives no mass gets a stand-in, said aloud.
  const auto inertial_or_guess = [&](int body, const Pose& F, const std::string& what) {
    if (auto in = body_inertial(ch, body, F)) return *in;
    spdlog::warn("{}: {} has no <inertial> in the URDF; a 5 kg stand-in is simulated (its "
                 "dynamics are not the real arm's)",
                 file, what);
    Inertial guess;
    guess.mass = 5.0;
    guess.inertia = Vec3::Constant(0.05);
    return guess;
  };
  r.base = inertial_or_guess(0, f.F[0], "the base");
  for (int i = 0; i < kNumJoints; ++i)
    r.links[i] = inertial_or_guess(i + 1, f.F[i + 1], "link " + std::to_string(i + 1));

  // The tool: the FT6's spindle and burr (models/robots/ft6.yaml) mounted on the URDF's flange
  // link; a scenario's tool: block resizes the burr.
  const Pose X_EF = f.F[6].inverse() * ch.X_BF;
  r.tool.name = "spindle_burr";
  Pose X_FT = Pose::Identity();
  X_FT.translation() = Vec3(0, 0, 0.22);
  r.tool.X_ET = X_EF * X_FT;
  r.tool.inertial.mass = 3.0;
  r.tool.inertial.com = X_EF * Vec3(0, 0, 0.08);
  r.tool.inertial.inertia = Vec3(0.012, 0.012, 0.003);
  r.tool.radius = 0.006;
  r.tool.length = 0.020;
  return r;
}

}  // namespace flashtwin
