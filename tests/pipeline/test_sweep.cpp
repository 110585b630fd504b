// Sweeps and scenario overrides: seed lists, shards, summaries, --set on the YAML, report pieces.
#include <gtest/gtest.h>

#include <cmath>
#include <fstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/pipeline/report.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/pipeline/sweep.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::pipeline;

TEST(Sweep, SeedListsAndShards) {
  EXPECT_EQ(parse_seeds("3"), (std::vector<std::uint64_t>{3}));
  EXPECT_EQ(parse_seeds("1-4,9,3-5"), (std::vector<std::uint64_t>{1, 2, 3, 4, 9, 5}));
  EXPECT_EQ(parse_seeds("1-100").size(), 100u);
  for (const char* bad : {"", "a", "5-1", "1-", "-3", "1,,2", "1.5"})
    EXPECT_THROW(parse_seeds(bad), ArgumentError) << bad;
  EXPECT_EQ(parse_shard("0/1"), std::make_pair(0, 1));
  EXPECT_EQ(parse_shard("3/16"), std::make_pair(3, 16));
  for (const char* bad : {"1/1", "-1/4", "4", "a/b", "2/0", "1/2x"})
    EXPECT_THROW(parse_shard(bad), ArgumentError) << bad;
}

TEST(Sweep, SummaryStatisticsAndFailures) {
  std::vector<nlohmann::ordered_json> runs(3);
  runs[0] = {{"seed", 1}, {"exit_code", 0}, {"path.rmse_mm", 0.1}, {"registration.confident", true}};
  runs[1] = {{"seed", 2}, {"exit_code", 1}, {"path.rmse_mm", 0.3}, {"registration.confident", false}};
  runs[2] = {{"seed", 3}, {"exit_code", 0}, {"path.rmse_mm", 0.2}, {"registration.confident", true},
             {"verdict", "text is skipped"}};
  const auto s = summarize_runs(runs);
  EXPECT_EQ(s["runs"], 3);
  EXPECT_EQ(s["failures"], 1);
  EXPECT_EQ(s["failed_seeds"], nlohmann::ordered_json::array({2}));
  EXPECT_NEAR(s["metrics"]["path.rmse_mm"]["mean"].get<double>(), 0.2, 1e-12);
  EXPECT_DOUBLE_EQ(s["metrics"]["path.rmse_mm"]["min"].get<double>(), 0.1);
  EXPECT_DOUBLE_EQ(s["metrics"]["path.rmse_mm"]["max"].get<double>(), 0.3);
  EXPECT_NEAR(s["metrics"]["registration.confident"]["mean"].get<double>(), 2.0 / 3, 1e-12);
  EXPECT_FALSE(s["metrics"].contains("verdict"));
  EXPECT_FALSE(s["metrics"].contains("seed"));
}

TEST(Sweep, PercentilesByNearestRankAndPassRate) {
  EXPECT_DOUBLE_EQ(nearest_rank({1, 2, 3, 4, 5, 6, 7, 8, 9, 10}, 0.1), 1);
  EXPECT_DOUBLE_EQ(nearest_rank({1, 2, 3, 4, 5, 6, 7, 8, 9, 10}, 0.5), 5);
  EXPECT_DOUBLE_EQ(nearest_rank({1, 2, 3, 4, 5, 6, 7, 8, 9, 10}, 0.9), 9);
  EXPECT_DOUBLE_EQ(nearest_rank({4}, 0.1), 4);
  EXPECT_TRUE(std::isnan(nearest_rank({}, 0.5)));
  std::vector<nlohmann::ordered_json> runs;
  for (int i = 0; i < 10; ++i)
    runs.push_back({{"seed", i}, {"exit_code", i == 9 ? 1 : 0}, {"expect_violations", i >= 7 ? 1 : 0},
                    {"path.coverage", 0.9 + 0.01 * i}});
  runs.push_back({{"seed", 10}, {"exit_code", 2}, {"error", "boom"}});
  const auto s = summarize_runs(runs);
  EXPECT_NEAR(s["pass_rate"].get<double>(), 7.0 / 11, 1e-12);  // 7 within bounds, 1 error
  EXPECT_NEAR(s["metrics"]["path.coverage"]["p10"].get<double>(), 0.90, 1e-12);
  EXPECT_NEAR(s["metrics"]["path.coverage"]["p50"].get<double>(), 0.94, 1e-12);
  EXPECT_NEAR(s["metrics"]["path.coverage"]["p90"].get<double>(), 0.98, 1e-12);

  SweepExpectation ex;
  ex.min_pass_rate = 0.6;
  ex.bounds = {{"path.coverage", "p50", 0.93, 1e300}, {"path.coverage", "p10", 0.91, 1e300}};
  const auto bad = check_sweep_expectations(ex, s);
  ASSERT_EQ(bad.size(), 1u);
  EXPECT_EQ(bad[0].rfind("path.coverage.p10: expected within [0.910000, inf], got 0.9", 0), 0u);
  ex.min_pass_rate = 0.7;
  ex.bounds.push_back({"path.rmse_mm", "p50", -1e300, 0.1});
  EXPECT_EQ(check_sweep_expectations(ex, s).size(), 3u);  // pass rate, p10, missing metric
}

