#include "flashtwin/sim/executor.hpp"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <deque>
#include <optional>
#include <string>

#include "flashtwin/core/format.hpp"
#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/ft_sensor.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"

namespace flashtwin::sim {

namespace {

[[noreturn]] void bad(const std::string& field, const std::string& expected, double got) {
  throw ArgumentError("execution." + field + ": expected " + expected + ", got " +
                      std::to_string(got));
}

// What the loop needs from the model: indices of the contract names and the servo gains.
struct CellIndex {
  int qadr[kNumJoints], dadr[kNumJoints], act[kNumJoints];
  double lo[kNumJoints], hi[kNumJoints];
  bool limited[kNumJoints];
  double kp[kNumJoints];
  int tcp = -1, tool = -1, casting = -1;
  int force_adr = -1, torque_adr = -1, force_site = -1;
};

CellIndex index_model(const mjModel* m) {
  CellIndex c;
  for (int i = 0; i < kNumJoints; ++i) {
    const std::string jname = "joint" + std::to_string(i + 1);
    const int j = require_id(m, mjOBJ_JOINT, jname);
    if (m->jnt_type[j] != mjJNT_HINGE)
      throw InputError("model: expected joint '" + jname + "' to be a hinge");
    c.qadr[i] = m->jnt_qposadr[j];
    c.dadr[i] = m->jnt_dofadr[j];
    c.limited[i] = m->jnt_limited[j] != 0;
    c.lo[i] = c.limited[i] ? m->jnt_range[2 * j] : -1e300;
    c.hi[i] = c.limited[i] ? m->jnt_range[2 * j + 1] : 1e300;

    const std::string aname = "act" + std::to_string(i + 1);
    const int a = require_id(m, mjOBJ_ACTUATOR, aname);
    const double kp = m->actuator_gainprm[a * mjNGAIN];
    const bool servo = m->actuator_trntype[a] == mjTRN_JOINT && m->actuator_trnid[2 * a] == j &&
                       m->actuator_gaintype[a] == mjGAIN_FIXED &&
                       m->actuator_biastype[a] == mjBIAS_AFFINE && kp > 0 &&
                       std::abs(m->actuator_biasprm[a * mjNBIAS + 1] + kp) <= 1e-9 * kp &&
                       std::abs(m->actuator_gear[6 * a] - 1.0) <= 1e-12;
    if (!servo)
      throw InputError("model: expected actuator '" + aname +
                       "' to be a position servo (kp > 0, gear 1) on '" + jname + "'");
    c.act[i] = a;
    c.kp[i] = kp;
  }
  c.tcp = require_id(m, mjOBJ_SITE, "tcp");
  c.tool = require_id(m, mjOBJ_BODY, "tool");
  c.casting = require_id(m, mjOBJ_BODY, "casting");
  const int fs = mj_name2id(m, mjOBJ_SENSOR, "flange_force");
  const int ts = mj_name2id(m, mjOBJ_SENSOR, "flange_torque");
  if (fs >= 0 && m->sensor_type[fs] == mjSENS_FORCE && m->sensor_objtype[fs] == mjOBJ_SITE) {
    c.force_adr = m->sensor_adr[fs];
    c.force_site = m->sensor_objid[fs];
  }
  if (ts >= 0 && m->sensor_type[ts] == mjSENS_TORQUE && m->sensor_objtype[ts] == mjOBJ_SITE &&
      m->sensor_objid[ts] == c.force_site)
    c.torque_adr = m->sensor_adr[ts];
  return c;
}

Vec3 vec3_at(const mjtNum* p) {
  return Vec3(p[0], p[1], p[2]);
}

Mat3 mat3_at(const mjtNum* p) {
  Mat3 R;
  for (int r = 0; r < 3; ++r)
    for (int k = 0; k < 3; ++k) R(r, k) = p[3 * r + k];
  return R;
}

Pose pose_of(const mjtNum* pos, const mjtNum* mat) {
  Pose X = Pose::Identity();
  X.translation() = vec3_at(pos);
  X.linear() = mat3_at(mat);
  return X;
}

// Reference of one instant: position, velocity, acceleration.
struct Reference {
  Vector6 q, dq, ddq;
};

// Cubic Hermite interpolation through (t_k, q_k, dq_k); the last sample is held at rest after
// the end. `seg` caches the segment of the previous (earlier or equal) time.
Reference reference_at(const JointTrajectory& tr, const std::vector<Vector6>& dq, double t,
                       std::size_t& seg) {
  const std::size_t n = tr.t.size();
  Reference r;
  if (n == 1 || t >= tr.t.back()) {
    r.q = tr.q.back();
    r.dq.setZero();
    r.ddq.setZero();
    return r;
  }
  if (t <= tr.t.front()) t = tr.t.front();
  while (seg + 2 < n && tr.t[seg + 1] <= t) ++seg;
  const double h = tr.t[seg + 1] - tr.t[seg];
  const double s = (t - tr.t[seg]) / h, s2 = s * s, s3 = s2 * s;
  const Vector6 &q0 = tr.q[seg], &q1 = tr.q[seg + 1];
  const Vector6 v0 = dq[seg] * h, v1 = dq[seg + 1] * h;
  r.q = (2 * s3 - 3 * s2 + 1) * q0 + (s3 - 2 * s2 + s) * v0 + (-2 * s3 + 3 * s2) * q1 +
        (s3 - s2) * v1;
  r.dq = ((6 * s2 - 6 * s) * q0 + (3 * s2 - 4 * s + 1) * v0 + (-6 * s2 + 6 * s) * q1 +
          (3 * s2 - 2 * s) * v1) /
         h;
  r.ddq = ((12 * s - 6) * q0 + (6 * s - 4) * v0 + (-12 * s + 6) * q1 + (6 * s - 2) * v1) / (h * h);
  return r;
}

// Planned TCP position, linear between samples, held at the ends.
Vec3 planned_position_at(const JointTrajectory& tr, double t, std::size_t& seg) {
  const std::size_t n = tr.t.size();
  if (n == 1 || t >= tr.t.back()) return tr.planned_tcp_W.back().translation();
  if (t <= tr.t.front()) return tr.planned_tcp_W.front().translation();
  while (seg + 2 < n && tr.t[seg + 1] <= t) ++seg;
  const double s = (t - tr.t[seg]) / (tr.t[seg + 1] - tr.t[seg]);
  return (1 - s) * tr.planned_tcp_W[seg].translation() +
         s * tr.planned_tcp_W[seg + 1].translation();
}

void check_trajectory(const JointTrajectory& tr) {
  const std::size_t n = tr.t.size();
  if (n == 0) throw ArgumentError("execution.trajectory: expected at least 1 sample, got 0");
  auto shape = [&](const char* field, std::size_t got, bool may_be_empty) {
    if (got != n && !(may_be_empty && got == 0))
      throw ArgumentError(std::string("execution.trajectory.") + field + ": expected " +
                          std::to_string(n) + (may_be_empty ? " (or 0)" : "") +
                          " samples like t, got " + std::to_string(got));
  };
  shape("q", tr.q.size(), false);
  shape("dq", tr.dq.size(), true);
  shape("planned_tcp_W", tr.planned_tcp_W.size(), true);
  for (std::size_t k = 0; k < n; ++k) {
    if (!std::isfinite(tr.t[k]) || (k > 0 && !(tr.t[k] > tr.t[k - 1])))
      throw ArgumentError(
          "execution.trajectory.t: expected finite, strictly increasing times, got " +
          std::to_string(tr.t[k]) + " at sample " + std::to_string(k));
    if (!tr.q[k].allFinite() || (!tr.dq.empty() && !tr.dq[k].allFinite()) ||
        (!tr.planned_tcp_W.empty() && !tr.planned_tcp_W[k].matrix().allFinite()))
      throw ArgumentError("execution.trajectory: expected finite values, got NaN/inf at sample " +
                          std::to_string(k));
  }
  for (std::size_t k = 0; k < tr.tare_t.size(); ++k)
    if (!std::isfinite(tr.tare_t[k]) || (k > 0 && !(tr.tare_t[k] > tr.tare_t[k - 1])))
      throw ArgumentError(
          "execution.trajectory.tare_t: expected finite, strictly increasing times, got " +
          std::to_string(tr.tare_t[k]) + " at entry " + std::to_string(k));
}

// Velocities by finite differences (central inside, one-sided at the ends) when none are given.
std::vector<Vector6> velocities(const JointTrajectory& tr) {
  if (!tr.dq.empty()) return tr.dq;
  const std::size_t n = tr.t.size();
  std::vector<Vector6> dq(n, Vector6::Zero());
  if (n < 2) return dq;
  for (std::size_t k = 0; k < n; ++k) {
    const std::size_t a = k == 0 ? 0 : k - 1, b = k + 1 == n ? n - 1 : k + 1;
    dq[k] = (tr.q[b] - tr.q[a]) / (tr.t[b] - tr.t[a]);
  }
  return dq;
}

// Unit vector from a point to the tool axis, perpendicular to it (along the axis into the shank
// when the point lies on it): the process model's normal direction (grinding_force).
Vec3 towards_axis(const ToolParams& tool, const Pose& X_CT, const Vec3& p_C) {
  const Vec3 a = (tool.axis_sign * X_CT.linear().col(2)).normalized();
  const Vec3 w = X_CT.translation() - p_C;
  const Vec3 perp = w - a.dot(w) * a;
  const double len = perp.norm();
  return len > 1e-3 * tool.radius ? Vec3(perp / len) : a;
}

// The tool's penetration of the nominal body at the last removal step, all in {C}: its depth,
// the direction of the penalty force n (contact centroid → tool axis), the unit vector `inward`
// from the nominal surface to the deepest body point inside the tool, the TCP position then,
// and the contact centroid relative to the TCP (it moves with the tool).
struct PenaltyContact {
  double depth = 0;  // [m]
  Vec3 n_C = Vec3::Zero(), inward_C = Vec3::Zero(), p_C = Vec3::Zero(), arm_C = Vec3::Zero();
  // Depth with the TCP at p: the deepest point moves with the tool, the surface taken as the
  // tangent plane at its closest surface point.
  double depth_at(const Vec3& p) const { return std::max(0.0, depth + inward_C.dot(p - p_C)); }
};

// Unit vector from the nominal surface to an interior point (the closest surface point's
// direction); `fallback` when the point lies on the surface.
Vec3 inward_direction(const MeshBvh& nominal, const Vec3& p_C, const Vec3& fallback) {
  const ClosestPoint cp = nominal.closest(p_C);
  const Vec3 d = p_C - cp.point;
  return d.norm() > 1e-9 ? Vec3(d.normalized()) : fallback;
}

// The cutter's deepest penetration of the nominal (CAD) body where the voxel grid does not track
// the body (no BODY or GOUGE voxel 1.5 voxels below the closest surface point): away from the
// fins and their band the voxels hold no steel, and only this check sees the tool in it. Where
// the grid does track it, the voxels hold the body's first body_band only: the part of a deeper
// penetration beyond that band counts here (`beyond`: the band the voxels already push with). The
// cutter is the set of points within its radius of the axis from u0 (the ball tip's centre, or
// the flat tip) to its length, sampled every kSpacing; closest points beyond the cutting length
// (the shank) or below a flat tip are left out. A sample's side of the surface is taken from the
// closest triangle's normal (exact on faces and convex edges). Found within kReach of the
// cutter's surface only: an axis deeper than that in steel went through a contact first.
struct CadContact {
  double depth = 0;            // [m] below the CAD surface
  double beyond = 0;           // [m] of that the voxels account for (0 where they track none)
  Vec3 q_C = Vec3::Zero();     // closest surface point
  Vec3 n_C = Vec3::Zero();     // direction of the push on the tool (out of the body)
};

CadContact untracked_contact(const ToolParams& tool, const MaterialGrid& grid, const Pose& X_CT) {
  constexpr double kSpacing = 0.5e-3, kReach = 2e-3;
  const MeshBvh& bvh = grid.nominal();
  const TriangleMesh& mesh = bvh.mesh();  // outward-oriented (MaterialGrid's precondition)
  const Vec3 a = (tool.axis_sign * X_CT.linear().col(2)).normalized();
  const Vec3 tip = X_CT.translation();
  const double r = tool.radius, u0 = tool.end == ToolEnd::kBall ? r : 0.0;
  const auto n_samples = static_cast<int>(std::ceil((tool.length - u0) / kSpacing)) + 1;
  CadContact best;
  int hint = -1;
  for (int i = 0; i < n_samples; ++i) {
    const double u = n_samples > 1 ? u0 + (tool.length - u0) * i / (n_samples - 1) : u0;
    const Vec3 x = tip + u * a;
    const ClosestPoint cp = bvh.closest(x, r + kReach, hint);
    if (cp.triangle < 0) continue;
    hint = cp.triangle;
    const double u_q = (cp.point - tip).dot(a);
    if (u_q < -1e-9 || u_q > tool.length) continue;
    const Vec3 nf = mesh.triangle_normal(static_cast<std::size_t>(cp.triangle));
    const bool inside = (x - cp.point).dot(nf) < 0;
    const double depth = inside ? r + cp.distance : r - cp.distance;
    if (depth <= best.depth - best.beyond) continue;  // cannot win, band or not
    const VoxelLabel below = grid.label_at(cp.point - 1.5 * grid.voxel_size() * nf);
    const double band =
        below == VoxelLabel::kBody || below == VoxelLabel::kGouge ? grid.params().body_band : 0.0;
    if (depth - band <= best.depth - best.beyond) continue;
    const Vec3 d = inside ? Vec3(cp.point - x) : Vec3(x - cp.point);
    best = {depth, band, cp.point, d.norm() > 1e-12 ? Vec3(d.normalized()) : nf};
  }
  return best;
}

// How far the tool moved between two poses, for the removal and CAD-check triggers [m]:
// translation plus rotation times the cutter's length.
double tool_motion(const Pose& a, const Pose& b, const ToolParams& tool) {
  return (a.translation() - b.translation()).norm() +
         rotation_distance(a.linear(), b.linear()) * tool.length;
}

// The rate (grinding) part of a process wrench in {C}, torque about the TCP.
struct RateWrench {
  Vec3 force = Vec3::Zero(), torque = Vec3::Zero();
  double normal = 0, tangential = 0;
  RateWrench scaled(double s) const { return {s * force, s * torque, s * normal, s * tangential}; }
  void add(const RateWrench& o) {
    force += o.force;
    torque += o.torque;
    normal += o.normal;
    tangential += o.tangential;
  }
};

// One removal interval: distance travelled, displacement ({C}) and the rate wrench's impulse.
struct RemovalInterval {
  double ds = 0;
  Vec3 dp_C = Vec3::Zero();
  RateWrench impulse;  // [N·s], [N·m·s]
};

// True when some geom on a body that moves (not welded to the world) can collide with anything.
bool moving_geoms_collide(const mjModel* m) {
  for (int g = 0; g < m->ngeom; ++g)
    if ((m->geom_contype[g] || m->geom_conaffinity[g]) && m->body_weldid[m->geom_bodyid[g]] != 0)
      return true;
  return false;
}

bool bad_state(const mjModel* m, const mjData* d) {
  if (d->warning[mjWARN_BADQACC].number > 0 || d->warning[mjWARN_BADQPOS].number > 0 ||
      d->warning[mjWARN_BADQVEL].number > 0)
    return true;
  for (int i = 0; i < m->nq; ++i)
    if (!std::isfinite(d->qpos[i])) return true;
  return false;
}

}  // namespace

const char* to_string(CompensationSource source) {
  return source == CompensationSource::kSensor ? "sensor" : "process_model";
}

const char* to_string(ExecStatus status) {
  switch (status) {
    case ExecStatus::kOk:
      return "ok";
    case ExecStatus::kReferenceClamped:
      return "reference_clamped";
    case ExecStatus::kUnstable:
      return "unstable";
    case ExecStatus::kForceLimit:
      return "force_limit";
  }
  return "?";
}

void check_exec_params(const ExecParams& p) {
  if (!(std::isfinite(p.timestep) && p.timestep >= 0 && p.timestep <= 1e-3))
    bad("timestep", "0 (the model's) or a step in (0, 0.001] [s]", p.timestep);
  if (!(std::isfinite(p.settle_time) && p.settle_time >= 0))
    bad("settle_time", "a finite time >= 0 [s]", p.settle_time);
  if (p.log_decimation < 1) bad("log_decimation", "an integer >= 1", p.log_decimation);
  if (!(std::isfinite(p.limit_margin) && p.limit_margin >= 0))
    bad("limit_margin", "a finite angle >= 0 [rad]", p.limit_margin);
  if (!(std::isfinite(p.joint_tolerance) && p.joint_tolerance >= 0))
    bad("joint_tolerance", "a finite angle >= 0 [rad]", p.joint_tolerance);
  if (!(std::isfinite(p.removal_motion) && p.removal_motion >= 0))
    bad("removal_motion", "a finite number of voxels >= 0", p.removal_motion);
  if (!(std::isfinite(p.removal_contact_motion) && p.removal_contact_motion >= 0))
    bad("removal_contact_motion", "a finite number of voxels >= 0", p.removal_contact_motion);
  if (!(std::isfinite(p.removal_max_interval) && p.removal_max_interval > 0))
    bad("removal_max_interval", "a finite time > 0 [s]", p.removal_max_interval);
  if (!(std::isfinite(p.cad_check_motion) && p.cad_check_motion >= 0))
    bad("cad_check_motion", "a finite distance >= 0 [m]", p.cad_check_motion);
  if (!(std::isfinite(p.max_force) && p.max_force >= 0)) bad("max_force", "a finite force >= 0 [N] (0: off)", p.max_force);
  if (!(std::isfinite(p.rate_window) && p.rate_window >= 0.5))
    bad("rate_window", "a finite number of voxels >= 0.5", p.rate_window);
  const ForceControlParams& f = p.force_control;
  if (!(std::isfinite(f.target_force) && f.target_force >= 0))
    bad("force_control.target_force", "a finite force >= 0 [N]", f.target_force);
  if (!(std::isfinite(f.gain) && f.gain >= 0))
    bad("force_control.gain", "a finite gain >= 0 [m/(N*s)]", f.gain);
  if (!(std::isfinite(f.max_correction) && f.max_correction >= 0))
    bad("force_control.max_correction", "a finite distance >= 0 [m]", f.max_correction);
  if (!(std::isfinite(f.release_time) && f.release_time > 0))
    bad("force_control.release_time", "a finite time > 0 [s]", f.release_time);
  if (!(std::isfinite(f.contact_force) && f.contact_force >= 0))
    bad("force_control.contact_force", "a finite force >= 0 [N]", f.contact_force);
  if (!(std::isfinite(p.tcp_damping) && p.tcp_damping >= 0))
    bad("tcp_damping", "a finite damping >= 0 [N*s/m]", p.tcp_damping);
  check_ft_sensor_params(p.sensor);
  if (!p.tcp_offset_T.allFinite()) bad("tcp_offset_T", "a finite offset [m]", p.tcp_offset_T.norm());
  if (!(p.sensor_step_E.force.allFinite() && p.sensor_step_E.torque.allFinite()))
    bad("sensor_step_E", "a finite wrench [N, N*m]", p.sensor_step_E.force.norm());
}

ExecutionResult execute_trajectory(const std::string& mjcf_path, const JointTrajectory& trajectory,
                                   MaterialGrid* grid, const ToolParams& tool,
                                   const ForceParams& force, const ExecParams& params) {
  const MjModelPtr m = load_mjcf_file(mjcf_path);
  return execute_trajectory(*m, trajectory, grid, tool, force, params);
}

ExecutionResult execute_trajectory(const mjModel& model, const JointTrajectory& trajectory,
                                   MaterialGrid* grid, const ToolParams& tool,
                                   const ForceParams& force, const ExecParams& params) {
  check_exec_params(params);
  check_trajectory(trajectory);
  check_tool_params(tool);
  check_force_params(force);
  const double h = params.timestep > 0 ? params.timestep : model.opt.timestep;
  if (!(h > 0 && h <= 1e-3 * (1 + 1e-12)))
    bad("timestep", "a MuJoCo step <= 0.001 s (>= 1 kHz); the model's is too long", h);
  if (!params.start_qpos.empty() &&
      (params.start_qpos.size() != static_cast<std::size_t>(model.nq) ||
       params.start_qvel.size() != static_cast<std::size_t>(model.nv)))
    bad("start_qpos", "the model's nq positions and nv velocities", static_cast<double>(params.start_qpos.size()));

  // Our own copy: the step may change and the servos' ctrlrange is lifted so the feed-forward
  // offset can ride on ctrl (references are clamped here; forcerange still limits torque).
  const MjModelPtr mp(mj_copyModel(nullptr, &model));
  mjModel* m = mp.get();
  m->opt.timestep = h;
  const CellIndex c = index_model(m);
  const bool reads_sensor =
      params.load_compensation || params.force_control.enabled || params.max_force > 0;
  const bool has_sensor = c.force_adr >= 0 && c.torque_adr >= 0 && m->site_bodyid[c.force_site] == c.tool;
  if (reads_sensor && !has_sensor)
    throw InputError("model: the controller reads the flange F/T sensor (load compensation, force "
                     "control or the protective stop): expected sensors 'flange_force' and "
                     "'flange_torque' on one site of body 'tool'");
  for (int i = 0; i < kNumJoints; ++i) m->actuator_ctrllimited[c.act[i]] = 0;
  // The process model is the tool's only contact. When no geom of a moving body can collide
  // (the cell's contract: arm geoms have contype = conaffinity = 0), MuJoCo's collision pass
  // finds nothing and is skipped, with identical results.
  if (!moving_geoms_collide(m)) m->opt.disableflags |= mjDSBL_CONTACT;
  const MjDataPtr data_ptr = make_data(m);
  mjData* d = data_ptr.get();
  // Inverse dynamics at the reference, as a robot controller's model computes it: the rigid arm
  // without contacts or constraints (which also spares the collision pass every step); its
  // sensors are not read.
  const MjModelPtr mffp(mj_copyModel(nullptr, m));
  mjModel* mff = mffp.get();
  mff->opt.disableflags |= mjDSBL_CONSTRAINT | mjDSBL_CONTACT | mjDSBL_SENSOR;
  const MjDataPtr ffp = make_data(mff);
  mjData* dff = ffp.get();

  const std::vector<Vector6> dq_samples = velocities(trajectory);
  const double t0 = trajectory.t.front();
  const std::size_t n_samples = trajectory.t.size();
  const bool tracking = !trajectory.planned_tcp_W.empty();
  const ForceControlParams& fc = params.force_control;
  const double margin = params.limit_margin, tol = params.joint_tolerance;

  ExecutionResult res;
  res.timestep = h;

  // Joint-range clamp of a command; flags the first clamp.
  auto clamp_command = [&](Vector6& q, Vector6* dq, Vector6* ddq, double t) {
    bool any = false;
    for (int i = 0; i < kNumJoints; ++i) {
      if (!c.limited[i]) continue;
      const double lo = std::min(c.lo[i] + margin, 0.5 * (c.lo[i] + c.hi[i]));
      const double hi = std::max(c.hi[i] - margin, 0.5 * (c.lo[i] + c.hi[i]));
      if (q[i] >= lo && q[i] <= hi) continue;
      q[i] = std::clamp(q[i], lo, hi);
      if (dq) (*dq)[i] = 0;
      if (ddq) (*ddq)[i] = 0;
      if (!any && res.first_clamp_joint < 0) {
        res.first_clamp_joint = i;
        res.first_clamp_time = t;
      }
      any = true;
    }
    return any;
  };
  auto read_q = [&]() {
    Vector6 q;
    for (int i = 0; i < kNumJoints; ++i) q[i] = d->qpos[c.qadr[i]];
    return q;
  };
  auto check_limits = [&]() {
    double worst = 0;
    for (int i = 0; i < kNumJoints; ++i) {
      if (!c.limited[i]) continue;
      const double q = d->qpos[c.qadr[i]];
      worst = std::max({worst, c.lo[i] - q, q - c.hi[i]});
    }
    res.max_limit_excess = std::max(res.max_limit_excess, worst);
    if (worst > tol) ++res.joint_limit_violations;
  };

  // Initial state: at rest at q_0 (clamped into range), servos holding it.
  mj_resetData(m, d);
  {
    Vector6 q0 = trajectory.q.front();
    Vector6 dq0 = dq_samples.front();
    if (clamp_command(q0, &dq0, nullptr, 0.0)) ++res.clamped_steps;
    for (int i = 0; i < kNumJoints; ++i) {
      d->qpos[c.qadr[i]] = q0[i];
      d->qvel[c.dadr[i]] = dq0[i];
      d->ctrl[c.act[i]] = q0[i];
    }
    // The whole job run continuously: the state the previous motion left.
    if (!params.start_qpos.empty()) {
      mju_copy(d->qpos, params.start_qpos.data(), m->nq);
      mju_copy(d->qvel, params.start_qvel.data(), m->nv);
    }
  }
  mj_forward(m, d);
  mju_copy(dff->qpos, m->qpos0, m->nq);

  // The casting is fixed: {C} in {W} once.
  const Pose X_WC = pose_of(d->xpos + 3 * c.casting, d->xmat + 9 * c.casting);
  const Pose X_CW = X_WC.inverse();
  const Mat3 R_WC = X_WC.linear();

  // Process state between removal steps: the last removal step's wrench split into its rate
  // part (grinding, dissipative) and its penalty part (elastic), {C}, torques about the TCP,
  // held until the next removal step. With implicit_rate_force `rate` is per unit feed speed
  // (impulses of the intervals over the last rate_window voxels of travel / their net progress,
  // along `feed_C`); otherwise it is the wrench itself.
  RateWrench rate;
  Vec3 feed_C = Vec3::Zero();
  std::deque<RemovalInterval> window;
  Vec3 pen_F_C = Vec3::Zero(), pen_tau_C = Vec3::Zero();
  double penalty = 0;
  PenaltyContact contact;  // the last removal step's penetration of the body
  // The last exact CAD check's penetration where the grid tracks no body, and its push.
  PenaltyContact cad;
  Pose X_CT_cad = Pose::Identity();
  bool have_cad_pose = false;
  double since_cad = 0, cad_penalty = 0, cad_band = 0;
  Vec3 cad_F_C = Vec3::Zero(), cad_tau_C = Vec3::Zero();
  // The wrench applied to the tool: {W}, torque about the TCP.
  Vec3 F_W = Vec3::Zero(), tau_W = Vec3::Zero();
  double normal_force = 0, tangential_force = 0;
  bool have_removal_pose = false, in_contact = false;
  double last_contact = -1e300;  // [s] simulated time of the last step in contact
  Pose X_CT_last = Pose::Identity();
  double since_removal = 0, removed_total = 0;
  double delta = 0;              // admittance correction into the material [m]
  const double motion_trigger = grid ? params.removal_motion * grid->voxel_size() : 0;
  const double contact_trigger = grid ? params.removal_contact_motion * grid->voxel_size() : 0;

  double track_sq = 0, force_sum = 0, force_err_sq = 0;
  std::size_t contact_steps = 0;
  std::size_t next_sample = 0, ref_seg = 0, plan_seg = 0;

  const double span = trajectory.t.back() - t0;
  const std::size_t traj_steps = static_cast<std::size_t>(std::ceil(span / h - 1e-9));
  const std::size_t total_steps =
      traj_steps + static_cast<std::size_t>(std::llround(params.settle_time / h));
  std::vector<mjtNum> jacp(3 * m->nv), jacr(3 * m->nv), x3(3 * m->nv), tau_inv(m->nv);
  // The controller's side: the flange sensor, the load it estimates from it (force at the flange,
  // torque about it, {W}; the latest sample, held between samples) and the contact it infers.
  std::optional<FtSensor> sensor;
  std::optional<LoadEstimator> estimator;
  if (has_sensor) {
    sensor.emplace(params.sensor, params.sensor_seed);
    estimator.emplace(Payload{m->body_mass[c.tool], vec3_at(m->body_ipos + 3 * c.tool)},
                      vec3_at(m->opt.gravity), params.sensor.tare_time);
  }
  // The plan's stops in free air after the first tare (which the start takes anyway); entries
  // before t0 + tare_time are that first tare.
  std::size_t next_tare = 0;
  bool stepped = false;  // the sensor-bias drill's step is in
  while (next_tare < trajectory.tare_t.size() &&
         trajectory.tare_t[next_tare] < t0 + params.sensor.tare_time)
    ++next_tare;
  const std::size_t sample_every =
      std::max<std::size_t>(1, static_cast<std::size_t>(std::llround(params.sensor.period / h)));
  Wrench load_W, reading_E;
  const bool from_sensor = params.compensation_source == CompensationSource::kSensor;
  Vector6 grind_wrench_W = Vector6::Zero();  // the oracle's grinding wrench (COM), {W}
  Vec3 sensed_normal_W = Vec3::Zero();  // last sensed contact normal (material → tool)
  double sensed_normal = 0;             // [N] sensed normal force
  double load_err_sq = 0;
  std::size_t load_err_n = 0;

  auto compare_samples = [&](double t, const Pose& X_WT, double horizon) {
    while (next_sample < n_samples && trajectory.t[next_sample] <= t + horizon) {
      const Pose& P = trajectory.planned_tcp_W[next_sample];
      const double e = (X_WT.translation() - P.translation()).norm();
      track_sq += e * e;
      res.tracking_max = std::max(res.tracking_max, e);
      res.tracking_max_rotation =
          std::max(res.tracking_max_rotation, rotation_distance(X_WT.linear(), P.linear()));
      ++res.tracking_samples;
      ++next_sample;
    }
  };
  auto tcp_velocity_W = [&]() {
    mjtNum vel[6];
    mj_objectVelocity(m, d, mjOBJ_SITE, c.tcp, vel, 0);
    return Vec3(vel[3], vel[4], vel[5]);
  };

  // The penalty spring of a contact at `depth` (0: none) with the tool's speed into the body
  // (contact damping): its magnitude, and its force and torque about the TCP ({C}).
  auto push = [&](const PenaltyContact& pc, double depth, Vec3& F_C, Vec3& tau_C) {
    if (!(depth > 0)) {
      F_C.setZero();
      tau_C.setZero();
      return 0.0;
    }
    double speed_in = 0;
    if (force.contact_damping > 0)
      speed_in = std::max(0.0, -(X_CW.linear() * tcp_velocity_W()).dot(pc.n_C));
    const double p = penalty_force(force, depth, speed_in);
    F_C = p * pc.n_C;
    tau_C = pc.arm_C.cross(F_C);
    return p;
  };

  std::optional<CollisionMonitor> monitor;
  if (params.collisions) monitor.emplace(*params.collisions);
  const auto wall0 = std::chrono::steady_clock::now();
  std::size_t n = 0;
  for (; n < total_steps; ++n) {
    const double t_sim = static_cast<double>(n) * h;
    const double t = t0 + t_sim;
    const bool log_step =
        n % static_cast<std::size_t>(params.log_decimation) == 0 || n + 1 == total_steps;
    // MuJoCo's sensors are computed only on the F/T sensor's sample steps and logged steps
    // (unless a callback may read them at any step): the flange sensor costs a pass over the
    // bodies' forces. Their values there are unchanged.
    const bool sample_step = sensor && n % sample_every == 0;
    if (!params.on_step) {
      if (log_step || sample_step) m->opt.disableflags &= ~mjDSBL_SENSOR;
      else m->opt.disableflags |= mjDSBL_SENSOR;
    }
    mj_step1(m, d);  // positions, velocities (and their sensors) of the current state
    if (monitor) {
      // The twin's collision count (the controller never sees it).
      CollisionHit hit = monitor->update(*d);
      res.min_clearance = std::min(res.min_clearance, hit.clearance);
      if (hit.colliding()) {
        ++res.collision_steps;
        if (-hit.clearance > res.collision_max_depth) {
          res.collision_max_depth = -hit.clearance;
          res.deepest_collision = hit;
          res.deepest_collision_time = t_sim;
        }
        if (res.first_collision_time < 0) {
          res.first_collision = std::move(hit);
          res.first_collision_time = t_sim;
        }
      }
    }

    const Pose X_WT = pose_of(d->site_xpos + 3 * c.tcp, d->site_xmat + 9 * c.tcp);
    // {Tb}: where the burr's TCP truly stands (the controller's {T} but for a tcp_offset drill);
    // the process model cuts and pushes there.
    Pose X_WTb = X_WT;
    X_WTb.translation() += X_WT.linear() * params.tcp_offset_T;
    const Vector6 q_now = read_q();
    check_limits();
    if (tracking) compare_samples(t, X_WT, 0.5 * h);

    // Process model: material removal and the grinding wrench on the tool.
    if (grid) {
      since_removal += h;
      const Pose X_CT = X_CW * X_WTb;
      const double moved = have_removal_pose ? tool_motion(X_CT, X_CT_last, tool) : 1e300;
      // Between removal steps the penalty follows the tool (below); removal comes more often
      // while the tool presses into the body, where only a removal step sees the surface's shape.
      const double trigger = contact.depth > 0 ? contact_trigger : motion_trigger;
      if (moved >= trigger || since_removal >= params.removal_max_interval - 1e-12) {
        const Vec3 v_CT = X_CW.linear() * tcp_velocity_W();
        const StepRemoval step = remove_material(tool, *grid, X_CT);
        const GrindingWrench w = grinding_force(force, tool, step, since_removal, X_CT, v_CT);
        pen_F_C.setZero();
        pen_tau_C.setZero();
        contact = PenaltyContact{};
        if (w.penalty_force > 0 && step.contact_count > 0) {
          // The penalty part as grinding_force builds it: along the normal at the contact centroid.
          const Vec3 n_C = towards_axis(tool, X_CT, step.contact_centroid_C);
          contact = {step.penetration, n_C, inward_direction(grid->nominal(), step.deepest_C, -n_C),
                     X_CT.translation(), step.contact_centroid_C - X_CT.translation()};
          pen_F_C = w.penalty_force * contact.n_C;
          pen_tau_C = contact.arm_C.cross(pen_F_C);
        }
        rate = {w.force_C - pen_F_C, w.torque_C - pen_tau_C, w.normal_force - w.penalty_force,
                w.tangential_force};
        penalty = w.penalty_force;
        if (params.implicit_rate_force) {
          // Per unit feed speed over the last rate_window voxels of travel: removal comes in
          // whole voxels, so the cross-section the tool cuts is only meaningful over a few. The
          // first step has no interval (material the tool starts in costs no rate force).
          RemovalInterval iv;
          if (have_removal_pose) {
            iv.dp_C = X_CT.translation() - X_CT_last.translation();
            iv.ds = iv.dp_C.norm();
            iv.impulse = rate.scaled(since_removal);
          }
          window.push_back(iv);
          const double L = params.rate_window * grid->voxel_size();
          double travel = 0;
          for (const RemovalInterval& e : window) travel += e.ds;
          while (window.size() > 1 && travel - window.front().ds >= L) {
            travel -= window.front().ds;
            window.pop_front();
          }
          // Sums from scratch: a handful of intervals, and no drift.
          rate = RateWrench{};
          Vec3 dp = Vec3::Zero();
          for (const RemovalInterval& e : window) {
            rate.add(e.impulse);
            dp += e.dp_C;
          }
          // Per unit of net progress (vibration adds path length, not cutting).
          rate = rate.scaled(1 / std::max(dp.norm(), 0.5 * grid->voxel_size()));
          feed_C = dp.norm() > 1e-12 ? Vec3(dp.normalized()) : Vec3::Zero();
        }
        if (step.penetration > res.max_penetration) {
          res.max_penetration = step.penetration;
          res.max_penetration_time = t_sim;
          std::size_t seg = 0;
          res.max_penetration_tracking =
              tracking ? (X_WT.translation() - planned_position_at(trajectory, t, seg)).norm() : 0.0;
        }
        res.removed_flash_volume += step.flash_volume;
        res.removed_body_volume += step.body_volume;
        removed_total += step.volume();
        ++res.removal_steps;
        X_CT_last = X_CT;
        have_removal_pose = true;
        since_removal = 0;
      } else if (contact.depth > 0) {
        // The stiff penalty spring follows the tool at every step: the deepest body point of the
        // last removal step moves with the tool, its depth taken against the nominal surface's
        // tangent plane there (exact again at the next removal step, at most
        // removal_contact_motion voxels on).
        penalty = push(contact, contact.depth_at(X_CT.translation()), pen_F_C, pen_tau_C);
      }
      if (params.cad_check_motion > 0) {
        // Steel the voxels do not hold: the exact CAD check, its penalty following the tool in
        // between as the voxels' does.
        since_cad += h;
        const double moved_cad = have_cad_pose ? tool_motion(X_CT, X_CT_cad, tool) : 1e300;
        if (moved_cad >= params.cad_check_motion ||
            since_cad >= params.removal_max_interval - 1e-12) {
          const CadContact cc = untracked_contact(tool, *grid, X_CT);
          cad = cc.depth > cc.beyond
                    ? PenaltyContact{cc.depth - cc.beyond, cc.n_C, -cc.n_C, X_CT.translation(),
                                     cc.q_C - X_CT.translation()}
                    : PenaltyContact{};
          cad_band = cc.beyond;
          X_CT_cad = X_CT;
          have_cad_pose = true;
          since_cad = 0;
        }
        const double depth = cad.depth > 0 ? cad.depth_at(X_CT.translation()) : 0.0;
        cad_penalty = push(cad, depth, cad_F_C, cad_tau_C);
        if (depth > 0 && depth + cad_band > res.untracked_penetration_max) {
          res.untracked_penetration_max = depth + cad_band;
          res.untracked_penetration_time = t_sim;
        }
      }
    }

    // Reference, admittance correction, clamp, feed-forward → servo set-points.
    Reference r = reference_at(trajectory, dq_samples, t, ref_seg);
    if (fc.enabled) {
      mj_jacSite(m, d, jacp.data(), jacr.data(), c.tcp);
      // The sensed contact: the load across the tool axis and the reference's feed direction
      // (the burr's side cuts: the tangential force runs along the feed, the normal across it).
      Vec3 v_ref = Vec3::Zero();
      for (int k = 0; k < 3; ++k)
        for (int i = 0; i < kNumJoints; ++i) v_ref[k] += jacp[k * m->nv + c.dadr[i]] * r.dq[i];
      const Vec3 axis = X_WT.linear().col(2);
      Vec3 f_n = load_W.force - load_W.force.dot(axis) * axis;
      const Vec3 v_n = v_ref - v_ref.dot(axis) * axis;
      if (v_n.norm() > 1e-6) f_n -= f_n.dot(v_n.normalized()) * v_n.normalized();
      sensed_normal = f_n.norm();
      if (sensed_normal > fc.contact_force) {
        sensed_normal_W = f_n / sensed_normal;
        last_contact = t_sim;
      }
      // Admittance while in contact or shortly after (the tool may bounce off); released once
      // the contact has been lost for release_time.
      if (t_sim - last_contact <= fc.release_time)
        delta += fc.gain * (fc.target_force - sensed_normal) * h;
      else
        delta -= delta * std::min(1.0, h / fc.release_time);
      delta = std::clamp(delta, -fc.max_correction, fc.max_correction);
      if (delta != 0 && sensed_normal_W.squaredNorm() > 0) {
        // Δq = Jᵀ(J·Jᵀ + λ²I)⁻¹·[−δ·n; 0]: translate the TCP into the material, keep orientation.
        Matrix6 J;
        for (int i = 0; i < kNumJoints; ++i)
          for (int k = 0; k < 3; ++k) {
            J(k, i) = jacp[k * m->nv + c.dadr[i]];
            J(3 + k, i) = jacr[k * m->nv + c.dadr[i]];
          }
        Vector6 dx = Vector6::Zero();
        dx.head<3>() = -delta * sensed_normal_W;
        const Matrix6 A = J * J.transpose() + 1e-6 * Matrix6::Identity();
        r.q += J.transpose() * A.ldlt().solve(dx);
      }
    }
    if (clamp_command(r.q, &r.dq, &r.ddq, t_sim)) ++res.clamped_steps;
    Vector6 tau_ff = Vector6::Zero();
    if (params.feedforward) {
      for (int i = 0; i < kNumJoints; ++i) {
        dff->qpos[c.qadr[i]] = r.q[i];
        dff->qvel[c.dadr[i]] = r.dq[i];
        dff->qacc[c.dadr[i]] = r.ddq[i];
      }
      rigid_inverse_dynamics(mff, dff, tau_inv.data());
      for (int i = 0; i < kNumJoints; ++i) tau_ff[i] = tau_inv[c.dadr[i]];
    }
    if (params.load_compensation && from_sensor && estimator->tared()) {
      // Deflection compensation: cancel the load the sensor shows (force at the flange, torque
      // about it) through the flange's Jacobian.
      mj_jacSite(m, d, jacp.data(), jacr.data(), c.force_site);
      for (int i = 0; i < kNumJoints; ++i)
        for (int k = 0; k < 3; ++k)
          tau_ff[i] -= jacp[k * m->nv + c.dadr[i]] * load_W.force[k] +
                       jacr[k * m->nv + c.dadr[i]] * load_W.torque[k];
    } else if (params.load_compensation && !from_sensor && grind_wrench_W.squaredNorm() > 0) {
      // The oracle: the process model's grinding wrench of the previous step through the
      // Jacobian at the tool's centre of mass. Not the contact penalty: the servos yield to it.
      mj_jacBodyCom(m, d, jacp.data(), jacr.data(), c.tool);
      for (int i = 0; i < kNumJoints; ++i)
        for (int k = 0; k < 3; ++k)
          tau_ff[i] -= jacp[k * m->nv + c.dadr[i]] * grind_wrench_W[k] +
                       jacr[k * m->nv + c.dadr[i]] * grind_wrench_W[3 + k];
    }
    if (params.tcp_damping > 0) {
      // Active damping of the TCP's tracking-error velocity (encoders and the plan):
      // τ = Jpᵀ·c·(J·dq_ref − J·dq).
      mj_jacSite(m, d, jacp.data(), nullptr, c.tcp);
      Vec3 dv = Vec3::Zero();
      for (int k = 0; k < 3; ++k)
        for (int i = 0; i < kNumJoints; ++i)
          dv[k] += jacp[k * m->nv + c.dadr[i]] * (r.dq[i] - d->qvel[c.dadr[i]]);
      for (int i = 0; i < kNumJoints; ++i)
        for (int k = 0; k < 3; ++k) tau_ff[i] += jacp[k * m->nv + c.dadr[i]] * params.tcp_damping * dv[k];
    }
    for (int i = 0; i < kNumJoints; ++i) d->ctrl[c.act[i]] = r.q[i] + tau_ff[i] / c.kp[i];

    // The wrench applied this step. The rate part (grinding) is a resistance to the feed: with
    // implicit_rate_force it is the per-speed wrench times the feed speed at the end of the step,
    // solved implicitly along the feed direction d (as MuJoCo treats joint damping): with the
    // TCP's inverse inertia Λ⁻¹ = Jp·M⁻¹·Jpᵀ and its acceleration a without the rate force,
    // s⁺ = (d·v + h·d·a) / (1 − h·dᵀΛ⁻¹G). Applied explicitly, a removal rate taken over whole
    // voxels acts like a damper far stiffer than the tool's mass allows over one step and throws
    // the tool back and forth (stick-slip chatter).
    const Vec3 G_W = R_WC * rate.force, pen_F_W = R_WC * (pen_F_C + cad_F_C);
    double speed = 1;  // explicit: `rate` is the wrench itself
    if (params.implicit_rate_force) {
      speed = 0;
      const Vec3 d_W = R_WC * feed_C;
      // Only a wrench that resists the feed is applied (the window may lag a reversal).
      if (G_W.dot(d_W) < 0) {
        mj_jacSite(m, d, jacp.data(), nullptr, c.tcp);
        mj_solveM(m, d, x3.data(), jacp.data(), 3);  // rows of M⁻¹·Jpᵀ
        mj_fwdActuation(m, d);                       // servo forces of this step's ctrl
        Mat3 L_inv = Mat3::Zero();
        Vec3 a = Vec3::Zero();
        for (int k = 0; k < m->nv; ++k) {
          const double tau =
              d->qfrc_actuator[k] + d->qfrc_passive[k] - d->qfrc_bias[k] + d->qfrc_applied[k];
          for (int i = 0; i < 3; ++i) {
            a[i] += x3[i * m->nv + k] * tau;
            for (int j = 0; j < 3; ++j) L_inv(i, j) += jacp[i * m->nv + k] * x3[j * m->nv + k];
          }
        }
        a += L_inv * pen_F_W;
        const double s_free = d_W.dot(tcp_velocity_W()) + h * d_W.dot(a);
        const double resist = std::max(0.0, -d_W.dot(L_inv * G_W));
        speed = std::max(0.0, s_free / (1 + h * resist));
      }
    }
    F_W = speed * G_W + pen_F_W;
    tau_W = R_WC * (speed * rate.torque + pen_tau_C + cad_tau_C);
    {
      // The grinding part alone (rate wrench), about the tool's COM, for the oracle compensation.
      const Vec3 f = speed * G_W;
      const Vec3 torque = R_WC * (speed * rate.torque) +
                          (X_WTb.translation() - vec3_at(d->xipos + 3 * c.tool)).cross(f);
      grind_wrench_W << f, torque;
    }
    normal_force = speed * rate.normal + penalty + cad_penalty;
    tangential_force = speed * rate.tangential;
    {
      // xfrc_applied: world-frame force at the body's COM; shift the moment from the TCP.
      const Vec3 tau_com = tau_W + (X_WTb.translation() - vec3_at(d->xipos + 3 * c.tool)).cross(F_W);
      mjtNum* xf = d->xfrc_applied + 6 * c.tool;
      for (int k = 0; k < 3; ++k) {
        xf[k] = F_W[k];
        xf[3 + k] = tau_com[k];
      }
    }
    // In contact: the process acts on the tool (removal over the rate window with the tool
    // feeding, or penetration of the body).
    in_contact = normal_force > 0 || tangential_force > 0;
    if (in_contact) {
      ++contact_steps;
      force_sum += normal_force;
      const double e = normal_force - fc.target_force;
      force_err_sq += e * e;
      res.force_max = std::max(res.force_max, normal_force);
    }

    mj_step2(m, d);  // actuation, acceleration, force sensors of this state; integrate

    if (sample_step) {
      // The flange sensor's sample of this state; the controller's load estimate from it is used
      // from the next step on.
      const Mat3 R_WE = mat3_at(d->site_xmat + 9 * c.force_site);
      reading_E = sensor->sample(
          {vec3_at(d->sensordata + c.force_adr), vec3_at(d->sensordata + c.torque_adr)});
      // Where the plan stops the arm in free air the controller zeroes the sensor again.
      if (next_tare < trajectory.tare_t.size() && t + 1e-12 >= trajectory.tare_t[next_tare]) {
        estimator->retare(t_sim);
        ++next_tare;
      }
      const bool was_tared = estimator->tared();
      load_W = estimator->update(reading_E, R_WE, t_sim);
      // A sensor-bias drill: the zero steps right after the motion's first tare, unknown to the
      // controller (a later tare in free air takes a step within kTareLimit out again).
      if (!was_tared && estimator->tared() && !stepped) {
        sensor->shift_zero(params.sensor_step_E);
        stepped = true;
      }
      if (estimator->tared() && in_contact) {
        load_err_sq += (load_W.force - F_W).squaredNorm();
        ++load_err_n;
      }
    }

    if (log_step) {
      ExecutionLog& L = res.log;
      L.t.push_back(t_sim);
      L.q.push_back(q_now);
      L.q_ref.push_back(r.q);
      L.tcp_W.push_back(X_WT.translation());
      if (tracking) L.planned_tcp_W.push_back(planned_position_at(trajectory, t, plan_seg));
      L.normal_force.push_back(normal_force);
      L.tangential_force.push_back(tangential_force);
      L.process_force_W.push_back(F_W);
      if (sensor) {
        L.sensor_force_E.push_back(reading_E.force);
        L.sensor_force_W.push_back(mat3_at(d->site_xmat + 9 * c.force_site) * reading_E.force);
        L.sensor_torque_E.push_back(reading_E.torque);
        L.load_force_W.push_back(load_W.force);
      }
      L.removed_volume.push_back(removed_total);
      L.correction.push_back(delta);
    }
    if (params.on_step) params.on_step(m, d, d->time);
    if (bad_state(m, d)) {
      res.status = ExecStatus::kUnstable;
      res.message = "MuJoCo reported an unstable state at t = " + std::to_string(t_sim) +
                    " s; execution stopped";
      ++n;
      break;
    }
    if (params.max_force > 0 && estimator && estimator->untared_force_W().norm() > params.max_force) {
      res.status = ExecStatus::kForceLimit;
      res.message = strf("protective stop at t = %.3f s: sensed force %.0f N above max_force %.0f N "
                         "(process normal force %.0f N: cutting %.0f N, body contact %.0f N: %s)",
                         t_sim, estimator->untared_force_W().norm(), params.max_force, normal_force,
                         normal_force - penalty - cad_penalty, penalty + cad_penalty,
                         penalty + cad_penalty > 0.5 * normal_force ? "tool driven into the part"
                                                      : "too much material in one cut");
      ++n;
      break;
    }
  }
  const bool stopped = res.status == ExecStatus::kUnstable || res.status == ExecStatus::kForceLimit;
  const auto wall1 = std::chrono::steady_clock::now();

  // Final state: remaining samples (trajectory end without settling) and the final error.
  m->opt.disableflags &= ~mjDSBL_SENSOR;
  mj_forward(m, d);
  if (!stopped) {
    check_limits();
    const Pose X_WT = pose_of(d->site_xpos + 3 * c.tcp, d->site_xmat + 9 * c.tcp);
    if (tracking) {
      compare_samples(1e300, X_WT, 0);
      res.final_error = (X_WT.translation() - trajectory.planned_tcp_W.back().translation()).norm();
    }
  }

  res.q_end.assign(d->qpos, d->qpos + m->nq);
  res.qvel_end.assign(d->qvel, d->qvel + m->nv);
  res.steps = n;
  res.sim_time = static_cast<double>(n) * h;
  res.wall_time = std::chrono::duration<double>(wall1 - wall0).count();
  res.realtime_factor = res.wall_time > 0 ? res.sim_time / res.wall_time : 0;
  res.step_cost = n > 0 ? res.wall_time / static_cast<double>(n) : 0;
  if (res.tracking_samples > 0)
    res.tracking_rmse = std::sqrt(track_sq / static_cast<double>(res.tracking_samples));
  res.contact_time = static_cast<double>(contact_steps) * h;
  if (contact_steps > 0) {
    res.force_mean = force_sum / static_cast<double>(contact_steps);
    res.force_rmse = std::sqrt(force_err_sq / static_cast<double>(contact_steps));
  }
  if (load_err_n > 0) res.load_estimate_rmse = std::sqrt(load_err_sq / static_cast<double>(load_err_n));
  if (grid && params.analyze_residual) {
    res.residual = analyze_residual(*grid);
    res.has_residual = true;
  }
  if (!stopped) {
    if (res.first_clamp_joint >= 0) {
      res.status = ExecStatus::kReferenceClamped;
      res.message = "reference of joint" + std::to_string(res.first_clamp_joint + 1) +
                    " left its range (less a margin of " + std::to_string(margin) +
                    " rad) at t = " + std::to_string(res.first_clamp_time) + " s; clamped in " +
                    std::to_string(res.clamped_steps) + " steps";
    } else {
      res.message = "ok";
    }
  }
  return res;
}

}  // namespace flashtwin::sim
