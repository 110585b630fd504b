#include <gtest/gtest.h>

#include <set>

#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

Vector6 random_q(const RobotModel& robot, Rng& rng) {
  Vector6 q;
  for (int i = 0; i < 6; ++i) q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
  return q;
}

double pose_pos_error(const Pose& a, const Pose& b) {
  return (a.translation() - b.translation()).norm();
}
double pose_rot_error(const Pose& a, const Pose& b) { return rotation_distance(a.linear(), b.linear()); }

double wrapped_max_diff(const Vector6& a, const Vector6& b) {
  double m = 0;
  for (int i = 0; i < 6; ++i) m = std::max(m, std::abs(std::remainder(a[i] - b[i], 2 * M_PI)));
  return m;
}

}  // namespace

TEST(Ik, RoundTripOnTenThousandRandomConfigurations) {
  const RobotModel robot = ftest::ft6();
  Rng rng(2024);
  int checked_original = 0, total_solutions = 0;
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 10000; ++n) {
    const Vector6 q = random_q(robot, rng);
    const Pose X_BE = fk_flange(robot, q);
    const IkResult res = ik_flange(robot, X_BE);
    ASSERT_TRUE(res.ok()) << res.message;
    ASSERT_LE(res.solutions.size(), 8u);
    std::set<int> branches;
    bool found = false;
    for (const auto& s : res.solutions) {
      ASSERT_TRUE(s.q.allFinite());
      ASSERT_TRUE(robot.within_limits(s.q, 1e-12));
      const Pose X = fk_flange(robot, s.q);
      worst_p = std::max(worst_p, pose_pos_error(X, X_BE));
      worst_r = std::max(worst_r, pose_rot_error(X, X_BE));
      EXPECT_TRUE(branches.insert(s.branch.index()).second) << "branch listed twice";
      found = found || wrapped_max_diff(s.q, q) < 1e-7;
    }
    total_solutions += static_cast<int>(res.solutions.size());
    const auto sing = check_singularity(robot, q);
    if (sing.wrist > 1e-3 && sing.elbow > 1e-3 && sing.shoulder > 1e-3) {
      ++checked_original;
      EXPECT_TRUE(found) << "original configuration not among the solutions at n=" << n;
      // With the original as reference, it comes back exactly (no 2π ambiguity).
      IkParams p;
      p.q_ref = q;
      const IkResult again = ik_flange(robot, X_BE, p);
      double best = 1e9;
      for (const auto& s : again.solutions) best = std::min(best, (s.q - q).cwiseAbs().maxCoeff());
      EXPECT_LT(best, 1e-7);
    }
  }
  EXPECT_LT(worst_p, 1e-9);
  EXPECT_LT(worst_r, 1e-9);
  EXPECT_GT(checked_original, 9000);
  RecordProperty("worst_position_error_m", std::to_string(worst_p));
  RecordProperty("worst_rotation_error_rad", std::to_string(worst_r));
  RecordProperty("mean_solutions", std::to_string(total_solutions / 10000.0));
  std::printf("IK round trip: worst position error %.3g m, worst rotation error %.3g rad, "
              "%.2f solutions per pose on average\n",
              worst_p, worst_r, total_solutions / 10000.0);
}

TEST(Ik, AllEightBranchesWithoutLimitsAndTheirGeometricMeaning) {
  const RobotModel robot = ftest::ft6();
  Vector6 q;
  q << 0.4, -1.2, 0.3, 0.5, 0.9, -0.4;
  const Pose X_BE = fk_flange(robot, q);
  IkParams p;
  p.within_limits_only = false;
  const IkResult res = ik_flange(robot, X_BE, p);
  ASSERT_EQ(res.solutions.size(), 8u) << res.message;
  for (const auto& s : res.solutions) {
    EXPECT_LT(pose_pos_error(fk_flange(robot, s.q), X_BE), 1e-9);
    const auto F = fk_frames(robot, s.q);
    const Vec3 shoulder = F[1].translation(), elbow = F[2].translation(), wrist = F[4].translation();
    // front: the wrist centre lies ahead of the shoulder along x1.
    const double fwd = (F[1].inverse() * wrist).x();
    EXPECT_EQ(s.branch.front, fwd > 0) << s.branch.name();
    // elbow up: the elbow lies above the straight shoulder–wrist line.
    const Vec3 d = wrist - shoulder;
    const double t = (elbow - shoulder).dot(d) / d.squaredNorm();
    const Vec3 on_line = shoulder + t * d;
    EXPECT_EQ(s.branch.elbow_up, elbow.z() > on_line.z()) << s.branch.name();
    EXPECT_EQ(s.branch.flip, s.q[4] < 0) << s.branch.name();
  }
}

TEST(Ik, ToolPoseRoundTrip) {
  const RobotModel robot = ftest::ft6();
  Rng rng(9);
  for (int n = 0; n < 1000; ++n) {
    const Vector6 q = random_q(robot, rng);
    const Pose X_BT = fk_tool(robot, q);
    const IkResult res = ik_tool(robot, X_BT);
    ASSERT_TRUE(res.ok());
    for (const auto& s : res.solutions) ASSERT_LT(pose_pos_error(fk_tool(robot, s.q), X_BT), 1e-9);
  }
}