TEST(Scenario, ExpectSweepBlockIsReadAndChecked) {
  const std::string dir = ftest::temp_dir("expect_sweep");
  const std::string robot = ftest::source_path("models/robots/ft6.yaml");
  auto scenario = [&](const std::string& block) {
    const std::string p = dir + "/s.yaml";
    std::ofstream(p) << "name: s\nrobot: " << robot
                     << "\ncasting: {family: flanged_plate}\nexpect_sweep:\n" << block;
    return p;
  };
  const Scenario sc = load_scenario(scenario(
      "  seeds: 201-204,210\n  pass_rate: 0.75\n  path.coverage: {p50: [0.9, null], min: [0.5, null]}\n"));
  EXPECT_EQ(sc.expect_sweep.seeds, (std::vector<std::uint64_t>{201, 202, 203, 204, 210}));
  EXPECT_DOUBLE_EQ(sc.expect_sweep.min_pass_rate, 0.75);
  ASSERT_EQ(sc.expect_sweep.bounds.size(), 2u);
  EXPECT_EQ(sc.expect_sweep.bounds[0].statistic, "p50");
  EXPECT_DOUBLE_EQ(sc.expect_sweep.bounds[0].lo, 0.9);
  // The mean (a share of runs for a 0/1 metric such as registration.confident).
  const Scenario sm = load_scenario(scenario("  seeds: 1-8\n  registration.confident: {mean: [0.5, null]}\n"));
  ASSERT_EQ(sm.expect_sweep.bounds.size(), 1u);
  EXPECT_EQ(sm.expect_sweep.bounds[0].statistic, "mean");
  EXPECT_THROW(load_scenario(scenario("  pass_rate: 0.5\n")), ConfigError);  // no seeds
  EXPECT_THROW(load_scenario(scenario("  seeds: 5-1\n")), ConfigError);
  EXPECT_THROW(load_scenario(scenario("  seeds: 1-8\n  pass_rate: 2\n")), ConfigError);
  EXPECT_THROW(load_scenario(scenario("  seeds: 1-8\n  path.coverage: {p42: [0, 1]}\n")), ConfigError);
  EXPECT_THROW(load_scenario(scenario("  seeds: 1-8\n  path.coverage: {p50: [1, 0]}\n")), ConfigError);
  EXPECT_THROW(load_scenario(scenario("  seeds: 1-8\n  path.coverage: 0.9\n")), ConfigError);
}

TEST(Scenario, OverridesSetKeysAndUnknownKeysAreStillReported) {
  const std::string path = ftest::source_path("scenarios/default.yaml");
  const Scenario base = load_scenario(path);
  const Scenario sc = load_scenario(
      path, {"planning.feed=0.02", "execution.force_control.enabled=true",
             "execution.force_control.target_force=15", "process.voxel_size=0.0002", "seed=9"});
  EXPECT_DOUBLE_EQ(sc.grind.feed, 0.02);
  EXPECT_NE(base.grind.feed, 0.02);
  EXPECT_TRUE(sc.execution.exec.force_control.enabled);
  EXPECT_DOUBLE_EQ(sc.execution.exec.force_control.target_force, 15);
  EXPECT_DOUBLE_EQ(sc.execution.material.voxel_size, 2e-4);
  EXPECT_EQ(sc.seed, 9u);
  EXPECT_EQ(sc.robot.name, base.robot.name);  // relative paths still resolve
  EXPECT_THROW(load_scenario(path, {"planning.fed=0.02"}), ConfigError);       // typo
  EXPECT_THROW(load_scenario(path, {"planning.feed=-1"}), ConfigError);        // out of range
  EXPECT_THROW(load_scenario(path, {"process.voxel_size=abc"}), ConfigError);  // not a number
  EXPECT_THROW(load_scenario(path, {"noequals"}), ConfigError);
  EXPECT_THROW(load_scenario(path, {"name.x=1"}), ConfigError);  // below a scalar
  // List elements by index (a scenario that lists its scanner views).
  const std::string housing = ftest::temp_dir("views_list") + "/views.yaml";
  {
    std::ofstream f(housing);
    f << "name: v\nrobot: " << ftest::source_path("models/robots/ft6.yaml")
      << "\ncasting: {family: housing}\nscanner:\n  views:\n    - {kind: line}\n";
  }
  EXPECT_NO_THROW(load_scenario(housing, {"scanner.views.0.standoff=0.31"}));
  EXPECT_THROW(load_scenario(housing, {"scanner.views.0.standoff=99"}), ConfigError);
  EXPECT_THROW(load_scenario(housing, {"scanner.views.9.standoff=0.3"}), ConfigError);
  EXPECT_THROW(load_scenario(housing, {"scanner.views.x.standoff=0.3"}), ConfigError);
  Scenario s2 = base;
  set_seed(s2, 42);
  EXPECT_EQ(s2.seed, 42u);
  EXPECT_EQ(s2.scan.seed, 42u);
  EXPECT_EQ(s2.casting.seed, 42u);
}

TEST(Report, Base64MatchesRfc4648Vectors) {
  EXPECT_EQ(base64_encode(""), "");
  EXPECT_EQ(base64_encode("f"), "Zg==");
  EXPECT_EQ(base64_encode("fo"), "Zm8=");
  EXPECT_EQ(base64_encode("foo"), "Zm9v");
  EXPECT_EQ(base64_encode("foob"), "Zm9vYg==");
  EXPECT_EQ(base64_encode("fooba"), "Zm9vYmE=");
  EXPECT_EQ(base64_encode("foobar"), "Zm9vYmFy");
  EXPECT_EQ(base64_encode(std::string("\xff\x00\x80", 3)), "/wCA");
}
