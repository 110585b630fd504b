#include <gtest/gtest.h>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/core/transform.hpp"

using namespace flashtwin;

TEST(Transform, RpyRoundTrip) {
  Rng rng(3);
  for (int i = 0; i < 1000; ++i) {
    const Vec3 rpy(rng.uniform(-M_PI, M_PI), rng.uniform(-1.5, 1.5), rng.uniform(-M_PI, M_PI));
    const Pose X = pose_from_xyz_rpy(Vec3(1, 2, 3), rpy);
    const Vec3 back = rpy_from_rotation(X.linear());
    EXPECT_LT(rotation_distance(X.linear(), pose_from_xyz_rpy(Vec3::Zero(), back).linear()),
              1e-12);
  }
}

TEST(Transform, RowMajorRoundTripAndRejection) {
  const Pose X = pose_from_xyz_rpy(Vec3(0.1, -0.2, 0.3), Vec3(0.3, -0.4, 1.2));
  const auto m = to_row_major(X);
  EXPECT_NEAR(m[3], 0.1, 1e-15);  // translation in the last column
  const Pose Y = pose_from_row_major(m, "pose");
  EXPECT_LT((X.matrix() - Y.matrix()).cwiseAbs().maxCoeff(), 1e-15);

  auto scaled = m;
  scaled[0] *= 2;  // not orthonormal
  EXPECT_THROW(pose_from_row_major(scaled, "pose"), ArgumentError);
  auto mirrored = m;
  for (int r = 0; r < 3; ++r) mirrored[4 * r] = -mirrored[4 * r];  // det -1
  EXPECT_THROW(pose_from_row_major(mirrored, "pose"), ArgumentError);
  auto nan = m;
  nan[5] = std::nan("");
  EXPECT_THROW(pose_from_row_major(nan, "pose"), ArgumentError);
}

TEST(Transform, RotationDistanceIsAccurateNearZeroAndPi) {
  const Mat3 I = Mat3::Identity();
  const Mat3 small = Eigen::AngleAxisd(1e-9, Vec3::UnitX()).toRotationMatrix();
  EXPECT_NEAR(rotation_distance(I, small), 1e-9, 1e-20);
  const Mat3 half = Eigen::AngleAxisd(M_PI - 1e-7, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  EXPECT_NEAR(rotation_distance(I, half), M_PI - 1e-7, 1e-12);
}

TEST(Random, SameSeedSameSequenceAndSaneMoments) {
  Rng a(42), b(42);
  double sum = 0, sq = 0;
  const int n = 200000;
  for (int i = 0; i < n; ++i) {
    const double x = a.normal();
    ASSERT_EQ(x, b.normal());
    sum += x;
    sq += x * x;
  }
  EXPECT_NEAR(sum / n, 0.0, 0.01);
  EXPECT_NEAR(sq / n, 1.0, 0.01);
}
