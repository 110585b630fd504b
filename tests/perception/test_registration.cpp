#include <gtest/gtest.h>

#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdlib>

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
