// Executor: joint trajectories run on the MuJoCo cell under dynamics, with reference clamping,
// the process model's removal and forces fed back through the tool body, and determinism.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <fstream>
#include <memory>
#include <sstream>
#include <string>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/executor.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/process.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

constexpr double mm = 1e-3;

// The default scenario's cell, written and compiled once for the suite.
struct DefaultCell {
  RobotModel robot;
  CellSpec spec;
  std::string mjcf;
  MjModelPtr model;
};

const DefaultCell& default_cell() {
  static const DefaultCell cell = [] {
    const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
    const auto setup = pipeline::setup_cell(sc);
    const std::string dir = ftest::temp_dir("executor");
    const CellFiles files = write_cell(sc.robot, setup.spec, setup.casting, dir);
    DefaultCell c;
    c.robot = sc.robot;
    c.spec = setup.spec;
    c.mjcf = files.mjcf;
    c.model = load_mjcf_file(files.mjcf);
    return c;
  }();
  return cell;
}

// Quintic rest-to-rest joint motion from qa to qb in T seconds, sampled every dt, with the
// planned TCP from the D-H forward kinematics (X_WT = X_WB · X_BT).
JointTrajectory quintic(const DefaultCell& cell, const Vector6& qa, const Vector6& qb, double T,
                        double dt) {
  JointTrajectory tr;
  const int n = static_cast<int>(std::lround(T / dt));
  for (int k = 0; k <= n; ++k) {
    const double t = T * k / n, u = t / T;
    const double s = u * u * u * (10 - 15 * u + 6 * u * u);
    const double ds = 30 * u * u * (1 - u) * (1 - u) / T;
    const Vector6 q = qa + s * (qb - qa);
    tr.t.push_back(t);
    tr.q.push_back(q);
    tr.dq.push_back(ds * (qb - qa));
    tr.planned_tcp_W.push_back(cell.spec.X_WB * planner::fk_tool(cell.robot, q));
  }
  return tr;
}


Vec3 mean_of(const std::vector<Vec3>& v, const std::vector<std::size_t>& rows) {
  Vec3 s = Vec3::Zero();
  for (std::size_t r : rows) s += v[r];
  return rows.empty() ? s : Vec3(s / static_cast<double>(rows.size()));
}

// A slow sweep of joint 1 (the TCP moves about 25 mm along an arc, ~15 mm/s mid-way) and a thin fin
// standing across the TCP's path at mid-time: a body block below the tip, the fin on top of it
// reaching `fin_top` above the tip. Frame {F}: origin at the TCP at mid-time, x along the motion,
// z along the cutter axis (tip → shank).
struct FinCase {
  JointTrajectory traj;
  ToolParams tool;
  Pose X_CF;
  double fin_thickness = 0.3 * mm, fin_top = 3 * mm;
  std::unique_ptr<MaterialGrid> grid;
};

FinCase fin_case(const DefaultCell& cell) {
  FinCase fc;
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb[0] += 0.035;
  fc.traj = quintic(cell, qa, qb, 3.0, 0.005);
  fc.tool = tool_params_from(cell.robot.tool);
  const Pose X_CW = cell.spec.X_WC.inverse();
  const std::size_t mid = fc.traj.t.size() / 2;
  const Pose X_CT = X_CW * fc.traj.planned_tcp_W[mid];
  const Vec3 a = fc.tool.axis_sign * X_CT.linear().col(2);
  Vec3 x = X_CW.linear() * (fc.traj.planned_tcp_W[mid + 1].translation() -
                            fc.traj.planned_tcp_W[mid - 1].translation());
  x = (x - x.dot(a) * a).normalized();
  fc.X_CF = Pose::Identity();
  fc.X_CF.linear() << x, a.cross(x), a;
  fc.X_CF.translation() = X_CT.translation();
  const double w = 0.5 * fc.fin_thickness;
  const TriangleMesh body = box_mesh(Vec3(-15, -15, -13) * mm, Vec3(15, 15, -3) * mm).transformed(fc.X_CF);
  const TriangleMesh fin =
      box_mesh(Vec3(-w, -15 * mm, -3 * mm), Vec3(w, 15 * mm, fc.fin_top)).transformed(fc.X_CF);
  fc.grid = std::make_unique<MaterialGrid>(body, std::vector<TriangleMesh>{fin});
  return fc;
}

}  // namespace

TEST(Executor, FreeMotionTracksTheReference) {
  const DefaultCell& cell = default_cell();
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb << 0.25, -1.35, -0.2, 0.3, 1.3, 0.4;
  const JointTrajectory tr = quintic(cell, qa, qb, 1.0, 0.01);
  ExecParams p;
  p.settle_time = 0.2;
  const ExecutionResult r =
      execute_trajectory(cell.mjcf, tr, nullptr, ToolParams{}, ForceParams{}, p);
  EXPECT_EQ(r.status, ExecStatus::kOk) << r.message;
  EXPECT_EQ(r.first_clamp_joint, -1);
  EXPECT_EQ(r.joint_limit_violations, 0u);
  EXPECT_EQ(r.tracking_samples, tr.t.size());
  EXPECT_LT(r.tracking_rmse, 1 * mm);
  EXPECT_LT(r.tracking_max, 2 * mm);
  EXPECT_LT(r.final_error, 0.1 * mm);
  EXPECT_DOUBLE_EQ(r.timestep, 0.001);
  EXPECT_EQ(r.steps, 1200u);
  EXPECT_NEAR(r.sim_time, 1.2, 1e-12);
  EXPECT_GT(r.realtime_factor, 1.0);
  EXPECT_EQ(r.contact_time, 0.0);
  EXPECT_FALSE(r.has_residual);
  // Decimated logs: every 10th step plus the last one.
  ASSERT_EQ(r.log.t.size(), 121u);
  EXPECT_EQ(r.log.q.size(), r.log.t.size());
  EXPECT_EQ(r.log.planned_tcp_W.size(), r.log.t.size());
  EXPECT_EQ(r.log.sensor_force_E.size(), r.log.t.size());
  EXPECT_NEAR(r.log.t[100], 1.0, 1e-12);
  EXPECT_NEAR((r.log.tcp_W.back() - tr.planned_tcp_W.back().translation()).norm(), 0, 0.1 * mm);

  // Without feed-forward the servos sag under gravity: worse tracking (the figure is reported).
  ExecParams nff = p;
  nff.feedforward = false;
  const ExecutionResult r2 =
      execute_trajectory(cell.mjcf, tr, nullptr, ToolParams{}, ForceParams{}, nff);
  EXPECT_GT(r2.tracking_rmse, r.tracking_rmse);
  std::printf(
      "free motion 1 s: tracking RMSE %.4f mm, max %.4f mm, max rotation %.3g mrad, final %.4f mm;"
      " without feed-forward RMSE %.3f mm; realtime factor %.0f, step %.1f us\n",
      r.tracking_rmse / mm, r.tracking_max / mm, r.tracking_max_rotation * 1e3, r.final_error / mm,
      r2.tracking_rmse / mm, r.realtime_factor, r.step_cost * 1e6);
}

