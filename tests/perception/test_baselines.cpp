#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <string>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/perception/baselines.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::perception;

namespace {

// Every 10th vertex of the Stanford Bunny (3,595 points), in metres.
const PointCloud& bunny_subset() {
  static const PointCloud c = [] {
    const PointCloud all = load_cloud(std::string(FLASHTWIN_SHARED_DATA) + "/bunny/bun_zipper.ply");
    PointCloud out;
    for (std::size_t i = 0; i < all.size(); i += 10) out.points.push_back(all.points[i]);
    return out;
  }();
  return c;
}

// A 20° rotation about a tilted axis and a 3 cm shift: T_target_source of the test.
Pose known_pose() {
  Pose X = Pose::Identity();
  X.linear() = Eigen::AngleAxisd(20.0 * M_PI / 180.0, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  X.translation() = Vec3(0.03, -0.02, 0.01);
  return X;
}

// Source = target points moved by X⁻¹, so the right answer is X.
PointCloud moved(const PointCloud& target, const Pose& X) {
  PointCloud s;
  const Pose inv = X.inverse();
  for (const auto& p : target.points) s.points.push_back((inv * p.cast<double>()).cast<float>());
  return s;
}

void expect_recovers(Baseline method) {
  const Pose X = known_pose();
  const PointCloud& target = bunny_subset();
  const RegistrationResult r = register_baseline(method, moved(target, X), target, 7);
  ASSERT_TRUE(r.ran) << r.message;
  const double rot_deg = rotation_distance(r.T_target_source.linear(), X.linear()) * 180.0 / M_PI;
  EXPECT_LT(rot_deg, 2.0) << to_string(method) << ": " << r.message;
  EXPECT_LT((r.T_target_source.translation() - X.translation()).norm(), 0.005) << to_string(method);
  EXPECT_GT(r.fitness, 0.9) << to_string(method);
  EXPECT_TRUE(r.confident) << to_string(method) << ": " << r.message;
  EXPECT_GT(r.time_s, 0.0);
}

}  // namespace

TEST(Baselines, FpcsIcpRecoversAKnownPoseOnTheBunny) { expect_recovers(Baseline::kFpcsIcp); }

TEST(Baselines, SacIaNdtRecoversAKnownPoseOnTheBunny) { expect_recovers(Baseline::kSacIaNdt); }

TEST(Baselines, BadCloudsGiveRanFalseWithAMessage) {
  const PointCloud& good = bunny_subset();
  PointCloud empty;
  PointCloud five;
  for (int i = 0; i < 5; ++i) five.points.emplace_back(0.01f * i, 0.0f, 0.02f * i);
  PointCloud with_nan = good;
  with_nan.points[17].y() = std::numeric_limits<float>::quiet_NaN();
  PointCloud with_inf = good;
  with_inf.points[3].x() = std::numeric_limits<float>::infinity();

  for (const Baseline b : {Baseline::kSacIaNdt, Baseline::kNdtIcp, Baseline::kIss3dscIcp, Baseline::kFpcsIcp}) {
    SCOPED_TRACE(to_string(b));
    RegistrationResult r = register_baseline(b, empty, good);
    EXPECT_FALSE(r.ran);
    EXPECT_FALSE(r.confident);
    EXPECT_NE(r.message.find("source"), std::string::npos) << r.message;
    EXPECT_NE(r.message.find("empty"), std::string::npos) << r.message;

    r = register_baseline(b, five, good);
    EXPECT_FALSE(r.ran);
    EXPECT_NE(r.message.find("at least 10 points, got 5"), std::string::npos) << r.message;

    r = register_baseline(b, with_nan, good);
    EXPECT_FALSE(r.ran);
    EXPECT_NE(r.message.find("point 17"), std::string::npos) << r.message;
    EXPECT_NE(r.message.find("NaN"), std::string::npos) << r.message;

    r = register_baseline(b, good, with_inf);
    EXPECT_FALSE(r.ran);
    EXPECT_NE(r.message.find("target"), std::string::npos) << r.message;
    EXPECT_NE(r.message.find("inf"), std::string::npos) << r.message;

    r = register_baseline(b, good, empty);
    EXPECT_FALSE(r.ran);
    EXPECT_NE(r.message.find("target"), std::string::npos) << r.message;
  }
}

TEST(Baselines, NamesRoundTripAndUnknownNamesThrow) {
  for (const Baseline b : {Baseline::kSacIaNdt, Baseline::kNdtIcp, Baseline::kIss3dscIcp, Baseline::kFpcsIcp})
    EXPECT_EQ(baseline_from_string(to_string(b)), b);
  EXPECT_EQ(to_string(Baseline::kSacIaNdt), "sacia-ndt");
  EXPECT_EQ(to_string(Baseline::kNdtIcp), "ndt-icp");
  EXPECT_EQ(to_string(Baseline::kIss3dscIcp), "iss-3dsc-icp");
  EXPECT_EQ(to_string(Baseline::kFpcsIcp), "fpcs-icp");
  EXPECT_THROW(baseline_from_string("icp"), ArgumentError);
  EXPECT_THROW(baseline_from_string("FPCS-ICP"), ArgumentError);
  EXPECT_THROW(baseline_from_string(""), ArgumentError);
  try {
    baseline_from_string("ransac");
    FAIL() << "expected ArgumentError";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("ransac"), std::string::npos);
    EXPECT_NE(std::string(e.what()).find("fpcs-icp"), std::string::npos);
  }
}
