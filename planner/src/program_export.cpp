#include "flashtwin/planner/program_export.hpp"

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <map>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"
#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

namespace {

constexpr double kRad2Deg = 180.0 / M_PI;
constexpr double kDeg2Rad = M_PI / 180.0;

// Fixed-point number without a "-0.000" for values that round to zero.
std::string fixed(double v, int decimals) {
  std::string s;
  append_fixed(s, v, decimals);
  if (s[0] == '-' && s.find_first_not_of("-0.") == std::string::npos) s.erase(0, 1);
  return s;
}

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

// KRL: positions [mm] to 1e-4, angles [deg] to 1e-5; URScript: [m] and [rad] to 1e-7.
std::string mm(double metres) {
  return fixed(metres * 1000.0, 4);
}
std::string deg(double degrees) {
  return fixed(degrees, 5);
}
std::string ur(double v) {
  return fixed(v, 7);
}

// Angle [deg] in (-180, 180].
double wrap180(double a) {
  a = std::remainder(a, 360.0);
  return a <= -180.0 ? a + 360.0 : a;
}

std::string krl_frame(const Pose& X) {
  const KukaFrame f = kuka_frame_from_pose(X);
  return "{X " + fixed(f.x, 4) + ", Y " + fixed(f.y, 4) + ", Z " + fixed(f.z, 4) + ", A " +
         deg(f.a) + ", B " + deg(f.b) + ", C " + deg(f.c) + "}";
}

std::string ur_pose(const Pose& X) {
  const UrPose p = ur_pose_from_pose(X);
  std::string s = "p[";
  for (int i = 0; i < 6; ++i) s += (i ? ", " : "") + ur(p[i]);
  return s + "]";
}

bool valid_name(const std::string& n) {
  if (n.empty() || n.size() > 24 || !std::isalpha(static_cast<unsigned char>(n[0]))) return false;
  return std::all_of(n.begin(), n.end(), [](char c) {
    return std::isalnum(static_cast<unsigned char>(c)) || c == '_';
  });
}

std::string trim(const std::string& s) {
  const auto b = s.find_first_not_of(" \t\r\n");
  if (b == std::string::npos) return "";
  const auto e = s.find_last_not_of(" \t\r\n");
  return s.substr(b, e - b + 1);
}

std::string upper(std::string s) {
  for (char& c : s) c = static_cast<char>(std::toupper(static_cast<unsigned char>(c)));
  return s;
}

bool starts_with(const std::string& s, const std::string& p) {
  return s.rfind(p, 0) == 0;
}

[[noreturn]] void parse_error(int line, const std::string& expected, const std::string& got) {
  throw ArgumentError("program line " + std::to_string(line) + ": expected " + expected + ", got " +
                      (got.empty() ? "nothing" : "'" + got + "'"));
}

double parse_number(const std::string& text, int line, const std::string& what) {
  const std::string t = trim(text);
  char* end = nullptr;
  const double v = std::strtod(t.c_str(), &end);
  if (t.empty() || end != t.c_str() + t.size() || !std::isfinite(v))
    parse_error(line, "a number for " + what, t);
  return v;
}

// URScript movel/movep state no orientation speed: the controller turns the tool at up to this
// many rad/s per m/s of the programmed tool speed (and rad/s² per m/s² of the acceleration) and
// takes whichever of the translation and the rotation needs longer (Universal Robots forum,
// "MoveL: Tool Angular Speed", 2021 — a user's measurement, not a manual's statement).
constexpr double kUrOriPerSpeed = 4.0;

// Splits at top-level commas (not inside brackets or parentheses).
std::vector<std::string> split_top(const std::string& s) {
  std::vector<std::string> parts;
  int depth = 0;
  std::string cur;
  for (char c : s) {
    if (c == '(' || c == '[' || c == '{') ++depth;
    if (c == ')' || c == ']' || c == '}') --depth;
    if (c == ',' && depth == 0) {
      parts.push_back(trim(cur));
      cur.clear();
    } else {
      cur += c;
    }
  }
  if (!trim(cur).empty() || !parts.empty()) parts.push_back(trim(cur));
  return parts;
}

}  // namespace

ProgramParams program_params_for(const RobotModel& robot) {
  ProgramParams P;
  P.joint_sign = robot.controller.sign;
  P.joint_offset = robot.controller.offset;
  if (robot.controller.language == "rapid") P.dialect = ProgramDialect::kRapid;
  if (robot.controller.language == "urscript") P.dialect = ProgramDialect::kUrScript;
  return P;
}

