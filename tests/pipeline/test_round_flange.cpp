// The round flange as `flashtwin run` scans, perceives and plans it: roots seen by sparse scan
// lines, and a fin's end where the wrist reaches its range. Scored against the truth.
#include <gtest/gtest.h>

#include "scenario_run.hpp"

using namespace flashtwin;

// Seeds 6023 and 6027: stretches of the rim's root were seen only by scan lines about 1.8 mm
// apart (two or three root points where each line crosses it), farther apart than the 1.6 mm
// gap that splits a root into polylines. The pieces, each too short to keep, were dropped:
// 12 mm and 8 mm of root had no path (path.max_mm 6.9 and 5.4) and their fins stood after
// grinding. The sparse links are kept where the sampling is that sparse round them.
TEST(RoundFlange, RootSeenBySparseScanLinesStaysOneLine) {
  for (const std::uint64_t seed : {6023u, 6027u}) {
    SCOPED_TRACE("seed " + std::to_string(seed));
    const auto m = ftest::scenario_metrics("round_flange", seed, false);
    ASSERT_TRUE(m.contains("path.max_mm"));
    EXPECT_LE(m["path.max_mm"].get<double>(), 2.5);
    EXPECT_GE(m["path.coverage"].get<double>(), 0.995);
  }
}

// Seed 6031: the end of a fin round the rim takes the wrist to its range; the plan that was
// chosen leaned the burr 11° off the wall there (a tilt), and its side, no longer flush, left a
// wedge of fin 1.76 mm high over the last 10 mm. Another IK seed grinds it flush.
TEST(RoundFlange, FinEndWhereTheWristIsAtItsRangeIsGroundFlush) {
  const auto m = ftest::scenario_metrics("round_flange", 6031, true);
  ASSERT_TRUE(m.contains("removal.residual_flash_max_mm"));
  EXPECT_LE(m["removal.residual_flash_max_mm"].get<double>(), 0.2);
  EXPECT_LE(m["removal.gouge_max_mm"].get<double>(), 0.1);
  EXPECT_EQ(m["execution.paths_stopped_force_limit"].get<int>(), 0);
}
