#include "flashtwin/pipeline/sweep.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <filesystem>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"

namespace flashtwin::pipeline {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

namespace {

std::uint64_t parse_u64(const std::string& s, const std::string& whole) {
  if (s.empty() || s.find_first_not_of("0123456789") != std::string::npos || s.size() > 18)
    throw ArgumentError("--seeds " + whole + ": expected numbers like 1-100 or 1,5,9");
  return std::stoull(s);
}

}  // namespace

double nearest_rank(const std::vector<double>& sorted, double q) {
  if (sorted.empty()) return std::nan("");
  // Nearest rank: the smallest value with at least q of the values at or below it.
  const double rank = std::ceil(q * static_cast<double>(sorted.size()));
  const std::size_t i = static_cast<std::size_t>(std::max(1.0, rank)) - 1;
  return sorted[std::min(i, sorted.size() - 1)];
}

std::vector<std::string> check_sweep_expectations(const SweepExpectation& ex,
                                                  const nlohmann::ordered_json& summary) {
  std::vector<std::string> bad;
  auto range = [](double lo, double hi) {
    std::ostringstream os;
    os << "[" << (lo < -1e299 ? std::string("-inf") : std::to_string(lo)) << ", "
       << (hi > 1e299 ? std::string("inf") : std::to_string(hi)) << "]";
    return os.str();
  };
  const double rate = summary.value("pass_rate", 0.0);
  if (rate < ex.min_pass_rate) {
    std::ostringstream os;
    os << "pass_rate: expected at least " << ex.min_pass_rate << ", got " << rate
       << " (seeds outside expect: " << summary["outside_expect_seeds"].dump()
       << ", failed: " << summary["failed_seeds"].dump() << ")";
    bad.push_back(os.str());
  }
  const json& metrics = summary["metrics"];
  for (const SweepBound& b : ex.bounds) {
    if (!metrics.contains(b.key) || !metrics[b.key].contains(b.statistic)) {
      bad.push_back(b.key + "." + b.statistic + ": expected by the scenario, missing from the sweep");
      continue;
    }
    const double x = metrics[b.key][b.statistic].get<double>();
    if (!(x >= b.lo && x <= b.hi))
      bad.push_back(b.key + "." + b.statistic + ": expected within " + range(b.lo, b.hi) +
                    ", got " + std::to_string(x));
  }
  return bad;
}

std::vector<std::uint64_t> parse_seeds(const std::string& text) {
  std::vector<std::uint64_t> out;
  std::set<std::uint64_t> seen;
  std::stringstream ss(text);
  std::string item;
  while (std::getline(ss, item, ',')) {
    const auto dash = item.find('-');
    std::uint64_t a, b;
    if (dash == std::string::npos) {
      a = b = parse_u64(item, text);
    } else {
      a = parse_u64(item.substr(0, dash), text);
      b = parse_u64(item.substr(dash + 1), text);
      if (b < a) throw ArgumentError("--seeds " + text + ": expected a range low-high, got " + item);
    }
    if (b - a > 10000000 || out.size() + (b - a) > 10000000)
      throw ArgumentError("--seeds " + text + ": expected at most 10^7 seeds");
    for (std::uint64_t s = a; s <= b; ++s)
      if (seen.insert(s).second) out.push_back(s);
  }
  if (out.empty()) throw ArgumentError("--seeds " + text + ": expected at least one seed");
  return out;
}

std::pair<int, int> parse_shard(const std::string& text) {
  const auto slash = text.find('/');
  try {
    if (slash != std::string::npos) {
      std::size_t i1 = 0, i2 = 0;
      const int k = std::stoi(text.substr(0, slash), &i1);
      const int n = std::stoi(text.substr(slash + 1), &i2);
      if (i1 == slash && i2 == text.size() - slash - 1 && n >= 1 && k >= 0 && k < n) return {k, n};
    }
  } catch (const std::exception&) {
  }
  throw ArgumentError("--shard " + text + ": expected k/N with 0 <= k < N (e.g. 0/4)");
}

json summarize_runs(const std::vector<json>& runs) {
  struct Stat {
    double sum = 0, lo = 1e300, hi = -1e300;
    std::size_t n = 0;
    std::vector<double> values;
  };
  std::map<std::string, Stat> stats;
  std::vector<std::string> order;
  json failed = json::array(), outside = json::array();
  std::size_t failures = 0, passed = 0;
  for (const auto& r : runs) {
    const int code = r.value("exit_code", 1);
    if (code != 0) {
      ++failures;
      failed.push_back(r.value("seed", json(nullptr)));
    }
    if (r.value("expect_violations", 0) > 0) outside.push_back(r.value("seed", json(nullptr)));
    passed += !r.contains("error") && r.value("expect_violations", 0) == 0;
    for (auto it = r.begin(); it != r.end(); ++it) {
      const auto& v = it.value();
      if (it.key() == "seed" || it.key() == "exit_code" || it.key() == "expect_violations") continue;
      double x;
      if (v.is_number()) x = v.get<double>();
      else if (v.is_boolean()) x = v.get<bool>() ? 1 : 0;
      else continue;
      if (!std::isfinite(x)) continue;
      auto [pos, fresh] = stats.try_emplace(it.key());
      if (fresh) order.push_back(it.key());
      Stat& s = pos->second;
      s.sum += x;
      s.lo = std::min(s.lo, x);
      s.hi = std::max(s.hi, x);
      ++s.n;
      s.values.push_back(x);
    }
  }
  json out;
  out["runs"] = runs.size();
  out["failures"] = failures;
  out["failed_seeds"] = failed;
  out["outside_expect"] = outside.size();
  out["outside_expect_seeds"] = outside;
  // Runs within every expect: bound (the exit code among them where the scenario states it);
  // a run that ended in an error never passes.
  out["pass_rate"] = runs.empty() ? 0.0 : static_cast<double>(passed) / runs.size();
  json metrics = json::object();
  for (const auto& k : order) {
    Stat& s = stats[k];
    std::sort(s.values.begin(), s.values.end());
    metrics[k] = {{"mean", s.sum / s.n}, {"min", s.lo},
                  {"p10", nearest_rank(s.values, 0.1)}, {"p50", nearest_rank(s.values, 0.5)},
                  {"p90", nearest_rank(s.values, 0.9)}, {"max", s.hi}, {"n", s.n}};
  }
  out["metrics"] = metrics;
  return out;
}

SweepResult run_sweep(const Scenario& base, const SweepOptions& o) {
  if (o.shards < 1 || o.shard < 0 || o.shard >= o.shards)
    throw ArgumentError("sweep: expected shard k/N with 0 <= k < N");
  if (o.threads < 1 || o.threads > 256) throw ArgumentError("sweep: --threads expected 1..256");
  if (o.out_dir.empty()) throw ArgumentError("sweep: expected an output folder (-o)");
  std::vector<std::uint64_t> mine;
  for (std::size_t i = 0; i < o.seeds.size(); ++i)
    if (static_cast<int>(i % o.shards) == o.shard) mine.push_back(o.seeds[i]);
  ensure_directory(o.out_dir);
  const std::string suffix =
      o.shards > 1 ? ".shard-" + std::to_string(o.shard) + "-of-" + std::to_string(o.shards) : "";

  std::vector<json> results(mine.size());
  std::atomic<std::size_t> next{0}, done{0};
  std::mutex progress_mutex;
  const auto worker = [&] {
    while (true) {
      const std::size_t i = next.fetch_add(1);
      if (i >= mine.size()) return;
      Scenario sc = base;
      set_seed(sc, mine[i]);
      RunOptions ro;  // no files: the metrics line is the result
      ro.threads = 1;
      ro.report = false;
      json line;
      try {
        RunResult r = run_scenario(sc, ro);
        line = std::move(r.metrics);
        const auto bad = check_expectations(sc, line);
        line["expect_violations"] = bad.size();
      } catch (const std::exception& e) {
        line = json::object();
        line["scenario"] = sc.name;
        line["seed"] = mine[i];
        line["exit_code"] = 2;
        line["error"] = e.what();
      }
      results[i] = std::move(line);
      const std::size_t d = ++done;
      if (o.progress) {
        const std::lock_guard<std::mutex> lock(progress_mutex);
        o.progress(d, mine.size(), mine[i], results[i].value("exit_code", 1));
      }
    }
  };
  std::vector<std::thread> pool;
  const int n = std::min<int>(o.threads, static_cast<int>(std::max<std::size_t>(1, mine.size())));
  for (int t = 0; t < n; ++t) pool.emplace_back(worker);
  for (auto& t : pool) t.join();

  SweepResult out;
  out.runs = mine.size();
  std::string lines;
  for (const auto& r : results) lines += r.dump() + "\n";
  out.jsonl_path = (fs::path(o.out_dir) / ("runs" + suffix + ".jsonl")).string();
  write_text_file(out.jsonl_path, lines);
  out.summary = summarize_runs(results);
  out.summary["scenario"] = base.name;
  out.summary["shard"] = std::to_string(o.shard) + "/" + std::to_string(o.shards);
  out.failures = out.summary["failures"].get<std::size_t>();
  out.summary_path = (fs::path(o.out_dir) / ("summary" + suffix + ".json")).string();
  write_text_file(out.summary_path, out.summary.dump(2) + "\n");
  std::ostringstream md;
  md << "# Sweep of " << base.name << " (" << out.runs << " runs, " << out.failures
     << " failed, " << out.summary["outside_expect"].get<std::size_t>()
     << " outside the scenario's expect: bounds, shard " << o.shard << "/" << o.shards << ")\n\n"
     << "Pass rate (runs within every expect: bound): "
     << out.summary["pass_rate"].get<double>() << "\n\n"
     << "| metric | mean | min | p10 | p50 | p90 | max | runs |\n"
     << "|---|---:|---:|---:|---:|---:|---:|---:|\n";
  for (auto it = out.summary["metrics"].begin(); it != out.summary["metrics"].end(); ++it) {
    char buf[384];
    const json& v = it.value();
    std::snprintf(buf, sizeof buf, "| %s | %.4g | %.4g | %.4g | %.4g | %.4g | %.4g | %zu |\n",
                  it.key().c_str(), v["mean"].get<double>(), v["min"].get<double>(),
                  v["p10"].get<double>(), v["p50"].get<double>(), v["p90"].get<double>(),
                  v["max"].get<double>(), v["n"].get<std::size_t>());
    md << buf;
  }
  if (out.failures) md << "\nFailed seeds: " << out.summary["failed_seeds"].dump() << "\n";
  if (!out.summary["outside_expect_seeds"].empty())
    md << "Seeds outside the expect: bounds: " << out.summary["outside_expect_seeds"].dump() << "\n";
  out.table_path = (fs::path(o.out_dir) / ("summary" + suffix + ".md")).string();
  write_text_file(out.table_path, md.str());
  return out;
}

}  // namespace flashtwin::pipeline