namespace {

// Controller axis values <-> D-H angles.
Vector6 to_axes(const Vector6& q, const ProgramParams& P) {
  return P.joint_sign.cwiseProduct(q) + P.joint_offset;
}
Vector6 from_axes(const Vector6& axes, const ProgramParams& P) {
  return (axes - P.joint_offset).cwiseQuotient(P.joint_sign);
}

// ---- Decimation and per-point speeds.

// Largest deviation of the TCP samples strictly between a and b from the straight move a→b the
// controller makes of them: position from the chord, orientation from the slerp at the sample's
// fraction along it (scaled to metres by `ori_scale` [m/rad]) [m].
double chord_deviation(const std::vector<Pose>& X, const std::vector<Eigen::Quaterniond>& r,
                       std::size_t a, std::size_t b, double ori_scale) {
  const Vec3 pa = X[a].translation(), d = X[b].translation() - pa;
  const double len2 = d.squaredNorm();
  double worst = 0;
  for (std::size_t n = a + 1; n < b; ++n) {
    const Vec3 q = X[n].translation() - pa;
    const double u = len2 > 0 ? std::clamp(q.dot(d) / len2, 0.0, 1.0) : 0.0;
    worst = std::max(worst, (q - u * d).norm());
    if (ori_scale > 0) worst = std::max(worst, ori_scale * r[a].slerp(u, r[b]).angularDistance(r[n]));
  }
  return worst;
}

// The exported samples: every point_spacing of path length (or every time_step), and, for the
// Cartesian motions, wherever the straight moves between exported points would leave the
// planned TCP path by more than chord_tolerance (CAM's chordal deviation: a small hole ring's
// TCP circle needs targets much closer than the spacing).
std::vector<std::size_t> decimate(const JointTrajectory& tr, const std::vector<Pose>& X_WT,
                                  const ProgramParams& P) {
  std::vector<std::size_t> idx{0};
  const std::size_t K = tr.size();
  const bool cartesian = P.motion == ProgramMotion::kLinear || P.motion == ProgramMotion::kSpline;
  const bool chordal = cartesian && P.chord_tolerance > 0;
  std::vector<Eigen::Quaterniond> r;
  if (chordal)
    for (const Pose& X : X_WT) r.emplace_back(X.linear());
  const double ori_scale = P.chord_tolerance / P.angle_tolerance;
  const std::size_t step = P.time_step > 0 ? std::max<std::size_t>(
                                                 1, static_cast<std::size_t>(std::llround(P.time_step / tr.dt)))
                                           : 0;
  for (std::size_t n = 1; n + 1 < K; ++n) {
    const std::size_t a = idx.back();
    const bool due = step ? n - a >= step : tr.s[n] - tr.s[a] >= P.point_spacing * (1 - 1e-9);
    if (chordal && n - a > 1 && chord_deviation(X_WT, r, a, n, ori_scale) > P.chord_tolerance) {
      idx.push_back(n - 1);  // the longest move from a that still follows the path
      --n;
      continue;
    }
    if (due) idx.push_back(n);
  }
  if (K > 1) idx.push_back(K - 1);
  return idx;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Angle conventions

KukaFrame kuka_frame_from_pose(const Pose& X) {
  const Mat3 R = X.linear();
  KukaFrame f;
  f.x = X.translation().x() * 1000.0;
  f.y = X.translation().y() * 1000.0;
  f.z = X.translation().z() * 1000.0;
  // R = Rz(A)·Ry(B)·Rx(C): first column (cA·cB, sA·cB, −sB), last row (−sB, cB·sC, cB·cC).
  const double cb = std::hypot(R(0, 0), R(1, 0));
  const double b = std::atan2(-R(2, 0), cb);
  double a, c;
  if (cb > 1e-9) {
    a = std::atan2(R(1, 0), R(0, 0));
    c = std::atan2(R(2, 1), R(2, 2));
  } else {
    // Gimbal lock (B = ±90°): only A ∓ C is defined; take C = 0, then R(0,1) = −sA, R(1,1) = cA.
    c = 0;
    a = std::atan2(-R(0, 1), R(1, 1));
  }
  f.a = wrap180(a * kRad2Deg);
  f.b = b * kRad2Deg;
  f.c = wrap180(c * kRad2Deg);
  return f;
}

Pose pose_from_kuka_frame(const KukaFrame& f) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(f.x, f.y, f.z) / 1000.0;
  X.linear() = (Eigen::AngleAxisd(f.a * kDeg2Rad, Vec3::UnitZ()) *
                Eigen::AngleAxisd(f.b * kDeg2Rad, Vec3::UnitY()) *
                Eigen::AngleAxisd(f.c * kDeg2Rad, Vec3::UnitX()))
                   .toRotationMatrix();
  return X;
}

UrPose ur_pose_from_pose(const Pose& X) {
  const Eigen::AngleAxisd aa(Eigen::Quaterniond(X.linear()).normalized());
  const Vec3 r = aa.angle() * aa.axis();
  const Vec3 p = X.translation();
  return {p.x(), p.y(), p.z(), r.x(), r.y(), r.z()};
}

Pose pose_from_ur_pose(const UrPose& u) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(u[0], u[1], u[2]);
  const Vec3 r(u[3], u[4], u[5]);
  const double angle = r.norm();
  if (angle > 0) X.linear() = Eigen::AngleAxisd(angle, r / angle).toRotationMatrix();
  return X;
}

std::string to_string(ProgramDialect dialect) {
  switch (dialect) {
    case ProgramDialect::kKrl: return "krl";
    case ProgramDialect::kUrScript: return "urscript";
    case ProgramDialect::kRapid: return "rapid";
  }
  return "?";
}