TEST(Executor, ClampsReferencesBeyondAJointRange) {
  const DefaultCell& cell = default_cell();
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb[4] = 2.5;  // joint5 upper limit: 2.094 rad
  const JointTrajectory tr = quintic(cell, qa, qb, 1.0, 0.01);
  ExecParams p;
  p.settle_time = 0.3;
  p.log_decimation = 1;
  const ExecutionResult r =
      execute_trajectory(cell.mjcf, tr, nullptr, ToolParams{}, ForceParams{}, p);
  EXPECT_EQ(r.status, ExecStatus::kReferenceClamped);
  EXPECT_NE(r.message.find("joint5"), std::string::npos) << r.message;
  EXPECT_EQ(r.first_clamp_joint, 4);
  // First time the quintic passes upper − margin.
  const double upper = cell.robot.limits[4].upper, bound = upper - p.limit_margin;
  double t_cross = -1;
  for (int k = 0; k <= 100000 && t_cross < 0; ++k) {
    const double u = k / 100000.0, s = u * u * u * (10 - 15 * u + 6 * u * u);
    if (qa[4] + s * (qb[4] - qa[4]) > bound) t_cross = u;
  }
  EXPECT_NEAR(r.first_clamp_time, t_cross, 1.5e-3);
  EXPECT_GT(r.clamped_steps, 100u);
  EXPECT_EQ(r.joint_limit_violations, 0u);
  EXPECT_LE(r.max_limit_excess, p.joint_tolerance);
  double q5_max = -1e9, ref5_max = -1e9;
  for (std::size_t k = 0; k < r.log.t.size(); ++k) {
    q5_max = std::max(q5_max, r.log.q[k][4]);
    ref5_max = std::max(ref5_max, r.log.q_ref[k][4]);
  }
  EXPECT_LE(ref5_max, bound + 1e-12);
  EXPECT_LE(q5_max, upper + p.joint_tolerance);
  // The arm settles at the clamped reference.
  EXPECT_NEAR(r.log.q.back()[4], bound, 1e-3);
  std::printf("clamped joint5 at t = %.3f s (%zu steps); max q5 %.5f rad vs upper %.5f\n",
              r.first_clamp_time, r.clamped_steps, q5_max, upper);
}

TEST(Executor, GrindingRemovesMaterialAndLoadsTheFlange) {
  const DefaultCell& cell = default_cell();
  FinCase fc = fin_case(cell);
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 5;
  const ForceParams force;
  const ExecutionResult free_run =
      execute_trajectory(*cell.model, fc.traj, nullptr, fc.tool, force, p);
  const double initial = fc.grid->flash_voxels_initial() * fc.grid->voxel_volume();
  const ExecutionResult r =
      execute_trajectory(*cell.model, fc.traj, fc.grid.get(), fc.tool, force, p);
  ASSERT_EQ(r.status, ExecStatus::kOk) << r.message;
  EXPECT_EQ(r.joint_limit_violations, 0u);
  ASSERT_TRUE(r.has_residual);

  // The burr cut a slot through the fin: its silhouette above the fin's root (the ball end up to
  // fin_top above the tip: a circular segment) times the fin's thickness.
  const double rad = fc.tool.radius, hseg = fc.fin_top;
  const double segment = rad * rad * std::acos((rad - hseg) / rad) -
                         (rad - hseg) * std::sqrt(2 * rad * hseg - hseg * hseg);
  const double slot = segment * fc.fin_thickness;
  EXPECT_NEAR(r.removed_flash_volume, slot, 0.3 * slot);
  EXPECT_NEAR(r.residual.flash_volume_initial, initial, 1e-15);
  EXPECT_NEAR(r.residual.flash_volume_initial - r.residual.flash_volume_remaining,
              r.removed_flash_volume, 1e-15);
  EXPECT_GT(r.residual.flash_removed_fraction, 0.0);
  EXPECT_LT(r.residual.flash_removed_fraction, 0.5);
  EXPECT_EQ(r.removed_body_volume, 0.0);
  EXPECT_GT(r.removal_steps, 100u);
  EXPECT_GT(r.contact_time, 0.3);
  EXPECT_GT(r.force_mean, 5.0);
  EXPECT_GE(r.force_max, r.force_mean);
  EXPECT_GT(r.log.removed_volume.back(), 0.0);

  // The flange sensor feels the process force: in contact, the change of its reading (against
  // the same motion without material) matches the force on the tool.
  ASSERT_EQ(free_run.log.t.size(), r.log.t.size());
  std::vector<std::size_t> contact;
  for (std::size_t k = 0; k < r.log.t.size(); ++k)
    if (r.log.normal_force[k] > 1.0) contact.push_back(k);
  ASSERT_GT(contact.size(), 20u);
  std::vector<Vec3> delta(r.log.t.size());
  for (std::size_t k = 0; k < delta.size(); ++k)
    delta[k] = r.log.sensor_force_W[k] - free_run.log.sensor_force_W[k];
  const Vec3 applied = mean_of(r.log.process_force_W, contact);
  const Vec3 felt = mean_of(delta, contact);
  EXPECT_GT(applied.norm(), 5.0);
  // MuJoCo's force sensor reports the force the parent (the wrist) exerts on the child (flange
  // and tool), so it changes by minus the force on the tool.
  EXPECT_LT((felt + applied).norm(), 0.15 * applied.norm())
      << "applied " << applied.transpose() << " felt " << felt.transpose();
  // Without contact the two runs see the same flange force.
  EXPECT_LT((delta.front()).norm(), 1e-9);
  std::printf(
      "fin cut: removed %.2f mm^3 (slot %.2f), contact %.2f s, normal force mean %.1f N max %.1f "
      "N; mean force on tool %.1f N, sensor change %.1f N; tracking RMSE %.3f mm (free %.4f "
      "mm); %zu removal steps, realtime factor %.0f\n",
      r.removed_flash_volume / (mm * mm * mm), slot / (mm * mm * mm), r.contact_time, r.force_mean,
      r.force_max, applied.norm(), felt.norm(), r.tracking_rmse / mm, free_run.tracking_rmse / mm,
      r.removal_steps, r.realtime_factor);

  // Applied explicitly (each removal step's wrench held until the next), the rate force throws
  // the tool back and forth: force peaks several times higher for the same cut.
  ExecParams px = p;
  px.implicit_rate_force = false;
  MaterialGrid gx = *fin_case(cell).grid;
  const ExecutionResult x = execute_trajectory(*cell.model, fc.traj, &gx, fc.tool, force, px);
  EXPECT_GT(x.force_max, 3 * r.force_max);
  std::printf("explicit rate force: normal force mean %.1f N max %.1f N, tracking RMSE %.3f mm\n",
              x.force_mean, x.force_max, x.tracking_rmse / mm);

  // Protective stop: a force limit below the cut's peak stops the trajectory at the first step
  // above it, and says so.
  ExecParams ps = p;
  ps.max_force = 0.5 * r.force_max;
  MaterialGrid gs = *fin_case(cell).grid;
  const ExecutionResult s = execute_trajectory(*cell.model, fc.traj, &gs, fc.tool, force, ps);
  EXPECT_EQ(s.status, ExecStatus::kForceLimit);
  EXPECT_NE(s.message.find("max_force"), std::string::npos) << s.message;
  EXPECT_LT(s.sim_time, r.sim_time);
  EXPECT_LE(s.removed_flash_volume, r.removed_flash_volume);
  EXPECT_STREQ(to_string(s.status), "force_limit");
}

