#include "flashtwin/planner/program_replay.hpp"

#include <algorithm>
#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

namespace {

using Quat = Eigen::Quaterniond;

[[noreturn]] void replay_error(int line, const std::string& what) {
  throw ArgumentError("program line " + std::to_string(line) + ": " + what);
}

// A Cartesian target with what the controller moves to it with.
struct Target {
  Vec3 p;
  Quat r;
  double speed = 0, accel = 0, ori_speed = 0, ori_accel = 0, blend = 0;
  int line = 0;
};

// One sample of the path the controller interpolates, and how fast it may pass it.
struct PathSample {
  Vec3 p;
  Quat r;
  // Interpolation parameter σ: each step counts its TCP travel, or its rotation at the
  // programmed ratio speed/orientation speed when that is longer, so that moving σ at the
  // programmed speed keeps both the path speed and the orientation speed within their bounds.
  double sigma = 0;
  double v_cap = 0;  ///< programmed speed here [σ/s]
  double accel = 0;  ///< ramp acceleration here [σ/s²]
  int line = 0;      ///< program line of the move this sample belongs to
};

// Pose of a target at fraction u of the straight move from a to b (orientation by slerp,
// as KRL's $ORI_TYPE = #VAR and the others' linear moves turn the tool).
Target along(const Target& a, const Target& b, double u) {
  Target t = b;
  t.p = a.p + u * (b.p - a.p);
  t.r = a.r.slerp(u, b.r);
  return t;
}

// Appends samples from the last one to `to` along `shape` (shape(τ) for τ in (0, 1]) with the
// speed of move `m`; steps no longer than `step` in position nor in rotation scaled by it.
template <typename Shape>
void append(std::vector<PathSample>& out, const Target& m, double chord, double angle,
            double step, const Shape& shape) {
  const double n_pos = chord / step;
  const double n_rot = m.ori_speed > 0 ? angle * m.speed / m.ori_speed / step : angle / 0.01;
  const int n = std::max(1, static_cast<int>(std::ceil(std::max(n_pos, n_rot))));
  for (int k = 1; k <= n; ++k) {
    PathSample s;
    shape(static_cast<double>(k) / n, s.p, s.r);
    const PathSample& prev = out.back();
    const double dp = (s.p - prev.p).norm();
    const double dr = prev.r.angularDistance(s.r);
    const double dr_len = m.ori_speed > 0 ? dr * m.speed / m.ori_speed : 0.0;
    s.sigma = prev.sigma + std::max(dp, dr_len);
    s.v_cap = m.speed;
    // σ's acceleration keeps the turn's within the orientation bound too (σ = turn·v/w there).
    s.accel = m.ori_accel > 0 ? std::min(m.accel, m.ori_accel * m.speed / m.ori_speed) : m.accel;
    s.line = m.line;
    if (s.sigma > prev.sigma) out.push_back(s);
  }
}

// The rounded path through the targets: straight moves, each corner replaced within the
// target's blend distance (at most half of either adjoining move) by a quadratic Bézier from
// where the corner starts on the incoming move to where it ends on the outgoing one, its
// control point the target itself (tangent to both moves); the orientation turns by slerp
// across the corner. The path passes the exact target only where the blend is 0.
std::vector<PathSample> rounded_path(const std::vector<Target>& T, double step) {
  const std::size_t n = T.size();
  std::vector<double> len(n, 0.0), cut(n, 0.0);  // len[i]: move into target i
  for (std::size_t i = 1; i < n; ++i) len[i] = (T[i].p - T[i - 1].p).norm();
  for (std::size_t i = 1; i + 1 < n; ++i)
    cut[i] = std::min({T[i].blend, 0.5 * len[i], 0.5 * len[i + 1]});
  std::vector<PathSample> out(1);
  out[0].p = T[0].p;
  out[0].r = T[0].r;
  out[0].line = T[0].line;
  Target from = T[0];
  for (std::size_t i = 1; i < n; ++i) {
    // Straight part of move i: from where the last corner ended to where the next begins.
    const double u1 = len[i] > 0 ? 1.0 - cut[i] / len[i] : 1.0;
    const Target end = along(T[i - 1], T[i], u1);
    append(out, T[i], (end.p - from.p).norm(), from.r.angularDistance(end.r), step,
           [&](double u, Vec3& p, Quat& r) {
             p = from.p + u * (end.p - from.p);
             r = from.r.slerp(u, end.r);
           });
    from = end;
    if (cut[i] <= 0) continue;
    const Target exit = along(T[i], T[i + 1], cut[i] / len[i + 1]);
    const Vec3 c = T[i].p;
    // The corner runs at the slower path speed of the two moves and turns the tool at the faster
    // turn rate (it finishes one move's turn and starts the next's).
    Target corner = T[i + 1];
    corner.speed = std::min(T[i].speed, T[i + 1].speed);
    corner.ori_speed = std::max(T[i].ori_speed, T[i + 1].ori_speed);
    corner.ori_accel = std::max(T[i].ori_accel, T[i + 1].ori_accel);
    append(out, corner, (exit.p - from.p).norm(), from.r.angularDistance(exit.r), step,
           [&](double u, Vec3& p, Quat& r) {
             p = (1 - u) * (1 - u) * from.p + 2 * u * (1 - u) * c + u * u * exit.p;
             r = from.r.slerp(u, exit.r);
           });
    from = exit;
  }
  return out;
}

// Speed along σ at each sample: at rest at both ends, never above the programmed speed, ramps
// no steeper than the programmed acceleration (v² changes by at most 2·a·Δσ per step).
std::vector<double> speed_profile(const std::vector<PathSample>& S) {
  const std::size_t n = S.size();
  std::vector<double> v(n);
  for (std::size_t i = 0; i < n; ++i) v[i] = S[i].v_cap;
  v.front() = v.back() = 0;
  for (std::size_t i = 1; i < n; ++i)
    v[i] = std::min(v[i], std::sqrt(v[i - 1] * v[i - 1] + 2 * S[i].accel * (S[i].sigma - S[i - 1].sigma)));
  for (std::size_t i = n - 1; i-- > 0;)
    v[i] = std::min(v[i], std::sqrt(v[i + 1] * v[i + 1] + 2 * S[i + 1].accel * (S[i + 1].sigma - S[i].sigma)));
  return v;
}

// The program's motions as targets: the start (the joint move's flange pose with the tool) and
// the Cartesian targets after it, with the stated speeds or the controller's defaults.
std::vector<Target> targets_of(const RobotModel& robot, const ParsedProgram& prog,
                               const ReplayedProgram& out, const ReplayParams& P, Vector6& q0) {
  if (prog.points.empty()) replay_error(0, "expected motions, got none");
  const ProgramPoint& first = prog.points.front();
  if (first.cartesian)
    replay_error(first.line, "expected a joint move to the start (PTP, movej, MoveAbsJ), got " +
                                 first.instruction);
  q0 = first.q;
  const Pose X_WB = out.X_BW.inverse();
  std::vector<Target> T(1);
  const Pose X_WT0 = X_WB * fk_flange(robot, q0) * out.X_ET;
  T[0].p = X_WT0.translation();
  T[0].r = Quat(X_WT0.linear());
  T[0].line = first.line;
  for (std::size_t i = 1; i < prog.points.size(); ++i) {
    const ProgramPoint& pt = prog.points[i];
    if (!pt.cartesian)
      replay_error(pt.line, "expected a Cartesian move (LIN, SPL, movel, movep, MoveL) after the "
                            "start, got " + pt.instruction + " (joint moves are not interpolated here)");
    if (!(pt.speed > 0)) replay_error(pt.line, "expected a programmed speed > 0, got none");
    Target t;
    t.p = pt.X_WT.translation();
    t.r = Quat(pt.X_WT.linear());
    if (t.r.dot(T.back().r) < 0) t.r.coeffs() *= -1;  // the short way round
    t.speed = pt.speed;
    t.accel = pt.accel > 0 ? pt.accel : P.default_accel;
    t.ori_speed = pt.ori_speed > 0 ? pt.ori_speed : P.default_ori_speed;
    t.ori_accel = pt.ori_accel;
    t.blend = pt.blend;
    t.line = pt.line;
    T.push_back(t);
  }
  if (T.size() < 2) replay_error(first.line, "expected Cartesian moves after the start, got none");
  return T;
}

// Output samples every dt along the timed path: σ(t) with the speed linear in time over each
// path step (constant acceleration), the pose interpolated within the step.
void sample_in_time(const std::vector<PathSample>& S, const std::vector<double>& v, double dt,
                    std::vector<double>& t_out, std::vector<Pose>& X_WT, std::vector<double>& sigma,
                    std::vector<int>& line) {
  const std::size_t n = S.size();
  std::vector<double> t(n, 0.0);
  for (std::size_t i = 1; i < n; ++i) {
    const double ds = S[i].sigma - S[i - 1].sigma, vv = v[i] + v[i - 1];
    // A lone step from rest to rest: accelerate over half of it, brake over the other half.
    t[i] = t[i - 1] + (vv > 0 ? 2 * ds / vv : 2 * std::sqrt(ds / S[i].accel));
  }
  const auto count = static_cast<std::size_t>(std::ceil(t.back() / dt - 1e-9)) + 1;
  std::size_t j = 0;
  for (std::size_t k = 0; k < count; ++k) {
    const double tk = std::min(static_cast<double>(k) * dt, t.back());
    while (j + 2 < n && t[j + 1] <= tk) ++j;
    const double h = t[j + 1] - t[j], tau = tk - t[j];
    const double ds = S[j + 1].sigma - S[j].sigma;
    // Distance covered after τ of the step: v_j·τ + ½·(v_{j+1} − v_j)/h·τ².
    const double d = v[j] * tau + 0.5 * (v[j + 1] - v[j]) / h * tau * tau;
    const double u = std::clamp(ds > 0 ? d / ds : 1.0, 0.0, 1.0);
    Pose X = Pose::Identity();
    X.translation() = S[j].p + u * (S[j + 1].p - S[j].p);
    X.linear() = S[j].r.slerp(u, S[j + 1].r).toRotationMatrix();
    t_out.push_back(static_cast<double>(k) * dt);
    X_WT.push_back(X);
    sigma.push_back(S[j].sigma + u * ds);
    line.push_back(S[j + 1].line);
  }
}

// Joint positions for the commanded poses: the controller's IK, the solution nearest the
// previous sample (the arm keeps its configuration); a jump or a joint out of its limits stops
// the program at the line being run.
std::vector<Vector6> follow_ik(const RobotModel& robot, const std::vector<Pose>& X_BT,
                               const Pose& X_ET, const Vector6& q0, const std::vector<int>& line,
                               double max_step) {
  std::vector<Vector6> q(X_BT.size());
  const Pose X_TE = X_ET.inverse();
  Vector6 prev = q0;
  for (std::size_t k = 0; k < X_BT.size(); ++k) {
    IkParams ip;
    ip.within_limits_only = false;
    ip.q_ref = prev;
    const IkResult ik = ik_flange(robot, X_BT[k] * X_TE, ip);
    if (ik.solutions.empty())
      replay_error(line[k], "expected a reachable target, got a pose the arm cannot reach (" +
                                ik.message + ")");
    const IkSolution* best = nullptr;
    double best_d = 1e300;
    for (const auto& s : ik.solutions) {
      const double d = (s.q - prev).cwiseAbs().maxCoeff();
      if (d < best_d) {
        best_d = d;
        best = &s;
      }
    }
    if (best_d > max_step) {
      int j = 0;
      (best->q - prev).cwiseAbs().maxCoeff(&j);
      replay_error(line[k], "expected a continuous joint motion, got axis " + std::to_string(j + 1) +
                                " jumping " + std::to_string(best_d) +
                                " rad in one interpolation step (a singularity or a change of "
                                "configuration on the way)");
    }
    for (int j = 0; j < kNumJoints; ++j)
      if (!robot.limits[j].contains(best->q[j], 1e-9))
        replay_error(line[k], "expected axis " + std::to_string(j + 1) + " within [" +
                                  std::to_string(robot.limits[j].lower) + ", " +
                                  std::to_string(robot.limits[j].upper) + "] rad, got " +
                                  std::to_string(best->q[j]));
    q[k] = prev = best->q;
  }
  return q;
}

// First and second differences (central inside, one-sided at the ends, where the motion is at
// rest).
void differentiate(JointTrajectory& tr) {
  const std::size_t n = tr.size();
  const double dt = tr.dt;
  tr.dq.assign(n, Vector6::Zero());
  tr.ddq.assign(n, Vector6::Zero());
  tr.sdot.assign(n, 0.0);
  tr.sddot.assign(n, 0.0);
  for (std::size_t k = 1; k + 1 < n; ++k) {
    tr.dq[k] = (tr.q[k + 1] - tr.q[k - 1]) / (2 * dt);
    tr.ddq[k] = (tr.q[k + 1] - 2 * tr.q[k] + tr.q[k - 1]) / (dt * dt);
    tr.sdot[k] = (tr.s[k + 1] - tr.s[k - 1]) / (2 * dt);
    tr.sddot[k] = (tr.s[k + 1] - 2 * tr.s[k] + tr.s[k - 1]) / (dt * dt);
  }
}

}  // namespace

