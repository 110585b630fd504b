#pragma once
// Parameter sweeps (`flashtwin sweep`): one scenario run for many seeds (and --set overrides),
// in parallel threads, sharded for job arrays. Each run writes one JSON line (its metrics);
// the summary gives per-metric mean, min, max and the failures.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

namespace flashtwin::pipeline {

struct Scenario;

/// "1-100", "7", "1-10,20,30-32" → the seeds in order (duplicates kept once).
/// @throws ArgumentError naming the text when malformed or empty (at most 10^7 seeds).
std::vector<std::uint64_t> parse_seeds(const std::string& text);

/// "k/N" with 0 ≤ k < N → {k, N}. @throws ArgumentError.
std::pair<int, int> parse_shard(const std::string& text);

struct SweepOptions {
  std::vector<std::uint64_t> seeds;
  int shard = 0, shards = 1;  ///< this process runs seeds[i] with i % shards == shard
  int threads = 2;            ///< runs at once
  std::string out_dir;        ///< runs.jsonl and summary.json/.md go here (shard-suffixed)
  /// Called after each run (runs done, runs of this shard, its seed, its exit code).
  std::function<void(std::size_t, std::size_t, std::uint64_t, int)> progress;
};

struct SweepResult {
  std::size_t runs = 0, failures = 0;  ///< failures: exit code ≠ 0 or an exception
  nlohmann::ordered_json summary;      ///< what summary.json holds
  std::string jsonl_path, summary_path, table_path;
};

/// Runs the shard's seeds of `scenario` (the seed set per run) with `threads` threads; writes
/// DIR/runs[.shard-k-of-N].jsonl (one line per run, in seed order) and
/// DIR/summary[.shard...].json and .md. Deterministic: a run's metrics do not depend on the
/// thread count (timings aside).
SweepResult run_sweep(const Scenario& scenario, const SweepOptions& options);

/// Per-metric statistics over JSON lines of metrics (numbers only; booleans count trues):
/// {"runs": n, "failures": f (exit code ≠ 0), "failed_seeds": [...], "outside_expect": e (runs
/// with expect_violations > 0), "outside_expect_seeds": [...], "pass_rate": share of runs within
/// every expect: bound (without an error), "metrics": {key: {mean, min, p10, p50, p90, max, n}}} (percentiles
/// by nearest rank).
nlohmann::ordered_json summarize_runs(const std::vector<nlohmann::ordered_json>& runs);

/// The q-quantile of ascending values by nearest rank (q in [0, 1]; NaN when empty).
double nearest_rank(const std::vector<double>& sorted, double q);

struct SweepExpectation;

/// Checks a sweep summary (summarize_runs) against the scenario's `expect_sweep:` bounds;
/// returns one line per violation.
std::vector<std::string> check_sweep_expectations(const SweepExpectation& expectation,
                                                  const nlohmann::ordered_json& summary);

}  // namespace flashtwin::pipeline