TEST(Executor, SameInputsGiveIdenticalLogs) {
  const DefaultCell& cell = default_cell();
  FinCase fc = fin_case(cell);
  ExecParams p;
  p.settle_time = 0.05;
  p.log_decimation = 3;
  MaterialGrid g1 = *fc.grid, g2 = *fc.grid;
  const ExecutionResult a =
      execute_trajectory(*cell.model, fc.traj, &g1, fc.tool, ForceParams{}, p);
  const ExecutionResult b =
      execute_trajectory(*cell.model, fc.traj, &g2, fc.tool, ForceParams{}, p);
  ASSERT_GT(a.removed_flash_volume, 0.0);
  EXPECT_EQ(a.log.t, b.log.t);
  EXPECT_EQ(a.log.q, b.log.q);
  EXPECT_EQ(a.log.q_ref, b.log.q_ref);
  EXPECT_EQ(a.log.tcp_W, b.log.tcp_W);
  EXPECT_EQ(a.log.normal_force, b.log.normal_force);
  EXPECT_EQ(a.log.tangential_force, b.log.tangential_force);
  EXPECT_EQ(a.log.process_force_W, b.log.process_force_W);
  EXPECT_EQ(a.log.sensor_force_E, b.log.sensor_force_E);
  EXPECT_EQ(a.log.sensor_torque_E, b.log.sensor_torque_E);
  EXPECT_EQ(a.log.removed_volume, b.log.removed_volume);
  EXPECT_EQ(a.tracking_rmse, b.tracking_rmse);
  EXPECT_EQ(a.force_mean, b.force_mean);
  EXPECT_EQ(a.residual.flash_volume_remaining, b.residual.flash_volume_remaining);
  EXPECT_EQ(g1.flash_voxels_remaining(), g2.flash_voxels_remaining());
}

TEST(Executor, AdmittanceHoldsTheTargetNormalForce) {
  // The tool sweeps past a wall of flash at constant speed (joint 1 turns at a constant rate
  // between smooth ramps), its cutter overlapping the wall by 0.1 mm as planned. The arm yields
  // to the grinding force, so without control the force stays low; the admittance control moves
  // the tool into the wall until the normal force reaches the target.
  const DefaultCell& cell = default_cell();
  const ToolParams tool = tool_params_from(cell.robot.tool);
  const Vector6 home = cell.robot.home;
  const Pose X_WT = cell.spec.X_WB * planner::fk_tool(cell.robot, home);
  // Joint 1 speed for 10 mm/s at the TCP's distance from the base axis.
  const Vec3 p_BT = planner::fk_tool(cell.robot, home).translation();
  const double w1 = 0.010 / std::hypot(p_BT.x(), p_BT.y());
  JointTrajectory tr;
  const double ramp = 0.3, T = 3.0, dt = 0.01;
  for (int k = 0; k <= static_cast<int>(std::lround(T / dt)); ++k) {
    const double t = k * dt;
    // Trapezoidal speed: up over `ramp`, constant, down over `ramp`.
    double th, om;
    if (t < ramp) {
      om = w1 * t / ramp;
      th = 0.5 * w1 * t * t / ramp;
    } else if (t < T - ramp) {
      om = w1;
      th = w1 * (t - 0.5 * ramp);
    } else {
      const double u = T - t;
      om = w1 * u / ramp;
      th = w1 * (T - ramp) - 0.5 * w1 * u * u / ramp;
    }
    Vector6 q = home, dq = Vector6::Zero();
    q[0] += th;
    dq[0] = om;
    tr.t.push_back(t);
    tr.q.push_back(q);
    tr.dq.push_back(dq);
  }
  // Frame {F} at the start TCP: y along the motion (horizontal tangent), x horizontal away from
  // the base axis, z along the cutter axis (up).
  const Pose X_CW = cell.spec.X_WC.inverse();
  const Vec3 a_W = tool.axis_sign * X_WT.linear().col(2);
  const Vec3 y_W =
      a_W.cross(Vec3(p_BT.x(), p_BT.y(), 0).normalized()).normalized() * (w1 > 0 ? 1.0 : -1.0);
  Pose X_WF = Pose::Identity();
  X_WF.linear() << y_W.cross(a_W), y_W, a_W;
  X_WF.translation() = X_WT.translation();
  const Pose X_CF = X_CW * X_WF;
  // The wall on the tool's +x side (cylindrical part of the cutter only: z in [8, 11] mm), its
  // face 0.1 mm inside the cutter radius; the body beyond it, out of the tool's reach.
  const double face = tool.radius - 0.1 * mm;
  const TriangleMesh wall =
      box_mesh(Vec3(face, -20 * mm, 8 * mm), Vec3(20 * mm, 60 * mm, 11 * mm)).transformed(X_CF);
  const TriangleMesh body =
      box_mesh(Vec3(20 * mm, -20 * mm, 0), Vec3(30 * mm, 60 * mm, 20 * mm)).transformed(X_CF);
  const MaterialGrid grid0(body, {wall});

  ExecParams p;
  p.settle_time = 0;
  p.force_control.enabled = true;
  p.force_control.target_force = 40;
  MaterialGrid g_on = grid0, g_off = grid0;
  const ExecutionResult on = execute_trajectory(*cell.model, tr, &g_on, tool, ForceParams{}, p);
  ExecParams p_off = p;
  p_off.force_control.enabled = false;
  const ExecutionResult off =
      execute_trajectory(*cell.model, tr, &g_off, tool, ForceParams{}, p_off);
  ASSERT_EQ(on.status, ExecStatus::kOk) << on.message;
  ASSERT_EQ(off.status, ExecStatus::kOk) << off.message;
  // Mean normal force over the second half of the constant-speed phase.
  auto cruise_mean = [&](const ExecutionResult& r) {
    double s = 0;
    int n = 0;
    for (std::size_t k = 0; k < r.log.t.size(); ++k)
      if (r.log.t[k] >= 1.5 && r.log.t[k] <= T - ramp) {
        s += r.log.normal_force[k];
        ++n;
      }
    return n ? s / n : 0.0;
  };
  const double f_on = cruise_mean(on), f_off = cruise_mean(off);
  EXPECT_NEAR(f_on, 40.0, 8.0);
  EXPECT_LT(f_off, 20.0);
  EXPECT_GT(on.removed_flash_volume, 2 * off.removed_flash_volume);
  EXPECT_EQ(on.removed_body_volume, 0.0);
  EXPECT_GT(on.log.correction.back(), 0.0);
  EXPECT_LE(on.log.correction.back(), p.force_control.max_correction);
  EXPECT_EQ(off.log.correction.back(), 0.0);
  EXPECT_EQ(on.joint_limit_violations, 0u);
  std::printf(
      "admittance: target 40 N, cruise mean %.1f N (without control %.1f N); correction %.3f mm; "
      "removed %.2f mm^3 (without %.2f)\n",
      f_on, f_off, on.log.correction.back() / mm, on.removed_flash_volume / (mm * mm * mm),
      off.removed_flash_volume / (mm * mm * mm));
}

