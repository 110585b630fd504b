// The whole `flashtwin run` of a scenario (scan, perception, planning, execution with the
// process model, re-scan, scoring, report; no video): wall time per run and the simulation's
// real-time factor. Goal (issue 7, default scenario): ≤ 30 s per run, real-time factor ≥ 3.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <string>

#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"

namespace {

void BM_RunScenario(benchmark::State& state, const std::string& name, bool report) {
  const auto sc = flashtwin::pipeline::load_scenario(std::string(FLASHTWIN_SOURCE_DIR) +
                                                     "/scenarios/" + name + ".yaml");
  const std::string out =
      (std::filesystem::temp_directory_path() / ("flashtwin_bench_run_" + name)).string();
  double rtf = 0, exec = 0;
  for (auto _ : state) {
    flashtwin::pipeline::RunOptions opt;
    opt.out_dir = out;
    opt.report = report;
    const auto r = flashtwin::pipeline::run_scenario(sc, opt);
    rtf = r.metrics.value("sim.realtime_factor", 0.0);
    exec = r.metrics.value("timing.execution_s", 0.0);
    benchmark::DoNotOptimize(r.exit_code);
  }
  state.counters["realtime_factor"] = rtf;
  state.counters["execution_s"] = exec;
  std::filesystem::remove_all(out);
}

}  // namespace

BENCHMARK_CAPTURE(BM_RunScenario, default_with_report, std::string("default"), true)
    ->Unit(benchmark::kSecond)->Iterations(1)->Repetitions(3);
BENCHMARK_CAPTURE(BM_RunScenario, user_mesh_no_report, std::string("user_mesh"), false)
    ->Unit(benchmark::kSecond)->Iterations(1)->Repetitions(2);
