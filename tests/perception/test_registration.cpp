#include <gtest/gtest.h>

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdlib>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "flashtwin/perception/registration.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::perception;

namespace {

const TriangleMesh& bunny() {
  static const TriangleMesh m = load_mesh(std::string(FLASHTWIN_SHARED_DATA) + "/bunny/bun_zipper.ply");
  return m;
}

Pose random_pose(Rng& rng, double diag) {
  const double u1 = rng.uniform(), u2 = rng.uniform(), u3 = rng.uniform();
  const Eigen::Quaterniond q(std::sqrt(u1) * std::cos(2 * M_PI * u3), std::sqrt(1 - u1) * std::sin(2 * M_PI * u2),
                             std::sqrt(1 - u1) * std::cos(2 * M_PI * u2), std::sqrt(u1) * std::sin(2 * M_PI * u3));
  Pose X = Pose::Identity();
  X.linear() = q.toRotationMatrix();
  X.translation() = Vec3(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)) * diag;
  return X;
}

// Source = model points moved by X_true⁻¹ (so the right answer maps source → model by X_true).
PointCloud moved_copy(const std::vector<Vec3>& pts, const Pose& X_true, double sigma, Rng& rng, int stride = 1) {
  PointCloud c;
  const Pose inv = X_true.inverse();
  for (std::size_t i = 0; i < pts.size(); i += static_cast<std::size_t>(stride)) {
    Vec3 p = inv * pts[i];
    if (sigma > 0) p += Vec3(rng.normal(), rng.normal(), rng.normal()) * sigma;
    c.points.push_back(p.cast<float>());
  }
  return c;
}

}  // namespace

TEST(Registration, RandomPosesOnTheBunnyAllSucceed) {
  if (std::getenv("FT_DEBUG")) spdlog::set_level(spdlog::level::debug);
  const auto target = ModelTarget::from_mesh(bunny());
  const double diag = target->diagonal();
  Rng rng(42);
  double worst_rot = 0, worst_t = 0, total_time = 0;
  std::vector<double> rots, times;
  for (int trial = 0; trial < 20; ++trial) {
    const Pose X = random_pose(rng, diag);
    const PointCloud src = moved_copy(bunny().vertices, X, 0.001 * diag, rng, 1);
    const RegistrationResult r = register_scan(src, *target);
    ASSERT_TRUE(r.ran) << r.message;
    const double rot = rotation_distance(r.T_target_source.linear(), X.linear()) * 180 / M_PI;
    const double tr = (r.T_target_source.translation() - X.translation()).norm();
    worst_rot = std::max(worst_rot, rot);
    worst_t = std::max(worst_t, tr);
    total_time += r.time_s;
    rots.push_back(rot);
    times.push_back(r.time_s);
    EXPECT_LT(rot, 1.0) << "trial " << trial << " stage " << r.stage;
    EXPECT_LT(tr, 0.005 * diag) << "trial " << trial;
    EXPECT_TRUE(r.confident) << r.message;
  }
  std::sort(rots.begin(), rots.end());
  std::sort(times.begin(), times.end());
  std::printf("bunny 0.1%% noise: median rotation %.5f deg, worst %.4f deg, worst translation %.4f mm, "
              "median time %.1f ms\n",
              rots[10], worst_rot, worst_t * 1000, times[10] * 1000);
}

TEST(Registration, ExactCopyIsRecoveredToRoundOff) {
  // Target and source are the same points: at the true pose every residual is zero.
  PointCloud model;
  for (std::size_t i = 0; i < bunny().vertices.size(); i += 4) model.points.push_back(bunny().vertices[i].cast<float>());
  const auto target = ModelTarget::from_cloud(model);
  Rng rng(7);
  RegistrationParams p;
  p.fine_voxel = 1e-5;  // one point per voxel: the source points stay exactly themselves
  for (int trial = 0; trial < 5; ++trial) {
    const Pose X = random_pose(rng, target->diagonal());
    std::vector<Vec3> pts;
    for (const auto& q : model.points) pts.push_back(q.cast<double>());
    const RegistrationResult r = register_scan(moved_copy(pts, X, 0, rng), *target, p);
    ASSERT_TRUE(r.ran) << r.message;
    EXPECT_LT(rotation_distance(r.T_target_source.linear(), X.linear()), 1e-6);
    EXPECT_LT((r.T_target_source.translation() - X.translation()).norm(), 1e-6);
  }
}

