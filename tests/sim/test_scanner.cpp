#include <gtest/gtest.h>

#include <algorithm>

#include <cmath>
#include <cstdlib>
#include <cstring>
#include <string>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/mujoco_scene.hpp"
#include "flashtwin/sim/scanner.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

// Rectangle of half-sizes (hx, hy) in the x-y plane of X (normal +z of X), split into 2×2 quads.
TriangleMesh rect(const Pose& X, double hx, double hy) {
  TriangleMesh m;
  for (int i = 0; i <= 2; ++i)
    for (int j = 0; j <= 2; ++j) m.vertices.push_back(X * Vec3(hx * (i - 1), hy * (j - 1), 0));
  for (int i = 0; i < 2; ++i)
    for (int j = 0; j < 2; ++j) {
      const int a = 3 * i + j;
      m.triangles.emplace_back(a, a + 3, a + 4);
      m.triangles.emplace_back(a, a + 4, a + 1);
    }
  return m;
}

Pose at(const Vec3& p) {
  Pose X = Pose::Identity();
  X.translation() = p;
  return X;
}

Pose rot_x(double angle, const Vec3& p) {
  Pose X = at(p);
  X.linear() = Eigen::AngleAxisd(angle, Vec3::UnitX()).toRotationMatrix();
  return X;
}

// Closed axis-aligned box.
TriangleMesh box(const Vec3& c, const Vec3& h) {
  TriangleMesh m;
  for (int i = 0; i < 8; ++i)
    m.vertices.push_back(
        c + Vec3((i & 1) ? h.x() : -h.x(), (i & 2) ? h.y() : -h.y(), (i & 4) ? h.z() : -h.z()));
  const int f[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                       {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& q : f) {
    m.triangles.emplace_back(q[0], q[1], q[2]);
    m.triangles.emplace_back(q[0], q[2], q[3]);
  }
  return m;
}

ScanView line_view(int rays, double fov, double sweep, double spacing = 0.0005) {
  ScanView v;
  v.kind = SensorKind::kLineProfiler;
  v.line.points_per_profile = rays;
  v.line.fov = fov;
  v.line.sweep_length = sweep;
  v.line.profile_spacing = spacing;
  return v;
}

// Noise model switched off except for what a test turns on.
NoiseParams quiet() {
  NoiseParams n;
  n.sigma = 0;
  n.outlier_rate = 0;
  n.mixed_probability = 0;
  return n;
}

ScanParams params_with(const ScanView& v, const NoiseParams& n) {
  ScanParams p;
  p.views = {v};
  p.noise = n;
  return p;
}

struct Stats {
  double mean = 0, std = 0;
  std::size_t n = 0;
};

// Range residual along each ray for a scan of the plane z = z0 in {M} (sensor frame = {M}, line
// profiler without tilt: the ray of a point leaves from (x, 0, 0)).
Stats range_residuals_on_plane(const ScanResult& r, double z0, const Vec3& n_plane) {
  Stats s;
  double sum = 0, sum2 = 0;
  for (const auto& pf : r.cloud_M.points) {
    const Vec3 p = pf.cast<double>();
    const Vec3 o(p.x(), 0, 0);
    const Vec3 d = (p - o).normalized();
    // Exact distance to the plane n·(x − (0,0,z0)) = 0 along d, vs the measured distance.
    const double t_true = n_plane.dot(Vec3(0, 0, z0) - o) / n_plane.dot(d);
    const double e = (p - o).norm() - t_true;
    sum += e;
    sum2 += e * e;
    ++s.n;
  }
  s.mean = sum / s.n;
  s.std = std::sqrt(sum2 / s.n - s.mean * s.mean);
  return s;
}

bool same_bytes(const ScanResult& a, const ScanResult& b) {
  return a.cloud_M.size() == b.cloud_M.size() && a.truth == b.truth &&
         std::memcmp(a.cloud_M.points.data(), b.cloud_M.points.data(),
                     a.cloud_M.size() * sizeof(Eigen::Vector3f)) == 0 &&
         std::memcmp(a.cloud_M.normals.data(), b.cloud_M.normals.data(),
                     a.cloud_M.size() * sizeof(Eigen::Vector3f)) == 0;
}

std::size_t count_label(const ScanResult& r, TruthLabel l) {
  std::size_t n = 0;
  for (auto t : r.truth) n += t == l;
  return n;
}

}  // namespace

// ---------------------------------------------------------------------------------------------
// Noise
// ---------------------------------------------------------------------------------------------

