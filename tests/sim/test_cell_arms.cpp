// Every arm of the robot library in the MuJoCo cell: the MJCF's flange and TCP sites follow the
// D-H kinematics, and the position servos hold the home pose against gravity within their
// torque limits (real dynamics: a torque limit too small for the arm's own weight fails here).
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "test_util.hpp"

using namespace flashtwin;

namespace {

class CellArms : public ::testing::TestWithParam<const char*> {
 protected:
  RobotModel robot = load_robot(ftest::source_path(std::string("models/robots/") + GetParam() +
                                                   ".yaml"));
};

Pose site_pose(const mjData* d, int id) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(d->site_xpos[3 * id], d->site_xpos[3 * id + 1], d->site_xpos[3 * id + 2]);
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) X.linear()(r, c) = d->site_xmat[9 * id + 3 * r + c];
  return X;
}

}  // namespace

TEST_P(CellArms, MjcfSitesFollowTheDhKinematics) {
  const sim::CellSpec spec;
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, spec), "cell.xml");
  const auto d = sim::make_data(m.get());
  const int flange = sim::require_id(m.get(), mjOBJ_SITE, "flange");
  const int tcp = sim::require_id(m.get(), mjOBJ_SITE, "tcp");
  Rng rng(17);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 300; ++n) {
    Vector6 q;
    for (int i = 0; i < 6; ++i) {
      q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
      d->qpos[m->jnt_qposadr[sim::require_id(m.get(), mjOBJ_JOINT, "joint" + std::to_string(i + 1))]] = q[i];
    }
    mj_kinematics(m.get(), d.get());
    const Pose E = site_pose(d.get(), flange), T = site_pose(d.get(), tcp);
    const Pose X_WE = spec.X_WB * planner::fk_flange(robot, q);
    const Pose X_WT = spec.X_WB * planner::fk_tool(robot, q);
    worst_p = std::max({worst_p, (E.translation() - X_WE.translation()).norm(),
                        (T.translation() - X_WT.translation()).norm()});
    worst_r = std::max(worst_r, rotation_distance(E.linear(), X_WE.linear()));
  }
  EXPECT_LT(worst_p, 1e-9) << robot.name;
  EXPECT_LT(worst_r, 1e-9) << robot.name;
}

TEST_P(CellArms, ServosHoldHomeAgainstGravityWithinTheirTorques) {
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, sim::CellSpec{}), "cell.xml");
  const auto d = sim::make_data(m.get());
  mj_resetDataKeyframe(m.get(), d.get(), sim::require_id(m.get(), mjOBJ_KEY, "home"));
  for (int k = 0; k < 2000; ++k) mj_step(m.get(), d.get());  // 2 s at 1 kHz
  double worst = 0;
  for (int i = 0; i < 6; ++i) worst = std::max(worst, std::abs(d->qpos[i] - robot.home[i]));
  EXPECT_LT(worst, 0.02) << robot.name;
  for (int i = 0; i < 6; ++i) {
    EXPECT_LT(std::abs(d->qvel[i]), 1e-2) << robot.name << " joint " << i + 1;
    // Holding the pose takes less than the joint's torque limit (the servo is not saturated).
    EXPECT_LT(std::abs(d->actuator_force[i]), 0.9 * robot.limits[i].torque)
        << robot.name << " joint " << i + 1;
  }
}

namespace {

// Joint-space inertia diagonal at home and the servos' stiffness and damping, from the MJCF.
struct ServoAtHome {
  std::array<double, kNumJoints> M{}, kp{}, damping{};
};

ServoAtHome servo_at_home(const RobotModel& robot) {
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, sim::CellSpec{}), "cell.xml");
  const auto d = sim::make_data(m.get());
  mj_resetDataKeyframe(m.get(), d.get(), sim::require_id(m.get(), mjOBJ_KEY, "home"));
  mj_forward(m.get(), d.get());
  std::vector<mjtNum> M(m->nv * m->nv);
  mj_fullM(m.get(), M.data(), d->qM);
  ServoAtHome s;
  for (int i = 0; i < kNumJoints; ++i) {
    const int j = sim::require_id(m.get(), mjOBJ_JOINT, "joint" + std::to_string(i + 1));
    const int v = m->jnt_dofadr[j];
    s.M[i] = M[v * m->nv + v];
    s.kp[i] = m->actuator_gainprm[i * mjNGAIN];
    s.damping[i] = m->dof_damping[v];
  }
  return s;
}

}  // namespace

// The library's servo gains follow one rule: each joint's bandwidth sqrt(kp/M) and damping ratio
// at home are the FT6's (whose gains the executor and the sweeps were tuned with), so a heavier
// arm is not a softer one.
TEST_P(CellArms, ServoBandwidthIsTheFt6s) {
  const ServoAtHome ft6 = servo_at_home(ftest::ft6()), arm = servo_at_home(robot);
  for (int i = 0; i < kNumJoints; ++i) {
    const double w_ft6 = std::sqrt(ft6.kp[i] / ft6.M[i]), w = std::sqrt(arm.kp[i] / arm.M[i]);
    const double z_ft6 = ft6.damping[i] / (2 * std::sqrt(ft6.kp[i] * ft6.M[i]));
    const double z = arm.damping[i] / (2 * std::sqrt(arm.kp[i] * arm.M[i]));
    EXPECT_NEAR(w / w_ft6, 1.0, 0.01) << robot.name << " joint " << i + 1;
    EXPECT_NEAR(z / z_ft6, 1.0, 0.01) << robot.name << " joint " << i + 1;
  }
}

INSTANTIATE_TEST_SUITE_P(Library, CellArms,
                         ::testing::Values("ft6", "kuka_kr16", "abb_irb4600", "fanuc_m20ia",
                                           "ur10e"));

// Every library arm waits at home clear of the default cell's scanner head (on the floor, the
// UR10e on a pedestal at the table's height: the default scenario's cell with each arm), and an
// arm parked through the head is refused naming the field and the link.
TEST_P(CellArms, HomeIsClearOfTheScannerHead) {
  sim::CellSpec spec;
  spec.base_height = 0;
  spec.X_WB = Pose(Eigen::Translation3d(0, 0, robot.name == "ur10e" ? 0.78 : 0.0));
  if (robot.name == "ft6") spec = sim::CellSpec{};
  EXPECT_NO_THROW(sim::check_arm_clear_of_scanner(robot, spec)) << robot.name;
}

TEST(CellArms, AnArmParkedThroughTheScannerHeadIsRefused) {
  RobotModel kr16 = load_robot(ftest::source_path("models/robots/kuka_kr16.yaml"));
  kr16.home[0] = 0;  // facing the table: the forearm passes through the head at 1.3 m
  sim::CellSpec spec;
  spec.base_height = 0;
  spec.X_WB = Pose::Identity();
  try {
    sim::check_arm_clear_of_scanner(kr16, spec);
    ADD_FAILURE() << "accepted";
  } catch (const ConfigError& e) {
    const std::string m = e.what();
    EXPECT_NE(m.find("cell.scanner_mount"), std::string::npos) << m;
    EXPECT_NE(m.find("link 4"), std::string::npos) << m;
  }
}