TEST(Executor, RejectsBadInputs) {
  const DefaultCell& cell = default_cell();
  JointTrajectory tr;
  tr.t = {0.0, 0.1};
  tr.q = {cell.robot.home, cell.robot.home};
  const ToolParams tool;
  const ForceParams force;
  JointTrajectory shape = tr;
  shape.dq = {Vector6::Zero()};
  EXPECT_THROW(execute_trajectory(*cell.model, shape, nullptr, tool, force), ArgumentError);
  JointTrajectory order = tr;
  order.t = {0.1, 0.1};
  EXPECT_THROW(execute_trajectory(*cell.model, order, nullptr, tool, force), ArgumentError);
  JointTrajectory empty;
  EXPECT_THROW(execute_trajectory(*cell.model, empty, nullptr, tool, force), ArgumentError);
  ExecParams slow;
  slow.timestep = 0.002;  // below 1 kHz
  EXPECT_THROW(execute_trajectory(*cell.model, tr, nullptr, tool, force, slow), ArgumentError);
  ExecParams dec;
  dec.log_decimation = 0;
  EXPECT_THROW(execute_trajectory(*cell.model, tr, nullptr, tool, force, dec), ArgumentError);
  // A model without the contract's names.
  const auto bare = load_mjcf_string(
      "<mujoco><worldbody><body><joint name=\"joint1\"/><geom size=\"0.1\"/></body>"
      "</worldbody></mujoco>");
  EXPECT_THROW(execute_trajectory(*bare, tr, nullptr, tool, force), InputError);
}

TEST(Executor, CallbackSeesEveryStep) {
  const DefaultCell& cell = default_cell();
  JointTrajectory tr;
  tr.t = {0.0, 0.05};
  tr.q = {cell.robot.home, cell.robot.home};
  ExecParams p;
  p.settle_time = 0.01;
  int calls = 0;
  double last = 0;
  p.on_step = [&](const mjModel* m, mjData* d, double t) {
    ++calls;
    EXPECT_EQ(m->nu, 6);
    EXPECT_DOUBLE_EQ(d->time, t);
    last = t;
  };
  const ExecutionResult r =
      execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, p);
  EXPECT_EQ(calls, 60);
  EXPECT_EQ(r.steps, 60u);
  EXPECT_NEAR(last, 0.06, 1e-12);
}

// The executor's feed-forward: rigid_inverse_dynamics equals mj_inverse on the cell's arm with
// contacts and constraints off, at random states (positions, velocities, accelerations).
TEST(Executor, RigidInverseDynamicsMatchesMjInverse) {
  const DefaultCell& cell = default_cell();
  MjModelPtr m(mj_copyModel(nullptr, cell.model.get()));
  m->opt.disableflags |= mjDSBL_CONSTRAINT | mjDSBL_CONTACT;
  const MjDataPtr a = make_data(m.get()), b = make_data(m.get());
  std::vector<mjtNum> tau(m->nv);
  Rng rng(11);
  for (int trial = 0; trial < 50; ++trial) {
    for (int i = 0; i < m->nq; ++i) a->qpos[i] = b->qpos[i] = rng.uniform(-2, 2);
    for (int i = 0; i < m->nv; ++i) {
      a->qvel[i] = b->qvel[i] = rng.uniform(-2, 2);
      a->qacc[i] = b->qacc[i] = rng.uniform(-10, 10);
    }
    mj_inverse(m.get(), a.get());
    rigid_inverse_dynamics(m.get(), b.get(), tau.data());
    for (int i = 0; i < m->nv; ++i)
      EXPECT_NEAR(tau[i], a->qfrc_inverse[i], 1e-9 * (1 + std::abs(a->qfrc_inverse[i])))
          << "trial " << trial << " dof " << i;
  }
}

// The controller's load estimate from the flange sensor, in free air: the wrist turns through
// large angles (the spindle's weight turns with it in the sensor's frame) and the estimate stays
// at the sensor's noise and drift, so the payload's weight and the tare are removed at every
// orientation (a wrong sign or centre of mass would show the tool's weight, ~40 N).
TEST(Executor, LoadEstimateIsZeroInFreeAirAtAnyOrientation) {
  const DefaultCell& cell = default_cell();
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb[3] += 1.2;
  qb[4] -= 0.9;
  qb[5] -= 1.5;
  const JointTrajectory tr = quintic(cell, qa, qb, 3.0, 0.01);
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 2;
  p.sensor_seed = 9;
  const ExecutionResult r = execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, p);
  ASSERT_EQ(r.status, ExecStatus::kOk) << r.message;
  ASSERT_EQ(r.log.load_force_W.size(), r.log.t.size());
  double worst = 0;
  Vec3 first_reading = r.log.sensor_force_E.front(), last_reading = r.log.sensor_force_E.back();
  for (std::size_t k = 0; k < r.log.t.size(); ++k) worst = std::max(worst, r.log.load_force_W[k].norm());
  // Noise 0.5 N RMS per axis (|F| of three axes: ~0.8 N, 4σ ~2.6 N), drift 0.2 N/√s over 3 s.
  EXPECT_LT(worst, 4.0);
  // The reading itself changed by the turning weight (the estimate removed it).
  EXPECT_GT((first_reading - last_reading).norm(), 10.0);
  std::printf("free air: load estimate max %.2f N while the reading changed by %.1f N\n", worst,
              (first_reading - last_reading).norm());
}

// Steel far from any fin, where the voxel grid tracks no body: the fin case's motion with the
// casting's top 0.3 mm above the burr's tip and the only fin 40 mm away. The exact CAD check
// measures the cut and the body pushes back (k = 2e5 N/m: ~60 N at 0.3 mm); without it the tool
// would pass through the steel unseen. 8 mm deep, the contact force trips the protective stop.
TEST(Executor, AGougeFarFromAnyFinIsMeasuredAndPushesBack) {
  const DefaultCell& cell = default_cell();
  const FinCase fc = fin_case(cell);
  // The motion over a casting whose top stands `top` above the tip's path ({F}: z up the axis).
  std::size_t body_removed = 0;
  auto run = [&](double top, const ExecParams& params) {
    const TriangleMesh body = box_mesh(Vec3(-25 * mm, -25 * mm, -10 * mm), Vec3(25 * mm, 25 * mm, top))
                                  .transformed(fc.X_CF);
    const TriangleMesh fin = box_mesh(Vec3(40 * mm, -5 * mm, top - 1 * mm), Vec3(40.3 * mm, 5 * mm, top + 3 * mm))
                                 .transformed(fc.X_CF);
    MaterialGrid grid(body, std::vector<TriangleMesh>{fin});
    const ExecutionResult res = execute_trajectory(*cell.model, fc.traj, &grid, fc.tool, ForceParams{}, params);
    body_removed = grid.body_voxels_removed();
    return res;
  };
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 5;
  p.cad_check_motion = 0.25e-3;
  const ExecutionResult r = run(0.3 * mm, p);
  ASSERT_EQ(r.status, ExecStatus::kOk) << r.message;
  EXPECT_EQ(body_removed, 0u);  // the voxels never saw it
  EXPECT_GT(r.untracked_penetration_max, 0.15 * mm);
  EXPECT_LT(r.untracked_penetration_max, 0.35 * mm);
  EXPECT_GT(r.force_max, 20.0);
  EXPECT_LT(r.force_max, 80.0);

  ExecParams blind = p;
  blind.cad_check_motion = 0;
  const ExecutionResult b = run(0.3 * mm, blind);
  EXPECT_EQ(b.untracked_penetration_max, 0.0);
  EXPECT_EQ(b.force_max, 0.0);

  ExecParams guarded = p;
  guarded.max_force = 500;
  const ExecutionResult d = run(8 * mm, guarded);
  EXPECT_EQ(d.status, ExecStatus::kForceLimit) << d.message;
  EXPECT_NE(d.message.find("tool driven into the part"), std::string::npos) << d.message;
  std::printf("steel away from the fins: 0.3 mm below the tip gouged %.3f mm at up to %.0f N "
              "(unchecked: %.3f mm, %.0f N); 8 mm deep: %s\n",
              r.untracked_penetration_max / mm, r.force_max, b.untracked_penetration_max / mm,
              b.force_max, d.message.c_str());
}