namespace {

// ---- ABB RAPID: one MODULE with PERS tooldata/wobjdata and PROC main; positions [mm],
// orientations as quaternions [q1 q2 q3 q4] = [w x y z], axis values [deg].

std::string rapid_pos_quat(const Pose& X) {
  const Eigen::Quaterniond q(X.linear());
  const Vec3 p = X.translation();
  return "[[" + mm(p.x()) + ", " + mm(p.y()) + ", " + mm(p.z()) + "], [" + fixed(q.w(), 8) + ", " +
         fixed(q.x(), 8) + ", " + fixed(q.y(), 8) + ", " + fixed(q.z(), 8) + "]]";
}

// confdata [cf1, cf4, cf6, cfx]: the quadrants of axes 1, 4 and 6 (floor(angle / 90°)), and
// the arm configuration 0..7 = 4·(wrist centre behind axis 1) + 2·(wrist centre behind the
// lower arm) + (axis 5 negative), as ABB numbers it for serial arms.
std::string rapid_confdata(const RobotModel& robot, const Vector6& q, const Vector6& axes_deg) {
  const auto F = fk_frames(robot, q);
  const Vec3 p_w = F[4].translation();  // wrist centre (frame {4}'s origin)
  const bool behind_axis1 = (F[1].inverse() * p_w).x() < 0;
  const bool behind_lower_arm = (F[2].inverse() * p_w).y() < 0;
  const int cfx = 4 * behind_axis1 + 2 * behind_lower_arm + (axes_deg[4] < 0 ? 1 : 0);
  const auto quadrant = [](double a) {
    return std::to_string(static_cast<int>(std::floor(a / 90.0)));
  };
  return "[" + quadrant(axes_deg[0]) + ", " + quadrant(axes_deg[3]) + ", " +
         quadrant(axes_deg[5]) + ", " + std::to_string(cfx) + "]";
}

std::string rapid_jointtarget(const Vector6& axes_deg) {
  std::string s = "[[";
  for (int j = 0; j < kNumJoints; ++j) s += (j ? ", " : "") + deg(axes_deg[j]);
  return s + "], [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]]";
}

// speeddata [v_tcp mm/s, v_ori deg/s, v_leax, v_reax]; zonedata [finep, pzone_tcp, pzone_ori,
// pzone_eax, zone_ori, zone_leax, zone_reax] (mm, deg).
std::string rapid_speed(double v_tcp, double v_ori) {
  return "[" + fixed(v_tcp * 1000.0, 4) + ", " + fixed(v_ori * kRad2Deg, 4) + ", 5000, 1000]";
}
std::string rapid_zone(double radius) {
  const std::string r = mm(radius);
  return "[FALSE, " + r + ", " + r + ", " + r + ", 0.1, " + r + ", 0.1]";
}

template <typename SegmentSpeed, typename SegmentOriSpeed>
void write_rapid(std::ostringstream& o, const RobotModel& robot, const JointTrajectory& tr,
                 const ProgramParams& P, const Pose& X_ET, const std::vector<Pose>& X_WT,
                 const std::vector<std::size_t>& idx, const SegmentSpeed& segment_speed,
                 const SegmentOriSpeed& segment_ori_speed) {
  const std::size_t npts = idx.size();
  const auto axes_deg = [&](const Vector6& q) { return Vector6(to_axes(q, P) * kRad2Deg); };
  const Inertial& tool = robot.tool.inertial;
  const Vec3 com_mm = 1000.0 * (X_ET.inverse() * tool.com);  // the load's COM in {T}
  o << "MODULE " << P.name << "\n";
  o << "  ! flashtwin robot program (ABB RAPID): " << npts << " motion points, "
    << fixed(tr.duration(), 3) << " s trajectory\n";
  o << "  ! tooldata: tool {T} in flange {E}; wobjdata uframe: work frame {W} in robot base {B};"
       " mm, deg, quaternions [w, x, y, z]\n";
  o << "  ! axis values are D-H joint angles mapped as sign*q + offset; confdata from the"
       " configuration\n";
  o << "  PERS tooldata tFlashtwin := [TRUE, " << rapid_pos_quat(X_ET) << ", ["
    << fixed(std::max(tool.mass, 0.001), 3) << ", [" << fixed(com_mm.x(), 3) << ", "
    << fixed(com_mm.y(), 3) << ", " << fixed(com_mm.z(), 3) << "], [1, 0, 0, 0], 0, 0, 0]];\n";
  o << "  PERS wobjdata wFlashtwin := [FALSE, TRUE, \"\", " << rapid_pos_quat(P.X_BW)
    << ", [[0, 0, 0], [1, 0, 0, 0]]];\n";
  o << "  PROC main()\n";
  o << "    MoveAbsJ " << rapid_jointtarget(axes_deg(tr.q[idx[0]])) << ", v100, fine, tFlashtwin;\n";
  for (std::size_t i = 1; i < npts; ++i) {
    const std::string zone = i + 1 == npts ? "fine" : rapid_zone(P.blend_radius);
    const Vector6 a = axes_deg(tr.q[idx[i]]);
    if (P.motion == ProgramMotion::kJoint) {
      o << "    MoveAbsJ " << rapid_jointtarget(a) << ", " << rapid_speed(segment_speed(i), segment_ori_speed(i))
        << ", " << zone << ", tFlashtwin \\WObj:=wFlashtwin;\n";
    } else {
      const std::string pq = rapid_pos_quat(X_WT[idx[i]]);
      o << "    MoveL [" << pq.substr(1, pq.size() - 2) << ", "
        << rapid_confdata(robot, tr.q[idx[i]], a) << ", [9E9, 9E9, 9E9, 9E9, 9E9, 9E9]], "
        << rapid_speed(segment_speed(i), segment_ori_speed(i)) << ", " << zone
        << ", tFlashtwin \\WObj:=wFlashtwin;\n";
    }
  }
  o << "  ENDPROC\n";
  o << "ENDMODULE\n";
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Export

RobotProgram export_program(const RobotModel& robot, const JointTrajectory& tr,
                            const ProgramParams& P) {
  const std::size_t K = tr.size();
  if (K < 2)
    throw ArgumentError("trajectory: expected at least 2 samples, got " + std::to_string(K));
  if (tr.q.size() != K || tr.dq.size() != K || tr.ddq.size() != K || tr.s.size() != K ||
      tr.sdot.size() != K)
    throw ArgumentError("trajectory: expected q, dq, ddq, s, sdot of " + std::to_string(K) +
                        " samples each (the size of t), got sizes " + std::to_string(tr.q.size()) +
                        ", " + std::to_string(tr.dq.size()) + ", " + std::to_string(tr.ddq.size()) +
                        ", " + std::to_string(tr.s.size()) + ", " + std::to_string(tr.sdot.size()));
  if (!(tr.dt > 0))
    throw ArgumentError("trajectory.dt: expected a positive period, got " + num(tr.dt));
  if (!valid_name(P.name))
    throw ArgumentError("name: expected a letter then letters, digits or '_' (at most 24), got '" +
                        P.name + "'");
  if (!(P.point_spacing > 0))
    throw ArgumentError("point_spacing: expected a positive distance [m], got " +
                        num(P.point_spacing));
  if (!(P.time_step >= 0))
    throw ArgumentError("time_step: expected >= 0 [s], got " + num(P.time_step));
  if (!(P.chord_tolerance >= 0))
    throw ArgumentError("chord_tolerance: expected >= 0 [m], got " + num(P.chord_tolerance));
  if (!(P.angle_tolerance > 0))
    throw ArgumentError("angle_tolerance: expected > 0 [rad], got " + num(P.angle_tolerance));
  if (!(P.blend_radius >= 0))
    throw ArgumentError("blend_radius: expected >= 0 [m], got " + num(P.blend_radius));
  if (!(P.min_speed > 0))
    throw ArgumentError("min_speed: expected a positive speed [m/s], got " + num(P.min_speed));
  if (!(P.approach_speed > 0 && P.approach_speed <= 1))
    throw ArgumentError("approach_speed: expected a fraction in (0, 1], got " +
                        num(P.approach_speed));
  if (!(P.speed_change >= 0))
    throw ArgumentError("speed_change: expected a fraction >= 0, got " + num(P.speed_change));
  // URScript's documented ranges for servoj.
  if (P.motion == ProgramMotion::kServo && !(P.servo_lookahead >= 0.03 && P.servo_lookahead <= 0.2))
    throw ArgumentError("servo_lookahead: expected 0.03 to 0.2 s, got " + num(P.servo_lookahead));
  if (P.motion == ProgramMotion::kServo && !(P.servo_gain >= 100 && P.servo_gain <= 2000))
    throw ArgumentError("servo_gain: expected 100 to 2000, got " + num(P.servo_gain));
  for (int j = 0; j < kNumJoints; ++j)
    if (P.joint_sign[j] != 1.0 && P.joint_sign[j] != -1.0)
      throw ArgumentError("joint_sign[" + std::to_string(j) + "]: expected 1 or -1, got " +
                          num(P.joint_sign[j]));
  if (P.dialect == ProgramDialect::kKrl && P.motion == ProgramMotion::kServo)
    throw ArgumentError(
        "motion: expected linear, spline or joint for KRL, got servo (URScript only)");
  if (P.dialect == ProgramDialect::kRapid &&
      (P.motion == ProgramMotion::kServo || P.motion == ProgramMotion::kSpline))
    throw ArgumentError("motion: expected linear or joint for RAPID, got " +
                        std::string(P.motion == ProgramMotion::kServo ? "servo" : "spline"));

  const Pose X_ET = P.X_ET ? *P.X_ET : robot.tool.X_ET;
  const Pose X_WB = P.X_BW.inverse();
  RobotProgram prog;
  prog.dialect = P.dialect;
  prog.name = P.name;
  // TCP poses in {W}, the exported samples, and the speeds the decimated segments need.
  std::vector<Pose> X_WT(K);
  for (std::size_t n = 0; n < K; ++n) X_WT[n] = X_WB * fk_flange(robot, tr.q[n]) * X_ET;
  prog.samples = decimate(tr, X_WT, P);
  const auto& idx = prog.samples;
  std::vector<double> ori_speed(K, 0.0);
  for (std::size_t n = 1; n < K; ++n) {
    ori_speed[n] = rotation_distance(X_WT[n].linear(), X_WT[n - 1].linear()) / tr.dt;
  }
  double max_path_accel = 0, max_ori_speed = 0, max_ori_accel = 0;
  Vector6 max_dq = Vector6::Zero(), max_ddq = Vector6::Zero();
  for (std::size_t n = 0; n < K; ++n) {
    if (!tr.sddot.empty()) max_path_accel = std::max(max_path_accel, std::abs(tr.sddot[n]));
    max_ori_speed = std::max(max_ori_speed, ori_speed[n]);
    if (n > 1) max_ori_accel = std::max(max_ori_accel, std::abs(ori_speed[n] - ori_speed[n - 1]) / tr.dt);
    max_dq = max_dq.cwiseMax(tr.dq[n].cwiseAbs());
    max_ddq = max_ddq.cwiseMax(tr.ddq[n].cwiseAbs());
  }
  // Into exported point i >= 1: the chord between the targets at the plan's pace (its length
  // over the time the plan takes between them), so that the controller, moving the chord at the
  // programmed speed, takes the plan's time over it. (The fastest sample of the segment instead
  // would run a plan whose speed varies within a segment faster than planned: a hole ring's
  // program took half its plan's time.)
  const auto segment_speed = [&](std::size_t i) {
    const double chord = (X_WT[idx[i]].translation() - X_WT[idx[i - 1]].translation()).norm();
    return std::max(chord / (tr.t[idx[i]] - tr.t[idx[i - 1]]), P.min_speed);
  };
  // ... and the tool's turn between them at the plan's pace: where the turn governs (a burr
  // tilting on a small radius), the controller takes the plan's time too.
  const auto segment_ori_speed = [&](std::size_t i) {
    const double angle = rotation_distance(X_WT[idx[i - 1]].linear(), X_WT[idx[i]].linear());
    return std::max(angle / (tr.t[idx[i]] - tr.t[idx[i - 1]]), 1e-4);
  };
  const auto segment_joint_speed = [&](std::size_t i) {
    double v = 0;
    for (std::size_t n = idx[i - 1] + 1; n <= idx[i]; ++n)
      v = std::max(v, tr.dq[n].cwiseAbs().maxCoeff());
    return std::max(v, 0.01);
  };
  double vmin_joint = 1e300, amin_joint = 1e300;
  for (int j = 0; j < kNumJoints; ++j) {
    vmin_joint = std::min(vmin_joint, robot.limits[j].velocity);
    amin_joint = std::min(amin_joint, robot.limits[j].acceleration);
  }

  std::ostringstream o;
  const std::size_t npts = idx.size();
  if (P.dialect == ProgramDialect::kKrl) {
    const auto axes = [&](const Vector6& q) {
      const Vector6 a = to_axes(q, P) * kRad2Deg;
      std::string s = "{";
      for (int j = 0; j < kNumJoints; ++j)
        s += (j ? ", A" : "A") + std::to_string(j + 1) + " " + deg(a[j]);
      return s + "}";
    };
    const auto percent = [](double ratio) {
      return std::to_string(std::clamp(static_cast<int>(std::ceil(100.0 * ratio - 1e-9)), 1, 100));
    };
    o << "&ACCESS RVP\n&REL 1\n";
    o << "DEF " << P.name << "( )\n";
    o << "; flashtwin robot program (KUKA KRL): " << npts << " motion points, "
      << fixed(tr.duration(), 3) << " s trajectory\n";
    o << "; $TOOL: tool {T} in flange {E}; $BASE: work frame {W} in robot base {B}; mm, deg,"
         " A B C = rotations about Z Y X\n";
    o << "; axis values are D-H joint angles mapped as sign*q + offset\n";
    o << ";FOLD INI\n";
    o << "  $ORI_TYPE = #VAR\n";
    o << "  $APO.CDIS = " << mm(P.blend_radius) << "\n";
    o << "  $APO.CPTP = 10\n";
    o << "  $ACC.CP = " << fixed(std::max(1.2 * max_path_accel, 0.1), 4) << "\n";
    o << "  $VEL.ORI1 = " << fixed(std::max(1.2 * max_ori_speed * kRad2Deg, 10.0), 3) << "\n";
    o << "  $VEL.ORI2 = " << fixed(std::max(1.2 * max_ori_speed * kRad2Deg, 10.0), 3) << "\n";
    const std::string acc_ori = fixed(std::max(1.2 * max_ori_accel * kRad2Deg, 400.0), 3);
    o << "  $ACC.ORI1 = " << acc_ori << "\n  $ACC.ORI2 = " << acc_ori << "\n";
    for (int j = 1; j <= kNumJoints; ++j)
      o << "  $VEL_AXIS[" << j << "] = " << percent(P.approach_speed) << "\n";
    for (int j = 1; j <= kNumJoints; ++j)
      o << "  $ACC_AXIS[" << j << "] = " << percent(P.approach_speed) << "\n";
    o << ";ENDFOLD\n";
    o << "  $TOOL = " << krl_frame(X_ET) << "\n";
    o << "  $BASE = " << krl_frame(P.X_BW) << "\n";
    o << "  PTP " << axes(tr.q[idx[0]]) << "\n";
    if (P.motion == ProgramMotion::kJoint) {
      // Axis speeds and accelerations the trajectory needs, in percent of the limits.
      for (int j = 0; j < kNumJoints; ++j)
        o << "  $VEL_AXIS[" << j + 1 << "] = " << percent(max_dq[j] / robot.limits[j].velocity)
          << "\n";
      for (int j = 0; j < kNumJoints; ++j)
        o << "  $ACC_AXIS[" << j + 1 << "] = " << percent(max_ddq[j] / robot.limits[j].acceleration)
          << "\n";
      for (std::size_t i = 1; i < npts; ++i)
        o << "  PTP " << axes(tr.q[idx[i]]) << (i + 1 < npts ? " C_PTP" : "") << "\n";
    } else if (P.motion == ProgramMotion::kLinear) {
      double vcur = -1, wcur = -1;
      const auto changed = [&](double now, double cur) {
        return cur < 0 || std::abs(now - cur) > P.speed_change * cur;
      };
      for (std::size_t i = 1; i < npts; ++i) {
        const double v = segment_speed(i), w = segment_ori_speed(i);
        if (changed(v, vcur)) {
          o << "  $VEL.CP = " << fixed(v, 7) << "\n";
          vcur = v;
        }
        if (changed(w, wcur)) {
          o << "  $VEL.ORI1 = " << fixed(w * kRad2Deg, 4) << "\n";
          o << "  $VEL.ORI2 = " << fixed(w * kRad2Deg, 4) << "\n";
          wcur = w;
        }
        o << "  LIN " << krl_frame(X_WT[idx[i]]) << (i + 1 < npts ? " C_DIS" : "") << "\n";
      }
    } else {
      o << "  $VEL.CP = " << fixed(segment_speed(1), 7) << "\n";
      o << "  SPLINE\n";
      for (std::size_t i = 1; i < npts; ++i)
        o << "    SPL " << krl_frame(X_WT[idx[i]])
          << " WITH $VEL.CP = " << fixed(segment_speed(i), 7) << "\n";
      o << "  ENDSPLINE\n";
    }
    o << "END\n";
  } else if (P.dialect == ProgramDialect::kRapid) {
    write_rapid(o, robot, tr, P, X_ET, X_WT, idx, segment_speed, segment_ori_speed);
  } else {
    const auto joints = [&](const Vector6& q) {
      const Vector6 a = to_axes(q, P);
      std::string s = "[";
      for (int j = 0; j < kNumJoints; ++j) s += (j ? ", " : "") + ur(a[j]);
      return s + "]";
    };
    // A UR ramps the tool's turn at kUrOriPerSpeed rad/s² per m/s² of a: a turn-governed move
    // needs the plan's angular acceleration over that.
    const double a_cart = std::max({1.2 * max_path_accel, 1.2 * max_ori_accel / kUrOriPerSpeed, 0.1});
    const double a_joint = std::max(1.2 * max_ddq.maxCoeff(), 0.1);
    o << "def " << P.name << "():\n";
    o << "  # flashtwin robot program (URScript): " << npts << " motion points, "
      << fixed(tr.duration(), 3) << " s trajectory\n";
    o << "  # TCP: tool {T} in flange {E}; base_frame: work frame {W} in robot base {B}; m, rad,"
         " rotation vectors\n";
    o << "  # joint values are D-H joint angles mapped as sign*q + offset\n";
    o << "  set_tcp(" << ur_pose(X_ET) << ")\n";
    o << "  base_frame = " << ur_pose(P.X_BW) << "\n";
    o << "  movej(" << joints(tr.q[idx[0]]) << ", a=" << fixed(P.approach_speed * amin_joint, 4)
      << ", v=" << fixed(P.approach_speed * vmin_joint, 4) << ")\n";
    for (std::size_t i = 1; i < npts; ++i) {
      const bool last = i + 1 == npts;
      const std::string r = last ? "0" : fixed(P.blend_radius, 5);
      switch (P.motion) {
        case ProgramMotion::kLinear:
        case ProgramMotion::kSpline:
          o << "  " << (P.motion == ProgramMotion::kLinear ? "movel" : "movep")
            << "(pose_trans(base_frame, " << ur_pose(X_WT[idx[i]]) << "), a=" << fixed(a_cart, 4)
            << ", v=" << fixed(std::max(segment_speed(i), segment_ori_speed(i) / kUrOriPerSpeed), 7)
            << ", r=" << r << ")\n";
          break;
        case ProgramMotion::kJoint:
          o << "  movej(" << joints(tr.q[idx[i]]) << ", a=" << fixed(a_joint, 4)
            << ", v=" << fixed(segment_joint_speed(i), 5) << ", r=" << r << ")\n";
          break;
        case ProgramMotion::kServo: {
          const double t = static_cast<double>(idx[i] - idx[i - 1]) * tr.dt;
          o << "  servoj(" << joints(tr.q[idx[i]]) << ", t=" << fixed(t, 6)
            << ", lookahead_time=" << fixed(P.servo_lookahead, 4)
            << ", gain=" << fixed(P.servo_gain, 1) << ")\n";
          break;
        }
      }
    }
    if (P.motion == ProgramMotion::kServo) o << "  stopj(" << fixed(a_joint, 4) << ")\n";
    o << "end\n";
  }
  prog.text = o.str();
  return prog;
}

void write_program(const RobotProgram& program, const std::string& path) {
  std::ofstream f(path, std::ios::binary);
  if (!f) throw IoError(path + ": expected a writable file, got an error opening it");
  f << program.text;
  f.flush();
  if (!f) throw IoError(path + ": expected to write the program, got a write error");
}

std::string program_extension(ProgramDialect dialect) {
  switch (dialect) {
    case ProgramDialect::kKrl: return ".src";
    case ProgramDialect::kUrScript: return ".script";
    case ProgramDialect::kRapid: return ".mod";
  }
  return ".txt";
}

std::string export_program_file(const RobotModel& robot, const JointTrajectory& trajectory,
                                const ProgramParams& params, const std::string& dir) {
  const std::string path = dir + "/" + params.name + program_extension(params.dialect);
  write_program(export_program(robot, trajectory, params), path);
  return path;
}

// ---------------------------------------------------------------------------------------------
// Parsing

namespace {

// KRL aggregate "{X 1.0, Y 2.0, ...}" as upper-case key -> value.
std::map<std::string, double> krl_aggregate(const std::string& text, int line) {
  const auto b = text.find('{'), e = text.find('}');
  if (b == std::string::npos || e == std::string::npos || e < b)
    parse_error(line, "an aggregate {...}", trim(text));
  std::map<std::string, double> out;
  for (const std::string& part : split_top(text.substr(b + 1, e - b - 1))) {
    const auto sp = part.find_first_of(" \t");
    if (sp == std::string::npos) parse_error(line, "'KEY value' in the aggregate", part);
    const std::string key = upper(trim(part.substr(0, sp)));
    out[key] = parse_number(part.substr(sp + 1), line, key);
  }
  return out;
}

Pose krl_pose(const std::map<std::string, double>& agg, int line, const std::string& text) {
  KukaFrame f;
  double* dst[6] = {&f.x, &f.y, &f.z, &f.a, &f.b, &f.c};
  const char* keys[6] = {"X", "Y", "Z", "A", "B", "C"};
  for (int i = 0; i < 6; ++i) {
    const auto it = agg.find(keys[i]);
    if (it == agg.end()) parse_error(line, std::string("field ") + keys[i] + " in the frame", text);
    *dst[i] = it->second;
  }
  return pose_from_kuka_frame(f);
}

Vector6 krl_axes(const std::map<std::string, double>& agg, int line, const std::string& text) {
  Vector6 a;
  for (int j = 0; j < kNumJoints; ++j) {
    const auto it = agg.find("A" + std::to_string(j + 1));
    if (it == agg.end())
      parse_error(line, "field A" + std::to_string(j + 1) + " in the axis values", text);
    a[j] = it->second * kDeg2Rad;
  }
  return a;
}

// The value after "NAME =" in a KRL line (upper-cased line).
bool krl_assignment(const std::string& up, const std::string& var, std::string& value) {
  if (!starts_with(up, var)) return false;
  const std::string rest = trim(up.substr(var.size()));
  if (rest.empty() || rest[0] != '=') return false;
  value = trim(rest.substr(1));
  return true;
}

ParsedProgram parse_krl(const std::string& text, const ProgramParams& P) {
  ParsedProgram out;
  std::istringstream in(text);
  std::string raw;
  int line = 0;
  bool in_def = false, in_spline = false;
  std::string def_name;
  double vel_cp = 0, acc_cp = 0, vel_ori = 0, acc_ori = 0, apo_cdis = 0;
  while (std::getline(in, raw)) {
    ++line;
    std::string code = raw.substr(0, raw.find(';'));  // comments, folds
    code = trim(code);
    if (code.empty() || code[0] == '&') continue;  // header lines
    const std::string up = upper(code);
    const std::string first = up.substr(0, up.find_first_of(" \t{("));
    if (first == "DEF" || (first == "GLOBAL" && starts_with(up, "GLOBAL DEF"))) {
      if (in_def) parse_error(line, "END before the next DEF", code);
      const std::string after = trim(code.substr(up.find("DEF") + 3));
      const std::string name = trim(after.substr(0, after.find('(')));
      if (name.empty() || after.find('(') == std::string::npos)
        parse_error(line, "DEF name( )", code);
      in_def = true;
      def_name = name;
      if (out.routines == 0) out.name = name;
      continue;
    }
    if (up == "END") {
      if (!in_def) parse_error(line, "DEF before END", code);
      if (in_spline) parse_error(line, "ENDSPLINE before END", code);
      in_def = false;
      ++out.routines;
      continue;
    }
    if (!in_def) parse_error(line, "code inside DEF ... END", code);
    if (first == "SPLINE") {
      if (in_spline) parse_error(line, "ENDSPLINE before the next SPLINE", code);
      in_spline = true;
      continue;
    }
    if (first == "ENDSPLINE") {
      if (!in_spline) parse_error(line, "SPLINE before ENDSPLINE", code);
      in_spline = false;
      continue;
    }
    std::string value;
    if (krl_assignment(up, "$TOOL", value)) {
      out.X_ET = krl_pose(krl_aggregate(value, line), line, code);
      out.tool_declared = true;
      continue;
    }
    if (krl_assignment(up, "$BASE", value)) {
      out.X_BW = krl_pose(krl_aggregate(value, line), line, code);
      out.base_declared = true;
      continue;
    }
    if (krl_assignment(up, "$VEL.CP", value)) {
      vel_cp = parse_number(value, line, "$VEL.CP");
      continue;
    }
    if (krl_assignment(up, "$ACC.CP", value)) {
      acc_cp = parse_number(value, line, "$ACC.CP");
      continue;
    }
    if (krl_assignment(up, "$VEL.ORI1", value)) {
      vel_ori = parse_number(value, line, "$VEL.ORI1") * kDeg2Rad;
      continue;
    }
    if (krl_assignment(up, "$ACC.ORI1", value)) {
      acc_ori = parse_number(value, line, "$ACC.ORI1") * kDeg2Rad;
      continue;
    }
    if (krl_assignment(up, "$APO.CDIS", value)) {
      apo_cdis = parse_number(value, line, "$APO.CDIS") / 1000.0;
      continue;
    }
    if (first == "PTP" || first == "LIN" || first == "SPL" || first == "SPTP" || first == "SLIN") {
      if (first == "SPL" && !in_spline) parse_error(line, "SPL inside SPLINE ... ENDSPLINE", code);
      const auto agg = krl_aggregate(up, line);
      ProgramPoint pt;
      pt.instruction = first;
      pt.line = line;
      if (agg.count("A1")) {
        pt.q = from_axes(krl_axes(agg, line, code), P);
      } else {
        pt.cartesian = true;
        pt.X_WT = krl_pose(agg, line, code);
        pt.speed = vel_cp;
        pt.accel = acc_cp;
        pt.ori_speed = vel_ori;
        pt.ori_accel = acc_ori;
      }
      if (up.find("C_DIS") != std::string::npos) pt.blend = apo_cdis;
      const auto with = up.find("WITH");
      if (with != std::string::npos) {
        std::string v;
        const std::string tail = trim(up.substr(with + 4));
        if (krl_assignment(tail, "$VEL.CP", v)) pt.speed = parse_number(v, line, "$VEL.CP");
      }
      out.points.push_back(pt);
      continue;
    }
    // Anything else (system variable set-up, BAS calls) does not concern the motion.
  }
  if (in_spline) parse_error(line, "ENDSPLINE", "end of text");
  if (in_def) parse_error(line, "END closing DEF " + def_name, "end of text");
  if (out.routines == 0) parse_error(line, "a DEF ... END routine", "none");
  return out;
}

// URScript "p[...]" (possibly inside pose_trans(base_frame, p[...])) -> pose.
UrPose ur_pose_list(const std::string& s, int line) {
  const auto b = s.find("p["), e = s.find(']', b == std::string::npos ? 0 : b);
  if (b == std::string::npos || e == std::string::npos) parse_error(line, "a pose p[...]", s);
  const auto parts = split_top(s.substr(b + 2, e - b - 2));
  if (parts.size() != 6) parse_error(line, "6 numbers in p[...]", s);
  UrPose p;
  for (int i = 0; i < 6; ++i) p[i] = parse_number(parts[i], line, "pose");
  return p;
}

Vector6 ur_joint_list(const std::string& s, int line) {
  const auto b = s.find('['), e = s.find(']');
  if (b == std::string::npos || e == std::string::npos) parse_error(line, "a joint list [...]", s);
  const auto parts = split_top(s.substr(b + 1, e - b - 1));
  if (parts.size() != 6) parse_error(line, "6 joint values in [...]", s);
  Vector6 q;
  for (int j = 0; j < 6; ++j) q[j] = parse_number(parts[j], line, "joint value");
  return q;
}

ParsedProgram parse_urscript(const std::string& text, const ProgramParams& P) {
  ParsedProgram out;
  std::istringstream in(text);
  std::string raw;
  int line = 0, depth = 0;
  std::string def_name;
  while (std::getline(in, raw)) {
    ++line;
    std::string code = trim(raw.substr(0, raw.find('#')));
    if (code.empty()) continue;
    const std::string first = code.substr(0, code.find_first_of(" \t(:"));
    if (first == "def" || first == "thread") {
      if (first == "def" && depth == 0) {
        const auto paren = code.find('(');
        if (paren == std::string::npos || code.back() != ':')
          parse_error(line, "def name():", code);
        def_name = trim(code.substr(4, paren - 4));
        if (out.routines == 0) out.name = def_name;
      }
      ++depth;
      continue;
    }
    if (first == "if" || first == "while" || first == "for") {
      ++depth;
      continue;
    }
    if (code == "end") {
      if (depth == 0) parse_error(line, "def before end", code);
      if (--depth == 0) ++out.routines;
      continue;
    }
    if (depth == 0) parse_error(line, "code inside def ... end", code);
    if (first == "set_tcp") {
      out.X_ET = pose_from_ur_pose(ur_pose_list(code, line));
      out.tool_declared = true;
      continue;
    }
    {
      std::string c = code;
      if (starts_with(c, "global ")) c = trim(c.substr(7));
      if (starts_with(c, "local ")) c = trim(c.substr(6));
      if (starts_with(c, "base_frame") && c.find('=') != std::string::npos &&
          trim(c.substr(10)).rfind('=', 0) == 0) {
        out.X_BW = pose_from_ur_pose(ur_pose_list(c, line));
        out.base_declared = true;
        continue;
      }
    }
    if (first == "movel" || first == "movep" || first == "movej" || first == "servoj") {
      const auto b = code.find('('), e = code.rfind(')');
      if (b == std::string::npos || e == std::string::npos || e < b)
        parse_error(line, first + "(...)", code);
      const auto args = split_top(code.substr(b + 1, e - b - 1));
      if (args.empty()) parse_error(line, "a target in " + first, code);
      ProgramPoint pt;
      pt.instruction = first;
      pt.line = line;
      const std::string& target = args[0];
      if (starts_with(target, "pose_trans(") || starts_with(target, "p[")) {
        pt.cartesian = true;
        const Pose X = pose_from_ur_pose(ur_pose_list(target, line));
        // pose_trans(base_frame, p) is already in {W}; a bare pose is in the robot base {B}.
        pt.X_WT = starts_with(target, "p[") ? out.X_BW.inverse() * X : X;
      } else {
        pt.q = from_axes(ur_joint_list(target, line), P);
      }
      for (std::size_t i = 1; i < args.size(); ++i) {
        const auto eq = args[i].find('=');
        if (eq == std::string::npos) continue;
        const std::string key = trim(args[i].substr(0, eq));
        if (key == "v") pt.speed = parse_number(args[i].substr(eq + 1), line, "v");
        if (key == "v" && pt.cartesian) pt.ori_speed = kUrOriPerSpeed * pt.speed;
        if (key == "t") pt.period = parse_number(args[i].substr(eq + 1), line, "t");
        if (key == "a") pt.accel = parse_number(args[i].substr(eq + 1), line, "a");
        if (key == "a" && pt.cartesian) pt.ori_accel = kUrOriPerSpeed * pt.accel;
        if (key == "r") pt.blend = parse_number(args[i].substr(eq + 1), line, "r");
      }
      out.points.push_back(pt);
      continue;
    }
  }
  if (depth != 0) parse_error(line, "end closing def " + def_name, "end of text");
  if (out.routines == 0) parse_error(line, "a def ... end routine", "none");
  return out;
}

// RAPID data aggregate: a number/boolean/string leaf or a bracketed list.
struct RapidValue {
  bool list = false;
  double number = 0;
  std::vector<RapidValue> items;
};

RapidValue rapid_value(const std::string& text, int line) {
  const std::string t = trim(text);
  RapidValue v;
  if (!t.empty() && t.front() == '[') {
    if (t.back() != ']') parse_error(line, "a closing ] in the aggregate", t);
    v.list = true;
    for (const std::string& part : split_top(t.substr(1, t.size() - 2)))
      v.items.push_back(rapid_value(part, line));
    return v;
  }
  const std::string u = upper(t);
  if (u == "TRUE" || u == "FALSE") {
    v.number = u == "TRUE";
  } else if (!t.empty() && t.front() == '"') {
    v.number = 0;  // a string (wobjdata's ufprog/ufmec)
  } else {
    v.number = parse_number(t, line, "a RAPID value");
  }
  return v;
}

// Item `i` of a list, checked.
const RapidValue& rapid_item(const RapidValue& v, std::size_t i, int line, const char* what) {
  if (!v.list || v.items.size() <= i) parse_error(line, what, "a shorter aggregate");
  return v.items[i];
}

// [[x, y, z], [q1, q2, q3, q4]] (mm, quaternion w x y z) as a pose [m].
Pose rapid_pose(const RapidValue& pos, const RapidValue& rot, int line) {
  Pose X = Pose::Identity();
  for (int k = 0; k < 3; ++k)
    X.translation()[k] = rapid_item(pos, k, line, "[x, y, z]").number / 1000.0;
  Eigen::Quaterniond q(rapid_item(rot, 0, line, "[q1, q2, q3, q4]").number,
                       rapid_item(rot, 1, line, "[q1, q2, q3, q4]").number,
                       rapid_item(rot, 2, line, "[q1, q2, q3, q4]").number,
                       rapid_item(rot, 3, line, "[q1, q2, q3, q4]").number);
  if (!(q.norm() > 0.5)) parse_error(line, "a unit quaternion", "a near-zero one");
  X.linear() = q.normalized().toRotationMatrix();
  return X;
}

// A zonedata argument's TCP zone [m]: fine (0), a predefined zN (N mm) or an aggregate's
// pzone_tcp.
double rapid_zone_radius(const std::string& arg, int line) {
  const std::string z = upper(trim(arg));
  if (z == "FINE") return 0;
  if (!z.empty() && z.front() == '[')
    return rapid_item(rapid_value(z, line), 1, line, "zonedata").number / 1000.0;
  if (z.size() > 1 && z.front() == 'Z') return parse_number(z.substr(1), line, "zonedata") / 1000.0;
  parse_error(line, "a zone: fine, zN or [finep, pzone_tcp, ...]", arg);
}

ParsedProgram parse_rapid(const std::string& text, const ProgramParams& P) {
  ParsedProgram out;
  std::istringstream in(text);
  std::string raw;
  int line = 0;
  bool in_module = false, in_proc = false;
  while (std::getline(in, raw)) {
    ++line;
    std::string code = trim(raw.substr(0, raw.find('!')));
    if (code.empty()) continue;
    if (code.back() == ';') code = trim(code.substr(0, code.size() - 1));
    const std::string up = upper(code);
    const std::string first = up.substr(0, up.find_first_of(" \t"));
    if (first == "MODULE") {
      if (in_module) parse_error(line, "ENDMODULE before the next MODULE", code);
      in_module = true;
      if (out.name.empty()) out.name = trim(code.substr(6));
      continue;
    }
    if (first == "ENDMODULE") {
      if (!in_module || in_proc) parse_error(line, "MODULE (and ENDPROC) before ENDMODULE", code);
      in_module = false;
      continue;
    }
    if (!in_module) parse_error(line, "code inside MODULE ... ENDMODULE", code);
    if (first == "PROC") {
      if (in_proc) parse_error(line, "ENDPROC before the next PROC", code);
      in_proc = true;
      continue;
    }
    if (first == "ENDPROC") {
      if (!in_proc) parse_error(line, "PROC before ENDPROC", code);
      in_proc = false;
      ++out.routines;
      continue;
    }
    const auto assign = code.find(":=");
    if ((first == "PERS" || first == "CONST" || first == "VAR") && assign != std::string::npos) {
      const RapidValue v = rapid_value(code.substr(assign + 2), line);
      if (up.find("TOOLDATA") != std::string::npos) {
        const RapidValue& tframe = rapid_item(v, 1, line, "tooldata [robhold, tframe, tload]");
        out.X_ET = rapid_pose(rapid_item(tframe, 0, line, "tframe"), rapid_item(tframe, 1, line, "tframe"), line);
        out.tool_declared = true;
      } else if (up.find("WOBJDATA") != std::string::npos) {
        const RapidValue& uframe = rapid_item(v, 3, line, "wobjdata [.., .., .., uframe, oframe]");
        out.X_BW = rapid_pose(rapid_item(uframe, 0, line, "uframe"), rapid_item(uframe, 1, line, "uframe"), line);
        out.base_declared = true;
      }
      continue;
    }
    if (first == "MOVEABSJ" || first == "MOVEL" || first == "MOVEJ") {
      if (!in_proc) parse_error(line, "a motion inside PROC ... ENDPROC", code);
      const auto args = split_top(trim(code.substr(first.size())));
      if (args.size() < 4) parse_error(line, "target, speed, zone and tool", code);
      ProgramPoint pt;
      pt.instruction = code.substr(0, first.size());
      pt.line = line;
      const RapidValue target = rapid_value(args[0], line);
      if (first == "MOVEABSJ") {
        const RapidValue& ax = rapid_item(target, 0, line, "jointtarget [[robax], [extax]]");
        Vector6 a;
        for (int j = 0; j < kNumJoints; ++j) a[j] = rapid_item(ax, j, line, "six axis values").number * kDeg2Rad;
        pt.q = from_axes(a, P);
      } else {
        pt.cartesian = true;
        pt.X_WT = rapid_pose(rapid_item(target, 0, line, "robtarget [trans, rot, ...]"),
                             rapid_item(target, 1, line, "robtarget [trans, rot, ...]"), line);
      }
      if (!args[1].empty() && args[1].front() == '[') {
        const RapidValue speed = rapid_value(args[1], line);
        pt.speed = rapid_item(speed, 0, line, "speeddata").number / 1000.0;
        pt.ori_speed = rapid_item(speed, 1, line, "speeddata").number * kDeg2Rad;
      }
      pt.blend = rapid_zone_radius(args[2], line);
      out.points.push_back(pt);
      continue;
    }
  }
  if (in_proc || in_module) parse_error(line, "ENDPROC and ENDMODULE", "end of text");
  if (out.routines == 0) parse_error(line, "a PROC ... ENDPROC routine", "none");
  return out;
}

}  // namespace

ParsedProgram parse_program(const std::string& text, const ProgramParams& params) {
  switch (params.dialect) {
    case ProgramDialect::kKrl: return parse_krl(text, params);
    case ProgramDialect::kRapid: return parse_rapid(text, params);
    case ProgramDialect::kUrScript: break;
  }
  return parse_urscript(text, params);
}

}  // namespace flashtwin::planner
