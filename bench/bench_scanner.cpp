// Speed of the virtual laser scanner: a line-profiler sweep (801 profiles × 1280 rays, about
// 1.03 M primary rays, each with a camera visibility ray and the full noise model) over a scene
// of three ~100k-triangle meshes (table plate, sphere, box), with 1 and 2 threads.
#include <benchmark/benchmark.h>

#include <cmath>
#include <memory>
#include <vector>

#include "flashtwin/sim/scanner.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

// Flat plate in the world x-y plane at height z, n × n quads, normal +z.
TriangleMesh plate(double half, double z, int n) {
  TriangleMesh m;
  for (int i = 0; i <= n; ++i)
    for (int j = 0; j <= n; ++j)
      m.vertices.emplace_back(-half + 2 * half * i / n, -half + 2 * half * j / n, z);
  auto id = [n](int i, int j) { return i * (n + 1) + j; };
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < n; ++j) {
      m.triangles.emplace_back(id(i, j), id(i + 1, j), id(i + 1, j + 1));
      m.triangles.emplace_back(id(i, j), id(i + 1, j + 1), id(i, j + 1));
    }
  return m;
}

// Closed UV sphere: 2 · lon · (lat − 1) triangles.
TriangleMesh sphere(const Vec3& c, double r, int lon, int lat) {
  TriangleMesh m;
  m.vertices.push_back(c + Vec3(0, 0, -r));
  for (int i = 1; i < lat; ++i) {
    const double th = M_PI * i / lat - M_PI / 2;
    for (int k = 0; k < lon; ++k) {
      const double ph = 2 * M_PI * k / lon;
      m.vertices.push_back(
          c + r * Vec3(std::cos(th) * std::cos(ph), std::cos(th) * std::sin(ph), std::sin(th)));
    }
  }
  m.vertices.push_back(c + Vec3(0, 0, r));
  const int top = static_cast<int>(m.vertices.size()) - 1;
  auto ring = [lon](int i, int k) { return 1 + (i - 1) * lon + (k % lon); };
  for (int k = 0; k < lon; ++k) m.triangles.emplace_back(0, ring(1, k + 1), ring(1, k));
  for (int i = 1; i + 1 < lat; ++i)
    for (int k = 0; k < lon; ++k) {
      m.triangles.emplace_back(ring(i, k), ring(i, k + 1), ring(i + 1, k + 1));
      m.triangles.emplace_back(ring(i, k), ring(i + 1, k + 1), ring(i + 1, k));
    }
  for (int k = 0; k < lon; ++k)
    m.triangles.emplace_back(top, ring(lat - 1, k), ring(lat - 1, k + 1));
  return m;
}

// Box with every face split into n × n quads (faces not welded: fine for ray casting).
TriangleMesh box(const Vec3& c, const Vec3& half, int n) {
  TriangleMesh m;
  for (int axis = 0; axis < 3; ++axis)
    for (int sgn = -1; sgn <= 1; sgn += 2) {
      const int u = (axis + 1) % 3, v = (axis + 2) % 3;
      const int base = static_cast<int>(m.vertices.size());
      for (int i = 0; i <= n; ++i)
        for (int j = 0; j <= n; ++j) {
          Vec3 p;
          p[axis] = sgn * half[axis];
          p[u] = half[u] * (2.0 * i / n - 1);
          p[v] = half[v] * (2.0 * j / n - 1);
          m.vertices.push_back(c + p);
        }
      auto id = [&](int i, int j) { return base + i * (n + 1) + j; };
      for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
          if (sgn > 0) {
            m.triangles.emplace_back(id(i, j), id(i + 1, j), id(i + 1, j + 1));
            m.triangles.emplace_back(id(i, j), id(i + 1, j + 1), id(i, j + 1));
          } else {
            m.triangles.emplace_back(id(i, j), id(i + 1, j + 1), id(i + 1, j));
            m.triangles.emplace_back(id(i, j), id(i, j + 1), id(i + 1, j + 1));
          }
        }
    }
  return m;
}

struct Bench {
  std::unique_ptr<ScanScene> scene;
  Pose X_WM = Pose::Identity();
  ScanParams params;
};

const Bench& bench() {
  static const Bench b = [] {
    Bench out;
    std::vector<SceneMesh> meshes;
    meshes.push_back({plate(0.3, 0.0, 224), kTruthBackground, "table"});  // 100,352
    meshes.push_back(
        {sphere(Vec3(-0.05, 0.03, 0.06), 0.06, 320, 160), kTruthBody, "sphere"});  // 101,760
    meshes.push_back({box(Vec3(0.08, -0.03, 0.025), Vec3(0.05, 0.04, 0.025), 92), kTruthFlash,
                      "box"});  // 101,568
    out.scene = std::make_unique<ScanScene>(meshes);
    // Scanner 0.35 m above the table, looking down (+z_M = −z_W), sweeping along +x_W.
    out.X_WM.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
    out.X_WM.translation() = Vec3(-0.2, 0.0, 0.35);
    ScanView v;
    v.kind = SensorKind::kLineProfiler;
    v.line.points_per_profile = 1280;
    v.line.profile_spacing = 0.0005;
    v.line.sweep_length = 0.4;  // 801 profiles
    out.params.views = {v};
    out.params.seed = 7;
    return out;
  }();
  return b;
}

void BM_LineProfilerScan(benchmark::State& state) {
  const Bench& b = bench();
  ScanParams p = b.params;
  p.threads = static_cast<int>(state.range(0));
  std::uint64_t rays = 0, points = 0;
  for (auto _ : state) {
    const ScanResult r = scan(*b.scene, b.X_WM, p);
    rays += r.rays;
    points = r.cloud_M.size();
    benchmark::DoNotOptimize(r.cloud_M.points.data());
  }
  state.counters["rays_per_s"] =
      benchmark::Counter(static_cast<double>(rays), benchmark::Counter::kIsRate);
  state.counters["rays"] = static_cast<double>(rays) / state.iterations();
  state.counters["points"] = static_cast<double>(points);
  state.counters["triangles"] = static_cast<double>(b.scene->num_triangles());
}
BENCHMARK(BM_LineProfilerScan)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