// Cutting the fin, the load the controller estimates from the sensor follows the process
// model's force on the tool, and deflection compensation fed by it (with the TCP damping that
// takes back the delay's negative damping) holds the plan as the oracle compensation does.
TEST(Executor, SensorFedCompensationHoldsThePlanThroughACut) {
  const DefaultCell& cell = default_cell();
  FinCase fc = fin_case(cell);
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 5;
  MaterialGrid g_oracle = *fc.grid, g_sensor = *fc.grid;
  const ExecutionResult oracle =
      execute_trajectory(*cell.model, fc.traj, &g_oracle, fc.tool, ForceParams{}, p);
  ExecParams ps = p;
  ps.compensation_source = CompensationSource::kSensor;
  ps.tcp_damping = 1000;
  const ExecutionResult sensed =
      execute_trajectory(*cell.model, fc.traj, &g_sensor, fc.tool, ForceParams{}, ps);
  ExecParams pn = p;
  pn.load_compensation = false;
  MaterialGrid g_none = *fc.grid;
  const ExecutionResult none =
      execute_trajectory(*cell.model, fc.traj, &g_none, fc.tool, ForceParams{}, pn);
  ASSERT_EQ(sensed.status, ExecStatus::kOk) << sensed.message;
  ASSERT_EQ(oracle.status, ExecStatus::kOk) << oracle.message;
  EXPECT_GT(sensed.force_mean, 20.0);
  EXPECT_GT(sensed.load_estimate_rmse, 0.0);
  EXPECT_LT(sensed.load_estimate_rmse, 0.5 * sensed.force_mean);
  EXPECT_LT(sensed.tracking_rmse, 0.1 * mm);
  EXPECT_LT(sensed.tracking_rmse, 0.5 * none.tracking_rmse);
  EXPECT_NEAR(sensed.removed_flash_volume, oracle.removed_flash_volume,
              0.1 * oracle.removed_flash_volume);
  std::printf(
      "fin cut, compensation from the sensor: tracking RMSE %.3f mm (oracle %.3f, none %.3f), "
      "load estimate RMSE %.1f N (process force mean %.1f N), removed %.2f mm^3 (oracle %.2f)\n",
      sensed.tracking_rmse / mm, oracle.tracking_rmse / mm, none.tracking_rmse / mm,
      sensed.load_estimate_rmse, sensed.force_mean, sensed.removed_flash_volume / (mm * mm * mm),
      oracle.removed_flash_volume / (mm * mm * mm));
}

// A cell without the flange sensor cannot run a controller that reads it.
TEST(Executor, ControllerThatReadsTheSensorNeedsOne) {
  const DefaultCell& cell = default_cell();
  std::ifstream in(cell.mjcf);
  std::stringstream ss;
  ss << in.rdbuf();
  std::string xml = ss.str();
  for (const char* name : {"flange_force", "flange_torque"}) {
    const std::size_t at = xml.find(std::string("name=\"") + name + "\"");
    ASSERT_NE(at, std::string::npos);
    const std::size_t b = xml.rfind('<', at), e = xml.find("/>", at);
    xml.erase(b, e + 2 - b);
  }
  const std::string path = ftest::temp_dir("executor_nosensor") + "/cell.xml";
  // The meshes are referenced relative to the cell's folder.
  std::string dir = cell.mjcf.substr(0, cell.mjcf.rfind('/'));
  std::size_t pos = 0;
  while ((pos = xml.find("file=\"", pos)) != std::string::npos) {
    pos += 6;
    if (xml[pos] != '/') xml.insert(pos, dir + "/");
  }
  std::ofstream(path) << xml;
  const MjModelPtr m = load_mjcf_file(path);
  JointTrajectory tr;
  tr.t = {0.0, 0.05};
  tr.q = {cell.robot.home, cell.robot.home};
  try {
    execute_trajectory(*m, tr, nullptr, ToolParams{}, ForceParams{}, ExecParams{});
    FAIL() << "ran without the flange sensor";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("flange_force"), std::string::npos) << e.what();
  }
  // A controller that reads no sensor runs.
  ExecParams blind;
  blind.load_compensation = false;
  blind.max_force = 0;
  EXPECT_EQ(execute_trajectory(*m, tr, nullptr, ToolParams{}, ForceParams{}, blind).status,
            ExecStatus::kOk);
}

// Fault drill: the burr stands 3.5 mm further along its axis than the controller's tool data
// says (a burr seated out of its collet). The fin case's body lies 3 mm below the tip: the
// controller tracks its own TCP as before, the process model cuts with the burr where it stands,
// 0.5 mm into the body, and measures that gouge.
TEST(Executor, ABurrOffItsToolDataCutsWhereItStands) {
  const DefaultCell& cell = default_cell();
  FinCase fc = fin_case(cell);
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 5;
  MaterialGrid g_ok = *fc.grid, g_off = *fc.grid;
  const ExecutionResult ok = execute_trajectory(*cell.model, fc.traj, &g_ok, fc.tool, ForceParams{}, p);
  ExecParams pf = p;
  pf.tcp_offset_T = Vec3(0, 0, -3.5 * mm * fc.tool.axis_sign);  // towards the tip, out of the tool
  const ExecutionResult off = execute_trajectory(*cell.model, fc.traj, &g_off, fc.tool, ForceParams{}, pf);
  ASSERT_EQ(ok.status, ExecStatus::kOk) << ok.message;
  ASSERT_EQ(off.status, ExecStatus::kOk) << off.message;
  EXPECT_EQ(ok.removed_body_volume, 0.0);
  EXPECT_EQ(ok.max_penetration, 0.0);
  EXPECT_GT(off.removed_body_volume, 0.0);
  // 0.5 mm into the body at most (plus the voxels' quantisation, 0.1 mm); the servos yield some
  // of it to the contact's push (the controller's TCP is pushed off its plan by millimetres).
  EXPECT_GT(off.max_penetration, 0.2 * mm);
  EXPECT_LT(off.max_penetration, 0.8 * mm);
  EXPECT_GT(off.tracking_rmse, 10 * ok.tracking_rmse);
  // More of the fin goes: the burr's ball reaches 3.5 mm lower through it.
  EXPECT_GT(off.removed_flash_volume, 1.2 * ok.removed_flash_volume);
  std::printf("burr 3.5 mm off its tool data: gouge %.3f mm (%.3f mm^3), flash removed %.2f mm^3 "
              "(%.2f on plan), tracking RMSE of the controller's TCP %.3f mm (%.3f)\n",
              off.max_penetration / mm, off.removed_body_volume / (mm * mm * mm),
              off.removed_flash_volume / (mm * mm * mm), ok.removed_flash_volume / (mm * mm * mm),
              off.tracking_rmse / mm, ok.tracking_rmse / mm);
}