TEST(Ik, ExactWristSingularityKeepsTheReferenceTheta4) {
  const RobotModel robot = ftest::ft6();
  Vector6 q;
  q << 0.2, -1.0, 0.4, 0.7, 0.0, 0.3;
  const Pose X_BE = fk_flange(robot, q);
  IkParams p;
  p.q_ref = q;
  const IkResult res = ik_flange(robot, X_BE, p);
  ASSERT_TRUE(res.ok()) << res.message;
  EXPECT_TRUE(res.wrist_singular);
  EXPECT_NE(res.message.find("wrist singular"), std::string::npos);
  bool found = false;
  for (const auto& s : res.solutions) {
    ASSERT_TRUE(s.q.allFinite());
    EXPECT_LT(pose_pos_error(fk_flange(robot, s.q), X_BE), 1e-9);
    EXPECT_LT(pose_rot_error(fk_flange(robot, s.q), X_BE), 1e-9);
    found = found || (s.q - q).cwiseAbs().maxCoeff() < 1e-9;
  }
  EXPECT_TRUE(found) << "theta4 must stay at the reference, theta6 take the rest";
}

TEST(Ik, ExactShoulderSingularityGivesOneShoulderBranch) {
  const RobotModel robot = ftest::ft6();
  // Choose θ2 so that the wrist centre's forward coordinate a2·c2 + L·cos(θ2 + ψ) is exactly 0:
  // it then lies on the cylinder of radius d3 about axis 1, where front and back coincide.
  const double a2 = robot.dh[1].a, L = std::hypot(robot.dh[2].a, robot.dh[3].d);
  const double phi = std::atan2(robot.dh[3].d, robot.dh[2].a), psi = 1.2;
  const double th2 = std::atan2(a2 + L * std::cos(psi), L * std::sin(psi)) - M_PI;
  Vector6 q;
  q << 0.4, th2, psi - phi, 0.3, 0.8, -0.6;
  ASSERT_TRUE(robot.within_limits(q)) << q.transpose();
  ASSERT_LT(check_singularity(robot, q).shoulder, 1e-12);
  const Pose X_BE = fk_flange(robot, q);
  IkParams p;
  p.q_ref = q;
  const IkResult res = ik_flange(robot, X_BE, p);
  ASSERT_EQ(res.status, IkStatus::kOk) << res.message;
  EXPECT_TRUE(res.shoulder_singular);
  EXPECT_NE(res.message.find("shoulder singular"), std::string::npos);
  EXPECT_LE(res.solutions.size(), 4u);
  bool found = false;
  for (const auto& s : res.solutions) {
    ASSERT_TRUE(s.q.allFinite());
    EXPECT_LT(pose_pos_error(fk_flange(robot, s.q), X_BE), 1e-9);
    EXPECT_LT(pose_rot_error(fk_flange(robot, s.q), X_BE), 1e-9);
    found = found || (s.q - q).cwiseAbs().maxCoeff() < 1e-6;
  }
  EXPECT_TRUE(found);
}

TEST(Ik, StretchedArmIsElbowSingularButSolved) {
  const RobotModel robot = ftest::ft6();
  Vector6 q;
  q << 0.1, -0.6, -std::atan2(robot.dh[3].d, robot.dh[2].a), 0.3, 0.5, 0.2;
  const Pose X_BE = fk_flange(robot, q);
  const IkResult res = ik_flange(robot, X_BE);
  ASSERT_TRUE(res.ok()) << res.message;
  EXPECT_TRUE(res.elbow_singular);
  for (const auto& s : res.solutions)
    EXPECT_LT(pose_pos_error(fk_flange(robot, s.q), X_BE), 1e-9);
}

TEST(Ik, UnreachablePosesSayWhyWithoutNaN) {
  const RobotModel robot = ftest::ft6();
  const IkResult far = ik_flange(robot, pose_from_xyz_rpy(Vec3(1.5, 0.2, 0.1), Vec3::Zero()));
  EXPECT_EQ(far.status, IkStatus::kUnreachable);
  EXPECT_TRUE(far.solutions.empty());
  EXPECT_NE(far.message.find("out of reach"), std::string::npos) << far.message;

  const IkResult inside =
      ik_flange(robot, pose_from_xyz_rpy(Vec3(0.05, 0.0, 0.3), Vec3::Zero()));
  EXPECT_EQ(inside.status, IkStatus::kUnreachable);
  EXPECT_NE(inside.message.find("shoulder offset"), std::string::npos) << inside.message;

  Pose nan_pose = Pose::Identity();
  nan_pose.translation().x() = std::nan("");
  EXPECT_EQ(ik_flange(robot, nan_pose).status, IkStatus::kUnreachable);
}

TEST(Ik, SolutionsOnlyOutsideTheLimitsAreReportedAsSuch) {
  RobotModel robot = ftest::ft6();
  Vector6 q;
  q << 1.0, -1.0, 0.3, 0.2, 0.6, 0.1;
  const Pose X_BE = fk_flange(robot, q);
  robot.limits[0].lower = -0.1;
  robot.limits[0].upper = 0.1;
  const IkResult res = ik_flange(robot, X_BE);
  EXPECT_EQ(res.status, IkStatus::kOutsideLimits);
  EXPECT_TRUE(res.solutions.empty());
  EXPECT_EQ(res.discarded_by_limits, 8);
  EXPECT_NE(res.message.find("none within the joint limits"), std::string::npos);
}

TEST(Ik, UnsupportedGeometryIsReported) {
  RobotModel robot = ftest::ft6();
  robot.dh[3].alpha = 0.3;
  const IkResult res = ik_flange(robot, Pose::Identity());
  EXPECT_EQ(res.status, IkStatus::kUnsupportedGeometry);
}
