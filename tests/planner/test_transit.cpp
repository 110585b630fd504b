#include <gtest/gtest.h>

#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/transit.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

// Joint angles with the TCP at p_B, the tool pointing down (−z_B), nearest `near`.
Vector6 tool_down(const RobotModel& robot, const Vec3& p_B, const Vector6& near) {
  Pose X = Pose::Identity();
  X.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
  X.translation() = p_B;
  IkParams ip;
  ip.q_ref = near;
  const IkResult r = ik_tool(robot, X, ip);
  EXPECT_TRUE(r.ok()) << r.message;
  Vector6 best = near;
  double d = 1e300;
  for (const auto& s : r.solutions)
    if ((s.q - near).norm() < d) d = (s.q - near).norm(), best = s.q;
  return best;
}

// A ball obstacle in {B}: clearance of the TCP (a point) and of the flange from it.
ClearanceFn ball_obstacle(const RobotModel& robot, const Vec3& c_B, double radius) {
  return [&robot, c_B, radius](const Vector6& q) {
    const double d_tcp = (fk_tool(robot, q).translation() - c_B).norm() - radius;
    const double d_fl = (fk_flange(robot, q).translation() - c_B).norm() - radius;
    return Clearance{std::min(d_tcp, d_fl), d_tcp < d_fl ? "tool – ball" : "flange – ball"};
  };
}

}  // namespace

TEST(Transit, AClearDirectMoveIsTakenAsIs) {
  const RobotModel robot = ftest::ft6();
  const Vector6 a = tool_down(robot, Vec3(0.6, -0.2, -0.1), robot.home);
  const Vector6 b = tool_down(robot, Vec3(0.6, 0.2, -0.1), a);
  const TransitResult r = plan_transit(robot, a, b, ball_obstacle(robot, Vec3(-1.0, 0, 0), 0.1));
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_FALSE(r.lifted);
  EXPECT_EQ(r.message, "direct");
  EXPECT_TRUE(r.trajectory.q.front().isApprox(a, 1e-12));
  EXPECT_TRUE(r.trajectory.q.back().isApprox(b, 1e-12));
  EXPECT_EQ(r.tcp_B.size(), r.trajectory.q.size());
  // Within the speed fraction of every joint's limit.
  TransitParams P;
  for (const Vector6& dq : r.trajectory.dq)
    for (int j = 0; j < kNumJoints; ++j) EXPECT_LE(std::abs(dq[j]), P.speed_ratio * robot.limits[j].velocity + 1e-9);
}

TEST(Transit, AMoveThroughAnObstacleIsReplannedAroundItAndStaysClear) {
  const RobotModel robot = ftest::ft6();
  const Vector6 a = tool_down(robot, Vec3(0.6, -0.2, -0.1), robot.home);
  const Vector6 b = tool_down(robot, Vec3(0.6, 0.2, -0.1), a);
  // A ball of 60 mm radius on the direct move's way, half-way between the ends.
  const Vec3 mid = fk_tool(robot, 0.5 * (a + b)).translation();
  const ClearanceFn fn = ball_obstacle(robot, mid, 0.06);
  ASSERT_LT(fn(0.5 * (a + b)).distance, 0);  // the direct move would collide
  TransitParams P;
  const TransitResult r = plan_transit(robot, a, b, fn, P);
  ASSERT_TRUE(r.ok) << r.message;
  EXPECT_TRUE(r.lifted);
  EXPECT_NE(r.message, "direct");
  EXPECT_TRUE(r.trajectory.q.front().isApprox(a, 1e-12));
  EXPECT_TRUE(r.trajectory.q.back().isApprox(b, 1e-12));
  // Every sample of the trajectory keeps the clearance asked (the ends stand far from the ball).
  double least = 1e300;
  for (const Vector6& q : r.trajectory.q) least = std::min(least, fn(q).distance);
  EXPECT_GE(least, P.clearance * (1 - 1e-9));
  EXPECT_GE(r.min_clearance, P.clearance * (1 - 1e-9));
}

TEST(Transit, RefusedWhenNoRouteIsClearOrAnEndIsInContact) {
  const RobotModel robot = ftest::ft6();
  const Vector6 a = tool_down(robot, Vec3(0.6, -0.2, -0.1), robot.home);
  const Vector6 b = tool_down(robot, Vec3(0.6, 0.2, -0.1), a);
  // Clear only at the two ends: nothing between them is.
  const ClearanceFn caged = [&](const Vector6& q) {
    const bool end = (q - a).norm() < 1e-9 || (q - b).norm() < 1e-9;
    return Clearance{end ? 0.05 : -0.001, "link3 – cage"};
  };
  TransitParams P;
  P.rrt_iterations = 200;
  const TransitResult r = plan_transit(robot, a, b, caged, P);
  EXPECT_FALSE(r.ok);
  EXPECT_TRUE(r.trajectory.q.empty());
  EXPECT_NE(r.message.find("no clear transit"), std::string::npos) << r.message;
  EXPECT_NE(r.message.find("link3 – cage"), std::string::npos) << r.message;
  // An end already in contact.
  const ClearanceFn touching = [&](const Vector6& q) {
    return Clearance{(q - a).norm() < 1e-9 ? -0.002 : 0.05, "spindle – fixture_left"};
  };
  const TransitResult t = plan_transit(robot, a, b, touching, P);
  EXPECT_FALSE(t.ok);
  EXPECT_NE(t.message.find("an end of the transit is not clear"), std::string::npos) << t.message;
  // Bad settings name their field.
  P.clearance = -1;
  try {
    plan_transit(robot, a, b, caged, P);
    ADD_FAILURE() << "expected an ArgumentError";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("transit.clearance"), std::string::npos) << e.what();
  }
}

TEST(Transit, TheSameInputsGiveTheSameRoute) {
  const RobotModel robot = ftest::ft6();
  const Vector6 a = tool_down(robot, Vec3(0.6, -0.2, -0.1), robot.home);
  const Vector6 b = tool_down(robot, Vec3(0.6, 0.2, -0.1), a);
  const Vec3 mid = fk_tool(robot, 0.5 * (a + b)).translation();
  TransitParams P;
  P.lifts.clear();  // straight to the sampled route
  const TransitResult r1 = plan_transit(robot, a, b, ball_obstacle(robot, mid, 0.06), P);
  const TransitResult r2 = plan_transit(robot, a, b, ball_obstacle(robot, mid, 0.06), P);
  ASSERT_TRUE(r1.ok) << r1.message;
  EXPECT_NE(r1.message.find("sampled"), std::string::npos) << r1.message;
  ASSERT_EQ(r1.trajectory.q.size(), r2.trajectory.q.size());
  for (std::size_t i = 0; i < r1.trajectory.q.size(); ++i)
    EXPECT_EQ(r1.trajectory.q[i], r2.trajectory.q[i]);
}
