// The second setup (`placement.turn_over`): a part held in an orientation where some of its
// roots face the table or lie out of the arm's reach is turned over, scanned, registered and
// ground again on the same material.
#include <gtest/gtest.h>

#include <algorithm>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "scenario_run.hpp"
#include "test_util.hpp"

using namespace flashtwin;

// The turned part faces the asked direction up, rests on the table top and stands where the
// cell's layout check accepts it; the draw is the seed's (the same each time).
TEST(TurnOver, ThePartFacesTheAskedDirectionUpAndRestsOnTheTable) {
  auto sc = pipeline::load_scenario(ftest::source_path("scenarios/tilted.yaml"));
  sc.seed = 8001;
  const pipeline::CellSetup first = pipeline::setup_cell(sc);
  const Vec3 up_C = Vec3(0.3, -0.2, -0.9).normalized();
  const auto second = pipeline::turned_over(sc, first, first.casting, up_C);
  const Mat3 R_TC = first.spec.X_WTable.linear().transpose() * second.spec.X_WC.linear();
  EXPECT_GT((R_TC * up_C).z(), 1 - 1e-12);
  const Pose X_TC = first.spec.X_WTable.inverse() * second.spec.X_WC;
  double lowest = 1e300;
  for (const auto& v : second.casting.nominal.vertices) lowest = std::min(lowest, (X_TC * v).z());
  EXPECT_NEAR(lowest, 0.0, 1e-12);
  const auto again = pipeline::turned_over(sc, first, first.casting, up_C);
  EXPECT_TRUE(again.spec.X_WC.isApprox(second.spec.X_WC, 0));
  EXPECT_THROW(pipeline::turned_over(sc, first, first.casting, Vec3::Zero()), ArgumentError);
}

// Tilted seed 8001 lies with its plate on edge: the first setup reaches one of its seven roots
// (six paths put the wrist out of reach) and removes under half of the flash. The cell turns it
// so that the roots it could not grind face sideways and the plate lies low, registers it anew
// (perception is told nothing of the turn) and grinds the rest: the part comes out to spec.
TEST(TurnOver, ATiltedPlateTheArmCannotReachIsGroundInASecondSetup) {
  auto sc = pipeline::load_scenario(ftest::source_path("scenarios/tilted.yaml"));
  sc.seed = 8001;
  sc.placement.turn_over = true;
  pipeline::RunOptions o;
  o.report = false;
  o.write_scan = false;
  o.out_dir = ftest::temp_dir("turn_over_8001");
  const auto r = pipeline::run_scenario(sc, o);
  const auto& m = r.metrics;
  EXPECT_LT(m["setup1.removal.flash_removed_fraction"].get<double>(), 0.5);
  EXPECT_GE(m["trajectory.paths_deferred"].get<int>(), 4);
  EXPECT_EQ(m["setup2.registration.confident"], true);
  EXPECT_LT(m["setup2.registration.translation_error_mm"].get<double>(), 0.1);
  EXPECT_EQ(m["trajectory.paths_failed"].get<int>(), 0);
  EXPECT_GT(m["removal.flash_removed_fraction"].get<double>(), 0.97);
  EXPECT_LT(m["removal.gouge_max_mm"].get<double>(), 0.1);
  EXPECT_EQ(m["execution.paths_stopped_force_limit"].get<int>(), 0);
  EXPECT_GT(m["path.coverage"].get<double>(), 0.95);
  EXPECT_EQ(r.exit_code, 0) << r.verdict;
}

// Tilted 8011 (with a fin-ring rule tried and reverted this session, which sent its hole to a
// rack burr): a hole path's timed motion, sampled every period, took joint 5 0.034 rad past its
// range while its path samples and its timing grid were inside; the executor clamped the joint,
// the burr left its path and gouged 0.85 mm. The planner now checks the commanded motion itself:
// no reference the executor receives needs clamping, over both setups.
TEST(TurnOver, NoCommandedMotionLeavesAJointRange) {
  const auto r = ftest::scenario_run("tilted", 8011, true);
  const auto& m = r.metrics;
  EXPECT_EQ(m["execution.clamped_steps"].get<int>(), 0);
  EXPECT_EQ(m["execution.joint_limit_violations"].get<int>(), 0);
  EXPECT_GE(m["trajectory.paths_deferred"].get<int>(), 1);
  EXPECT_EQ(m["setup2.registration.confident"], true);
}
