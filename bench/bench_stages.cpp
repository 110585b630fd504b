// Each stage of `flashtwin run` on the default scenario, alone: the scan, the CAD-side
// registration target, registration of the cell scan, registration + flash detection, planning
// of every detected path, and execution of the planned paths in MuJoCo with the process model
// (material grid build and residual analysis included; the counter step_us is the cost of one
// 1 kHz simulation step). The inputs of each stage come from one run of the stages before it.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <string>
#include <vector>

#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/perception/registration.hpp"
#include "flashtwin/pipeline/execution.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/planner/grind_planner.hpp"

using namespace flashtwin;

namespace {

struct Stages {
  pipeline::Scenario sc;
  pipeline::ScenarioScan scan;
  Pose X_CM_est = Pose::Identity();
  perception::DetectionResult detection;
  std::vector<pipeline::PlannedPath> plans;
};

perception::RegistrationParams cell_registration() {
  perception::RegistrationParams rp;  // as run_scenario registers a cell scan
  rp.remove_support_plane = true;
  rp.viewpoint = Vec3::Zero();
  return rp;
}

std::vector<pipeline::PlannedPath> plan_all(const Stages& s) {
  const auto& spec = s.scan.setup.spec;
  const Pose X_BC_est = spec.X_WB.inverse() * spec.X_WM * s.X_CM_est.inverse();
  std::vector<pipeline::PlannedPath> plans;
  for (std::size_t k = 0; k < s.detection.paths.size(); ++k) {
    auto g = planner::plan_grind(s.sc.robot, X_BC_est, pipeline::grind_path_of(s.detection.paths[k]),
                                 s.sc.grind);
    if (g.ok()) plans.emplace_back(k, std::move(g));
  }
  return plans;
}

const Stages& stages() {
  static const Stages built = [] {
    Stages s;
    s.sc = pipeline::load_scenario(std::string(FLASHTWIN_SOURCE_DIR) + "/scenarios/default.yaml");
    const std::string dir =
        (std::filesystem::temp_directory_path() / "flashtwin_bench_stages").string();
    s.scan = pipeline::scan_scenario(s.sc, dir, 1);
    const auto target = perception::ModelTarget::from_mesh(s.scan.setup.casting.nominal);
    const auto reg = perception::register_scan(s.scan.scan.result.cloud_M, *target, cell_registration());
    s.X_CM_est = reg.T_target_source;
    const MeshBvh cad(s.scan.setup.casting.nominal);
    s.detection = perception::detect_flash(s.scan.scan.result.cloud_M, cad, s.X_CM_est, s.sc.detection);
    s.plans = plan_all(s);
    return s;
  }();
  return built;
}

void BM_Scan(benchmark::State& state) {
  const Stages& s = stages();
  const std::string dir =
      (std::filesystem::temp_directory_path() / "flashtwin_bench_stages_scan").string();
  for (auto _ : state) {
    const auto scan = pipeline::scan_scenario(s.sc, dir, static_cast<int>(state.range(0)));
    benchmark::DoNotOptimize(scan.scan.result.cloud_M.size());
  }
  state.counters["points"] = static_cast<double>(s.scan.scan.result.cloud_M.size());
}
BENCHMARK(BM_Scan)->Arg(1)->Arg(2)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_RegistrationTarget(benchmark::State& state) {
  const Stages& s = stages();
  for (auto _ : state)
    benchmark::DoNotOptimize(perception::ModelTarget::from_mesh(s.scan.setup.casting.nominal));
}
BENCHMARK(BM_RegistrationTarget)->Unit(benchmark::kMillisecond);

void BM_RegisterCellScan(benchmark::State& state) {
  const Stages& s = stages();
  const auto target = perception::ModelTarget::from_mesh(s.scan.setup.casting.nominal);
  for (auto _ : state)
    benchmark::DoNotOptimize(
        perception::register_scan(s.scan.scan.result.cloud_M, *target, cell_registration()));
  state.counters["points"] = static_cast<double>(s.scan.scan.result.cloud_M.size());
}
BENCHMARK(BM_RegisterCellScan)->Unit(benchmark::kMillisecond)->UseRealTime();

// The "registration + detection of a whole cell scan" (target built beforehand, as a
// sweep over one part reuses it).
void BM_RegisterAndDetect(benchmark::State& state) {
  const Stages& s = stages();
  const auto target = perception::ModelTarget::from_mesh(s.scan.setup.casting.nominal);
  const MeshBvh cad(s.scan.setup.casting.nominal);
  for (auto _ : state) {
    const auto reg = perception::register_scan(s.scan.scan.result.cloud_M, *target, cell_registration());
    benchmark::DoNotOptimize(
        perception::detect_flash(s.scan.scan.result.cloud_M, cad, reg.T_target_source, s.sc.detection));
  }
}
BENCHMARK(BM_RegisterAndDetect)->Unit(benchmark::kMillisecond)->UseRealTime();

void BM_PlanAllPaths(benchmark::State& state) {
  const Stages& s = stages();
  for (auto _ : state) benchmark::DoNotOptimize(plan_all(s));
  state.counters["paths"] = static_cast<double>(s.plans.size());
}
BENCHMARK(BM_PlanAllPaths)->Unit(benchmark::kMillisecond);

void BM_ExecuteAllPaths(benchmark::State& state) {
  const Stages& s = stages();
  double step_us = 0, steps = 0;
  for (auto _ : state) {
    nlohmann::ordered_json m;
    const auto ex = pipeline::execute_plans(s.sc, s.scan, s.plans, m);
    step_us = m.value("sim.step_us", 0.0);
    steps = m.value("sim.steps", 0.0);
    benchmark::DoNotOptimize(ex.residual.flash_removed_fraction);
  }
  state.counters["step_us"] = step_us;
  state.counters["sim_steps"] = steps;
}
BENCHMARK(BM_ExecuteAllPaths)->Unit(benchmark::kSecond)->Iterations(1)->Repetitions(3);

}  // namespace
