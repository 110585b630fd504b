#include <gtest/gtest.h>

#include <set>

#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"

using namespace flashtwin;
using namespace flashtwin::perception;

namespace {

// Points on the unit-ish sphere of radius r (outward normals known).
PointCloud sphere(int n, double r, Rng& rng) {
  PointCloud c;
  for (int i = 0; i < n; ++i) {
    Vec3 v(rng.normal(), rng.normal(), rng.normal());
    v.normalize();
    c.points.push_back((r * v).cast<float>());
  }
  return c;
}

}  // namespace

TEST(Preprocess, VoxelGridsKeepOnePointPerVoxel) {
  Rng rng(1);
  const PointCloud c = sphere(20000, 0.1, rng);
  const PointCloud centroid = voxel_downsample(c, 0.01);
  const PointCloud nearest = voxel_downsample_nearest(c, 0.01);
  ASSERT_EQ(centroid.size(), nearest.size());
  EXPECT_LT(centroid.size(), c.size() / 4);
  // The improved grid returns original points only, each in a distinct voxel.
  std::set<std::tuple<int, int, int>> voxels;
  std::set<std::tuple<float, float, float>> originals;
  for (const auto& p : c.points) originals.insert({p.x(), p.y(), p.z()});
  for (const auto& p : nearest.points) {
    EXPECT_TRUE(originals.count({p.x(), p.y(), p.z()}));
    voxels.insert({static_cast<int>(std::floor(p.x() / 0.01)), static_cast<int>(std::floor(p.y() / 0.01)),
                   static_cast<int>(std::floor(p.z() / 0.01))});
  }
  EXPECT_EQ(voxels.size(), nearest.size());
  // Centroids of a curved surface sit inside it; the kept originals sit on it.
  double in_c = 0, in_n = 0;
  for (const auto& p : centroid.points) in_c += 0.1 - p.norm();
  for (const auto& p : nearest.points) in_n += std::abs(0.1 - p.norm());
  EXPECT_GT(in_c / centroid.size(), 3e-5);  // measured 6.4e-5 m for 1 cm voxels on r = 0.1 m
  EXPECT_LT(in_n / nearest.size(), 1e-6);
}

TEST(Preprocess, OutlierRemovalDropsIsolatedPoints) {
  Rng rng(2);
  PointCloud c = sphere(5000, 0.1, rng);
  for (int i = 0; i < 20; ++i) c.points.emplace_back(0.5f + 0.05f * i, 0.5f, 0.5f);
  const PointCloud kept = remove_statistical_outliers(c, 16, 2.5);
  for (const auto& p : kept.points) EXPECT_LT(p.norm(), 0.2f);
  EXPECT_GT(kept.size(), 4900u);
}

TEST(Preprocess, NormalsAreConsistentlyOutwardWithAndWithoutViewpoint) {
  Rng rng(3);
  PointCloud c = sphere(4000, 0.1, rng);
  estimate_normals(c, 12);
  int outward = 0;
  for (std::size_t i = 0; i < c.size(); ++i) outward += c.normals[i].dot(c.points[i]) > 0.9f * c.points[i].norm();
  EXPECT_GT(outward, 3960);
  // With a viewpoint far along +x: normals face it.
  PointCloud d = sphere(4000, 0.1, rng);
  estimate_normals(d, 12, Vec3(10, 0, 0));
  for (std::size_t i = 0; i < d.size(); ++i)
    EXPECT_GE(d.normals[i].dot(Eigen::Vector3f(10, 0, 0) - d.points[i]), 0.f);
}

TEST(Preprocess, GammaFeaturesFindEdgesOfABox) {
  // Points on two faces of a box meeting at an edge: γ is large near the edge only.
  PointCloud c;
  for (int i = 0; i < 60; ++i)
    for (int j = 0; j < 60; ++j) {
      c.points.emplace_back(0.001f * i, 0.001f * j, 0.f);        // face z = 0
      c.points.emplace_back(0.001f * i, 0.f, 0.001f * (j + 1));  // face y = 0
    }
  estimate_normals(c, 12);
  const auto gamma = normal_variation(c, 12);
  const auto features = feature_points(gamma, 0.1);
  ASSERT_FALSE(features.empty());
  for (int k : features) EXPECT_LT(std::min(c.points[k].y(), c.points[k].z()), 0.004f);
}

TEST(Preprocess, SupportPlaneAndClutterAreRemoved) {
  Rng rng(4);
  PointCloud c;
  for (int i = 0; i < 40000; ++i)  // the table, z = 0
    c.points.emplace_back(static_cast<float>(rng.uniform(-0.3, 0.3)), static_cast<float>(rng.uniform(-0.3, 0.3)), 0.f);
  const PointCloud part = sphere(5000, 0.05, rng);
  for (const auto& p : part.points) c.points.push_back(p + Eigen::Vector3f(0, 0, 0.06f));
  for (int i = 0; i < 300; ++i)  // a separate block (fixture) away from the part
    c.points.emplace_back(0.2f + 0.0001f * (i % 20), 0.2f, 0.01f + 0.0001f * (i / 20));
  const PointCloud kept = remove_support_plane(c, 0.002, 0.01);
  EXPECT_NEAR(static_cast<double>(kept.size()), 5000, 50);
  for (const auto& p : kept.points) EXPECT_LT((p - Eigen::Vector3f(0, 0, 0.06f)).norm(), 0.051f);
}

TEST(Preprocess, ValidationNamesTheProblem) {
  PointCloud c;
  EXPECT_NE(validate_cloud(c).find("empty"), std::string::npos);
  for (int i = 0; i < 12; ++i) c.points.emplace_back(0.f, 0.f, static_cast<float>(i));
  EXPECT_EQ(validate_cloud(c), "");
  c.points[4].z() = std::numeric_limits<float>::infinity();
  EXPECT_NE(validate_cloud(c).find("point 4"), std::string::npos);
}