ReplayedProgram replay_program(const RobotModel& robot, const ParsedProgram& prog,
                               const ReplayParams& P) {
  if (!(P.dt > 0) || !(P.default_accel > 0) || !(P.default_ori_speed > 0) || !(P.path_step > 0) || !(P.max_joint_step > 0))
    throw ArgumentError("replay: expected dt, default_accel, default_ori_speed, path_step and max_joint_step > 0");
  ReplayedProgram out;
  out.X_ET = prog.tool_declared ? prog.X_ET : robot.tool.X_ET;
  out.X_BW = prog.base_declared ? prog.X_BW : Pose::Identity();
  Vector6 q0;
  const std::vector<Target> T = targets_of(robot, prog, out, P, q0);
  const std::vector<PathSample> S = rounded_path(T, P.path_step);
  if (S.size() < 2) replay_error(T.back().line, "expected targets apart from the start, got none");
  for (std::size_t i = 1; i < S.size(); ++i) out.path_length += (S[i].p - S[i - 1].p).norm();

  std::vector<Pose> X_WT;
  std::vector<int> line;
  JointTrajectory& tr = out.trajectory;
  tr.dt = P.dt;
  sample_in_time(S, speed_profile(S), P.dt, tr.t, X_WT, tr.s, line);
  out.X_BT.reserve(X_WT.size());
  for (const Pose& X : X_WT) out.X_BT.push_back(out.X_BW * X);
  tr.q = follow_ik(robot, out.X_BT, out.X_ET, q0, line, P.max_joint_step);
  differentiate(tr);
  for (std::size_t k = 0; k < tr.size(); ++k)
    for (int j = 0; j < kNumJoints; ++j) {
      out.max_joint_velocity_ratio =
          std::max(out.max_joint_velocity_ratio, std::abs(tr.dq[k][j]) / robot.limits[j].velocity);
      out.max_joint_accel_ratio = std::max(
          out.max_joint_accel_ratio, std::abs(tr.ddq[k][j]) / robot.limits[j].acceleration);
    }
  return out;
}

}  // namespace flashtwin::planner
