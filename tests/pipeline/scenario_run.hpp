#pragma once
// One shipped scenario at one seed, as `flashtwin run` runs it (no report, no scan file written),
// for tests that score a whole pass against the truth.
#include <gtest/gtest.h>

#include <cstdint>
#include <string>

#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "test_util.hpp"

namespace ftest {

/// scenarios/<scenario>.yaml run at `seed`; execution only when `execute` (else scan,
/// perception and planning). Fails the calling test when the pose is refused.
inline pipeline::RunResult scenario_run(const std::string& scenario, std::uint64_t seed,
                                        bool execute) {
  auto sc = pipeline::load_scenario(source_path("scenarios/" + scenario + ".yaml"));
  pipeline::set_seed(sc, seed);
  sc.execution.enabled = execute;
  pipeline::RunOptions o;
  o.report = false;
  o.write_scan = false;
  o.out_dir = temp_dir(scenario + "_" + std::to_string(seed));
  auto r = pipeline::run_scenario(sc, o);
  EXPECT_FALSE(r.refused) << r.verdict;
  return r;
}

/// The metrics of scenario_run.
inline nlohmann::ordered_json scenario_metrics(const std::string& scenario, std::uint64_t seed,
                                               bool execute) {
  return scenario_run(scenario, seed, execute).metrics;
}

}  // namespace ftest