// Fault drill: the sensor's zero steps by 60 N right after the tare. The controller reads it as
// load: with compensation from the sensor it pushes the tool against that phantom load, off its
// plan in free air by about 60 N over the arm's stiffness at the TCP; with the oracle
// compensation (which does not read the sensor) the tool stays on the plan.
TEST(Executor, ASensorZeroStepAfterTheTareIsReadAsLoad) {
  const DefaultCell& cell = default_cell();
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb[0] += 0.05;
  const JointTrajectory tr = quintic(cell, qa, qb, 2.0, 0.01);
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 2;
  p.sensor_seed = 3;
  p.compensation_source = CompensationSource::kSensor;
  p.tcp_damping = 1000;
  const ExecutionResult clean = execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, p);
  ExecParams pf = p;
  pf.sensor_step_E.force = Vec3(0, 60, 0);
  const ExecutionResult biased = execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, pf);
  ExecParams po = pf;
  po.compensation_source = CompensationSource::kProcessModel;
  po.tcp_damping = 0;
  const ExecutionResult oracle = execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, po);
  for (const auto* r : {&clean, &biased, &oracle}) ASSERT_EQ(r->status, ExecStatus::kOk) << r->message;
  // After the tare and the filter's settling, the estimate shows the step (±4 N of noise and
  // drift), in free air.
  double worst_dev = 0;
  for (std::size_t k = 0; k < biased.log.t.size(); ++k)
    if (biased.log.t[k] > 0.1) worst_dev = std::max(worst_dev, std::abs(biased.log.load_force_W[k].norm() - 60.0));
  EXPECT_LT(worst_dev, 4.0);
  EXPECT_LT(clean.tracking_max, 0.1 * mm);
  EXPECT_GT(biased.tracking_max, 0.5 * mm);
  EXPECT_LT(oracle.tracking_max, 0.1 * mm);
  std::printf("sensor zero step of 60 N: tracking max %.3f mm with compensation from the sensor "
              "(%.3f mm without the step, %.3f mm with the oracle compensation)\n",
              biased.tracking_max / mm, clean.tracking_max / mm, oracle.tracking_max / mm);
}

// Where the plan stops the arm in free air (JointTrajectory::tare_t) the controller zeroes the
// sensor again: the drift since the start (here a fast 5 N/√s random walk) leaves the load
// estimate, which is exactly zero while the new tare is taken. Without the stop the estimate
// keeps the drift. Bad tare times are refused naming the field.
TEST(Executor, AStopInFreeAirReZeroesTheSensorsDrift) {
  const DefaultCell& cell = default_cell();
  const Vector6 qa = cell.robot.home;
  Vector6 qb = qa;
  qb[0] += 0.05;
  // Out and back, at rest at t = 4 s.
  JointTrajectory tr = quintic(cell, qa, qb, 4.0, 0.01);
  const JointTrajectory back = quintic(cell, qb, qa, 1.0, 0.01);
  for (std::size_t k = 1; k < back.t.size(); ++k) {
    tr.t.push_back(4.0 + back.t[k]);
    tr.q.push_back(back.q[k]);
    tr.dq.push_back(back.dq[k]);
    tr.planned_tcp_W.push_back(back.planned_tcp_W[k]);
  }
  ExecParams p;
  p.settle_time = 0.1;
  p.log_decimation = 1;
  p.sensor_seed = 11;
  p.sensor.force_drift = 5;
  p.compensation_source = CompensationSource::kSensor;
  p.tcp_damping = 1000;
  const ExecutionResult kept =
      execute_trajectory(*cell.model, tr, nullptr, ToolParams{}, ForceParams{}, p);
  JointTrajectory stop = tr;
  stop.tare_t = {0.0, 4.0};  // the start's tare is taken anyway
  const ExecutionResult again =
      execute_trajectory(*cell.model, stop, nullptr, ToolParams{}, ForceParams{}, p);
  ASSERT_EQ(kept.status, ExecStatus::kOk) << kept.message;
  ASSERT_EQ(again.status, ExecStatus::kOk) << again.message;
  ASSERT_EQ(kept.log.t.size(), again.log.t.size());
  double zero_max = 0, kept_sum = 0, again_sum = 0;
  int taring = 0, after = 0;
  for (std::size_t k = 0; k < again.log.t.size(); ++k) {
    const double t = again.log.t[k];
    if (t > 4.003 && t < 4.019) {
      zero_max = std::max(zero_max, again.log.load_force_W[k].norm());
      ++taring;
    }
    if (t > 4.03 && t < 4.1) {
      kept_sum += kept.log.load_force_W[k].norm();
      again_sum += again.log.load_force_W[k].norm();
      ++after;
    }
  }
  ASSERT_GT(taring, 5);
  ASSERT_GT(after, 20);
  EXPECT_EQ(zero_max, 0.0);
  EXPECT_GT(kept_sum / after, 8.0);
  EXPECT_LT(again_sum, 0.3 * kept_sum);
  std::printf(
      "sensor drift 5 N/sqrt(s): load estimate after a stop in free air %.1f N (%.1f N "
      "without the re-tare)\n",
      again_sum / after, kept_sum / after);
  // A sensor-bias drill steps the zero by 10 N after the first tare: read as load until the
  // stop, taken out by the re-tare there (drift off here, so the step alone shows).
  ExecParams pd = p;
  pd.sensor.force_drift = 0;
  pd.sensor_step_E.force = Vec3(0, 10, 0);
  const ExecutionResult drill =
      execute_trajectory(*cell.model, stop, nullptr, ToolParams{}, ForceParams{}, pd);
  ASSERT_EQ(drill.status, ExecStatus::kOk) << drill.message;
  double before = 0, after_stop = 0;
  int nb = 0, na = 0;
  for (std::size_t k = 0; k < drill.log.t.size(); ++k) {
    const double t = drill.log.t[k];
    if (t > 3.0 && t < 3.9) before += drill.log.load_force_W[k].norm(), ++nb;
    if (t > 4.1 && t < 4.9) after_stop += drill.log.load_force_W[k].norm(), ++na;
  }
  ASSERT_GT(nb, 20);
  ASSERT_GT(na, 20);
  EXPECT_NEAR(before / nb, 10.0, 2.0);
  EXPECT_LT(after_stop / na, 2.0);
  JointTrajectory bad = tr;
  bad.tare_t = {4.0, 0.5};
  try {
    execute_trajectory(*cell.model, bad, nullptr, ToolParams{}, ForceParams{}, p);
    ADD_FAILURE() << "decreasing tare times accepted";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("execution.trajectory.tare_t"), std::string::npos)
        << e.what();
  }
}

// ---- Collisions of the robot with the cell (CellCollision, CollisionMonitor in the executor)