TEST(Registration, RotationallySymmetricPartIsNotConfident) {
  // A plain cylinder (r = 50 mm, h = 120 mm): any turn about its axis fits equally well.
  TriangleMesh cyl;
  const int n = 96;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    cyl.vertices.emplace_back(0.05 * std::cos(a), 0.05 * std::sin(a), 0.0);
    cyl.vertices.emplace_back(0.05 * std::cos(a), 0.05 * std::sin(a), 0.12);
  }
  cyl.vertices.emplace_back(0, 0, 0);
  cyl.vertices.emplace_back(0, 0, 0.12);
  const int b = 2 * n, t = 2 * n + 1;
  for (int i = 0; i < n; ++i) {
    const int j = (i + 1) % n;
    cyl.triangles.emplace_back(2 * i, 2 * j, 2 * j + 1);
    cyl.triangles.emplace_back(2 * i, 2 * j + 1, 2 * i + 1);
    cyl.triangles.emplace_back(b, 2 * j, 2 * i);
    cyl.triangles.emplace_back(t, 2 * i + 1, 2 * j + 1);
  }
  ASSERT_TRUE(check_mesh(cyl).watertight());
  const auto target = ModelTarget::from_mesh(cyl);
  Rng rng(3);
  TargetParams other;
  other.seed = 99;  // a different sampling of the same surface as the "scan"
  const auto scan = ModelTarget::from_mesh(cyl, other);
  std::vector<Vec3> pts;
  for (const auto& q : scan->dense().points) pts.push_back(q.cast<double>());
  const RegistrationResult r = register_scan(moved_copy(pts, random_pose(rng, 0.14), 0, rng), *target);
  ASSERT_TRUE(r.ran);
  EXPECT_FALSE(r.confident) << "ambiguity " << r.ambiguity;
  EXPECT_NE(r.message.find("ambiguous"), std::string::npos) << r.message;
}

TEST(Registration, BadInputFailsCleanly) {
  const auto target = ModelTarget::from_mesh(bunny());
  PointCloud empty;
  RegistrationResult r = register_scan(empty, *target);
  EXPECT_FALSE(r.ran);
  EXPECT_NE(r.message.find("empty"), std::string::npos) << r.message;
  PointCloud few;
  for (int i = 0; i < 5; ++i) few.points.emplace_back(i * 0.01f, 0.f, 0.f);
  r = register_scan(few, *target);
  EXPECT_FALSE(r.ran);
  EXPECT_NE(r.message.find("at least 10 points"), std::string::npos) << r.message;
  PointCloud nan;
  for (int i = 0; i < 50; ++i) nan.points.emplace_back(i * 0.01f, 0.f, 0.f);
  nan.points[17].y() = std::numeric_limits<float>::quiet_NaN();
  r = register_scan(nan, *target);
  EXPECT_FALSE(r.ran);
  EXPECT_NE(r.message.find("point 17"), std::string::npos) << r.message;
  EXPECT_THROW(ModelTarget::from_cloud(few), ArgumentError);
  EXPECT_THROW(ModelTarget::from_mesh(TriangleMesh{}), ArgumentError);
}

// The process-wide target cache: the same mesh and parameters give the same target object, a
// changed vertex or parameter a new one, and a cached target equals a freshly built one.
TEST(Registration, TargetCacheReturnsTheSameTargetOnlyForTheSameMeshAndParams) {
  const TriangleMesh box = box_mesh(Vec3(0, 0, 0), Vec3(0.2, 0.1, 0.05));
  TargetParams p;
  p.mesh_samples = 5000;
  const auto a = ModelTarget::from_mesh_cached(box, p);
  const auto b = ModelTarget::from_mesh_cached(box, p);
  EXPECT_EQ(a.get(), b.get());
  TriangleMesh moved = box;
  moved.vertices[3].x() += 1e-6;
  EXPECT_NE(ModelTarget::from_mesh_cached(moved, p).get(), a.get());
  TargetParams q = p;
  q.seed = 2;
  EXPECT_NE(ModelTarget::from_mesh_cached(box, q).get(), a.get());
  const auto fresh = ModelTarget::from_mesh(box, p);
  ASSERT_EQ(fresh->dense().size(), a->dense().size());
  for (std::size_t i = 0; i < fresh->dense().size(); ++i)
    ASSERT_EQ(fresh->dense().points[i], a->dense().points[i]);
  EXPECT_EQ(fresh->diagonal(), a->diagonal());
}
