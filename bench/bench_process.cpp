// Speed of the grinding process model: voxelising a realistic parting-line fin (1 mm × 5 mm
// section, 300 mm or a 1 m perimeter, 0.1 mm voxels), removal steps of the default burr
// (r = 6 mm, 20 mm long) moving along it at 5 mm/s with 1 kHz steps (5 µm per step), flush with
// the wall and gouging 0.3 mm, and the residual analysis. Goal: a step far under 1 ms so a 1 kHz
// simulation stays at least 3× real time.
#include <benchmark/benchmark.h>

#include <memory>
#include <vector>

#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/process.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

constexpr double mm = 1e-3;


// A 300 × 200 × 30 mm plate with a fin 1 mm thick, 5 mm out at z = 15 mm: along the y = +100 mm
// side (sides = 1: 300 mm, 1.5 M voxels) or around the whole outline (sides = 4: 1 m, 5 M voxels).
struct Plate {
  TriangleMesh body = box_mesh(Vec3(-150, -100, 0) * mm, Vec3(150, 100, 30) * mm);
  std::vector<TriangleMesh> fins;
  explicit Plate(int sides) {
    fins.push_back(box_mesh(Vec3(-150, 100, 14.5) * mm, Vec3(150, 105, 15.5) * mm));
    if (sides < 4) return;
    fins.push_back(box_mesh(Vec3(-150, -105, 14.5) * mm, Vec3(150, -100, 15.5) * mm));
    fins.push_back(box_mesh(Vec3(150, -105, 14.5) * mm, Vec3(155, 105, 15.5) * mm));
    fins.push_back(box_mesh(Vec3(-155, -105, 14.5) * mm, Vec3(-150, 105, 15.5) * mm));
  }
};

// Default burr standing upright: tip (TCP) 10 mm below the fin, cutter along +z_C.
Pose burr_pose(double x, double y) {
  Pose X = Pose::Identity();
  X.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
  X.translation() = Vec3(x, y, 5 * mm);
  return X;
}

void BM_BuildGrid(benchmark::State& state) {
  const Plate plate(static_cast<int>(state.range(0)));
  std::size_t voxels = 0, bytes = 0, body = 0;
  for (auto _ : state) {
    MaterialGrid grid(plate.body, plate.fins);
    voxels = grid.flash_voxels_initial();
    body = grid.body_voxels_initial();
    bytes = grid.memory_bytes();
    benchmark::DoNotOptimize(voxels);
  }
  state.counters["flash_voxels"] = static_cast<double>(voxels);
  state.counters["body_voxels"] = static_cast<double>(body);
  state.counters["MB"] = static_cast<double>(bytes) / 1e6;
}
BENCHMARK(BM_BuildGrid)->Arg(1)->Arg(4)->Unit(benchmark::kMillisecond);

void BM_BuildCastingGrid(benchmark::State& state) {
  CastingParams cp;
  cp.seed = 3;
  const Casting casting = make_casting(cp);
  std::size_t voxels = 0;
  for (auto _ : state) {
    const MaterialGrid grid = make_material_grid(casting);
    voxels = grid.flash_voxels_initial();
    benchmark::DoNotOptimize(voxels);
  }
  state.counters["flash_voxels"] = static_cast<double>(voxels);
  state.counters["nominal_tris"] = static_cast<double>(casting.nominal.num_triangles());
}
BENCHMARK(BM_BuildCastingGrid)->Unit(benchmark::kMillisecond);

// One removal step per iteration along the 300 mm fin; range(0) = depth into the wall [µm].
void BM_RemoveStep(benchmark::State& state) {
  const Plate plate(1);
  const MaterialGrid fresh(plate.body, plate.fins);
  auto grid = std::make_unique<MaterialGrid>(fresh);
  const ToolParams tool;  // r = 6 mm, 20 mm, ball end
  const double y = (100 + 6) * mm - state.range(0) * 1e-6;
  const double step = 5e-6;  // 5 mm/s at 1 kHz
  double x = -140 * mm, removed = 0;
  std::size_t steps = 0;
  for (auto _ : state) {
    const StepRemoval s = remove_material(tool, *grid, burr_pose(x, y));
    removed += s.volume();
    ++steps;
    x += step;
    if (x > 140 * mm) {
      state.PauseTiming();
      grid = std::make_unique<MaterialGrid>(fresh);
      x = -140 * mm;
      state.ResumeTiming();
    }
  }
  state.counters["mm3_per_step"] = removed / static_cast<double>(steps) * 1e9;
  state.counters["realtime_x_at_1kHz"] =
      benchmark::Counter(1e-3 * static_cast<double>(steps), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_RemoveStep)->Arg(0)->Arg(300)->Unit(benchmark::kMicrosecond);

void BM_AnalyzeResidual(benchmark::State& state) {
  const Plate plate(static_cast<int>(state.range(0)));
  const MaterialGrid grid(plate.body, plate.fins);
  double h = 0;
  for (auto _ : state) {
    const ResidualReport r = analyze_residual(grid);
    // (DoNotOptimize on a double corrupts it with GCC 12 + benchmark 1.7.1: keep it on integers.)
    benchmark::DoNotOptimize(r.flash_voxels_remaining);
    h = r.residual_flash_max;
  }
  state.counters["residual_max_mm"] = h * 1e3;
}
BENCHMARK(BM_AnalyzeResidual)->Arg(1)->Arg(4)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