namespace {

// The joint angles that put the TCP at p_W with the tool pointing straight down (nearest home).
Vector6 tool_down_at(const DefaultCell& cell, const Vec3& p_W) {
  const Pose X_BW = cell.spec.X_WB.inverse();
  Pose X_WT = Pose::Identity();
  X_WT.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();  // z_T down
  X_WT.translation() = p_W;
  planner::IkParams ip;
  ip.q_ref = cell.robot.home;
  const planner::IkResult r = planner::ik_tool(cell.robot, X_BW * X_WT, ip);
  EXPECT_TRUE(r.ok()) << r.message;
  Vector6 best = cell.robot.home;
  double d = 1e300;
  for (const auto& s : r.solutions)
    if ((s.q - cell.robot.home).norm() < d) d = (s.q - cell.robot.home).norm(), best = s.q;
  return best;
}

// A point on the table top 0.2 m beside the casting, lifted by h along the table normal.
// The arm of the cell's model at q (kinematics only).
void set_arm(const DefaultCell& cell, mjData* d, const Vector6& q) {
  for (int i = 0; i < kNumJoints; ++i)
    d->qpos[cell.model->jnt_qposadr[mj_name2id(cell.model.get(), mjOBJ_JOINT,
                                                ("joint" + std::to_string(i + 1)).c_str())]] = q[i];
  mj_kinematics(cell.model.get(), d);
}

Vec3 beside_casting(const DefaultCell& cell, double h) {
  return cell.spec.X_WTable * Vec3(0.0, 0.2, h);
}

// The default cell's collision geometry, its casting's CAD where it truly stands (built once).
struct CollisionCell {
  ToolDescription tool;
  TriangleMesh nominal;
  std::unique_ptr<MeshBvh> cad;
  std::unique_ptr<CellCollision> collision;
};
const CollisionCell& collision_cell() {
  static const CollisionCell cc = [] {
    const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
    CollisionCell c;
    c.tool = sc.robot.tool;
    c.nominal = pipeline::setup_cell(sc).casting.nominal;
    c.cad = std::make_unique<MeshBvh>(c.nominal);
    c.collision = std::make_unique<CellCollision>(*default_cell().model, *c.cad, default_cell().spec.X_WC);
    return c;
  }();
  return cc;
}

}  // namespace

TEST(Collision, ClearanceAboveTheTableIsTheBurrsHeightAndInsideItIsADepth) {
  const DefaultCell& cell = default_cell();
  const CellCollision& collision = *collision_cell().collision;
  ASSERT_GT(collision.robot_geoms(), 6u);
  const MjDataPtr d = make_data(cell.model.get());
  const auto at = [&](const Vector6& q) {
    set_arm(cell, d.get(), q);
    return collision.check(*d);
  };
  // The ball tip 30 mm above the top: the burr is what comes nearest, 30 mm from the table.
  const CollisionHit above = at(tool_down_at(cell, beside_casting(cell, 0.03)));
  EXPECT_FALSE(above.colliding());
  EXPECT_EQ(above.robot_geom, "burr");
  EXPECT_EQ(above.obstacle, "table_top");
  EXPECT_NEAR(above.clearance, 0.03, 1e-4);
  // 12 mm into the top: a penetration of that depth.
  const CollisionHit into = at(tool_down_at(cell, beside_casting(cell, -0.012)));
  EXPECT_TRUE(into.colliding());
  EXPECT_EQ(into.obstacle, "table_top");
  EXPECT_NEAR(into.clearance, -0.012, 1e-4);
  // The tool's shank 10 mm down into the casting's CAD body: the burr cuts (not a collision),
  // the shank above it collides with the casting.
  Vec3 lo, hi;
  collision_cell().nominal.bounds(lo, hi);
  const Vec3 top_W = cell.spec.X_WC * Vec3(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z());
  const Vec3 up_W = cell.spec.X_WC.linear().col(2);
  bool shank_hit = false;
  for (double dx = -0.06; dx <= 0.06 && !shank_hit; dx += 0.01) {
    // Somewhere on the top face (a hole may stand at the centre).
    const Vec3 p = top_W + cell.spec.X_WC.linear().col(0) * dx - up_W * (collision_cell().tool.length + 0.01);
    const CollisionHit h = at(tool_down_at(cell, p));
    shank_hit = h.colliding() && h.robot_geom == "shank" && h.obstacle == "casting";
  }
  EXPECT_TRUE(shank_hit) << "no pose over the top face put the shank into the casting";
}

// A burr from the tool rack stands in the rack's slim holder: beside a fixture block, where the
// mounted burr's collet nut (25 mm) stands 2.5 mm into the block, the slim holder (16 mm) keeps
// 2 mm clear of it.
TEST(Collision, ARackBurrsSlimHolderKeepsClearWhereTheColletNutWouldNot) {
  const DefaultCell& cell = default_cell();
  const CollisionCell& cc = collision_cell();
  const BurrHolder mounted = holder_for(cc.tool, cc.tool.radius);
  const double r_rack = cc.tool.radius - 0.001;  // a smaller burr: on a shank 1 mm under its radius
  const BurrHolder rack = holder_for(cc.tool, r_rack);
  EXPECT_EQ(mounted.collet_radius, cc.tool.collet_radius);
  EXPECT_EQ(rack.collet_radius, cc.tool.rack_collet_radius);
  EXPECT_NEAR(rack.shank_radius, std::min(cc.tool.shank_radius, r_rack - 0.001), 1e-15);
  const std::vector<FixtureBlock> blocks =
      cell.spec.fixtures.empty() ? fixture_blocks(cell.spec, cc.nominal) : cell.spec.fixtures;
  ASSERT_FALSE(blocks.empty());
  const FixtureBlock& b = blocks.front();
  // Tool upright, its tip 2 mm over the block's foot, its axis 10 mm beyond the block's end
  // face: the collet (from burr + shank up) reaches down beside the block's top 3 mm.
  const double collet_bottom = cc.tool.length + cc.tool.shank_length + 0.002;
  ASSERT_GT(2 * b.half_size.z(), collet_bottom + 0.002) << "the block is too low for the test";
  const double axis_off = mounted.collet_radius - 0.0025;
  const Vec3 tip_W = b.X_WF * Vec3(0, b.half_size.y() + axis_off, -b.half_size.z() + 0.002);
  const MjDataPtr d = make_data(cell.model.get());
  const Vector6 q = tool_down_at(cell, tip_W);
  set_arm(cell, d.get(), q);
  const CellCollision slim(*cell.model, *cc.cad, cell.spec.X_WC, nullptr, rack.shank_radius,
                           rack.collet_radius);
  const auto collet_hit = [&](const CellCollision& c) {
    for (std::size_t k = 0; k < c.robot_geoms(); ++k) {
      const char* name = mj_id2name(cell.model.get(), mjOBJ_GEOM, c.geom_id(k));
      if (name && std::string(name) == "collet") return c.check_geom(*d, k);
    }
    ADD_FAILURE() << "no collet geom";
    return CollisionHit{};
  };
  const CollisionHit nut = collet_hit(*cc.collision), holder = collet_hit(slim);
  EXPECT_EQ(nut.obstacle, b.name);
  EXPECT_NEAR(nut.clearance, -0.0025, 5e-4);
  EXPECT_EQ(holder.obstacle, b.name);
  EXPECT_NEAR(holder.clearance, axis_off - rack.collet_radius, 5e-4);
  EXPECT_GT(holder.clearance, 0.001);
}

