// The default scenario's full scan: cell geometry from MuJoCo, casting and flashes, five
// line-profiler views (2 M rays), as `flashtwin scan` runs it.
#include <benchmark/benchmark.h>

#include <filesystem>

#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/sim/scan_cell.hpp"

using namespace flashtwin;

namespace {

void BM_DefaultScenarioScan(benchmark::State& state) {
  const auto sc = pipeline::load_scenario(std::string(FLASHTWIN_SOURCE_DIR) + "/scenarios/default.yaml");
  const auto setup = pipeline::setup_cell(sc);
  const std::string dir = (std::filesystem::temp_directory_path() / "flashtwin_bench_cell").string();
  const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
  sim::ScanParams p = sc.scan;
  p.threads = static_cast<int>(state.range(0));
  std::uint64_t rays = 0, points = 0;
  for (auto _ : state) {
    const auto s = sim::scan_cell(files.mjcf, setup.casting, p, setup.spec.X_WM, setup.spec.X_WM);
    rays = s.result.rays;
    points = s.result.cloud_M.size();
    benchmark::DoNotOptimize(s);
  }
  state.counters["rays"] = static_cast<double>(rays);
  state.counters["points"] = static_cast<double>(points);
  state.counters["rays_per_s"] =
      benchmark::Counter(static_cast<double>(rays) * state.iterations(), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_DefaultScenarioScan)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
