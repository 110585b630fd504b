#include <gtest/gtest.h>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/planner/workspace.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

TEST(Workspace, ReachIsAboutOneMetreAndBoundedByTheGeometry) {
  const RobotModel robot = ftest::ft6();
  WorkspaceParams p;
  p.samples = 50000;
  const auto ws = sample_workspace(robot, p);
  ASSERT_EQ(ws.points.size(), 50000u);
  // Upper bound from the D-H lengths: shoulder-wrist distance ≤ a2 + sqrt(a3² + d4²), with
  // the lateral offset d3.
  const double L = std::hypot(robot.dh[2].a, robot.dh[3].d);
  const double bound = std::hypot(robot.dh[1].a + L, robot.dh[2].d);
  EXPECT_LE(ws.max_reach, bound + 1e-12);
  EXPECT_GT(ws.max_reach, 0.98 * bound);
  EXPECT_NEAR(ws.max_reach, 1.0, 0.05);
  // No point closer to axis 1 than the shoulder offset d3.
  for (const auto& pt : ws.points) ASSERT_GE(std::hypot(pt.x(), pt.y()), robot.dh[2].d - 1e-12);
}

TEST(Workspace, DeterministicBySeedAndRejectsBadCounts) {
  const RobotModel robot = ftest::ft6();
  WorkspaceParams p;
  p.samples = 1000;
  const auto a = sample_workspace(robot, p), b = sample_workspace(robot, p);
  for (std::size_t i = 0; i < a.points.size(); ++i) ASSERT_EQ(a.points[i], b.points[i]);
  p.samples = 0;
  EXPECT_THROW(sample_workspace(robot, p), ArgumentError);
}
