// Fault drills (`faults:`): what the cell gets wrong and perception and planning do not know
// must show in the part and its verdict.
#include <gtest/gtest.h>

#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "test_util.hpp"

using namespace flashtwin;

namespace {

pipeline::RunResult drill(const std::string& name, const pipeline::Faults& faults) {
  auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  sc.faults = faults;
  pipeline::RunOptions o;
  o.report = false;
  o.write_scan = false;
  o.out_dir = ftest::temp_dir("fault_" + name);
  return pipeline::run_scenario(sc, o);
}

}  // namespace

// The default plate ground 3 mm off (the part moved in its clamps after the scan): the burr
// cuts into the walls on one side and misses the fins' roots on the other. Perception is not
// told (its pose is as good as without the fault); the part fails its quality limits and the
// run exits 1 naming them. (The shipped seed is to spec without the fault: the regression
// check of scenarios/default.yaml.)
TEST(FaultDrill, APartThreeMillimetresOffItsScannedPoseFailsWithGougeAndFlashLeft) {
  pipeline::Faults f;
  f.part_offset_C.translation() = Vec3(0, 0.003, 0);
  const auto r = drill("offset", f);
  const auto& m = r.metrics;
  EXPECT_FALSE(r.refused) << r.verdict;
  EXPECT_LT(m["registration.translation_error_mm"].get<double>(), 0.1);
  EXPECT_NEAR(m["faults.part_offset_mm"].get<double>(), 3.0, 1e-9);
  EXPECT_GT(m["removal.gouge_max_mm"].get<double>(), 0.2);
  EXPECT_LT(m["removal.flash_removed_fraction"].get<double>(), 0.95);
  EXPECT_GT(m["removal.residual_flash_max_mm"].get<double>(), 1.0);
  EXPECT_GT(m["force.max_n"].get<double>(), 500.0);
  EXPECT_EQ(m["quality.pass"], false);
  EXPECT_EQ(r.exit_code, 1);
  EXPECT_NE(r.verdict.find("gouged"), std::string::npos) << r.verdict;
}

// A burr worn 0.5 mm under the radius the plan was made for stands 0.5 mm off every wall it
// grinds along: that much flash is left along the roots.
TEST(FaultDrill, AWornBurrLeavesFlashAlongTheRoots) {
  pipeline::Faults f;
  f.tool_radius_error = -0.5e-3;
  const auto r = drill("worn", f);
  const auto& m = r.metrics;
  EXPECT_NEAR(m["faults.tool_radius_error_mm"].get<double>(), -0.5, 1e-9);
  EXPECT_GT(m["removal.residual_flash_max_mm"].get<double>(), 0.3);
  EXPECT_EQ(m["quality.pass"], false);
  EXPECT_EQ(r.exit_code, 1);
}