// Flash the planner knows of (perception's detected points) is an obstacle of every robot geom,
// the burr's too: a transit planned only against the CAD ran its burr through 8 mm fins (cover
// seed 907, 10 mm deep, 130 mm off its path).
TEST(Collision, DetectedFlashIsAnObstacleOfTheBurrToo) {
  const DefaultCell& cell = default_cell();
  CellCollision collision(*cell.model, *collision_cell().cad, cell.spec.X_WC);
  const Vec3 tip_W = beside_casting(cell, 0.03);
  const Vec3 up_W = cell.spec.X_WTable.linear().col(2);
  const Vec3 side_W = cell.spec.X_WTable.linear().col(0);
  const MjDataPtr d = make_data(cell.model.get());
  const Vector6 q = tool_down_at(cell, tip_W);
  set_arm(cell, d.get(), q);
  const double r = collision_cell().tool.radius;
  // A point on the burr's axis 10 mm up from its tip lies r deep in it.
  collision.set_known_flash({tip_W + 0.01 * up_W});
  const CollisionHit in = collision.check(*d);
  EXPECT_TRUE(in.colliding());
  EXPECT_EQ(in.robot_geom, "burr");
  EXPECT_EQ(in.obstacle, "flash (detected)");
  EXPECT_NEAR(in.clearance, -r, 1e-9);
  // 16 mm to the side of the axis: 16 mm - r clear, nearer than the table 30 mm below.
  collision.set_known_flash({tip_W + 0.01 * up_W + 0.016 * side_W});
  const CollisionHit beside = collision.check(*d);
  EXPECT_EQ(beside.obstacle, "flash (detected)");
  EXPECT_NEAR(beside.clearance, 0.016 - r, 1e-9);
  // Without it the table is nearest.
  collision.set_known_flash({});
  EXPECT_NE(collision.check(*d).obstacle, "flash (detected)");
  EXPECT_THROW(collision.set_known_flash({tip_W}, 0.0), ArgumentError);
}

TEST(Collision, TheExecutorCountsStepsInContactAndNoneOnAClearMove) {
  const DefaultCell& cell = default_cell();
  const CellCollision& collision = *collision_cell().collision;
  const Vector6 q_high = tool_down_at(cell, beside_casting(cell, 0.06));
  const Vector6 q_low = tool_down_at(cell, beside_casting(cell, 0.02));
  const Vector6 q_into = tool_down_at(cell, beside_casting(cell, -0.008));
  ExecParams ep;
  ep.collisions = &collision;
  const ToolParams tool = tool_params_from(collision_cell().tool);
  const ExecutionResult clear =
      execute_trajectory(*cell.model, quintic(cell, q_high, q_low, 2.0, 0.01), nullptr, tool, {}, ep);
  EXPECT_EQ(clear.collision_steps, 0u);
  // What the checks found: never below the burr tip's 20 mm over the top at the end (the
  // monitor checks a geom again only once it could have come nearer than its last clearance).
  EXPECT_GE(clear.min_clearance, 0.02 - 1e-3);
  const ExecutionResult hit =
      execute_trajectory(*cell.model, quintic(cell, q_high, q_into, 2.0, 0.01), nullptr, tool, {}, ep);
  EXPECT_GT(hit.collision_steps, 0u);
  EXPECT_EQ(hit.first_collision.robot_geom, "burr");
  EXPECT_EQ(hit.first_collision.obstacle, "table_top");
  EXPECT_GT(hit.first_collision_time, 1.0);  // the tip reaches the top late in the move
  EXPECT_NEAR(hit.collision_max_depth, 0.008, 1e-3);
}

// While grinding, the burr in the casting's body is a cut (the process model's gouge); in a
// transit it is a collision, for the planner and for the twin's measurement: transits planned
// without it ran the burr from one bolt hole to the next through the flange between them
// (housing seed 7348: 0.94 mm gouge, the arm thrown 7 mm off its plan).
TEST(Collision, TheBurrInTheBodyIsACutWhileGrindingAndACollisionInATransit) {
  const DefaultCell& cell = default_cell();
  const CollisionCell& cc = collision_cell();
  CellCollision transit(*cell.model, *cc.cad, cell.spec.X_WC);
  transit.set_burr_checks_body(true);
  Vec3 lo, hi;
  cc.nominal.bounds(lo, hi);
  const Vec3 top_W = cell.spec.X_WC * Vec3(0.5 * (lo.x() + hi.x()), 0.5 * (lo.y() + hi.y()), hi.z());
  const Vec3 up_W = cell.spec.X_WC.linear().col(2);
  const MjDataPtr d = make_data(cell.model.get());
  // The ball tip 3 mm under the casting's top (somewhere on it: a hole may stand at the centre).
  bool found = false;
  for (double dx = -0.06; dx <= 0.06 && !found; dx += 0.01) {
    const Vec3 base_W = top_W + cell.spec.X_WC.linear().col(0) * dx;
    const Vector6 q_into = tool_down_at(cell, base_W - 0.003 * up_W);
    set_arm(cell, d.get(), q_into);
    const CollisionHit h = transit.check(*d);
    if (!(h.robot_geom == "burr" && h.obstacle == "casting")) continue;
    found = true;
    // In by at most the tip's 3 mm (less where a side of a narrow top is nearer).
    EXPECT_LT(h.clearance, -0.001);
    EXPECT_GE(h.clearance, -0.003 - 2e-4);
    const CollisionHit g = cc.collision->check(*d);  // grinding: the burr's cut is no collision
    EXPECT_FALSE(g.robot_geom == "burr" && g.obstacle == "casting");
    EXPECT_FALSE(g.colliding());
    // 10 mm over the face: 10 mm clear for the transit's check.
    const Vector6 q_over = tool_down_at(cell, base_W + 0.010 * up_W);
    set_arm(cell, d.get(), q_over);
    const CollisionHit over = transit.check(*d);
    EXPECT_EQ(over.obstacle, "casting");
    EXPECT_NEAR(over.clearance, 0.010, 2e-4);
    // Executed (no material grid): the transit's monitor counts the steps in the body, the
    // grinding one none.
    ExecParams ep;
    ep.collisions = &transit;
    const ToolParams tool = tool_params_from(cc.tool);
    const JointTrajectory plunge = quintic(cell, q_over, q_into, 1.0, 0.01);
    const ExecutionResult hit = execute_trajectory(*cell.model, plunge, nullptr, tool, {}, ep);
    EXPECT_GT(hit.collision_steps, 0u);
    EXPECT_EQ(hit.deepest_collision.robot_geom, "burr");
    EXPECT_EQ(hit.deepest_collision.obstacle, "casting");
    EXPECT_NEAR(hit.collision_max_depth, -h.clearance, 5e-4);
    ep.collisions = cc.collision.get();
    EXPECT_EQ(execute_trajectory(*cell.model, plunge, nullptr, tool, {}, ep).collision_steps, 0u);
  }
  EXPECT_TRUE(found) << "no pose over the top face put the burr into the casting";
}