TEST(Scanner, PlaneAtNormalIncidenceGivesConfiguredSigma) {
  const ScanScene scene({{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"}});
  NoiseParams n = quiet();
  n.sigma = 50e-6;
  const ScanParams p = params_with(line_view(1000, 0.02, 0.05), n);  // 101 profiles
  const ScanResult r = scan(scene, Pose::Identity(), p);
  ASSERT_EQ(r.rays, 101u * 1000u);
  ASSERT_EQ(r.cloud_M.size(), r.rays);  // every ray returns
  EXPECT_GT(r.time_s, 0);
  EXPECT_GT(r.rays_per_s(), 0);
  EXPECT_TRUE(r.cloud_M.labels.empty());  // truth is kept apart from the cloud
  ASSERT_EQ(r.truth.size(), r.cloud_M.size());
  EXPECT_EQ(count_label(r, kTruthBody), r.cloud_M.size());
  const Stats s = range_residuals_on_plane(r, 0.3, Vec3::UnitZ());
  EXPECT_NEAR(s.std, n.sigma, 0.1 * n.sigma);
  EXPECT_NEAR(s.mean, 0.0, 0.05 * n.sigma);
  // Normals face the sensor.
  for (const auto& nn : r.cloud_M.normals) ASSERT_NEAR(nn.z(), -1.0f, 1e-5f);
}

TEST(Scanner, NoiseGrowsWithIncidenceAsConfigured) {
  const double tilt = 0.6;
  const ScanScene scene({{rect(rot_x(tilt, Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"}});
  NoiseParams n = quiet();
  n.sigma = 40e-6;
  n.incidence_gain = 1.5;
  const ScanResult r = scan(scene, Pose::Identity(), params_with(line_view(500, 0.002, 0.05), n));
  ASSERT_EQ(r.cloud_M.size(), r.rays);
  const Vec3 normal = Eigen::AngleAxisd(tilt, Vec3::UnitX()) * Vec3::UnitZ();
  const Stats s = range_residuals_on_plane(r, 0.3, normal);
  const double expected = n.sigma * (1 + n.incidence_gain * std::pow(std::tan(tilt), 2));
  EXPECT_NEAR(s.std, expected, 0.1 * expected);
}

// ---------------------------------------------------------------------------------------------
// Occlusion and dropouts
// ---------------------------------------------------------------------------------------------

TEST(Scanner, LaserOcclusionHidesThePointBehindABox) {
  const ScanScene scene({{rect(at(Vec3(0, 0, 0.4)), 0.5, 0.5), kTruthBackground, "plane"},
                         {box(Vec3(0.01, 0, 0.25), Vec3(0.05, 0.02, 0.01)), kTruthBody, "box"}});
  // One ray per profile along +z, 41 profiles over x in [0, 0.02]: all behind the box.
  const ScanResult r = scan(scene, Pose::Identity(), params_with(line_view(1, 0.1, 0.02), quiet()));
  ASSERT_EQ(r.rays, 41u);
  ASSERT_EQ(r.cloud_M.size(), 41u);
  for (std::size_t i = 0; i < r.cloud_M.size(); ++i) {
    EXPECT_NEAR(r.cloud_M.points[i].z(), 0.24f, 1e-5f);  // the box's front face, not the plane
    EXPECT_EQ(r.truth[i], kTruthBody);
  }
}

TEST(Scanner, PointSeenByTheLaserButNotByTheCameraIsDropped) {
  // Laser rays at x = 0 hit the plane z = 0.4; the camera sits at x = -0.12 (baseline).
  const SceneMesh plane{rect(at(Vec3(0, 0, 0.4)), 0.5, 0.5), kTruthBody, "plane"};
  const Vec3 half(0.015, 0.05, 0.015);
  const ScanParams p = params_with(line_view(21, 0.02, 0.0), quiet());  // one profile
  ASSERT_DOUBLE_EQ(p.views[0].line.baseline, 0.12);

  // Blocker on the camera's line of sight only (x in [-0.075, -0.045]: clear of the laser).
  const ScanScene blocked({plane, {box(Vec3(-0.06, 0, 0.2), half), kTruthBackground, "blocker"}});
  EXPECT_EQ(scan(blocked, Pose::Identity(), p).cloud_M.size(), 0u);

  // The laser does reach the plane there: a coaxial camera (baseline 0) sees every point.
  ScanParams coaxial = p;
  coaxial.views[0].line.baseline = 0;
  const ScanResult rc = scan(blocked, Pose::Identity(), coaxial);
  ASSERT_EQ(rc.cloud_M.size(), 21u);
  for (const auto& q : rc.cloud_M.points) EXPECT_NEAR(q.z(), 0.4f, 1e-5f);

  // The same blocker mirrored to the other side of the laser hides nothing.
  const ScanScene mirrored({plane, {box(Vec3(0.06, 0, 0.2), half), kTruthBackground, "blocker"}});
  EXPECT_EQ(scan(mirrored, Pose::Identity(), p).cloud_M.size(), 21u);
}

TEST(Scanner, IncidenceDropoutAtTheConfiguredAngle) {
  NoiseParams n = quiet();
  n.max_incidence = 1.0;
  const ScanParams p = params_with(line_view(11, 0.002, 0.01), n);  // 21 × 11 rays
  for (const double tilt : {0.99, 1.01}) {
    const ScanScene scene({{rect(rot_x(tilt, Vec3(0, 0, 0.3)), 1.0, 1.0), kTruthBody, "plane"}});
    const ScanResult r = scan(scene, Pose::Identity(), p);
    EXPECT_EQ(r.cloud_M.size(), tilt < n.max_incidence ? r.rays : 0u) << "tilt " << tilt;
  }
}

TEST(Scanner, OutOfRangeSurfacesGiveNoReturnButStillBlock) {
  ScanView v = line_view(5, 0.01, 0.0);
  v.line.range_min = 0.2;
  v.line.range_max = 0.5;
  // Too far.
  const ScanScene far({{rect(at(Vec3(0, 0, 0.6)), 0.5, 0.5), kTruthBody, "far"}});
  EXPECT_EQ(scan(far, Pose::Identity(), params_with(v, quiet())).cloud_M.size(), 0u);
  // A sheet nearer than range_min blocks the plane behind it.
  const ScanScene near({{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"},
                        {rect(at(Vec3(0, 0, 0.1)), 0.5, 0.5), kTruthBackground, "sheet"}});
  EXPECT_EQ(scan(near, Pose::Identity(), params_with(v, quiet())).cloud_M.size(), 0u);
}

// ---------------------------------------------------------------------------------------------
// Step edge: mixed points and outliers
// ---------------------------------------------------------------------------------------------

namespace {

// Plane z = 0.3 (background) with a 20 mm step up (towards the sensor) for y >= 0 (body).
ScanScene step_scene() {
  return ScanScene({{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBackground, "plane"},
                    {box(Vec3(0, 0.1, 0.29), Vec3(0.2, 0.1, 0.01)), kTruthBody, "step"}});
}

// Distance along the ray (from (x, 0, 0)) from p to the nearer of the two step surfaces.
double step_depth_error(const Eigen::Vector3f& pf) {
  const Vec3 p = pf.cast<double>();
  const Vec3 o(p.x(), 0, 0);
  const double t = (p - o).norm();
  const double c = (p - o).normalized().z();
  return std::min(std::abs(t - 0.3 / c), std::abs(t - 0.28 / c));
}

}  // namespace

TEST(Scanner, MixedPointsAppearAtTheStepEdge) {
  const ScanScene scene = step_scene();
  NoiseParams n = quiet();
  n.mixed_jump = 0.002;
  // 41 profiles, one edge crossing each; an even ray count keeps every ray off the edge.
  const ScanView v = line_view(400, 0.2, 0.02);
  for (const double prob : {0.0, 0.5, 1.0}) {
    n.mixed_probability = prob;
    const ScanResult r = scan(scene, Pose::Identity(), params_with(v, n));
    const std::size_t mixed = count_label(r, kTruthMixed);
    if (prob == 0.0) {
      EXPECT_EQ(mixed, 0u);
    } else if (prob == 1.0) {
      EXPECT_EQ(mixed, 41u);
    } else {
      EXPECT_GE(mixed, 8u);
      EXPECT_LE(mixed, 33u);
    }
    for (std::size_t i = 0; i < r.cloud_M.size(); ++i) {
      const auto& q = r.cloud_M.points[i];
      if (r.truth[i] == kTruthMixed) {
        // Between the two depths, near the edge at y = 0, after its first ray.
        EXPECT_GT(q.z(), 0.28f);
        EXPECT_LT(q.z(), 0.30f);
        EXPECT_LT(std::abs(q.y()), 0.001f);
        ASSERT_GT(i, 0u);
        EXPECT_LT(r.cloud_M.points[i - 1].y(), 0.0f);
      } else {
        EXPECT_EQ(r.truth[i], q.y() > 0 ? kTruthBody : kTruthBackground);
        EXPECT_LT(step_depth_error(q), 1e-6);
      }
    }
  }
}

TEST(Scanner, SparseOutliersAreDisplacedAlongTheRayAndLabelled) {
  const ScanScene scene = step_scene();
  NoiseParams n = quiet();
  n.sigma = 20e-6;
  n.outlier_rate = 0.05;
  n.outlier_range = 0.01;
  n.mixed_probability = 0.5;
  const ScanResult r = scan(scene, Pose::Identity(), params_with(line_view(400, 0.2, 0.02), n));
  const double expected = n.outlier_rate * static_cast<double>(r.rays);  // ~822
  const std::size_t outliers = count_label(r, kTruthOutlier);
  EXPECT_NEAR(static_cast<double>(outliers), expected, 5 * std::sqrt(expected));
  EXPECT_GT(count_label(r, kTruthMixed), 0u);
  double max_outlier_error = 0;
  for (std::size_t i = 0; i < r.cloud_M.size(); ++i) {
    const double e = step_depth_error(r.cloud_M.points[i]);
    if (r.truth[i] == kTruthOutlier) {
      EXPECT_LE(e, n.outlier_range + 1e-6);
      max_outlier_error = std::max(max_outlier_error, e);
    } else if (r.truth[i] != kTruthMixed) {
      EXPECT_LT(e, 7 * n.sigma);
    }
  }
  EXPECT_GT(max_outlier_error, 0.5 * n.outlier_range);  // they do spread
}

// ---------------------------------------------------------------------------------------------
// Determinism
// ---------------------------------------------------------------------------------------------

namespace {

ScanScene busy_scene() {
  return ScanScene({{rect(at(Vec3(0, 0, 0.35)), 0.6, 0.6), kTruthBackground, "table"},
                    {box(Vec3(0.05, 0.02, 0.32), Vec3(0.04, 0.05, 0.03)), kTruthBody, "body"},
                    {rect(rot_x(0.7, Vec3(0.12, -0.05, 0.3)), 0.03, 0.02), kTruthFlash, "fin"}});
}

ScanParams busy_params(std::uint64_t seed, int threads) {
  ScanView line = line_view(500, 0.6, 0.2);  // 401 profiles: several work blocks
  ScanView area;
  area.kind = SensorKind::kAreaSensor;
  area.area.width = 320;
  area.area.height = 240;
  area.area.standoff = 0.4;
  area.area.range_min = 0.2;
  area.X_MS = at(Vec3(0.05, 0, 0));
  ScanParams p;
  p.views = {line, area};
  p.noise.outlier_rate = 0.01;
  p.seed = seed;
  p.threads = threads;
  return p;
}

}  // namespace

TEST(Scanner, SameSeedGivesByteIdenticalCloudsForAnyThreadCount) {
  const ScanScene scene = busy_scene();
  const ScanResult a = scan(scene, Pose::Identity(), busy_params(7, 1));
  const ScanResult b = scan(scene, Pose::Identity(), busy_params(7, 1));
  const ScanResult c = scan(scene, Pose::Identity(), busy_params(7, 2));
  const ScanResult d = scan(scene, Pose::Identity(), busy_params(7, 3));
  ASSERT_EQ(a.rays, 401u * 500u + 320u * 240u);
  ASSERT_GT(a.cloud_M.size(), a.rays / 2);
  EXPECT_GT(count_label(a, kTruthMixed), 0u);
  EXPECT_GT(count_label(a, kTruthOutlier), 0u);
  EXPECT_GT(count_label(a, kTruthFlash), 0u);
  EXPECT_TRUE(same_bytes(a, b));
  EXPECT_TRUE(same_bytes(a, c));
  EXPECT_TRUE(same_bytes(a, d));
}

TEST(Scanner, DifferentSeedGivesDifferentNoise) {
  const ScanScene scene = busy_scene();
  const ScanResult a = scan(scene, Pose::Identity(), busy_params(7, 1));
  const ScanResult b = scan(scene, Pose::Identity(), busy_params(8, 1));
  EXPECT_FALSE(same_bytes(a, b));
  // Same geometry, so most points are within a few sigma of each other.
  ASSERT_GT(b.cloud_M.size(), 0u);
}

// ---------------------------------------------------------------------------------------------
// Frames and the area sensor
// ---------------------------------------------------------------------------------------------

TEST(Scanner, PointsComeOutInTheScannerFrame) {
  Pose X_WM = Pose::Identity();
  X_WM.linear() = Eigen::AngleAxisd(0.4, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  X_WM.translation() = Vec3(0.3, -0.2, 0.8);
  ScanView v = line_view(200, 0.3, 0.03);
  v.X_MS.linear() = Eigen::AngleAxisd(-0.3, Vec3(0.2, 1, 0).normalized()).toRotationMatrix();
  v.X_MS.translation() = Vec3(0.01, 0.02, -0.03);
  // A plane facing the sensor 0.3 m ahead of the middle of the sweep.
  const Pose X_WS = X_WM * v.X_MS;
  Pose X_WP = X_WS * at(Vec3(0.015, 0, 0.3));
  const ScanScene scene({{rect(X_WP, 0.3, 0.3), kTruthBody, "plane"}});
  NoiseParams n = quiet();
  n.sigma = 10e-6;
  const ScanResult r = scan(scene, X_WM, params_with(v, n));
  ASSERT_EQ(r.cloud_M.size(), r.rays);
  const Vec3 normal_W = X_WP.linear().col(2);
  double x_min = 1e9, x_max = -1e9;
  for (std::size_t i = 0; i < r.cloud_M.size(); ++i) {
    const Vec3 p_M = r.cloud_M.points[i].cast<double>();
    const Vec3 p_W = X_WM * p_M;
    ASSERT_LT(std::abs(normal_W.dot(p_W - X_WP.translation())), 7 * n.sigma);
    // Normals in {M}, facing the sensor.
    const Vec3 n_W = X_WM.linear() * r.cloud_M.normals[i].cast<double>();
    ASSERT_NEAR(std::abs(n_W.dot(normal_W)), 1.0, 1e-5);
    const Vec3 p_S = v.X_MS.inverse() * p_M;
    ASSERT_NEAR(p_S.z(), 0.3, 1e-3);
    x_min = std::min(x_min, p_S.x());
    x_max = std::max(x_max, p_S.x());
  }
  // The sweep runs along the sensor's own x axis.
  EXPECT_NEAR(x_min, 0.0, 1e-5);
  EXPECT_NEAR(x_max, 0.03, 1e-5);
}

TEST(Scanner, AreaSensorSeesTheWholePlaneAndUsesItsOwnCamera) {
  ScanView v;
  v.kind = SensorKind::kAreaSensor;
  v.area.width = 64;
  v.area.height = 48;
  NoiseParams n = quiet();
  n.sigma = 50e-6;
  const SceneMesh plane{rect(at(Vec3(0, 0, 0.6)), 1.0, 1.0), kTruthBody, "plane"};
  const ScanResult r = scan(ScanScene({plane}), Pose::Identity(), params_with(v, n));
  ASSERT_EQ(r.rays, 64u * 48u);
  ASSERT_EQ(r.cloud_M.size(), r.rays);
  double max_x = 0, max_y = 0, sum2 = 0;
  for (const auto& q : r.cloud_M.points) {
    max_x = std::max(max_x, std::abs(static_cast<double>(q.x())));
    max_y = std::max(max_y, std::abs(static_cast<double>(q.y())));
    sum2 += std::pow(q.z() - 0.6, 2);
  }
  // Outermost pixel centres: tan(fov/2) · (1 − 1/n) · 0.6.
  EXPECT_NEAR(max_x, 0.6 * std::tan(0.35) * (1 - 1.0 / 64), 1e-4);
  EXPECT_NEAR(max_y, 0.6 * std::tan(0.275) * (1 - 1.0 / 48), 1e-4);
  EXPECT_LT(std::sqrt(sum2 / r.cloud_M.size()), 1.2 * n.sigma);

  // The camera is at +x (baseline 0.2): a blocker on that side hides everything it shadows,
  // the same blocker at -x hides nothing.
  const Vec3 half(0.03, 0.5, 0.03);
  const ScanScene right({plane, {box(Vec3(0.1, 0, 0.3), half), kTruthBackground, "b"}});
  const ScanScene left({plane, {box(Vec3(-0.1, 0, 0.3), half), kTruthBackground, "b"}});
  ScanView narrow = v;
  narrow.area.fov_x = 0.05;  // rays stay near x = 0, clear of both blockers
  narrow.area.fov_y = 0.05;
  EXPECT_EQ(scan(right, Pose::Identity(), params_with(narrow, n)).cloud_M.size(), 0u);
  EXPECT_EQ(scan(left, Pose::Identity(), params_with(narrow, n)).cloud_M.size(), r.rays);
}

// ---------------------------------------------------------------------------------------------
// Bad input
// ---------------------------------------------------------------------------------------------

namespace {

std::string error_of(const ScanScene& scene, const ScanParams& p,
                     const Pose& X = Pose::Identity()) {
  try {
    scan(scene, X, p);
  } catch (const ArgumentError& e) {
    return e.what();
  }
  return "(no ArgumentError)";
}

}  // namespace

TEST(Scanner, BadParametersThrowArgumentErrorNamingTheField) {
  const ScanScene scene({{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"}});
  const ScanParams good = params_with(line_view(10, 0.1, 0.01), NoiseParams{});
  EXPECT_NO_THROW(scan(scene, Pose::Identity(), good));

  ScanParams p = good;
  p.views[0].line.points_per_profile = 0;
  EXPECT_EQ(error_of(scene, p), "scan.views[0].line.points_per_profile: expected > 0, got 0");

  p = good;
  p.views[0].line.range_max = p.views[0].line.range_min;
  EXPECT_NE(error_of(scene, p).find("scan.views[0].line.range_max: expected > range_min"),
            std::string::npos);

  auto expect_field = [&](const ScanParams& q, const std::string& field) {
    const std::string msg = error_of(scene, q);
    EXPECT_EQ(msg.rfind(field + ": expected", 0), 0u) << msg;
  };
  p = good;
  p.views[0].line.profile_spacing = 0;
  expect_field(p, "scan.views[0].line.profile_spacing");
  p = good;
  p.views[0].line.fov = 0;
  expect_field(p, "scan.views[0].line.fov");
  p = good;
  p.views[0].line.standoff = 0.9;
  expect_field(p, "scan.views[0].line.standoff");
  p = good;
  p.views[0].line.sweep_length = -1;
  expect_field(p, "scan.views[0].line.sweep_length");
  p = good;
  p.views[0].X_MS.linear() *= 2.0;
  expect_field(p, "scan.views[0].X_MS");
  p = good;
  ScanView area;
  area.kind = SensorKind::kAreaSensor;
  area.area.width = 0;
  p.views.push_back(area);
  expect_field(p, "scan.views[1].area.width");
  p = good;
  p.noise.sigma = std::nan("");
  expect_field(p, "scan.noise.sigma");
  p = good;
  p.noise.mixed_probability = 1.5;
  expect_field(p, "scan.noise.mixed_probability");
  p = good;
  p.noise.max_incidence = 2.0;
  expect_field(p, "scan.noise.max_incidence");
  p = good;
  p.threads = 0;
  expect_field(p, "scan.threads");
  p = good;
  p.views.clear();
  EXPECT_EQ(error_of(scene, p), "scan.views: expected at least one view, got 0");
  Pose bad = Pose::Identity();
  bad.matrix()(0, 0) = std::nan("");
  EXPECT_EQ(error_of(scene, good, bad).rfind("X_WM_true: expected", 0), 0u);
}

TEST(Scanner, EmptyOrBrokenSceneThrows) {
  EXPECT_THROW(ScanScene(std::vector<SceneMesh>{}), ArgumentError);
  EXPECT_THROW(ScanScene({{TriangleMesh{}, kTruthBody, "empty"}}), ArgumentError);
  TriangleMesh broken = rect(Pose::Identity(), 1, 1);
  broken.triangles[0][1] = 99;
  EXPECT_THROW(ScanScene({{broken, kTruthBody, "broken"}}), ArgumentError);
  TriangleMesh nan = rect(Pose::Identity(), 1, 1);
  nan.vertices[0].x() = std::nan("");
  EXPECT_THROW(ScanScene({{nan, kTruthBody, "nan"}}), ArgumentError);
  // Empty meshes beside real ones are fine.
  const ScanScene ok(
      {{TriangleMesh{}, kTruthBody, "empty"}, {rect(Pose::Identity(), 1, 1), kTruthBody, "plane"}});
  EXPECT_EQ(ok.num_triangles(), 8u);
}

// ---------------------------------------------------------------------------------------------
// MuJoCo geoms
// ---------------------------------------------------------------------------------------------

namespace {

const char* kGeomsXml = R"(
<mujoco>
  <compiler angle="radian"/>
  <asset>
    <mesh name="tet" vertex="0 0 0  0.1 0 0  0 0.1 0  0 0 0.1"/>
  </asset>
  <worldbody>
    <geom name="floor" type="plane" size="0 0 0.1"/>
    <body name="b" pos="0.1 0.2 0.3" euler="0 0 0.3">
      <geom name="box" type="box" size="0.05 0.1 0.15" pos="0.01 0.02 0.03" euler="0.4 0 0"/>
    </body>
    <geom name="ball" type="sphere" size="0.05" pos="1 0 0.5"/>
    <geom name="pill" type="capsule" size="0.03 0.1" pos="0 1 0.5"/>
    <geom name="can" type="cylinder" size="0.04 0.06" pos="0 -1 0.5"/>
    <geom name="egg" type="ellipsoid" size="0.03 0.04 0.05" pos="-1 0 0.5"/>
    <geom type="mesh" mesh="tet" pos="0 0 2"/>
  </worldbody>
</mujoco>
)";

}  // namespace

TEST(MujocoScene, BoxIsWatertightAndPosedLikeTheModel) {
  const MjModelPtr m = load_mjcf_string(kGeomsXml, "geoms.xml");
  const MjDataPtr d = make_data(m.get());
  mj_kinematics(m.get(), d.get());
  const int box_id = mj_name2id(m.get(), mjOBJ_GEOM, "box");
  const auto meshes = tessellate_geoms(
      m.get(), d.get(), [&](int g) { return g == box_id; }, kTruthBody);
  ASSERT_EQ(meshes.size(), 1u);
  EXPECT_EQ(meshes[0].name, "box");
  EXPECT_EQ(meshes[0].label, kTruthBody);
  const TriangleMesh& mesh = meshes[0].mesh_W;
  const MeshCheck c = check_mesh(mesh);
  EXPECT_TRUE(c.watertight());
  EXPECT_TRUE(c.consistently_oriented());
  EXPECT_EQ(c.degenerate_triangles, 0u);
  EXPECT_NEAR(mesh.volume(), 8 * 0.05 * 0.1 * 0.15, 1e-12);  // outward

  // Expected pose written from the MJCF numbers (single-axis rotations: no Euler ambiguity).
  Pose X_WB = at(Vec3(0.1, 0.2, 0.3));
  X_WB.linear() = Eigen::AngleAxisd(0.3, Vec3::UnitZ()).toRotationMatrix();
  Pose X_BG = at(Vec3(0.01, 0.02, 0.03));
  X_BG.linear() = Eigen::AngleAxisd(0.4, Vec3::UnitX()).toRotationMatrix();
  const Pose X_WG = X_WB * X_BG;
  Vec3 lo = Vec3::Constant(1e9), hi = Vec3::Constant(-1e9);
  for (int i = 0; i < 8; ++i) {
    const Vec3 corner =
        X_WG * Vec3((i & 1) ? 0.05 : -0.05, (i & 2) ? 0.1 : -0.1, (i & 4) ? 0.15 : -0.15);
    lo = lo.cwiseMin(corner);
    hi = hi.cwiseMax(corner);
  }
  Vec3 mlo, mhi;
  mesh.bounds(mlo, mhi);
  EXPECT_LT((mlo - lo).norm(), 1e-9);
  EXPECT_LT((mhi - hi).norm(), 1e-9);
}

TEST(MujocoScene, RoundShapesAreClosedAndCloseToTheirVolumes) {
  const MjModelPtr m = load_mjcf_string(kGeomsXml, "geoms.xml");
  const MjDataPtr d = make_data(m.get());
  mj_kinematics(m.get(), d.get());
  const auto meshes = tessellate_geoms(m.get(), d.get(), {}, kTruthBackground);
  ASSERT_EQ(static_cast<int>(meshes.size()), m->ngeom);
  auto find = [&](const std::string& name) -> const TriangleMesh& {
    for (const auto& sm : meshes)
      if (sm.name == name) return sm.mesh_W;
    ADD_FAILURE() << "no mesh " << name;
    return meshes[0].mesh_W;
  };
  const struct {
    const char* name;
    double volume;
    Vec3 center;
  } round[] = {
      {"ball", 4.0 / 3 * M_PI * std::pow(0.05, 3), Vec3(1, 0, 0.5)},
      {"pill", M_PI * 0.03 * 0.03 * 0.2 + 4.0 / 3 * M_PI * std::pow(0.03, 3), Vec3(0, 1, 0.5)},
      {"can", M_PI * 0.04 * 0.04 * 0.12, Vec3(0, -1, 0.5)},
      {"egg", 4.0 / 3 * M_PI * 0.03 * 0.04 * 0.05, Vec3(-1, 0, 0.5)},
  };
  for (const auto& s : round) {
    const TriangleMesh& mesh = find(s.name);
    const MeshCheck c = check_mesh(mesh);
    EXPECT_TRUE(c.watertight()) << s.name;
    EXPECT_TRUE(c.consistently_oriented()) << s.name;
    EXPECT_EQ(c.degenerate_triangles, 0u) << s.name;
    // Inscribed polyhedra: a little smaller than the true shape, within 2 %.
    EXPECT_LT(mesh.volume(), s.volume) << s.name;
    EXPECT_GT(mesh.volume(), 0.98 * s.volume) << s.name;
    Vec3 lo, hi;
    mesh.bounds(lo, hi);
    EXPECT_LT((0.5 * (lo + hi) - s.center).norm(), 1e-9) << s.name;
  }
  // Capsule: half-length 0.1 plus the radius along z.
  Vec3 lo, hi;
  find("pill").bounds(lo, hi);
  EXPECT_NEAR(hi.z() - lo.z(), 0.26, 1e-12);

  // Infinite plane: 3 m half-size square at z = 0.
  find("floor").bounds(lo, hi);
  EXPECT_NEAR(lo.x(), -3, 1e-12);
  EXPECT_NEAR(hi.y(), 3, 1e-12);
  EXPECT_NEAR(hi.z(), 0, 1e-12);

  // The unnamed mesh geom: a closed tetrahedron at z = 2 named after its id.
  int tet_id = -1;
  for (int g = 0; g < m->ngeom; ++g)
    if (m->geom_type[g] == mjGEOM_MESH) tet_id = g;
  ASSERT_GE(tet_id, 0);
  const TriangleMesh& tet = find("geom" + std::to_string(tet_id));
  EXPECT_EQ(tet.num_triangles(), 4u);
  EXPECT_TRUE(check_mesh(tet).watertight());
  EXPECT_NEAR(std::abs(tet.volume()), std::pow(0.1, 3) / 6, 1e-9);
  tet.bounds(lo, hi);
  EXPECT_NEAR(hi.z() - lo.z(), 0.1, 1e-6);
}

TEST(MujocoScene, ScannerSeesTheTessellatedBall) {
  const MjModelPtr m = load_mjcf_string(kGeomsXml, "geoms.xml");
  const MjDataPtr d = make_data(m.get());
  mj_kinematics(m.get(), d.get());
  const int ball = mj_name2id(m.get(), mjOBJ_GEOM, "ball");
  const ScanScene scene(tessellate_geoms(
      m.get(), d.get(), [&](int g) { return g == ball; }, kTruthBody));
  // Scanner 0.3 m above the ball looking down (+z_M = -z_W), sweeping across it.
  Pose X_WM = at(Vec3(1 - 0.03, 0, 0.5 + 0.3));
  X_WM.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
  NoiseParams n = quiet();
  const ScanResult r = scan(scene, X_WM, params_with(line_view(200, 0.3, 0.06), n));
  ASSERT_GT(r.cloud_M.size(), 1000u);
  // Points on the sphere, inside it by at most the facets' sagitta (about r (π/48)² ≈ 0.2 mm).
  for (const auto& q : r.cloud_M.points) {
    const double dist = (X_WM * q.cast<double>() - Vec3(1, 0, 0.5)).norm();
    ASSERT_LE(dist, 0.05 + 1e-6);
    ASSERT_GE(dist, 0.05 - 3e-4);
  }
}

TEST(MujocoScene, BadArgumentsThrow) {
  const MjModelPtr m = load_mjcf_string(kGeomsXml, "geoms.xml");
  const MjDataPtr d = make_data(m.get());
  EXPECT_THROW(tessellate_geoms(nullptr, d.get(), {}, kTruthBody), ArgumentError);
  EXPECT_THROW(tessellate_geom(m.get(), d.get(), m->ngeom), ArgumentError);
  EXPECT_THROW(tessellate_geom(m.get(), d.get(), 0, 2), ArgumentError);
}

// ---------------------------------------------------------------------------------------------
// Degenerate views under every Embree kernel path
// ---------------------------------------------------------------------------------------------

// Rays Embree must never see as invalid: packets with 1 or 17 active lanes (the rest masked),
// a single ray per profile, a sensor sitting on the surface it looks at (zero-length camera
// rays), rays grazing a plane edge-on and a camera exactly at the lit point. Each kernel path
// that this CPU can run (Embree caps the ISA at what the CPU has) must give the same returns.
TEST(Scanner, DegenerateViewsGiveTheSameReturnsOnEveryKernelPath) {
  struct Case {
    const char* what;
    std::vector<SceneMesh> meshes;
    ScanParams params;
    std::size_t expected;  // points with quiet noise
  };
  std::vector<Case> cases;
  // One active lane per packet; the 15 others masked.
  cases.push_back({"one ray per profile",
                   {{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"}},
                   params_with(line_view(1, 0.1, 0.02), quiet()),
                   41});
  // 17 rays: the second packet has one active lane.
  cases.push_back({"17 rays per profile",
                   {{rect(at(Vec3(0, 0, 0.3)), 0.5, 0.5), kTruthBody, "plane"}},
                   params_with(line_view(17, 0.1, 0.0), quiet()),
                   17});
  // The plane contains the sensor's origin and the rays: every ray grazes it edge-on.
  cases.push_back({"rays in the plane",
                   {{rect(rot_x(M_PI / 2, Vec3(0, 0, 0)), 0.5, 0.5), kTruthBody, "plane"}},
                   params_with(line_view(33, 0.1, 0.0), quiet()),
                   0});
  // Coaxial camera (baseline 0) on a plane at the sensor's own origin: the laser starts on the
  // surface (range 0 < range_min) and the camera ray would have zero length.
  {
    ScanView v = line_view(9, 0.1, 0.0);
    v.line.baseline = 0;
    cases.push_back({"sensor on the surface",
                     {{rect(at(Vec3(0, 0, 0)), 0.5, 0.5), kTruthBody, "plane"}},
                     params_with(v, quiet()),
                     0});
  }
  for (Case& c : cases) {
    std::vector<std::size_t> sizes;
    for (const char* config : {"max_isa=sse4.2", "max_isa=avx2", "max_isa=avx512"}) {
      const ScanScene scene(c.meshes, config);
      const ScanResult r = scan(scene, Pose::Identity(), c.params);
      sizes.push_back(r.cloud_M.size());
      for (const auto& q : r.cloud_M.points) ASSERT_TRUE(q.allFinite()) << c.what << " " << config;
      EXPECT_EQ(r.cloud_M.size(), c.expected) << c.what << " " << config;
    }
    EXPECT_EQ(sizes[0], sizes[1]) << c.what;
    EXPECT_EQ(sizes[1], sizes[2]) << c.what;
  }
}

TEST(Scanner, DefaultKernelPathIsPinnedAndOverridable) {
  const char* saved = std::getenv("FLASHTWIN_EMBREE_CONFIG");
  const std::string saved_value = saved ? saved : "";
  unsetenv("FLASHTWIN_EMBREE_CONFIG");
  EXPECT_EQ(default_embree_config(), "max_isa=avx2");
  setenv("FLASHTWIN_EMBREE_CONFIG", "max_isa=sse4.2", 1);
  EXPECT_EQ(default_embree_config(), "max_isa=sse4.2");
  if (saved)
    setenv("FLASHTWIN_EMBREE_CONFIG", saved_value.c_str(), 1);
  else
    unsetenv("FLASHTWIN_EMBREE_CONFIG");
}

// ---------------------------------------------------------------------------------------------
// view_sees (scan planning): the scanner's rules for one point at a time
// ---------------------------------------------------------------------------------------------

TEST(ViewSees, AgreesWithTheScanOnEveryMeasuredPoint) {
  // Every point a noise-free scan measured is judged seen (line profiler and area sensor; the
  // last bits of the hit point aside, so 99 %).
  const ScanScene scene = busy_scene();
  ScanParams p = busy_params(3, 1);
  p.noise = quiet();
  p.noise.max_incidence = 1.2;
  for (std::size_t v = 0; v < p.views.size(); ++v) {
    ScanParams one = p;
    one.views = {p.views[v]};
    const ScanResult r = scan(scene, Pose::Identity(), one);
    ASSERT_GT(r.cloud_M.size(), 1000u);
    std::vector<Vec3> pts, nrm;
    for (std::size_t i = 0; i < r.cloud_M.size(); ++i) {
      pts.push_back(r.cloud_M.points[i].cast<double>());
      nrm.push_back(r.cloud_M.normals[i].cast<double>());
    }
    const auto seen = view_sees(scene, Pose::Identity(), p.views[v], pts, nrm, p.noise.max_incidence);
    const auto n_seen = static_cast<double>(std::count(seen.begin(), seen.end(), 1));
    EXPECT_GE(n_seen / static_cast<double>(pts.size()), 0.99) << "view " << v;
  }
}

TEST(ViewSees, RefusesWhatTheScannerCannotMeasure) {
  const ScanScene scene({{rect(at(Vec3(0, 0, 0.4)), 0.5, 0.5), kTruthBackground, "plane"},
                         {box(Vec3(0.01, 0, 0.25), Vec3(0.05, 0.02, 0.01)), kTruthBody, "box"}});
  const ScanView v = line_view(101, 0.4, 0.1);  // profiles at x in [0, 0.1]
  const Vec3 up(0, 0, -1);                     // faces the sensor
  const std::vector<Vec3> pts{
      Vec3(0.08, 0.05, 0.4),   // open plane: seen
      Vec3(0.01, 0.0, 0.4),    // behind the box (laser blocked)
      Vec3(0.2, 0.0, 0.4),     // beyond the sweep
      Vec3(0.05, 0.3, 0.4),    // outside the fan (atan(0.3/0.4) > 0.2 rad)
      Vec3(0.08, 0.05, 0.4),   // the first again, with a normal too grazing for the laser
      Vec3(0.05, 0.06, 0.4),   // camera ray (from x - 0.12) clear: seen
  };
  const std::vector<Vec3> nrm{up, up, up, up, Vec3(1, 0, 0.05).normalized(), Vec3::Zero()};
  const auto seen = view_sees(scene, Pose::Identity(), v, pts, nrm, 1.3);
  EXPECT_EQ(seen, (std::vector<char>{1, 0, 0, 0, 0, 1}));
  // A blocker on the camera's line of sight only hides the point from the camera.
  const ScanScene cam_blocked({{rect(at(Vec3(0, 0, 0.4)), 0.5, 0.5), kTruthBackground, "plane"},
                               {box(Vec3(0.0, 0.025, 0.2), Vec3(0.015, 0.01, 0.015)), kTruthBody, "blocker"}});
  const auto seen2 = view_sees(cam_blocked, Pose::Identity(), v, {Vec3(0.06, 0.05, 0.4)}, {up}, 1.3);
  EXPECT_EQ(seen2, std::vector<char>{0});
}
