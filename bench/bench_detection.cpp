// Flash detection speed: the default scenario's scan (1.85 M points, cropped to the casting
// by detection itself) and a 1 M-point subset, with the pose from the calibrated scanner; and
// the improved voxel grid (§3.4) against the plain centroid grid on ~2,600 boundary points.
#include <benchmark/benchmark.h>

#include <filesystem>

#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/sim/scan_cell.hpp"

using namespace flashtwin;

namespace {

struct Fixture {
  PointCloud scan;
  std::unique_ptr<MeshBvh> cad;
  Pose X_CM;
};

const Fixture& fixture() {
  static const Fixture f = [] {
    Fixture x;
    const auto sc = pipeline::load_scenario(std::string(FLASHTWIN_SOURCE_DIR) + "/scenarios/default.yaml");
    const auto setup = pipeline::setup_cell(sc);
    const std::string dir = (std::filesystem::temp_directory_path() / "flashtwin_bench_detect").string();
    const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
    sim::ScanParams p = sc.scan;
    p.threads = 2;
    x.scan = sim::scan_cell(files.mjcf, setup.casting, p, setup.spec.X_WM, setup.spec.X_WM).result.cloud_M;
    x.cad = std::make_unique<MeshBvh>(setup.casting.nominal);
    x.X_CM = setup.spec.X_WC.inverse() * setup.spec.X_WM;
    return x;
  }();
  return f;
}

void BM_DetectFlash(benchmark::State& state) {
  const auto& f = fixture();
  PointCloud scan;
  const std::size_t n = std::min<std::size_t>(f.scan.size(), static_cast<std::size_t>(state.range(0)));
  // An evenly strided subset keeps every view represented.
  const double stride = static_cast<double>(f.scan.size()) / n;
  for (std::size_t i = 0; i < n; ++i) scan.points.push_back(f.scan.points[static_cast<std::size_t>(i * stride)]);
  std::size_t paths = 0;
  for (auto _ : state) {
    const auto r = perception::detect_flash(scan, *f.cad, f.X_CM);
    paths = r.paths.size();
    benchmark::DoNotOptimize(paths);
  }
  state.counters["points"] = static_cast<double>(n);
  state.counters["paths"] = static_cast<double>(paths);
}
BENCHMARK(BM_DetectFlash)->Arg(1000000)->Arg(1900000)->Unit(benchmark::kMillisecond)->UseRealTime();

// ~2,600 boundary-like points: a band along a 300 mm curve, 0.5 mm wide.
PointCloud boundary_points() {
  Rng rng(5);
  PointCloud c;
  for (int i = 0; i < 2600; ++i) {
    const double t = 0.3 * i / 2600.0;
    c.points.emplace_back(static_cast<float>(t), static_cast<float>(0.01 * std::sin(20 * t) + rng.uniform(0, 5e-4)),
                          static_cast<float>(rng.normal() * 3e-5));
  }
  return c;
}

void BM_VoxelNearest(benchmark::State& state) {
  const PointCloud c = boundary_points();
  for (auto _ : state) benchmark::DoNotOptimize(perception::voxel_downsample_nearest(c, 4e-4));
}
BENCHMARK(BM_VoxelNearest)->Unit(benchmark::kMicrosecond);

void BM_VoxelCentroid(benchmark::State& state) {
  const PointCloud c = boundary_points();
  for (auto _ : state) benchmark::DoNotOptimize(perception::voxel_downsample(c, 4e-4));
}
BENCHMARK(BM_VoxelCentroid)->Unit(benchmark::kMicrosecond);

}  // namespace
