#include <gtest/gtest.h>

#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

// The seed's link transform composed from elementary motions, independently of dh_link's
// closed-form matrix: Rot_z(θ)·Trans_z(d)·Trans_x(a)·Rot_x(α).
Pose seed_link(const DhRow& r, double theta) {
  return Pose(Eigen::AngleAxisd(theta, Vec3::UnitZ())) * Eigen::Translation3d(0, 0, r.d) *
         Eigen::Translation3d(r.a, 0, 0) * Eigen::AngleAxisd(r.alpha, Vec3::UnitX());
}

Vector6 random_q(const RobotModel& robot, Rng& rng) {
  Vector6 q;
  for (int i = 0; i < 6; ++i) q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
  return q;
}

}  // namespace

TEST(Kinematics, FkEqualsTheProductOfTheSeedDhMatrices) {
  const RobotModel robot = ftest::ft6();
  Rng rng(11);
  for (int n = 0; n < 2000; ++n) {
    const Vector6 q = random_q(robot, rng);
    Pose X = Pose::Identity();
    const auto frames = fk_frames(robot, q);
    for (int i = 0; i < 6; ++i) {
      X = X * seed_link(robot.dh[i], q[i]);
      ASSERT_LT((X.matrix() - frames[i + 1].matrix()).cwiseAbs().maxCoeff(), 1e-13);
    }
    ASSERT_LT((X.matrix() - fk_flange(robot, q).matrix()).cwiseAbs().maxCoeff(), 1e-13);
    const Pose X_BT = fk_tool(robot, q);
    ASSERT_LT((X_BT.translation() - (X * robot.tool.X_ET).translation()).norm(), 1e-13);
  }
}

TEST(Kinematics, KnownConfigurationAtZero) {
  // All θ = 0: upper arm along x, forearm pointing down, wrist centre at (a2+a3, d3, -d4).
  const RobotModel robot = ftest::ft6();
  const Pose X = fk_flange(robot, Vector6::Zero());
  EXPECT_NEAR(X.translation().x(), 0.52, 1e-15);
  EXPECT_NEAR(X.translation().y(), 0.15, 1e-15);
  EXPECT_NEAR(X.translation().z(), -0.50, 1e-15);
  EXPECT_NEAR(X.linear()(2, 2), -1.0, 1e-15);  // flange z points down
}

TEST(Kinematics, JacobianMatchesFiniteDifferencesOfFk) {
  const RobotModel robot = ftest::ft6();
  Rng rng(5);
  const double h = 1e-6;
  for (int n = 0; n < 200; ++n) {
    const Vector6 q = random_q(robot, rng);
    for (const Pose& X_EP : {Pose::Identity(), robot.tool.X_ET}) {
      const Matrix6 J = jacobian(robot, q, X_EP, JacobianFrame::kBase);
      const Matrix6 Jt = jacobian(robot, q, X_EP, JacobianFrame::kTool);
      const Pose X0 = fk_flange(robot, q) * X_EP;
      for (int i = 0; i < 6; ++i) {
        Vector6 qp = q, qm = q;
        qp[i] += h;
        qm[i] -= h;
        const Pose Xp = fk_flange(robot, qp) * X_EP, Xm = fk_flange(robot, qm) * X_EP;
        const Vec3 v = (Xp.translation() - Xm.translation()) / (2 * h);
        // Angular velocity from the skew part of dR·Rᵀ.
        const Mat3 W = (Xp.linear() - Xm.linear()) / (2 * h) * X0.linear().transpose();
        const Vec3 w(W(2, 1), W(0, 2), W(1, 0));
        EXPECT_LT((J.block<3, 1>(0, i) - v).norm(), 1e-7);
        EXPECT_LT((J.block<3, 1>(3, i) - w).norm(), 1e-7);
        // The tool-frame Jacobian is the base one seen in the point's frame.
        EXPECT_LT((Jt.block<3, 1>(0, i) - X0.linear().transpose() * v).norm(), 1e-7);
        EXPECT_LT((Jt.block<3, 1>(3, i) - X0.linear().transpose() * w).norm(), 1e-7);
      }
    }
  }
}

TEST(Kinematics, ManipulabilityVanishesAtTheThreeSingularities) {
  const RobotModel robot = ftest::ft6();
  Vector6 q;
  q << 0.3, -1.0, 0.5, 0.4, 0.8, 0.2;
  const auto regular = check_singularity(robot, q);
  EXPECT_GT(regular.manipulability, 1e-3);
  EXPECT_FALSE(regular.singular);
  // Yoshikawa's sqrt(det(J Jᵀ)) equals |det J| for a square Jacobian.
  const Matrix6 J = jacobian(robot, q, robot.tool.X_ET);
  EXPECT_NEAR(std::sqrt((J * J.transpose()).determinant()), regular.manipulability, 1e-12);

  Vector6 wrist = q;
  wrist[4] = 0;
  const auto w = check_singularity(robot, wrist);
  EXPECT_LT(w.manipulability, 1e-12);
  EXPECT_LT(w.wrist, 1e-12);
  EXPECT_TRUE(w.singular);

  Vector6 elbow = q;
  elbow[2] = -std::atan2(robot.dh[3].d, robot.dh[2].a);  // stretched arm
  const auto e = check_singularity(robot, elbow);
  EXPECT_LT(e.elbow, 1e-12);
  EXPECT_LT(e.manipulability, 1e-12);
}
