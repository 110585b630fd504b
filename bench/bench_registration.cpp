// The registration comparison: the project's register_scan against the PCL baselines (SAC-IA +
// NDT, NDT + ICP, ISS + 3DSC + ICP, FPCS + ICP) on the Stanford Bunny, Dragon, Armadillo and a
// generated casting. Writes OUT/registration.json (every trial) and OUT/registration.md (the
// table) and prints the table. Not a Google Benchmark binary: one trial is a whole
// registration, and the protocol (poses, noise, partial views, success rates) is the point.
//
//   bench_registration --datasets bunny --methods ours,sacia-ndt,fpcs-icp --trials 10
//                      --noise 0.001 --overlap full --out out/registration
#include <CLI/CLI.hpp>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iostream>
#include <string>

#include "flashtwin/core/errors.hpp"
#include "registration_harness.hpp"

namespace {

namespace fs = std::filesystem;
using flashtwin::ArgumentError;

std::vector<std::string> split(const std::string& s) {
  std::vector<std::string> out;
  std::string cur;
  for (char c : s) {
    if (c == ',') {
      if (!cur.empty()) out.push_back(cur);
      cur.clear();
    } else if (c != ' ') {
      cur += c;
    }
  }
  if (!cur.empty()) out.push_back(cur);
  return out;
}

int parse_count(const std::string& what, const std::string& s) {
  std::size_t used = 0;
  int v = -1;
  try {
    v = std::stoi(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size() || v < 0)
    throw ArgumentError(what + ": expected a count >= 0, got \"" + s + "\"");
  return v;
}

double parse_fraction(const std::string& s) {
  std::size_t used = 0;
  double v = -1;
  try {
    v = std::stod(s, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != s.size())
    throw ArgumentError("--noise: expected fractions of the diagonal such as 0.001, got \"" + s + "\"");
  return v;
}

// Writes the file through a temporary next to it, then renames (no half-written outputs).
void write_file(const fs::path& path, const std::string& text) {
  const fs::path tmp = path.string() + ".tmp";
  {
    std::ofstream out(tmp, std::ios::binary);
    out << text;
    if (!out) throw flashtwin::IoError(tmp.string() + ": cannot write");
  }
  fs::rename(tmp, path);
}

}  // namespace

int main(int argc, char** argv) {
  flashtwin::bench::HarnessOptions o;
  std::string datasets = "bunny,dragon,armadillo,casting";
  std::string methods = "ours,sacia-ndt,ndt-icp,iss-3dsc-icp,fpcs-icp";
  std::string trials = "100", noise = "0,0.001,0.005", overlap = "full,partial";
  int baseline_trials = -1;
  std::string out_dir = "out/registration";
#ifdef FLASHTWIN_SOURCE_DIR
  o.data_dir = std::string(FLASHTWIN_SOURCE_DIR) + "/../shared/data";
#else
  o.data_dir = "../shared/data";
#endif

  CLI::App app{
      "Registration comparison: ours vs PCL baselines on the Stanford models and a casting.\n"
      "Writes OUT/registration.json and OUT/registration.md. Exit codes: 0 done, 2 bad input."};
  app.add_option("--datasets", datasets, "Comma list of bunny, dragon, armadillo, casting")
      ->capture_default_str();
  app.add_option("--methods", methods,
                 "Comma list of ours, sacia-ndt, sacia-ndt-icp, ndt-icp, iss-3dsc-icp, fpcs-icp")
      ->capture_default_str();
  app.add_option("--trials", trials,
                 "Trials per configuration for ours (N), or per method (ours=100,sacia-ndt=10,...)")
      ->capture_default_str();
  app.add_option("--baseline-trials", baseline_trials,
                 "Trials per configuration for each PCL baseline (default: min(20, ours' trials))");
  app.add_option("--noise", noise, "Comma list of noise σ as fractions of the bounding-box diagonal")
      ->capture_default_str();
  app.add_option("--overlap", overlap, "Comma list of full, partial")->capture_default_str();
  app.add_option("--out", out_dir, "Output folder")->capture_default_str();
  app.add_option("--seed", o.seed, "Random seed (poses, noise, views, casting)")->capture_default_str();
  app.add_option("--data", o.data_dir, "Folder with bunny/, dragon/, armadillo/")->capture_default_str();
  app.add_option("--casting-samples", o.casting_samples, "Area-uniform model points on the casting")
      ->capture_default_str();
  app.add_flag("-v,--verbose", o.verbose, "One progress line per trial, and the methods' debug log");
  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return 2;
  }

  if (o.verbose) spdlog::set_level(spdlog::level::debug);
  std::string command = "bench_registration";
  for (int i = 1; i < argc; ++i) command += std::string(" ") + argv[i];

  try {
    o.datasets = split(datasets);
    o.methods = split(methods);
    o.overlaps = split(overlap);
    o.noise.clear();
    for (const auto& s : split(noise)) o.noise.push_back(parse_fraction(s));
    // --trials: "N" sets ours; "method=N" items set single methods.
    for (const auto& item : split(trials)) {
      const auto eq = item.find('=');
      if (eq == std::string::npos)
        o.trials = parse_count("--trials", item);
      else
        o.method_trials[item.substr(0, eq)] = parse_count("--trials " + item.substr(0, eq), item.substr(eq + 1));
    }
    o.baseline_trials = baseline_trials >= 0 ? baseline_trials : std::min(20, o.trials);
    flashtwin::bench::validate(o);
    if (!fs::is_directory(o.data_dir) &&
        std::any_of(o.datasets.begin(), o.datasets.end(), [](const std::string& d) { return d != "casting"; }))
      throw ArgumentError("--data: expected the folder with bunny/, dragon/, armadillo/, got \"" + o.data_dir + "\"");
    fs::create_directories(out_dir);

    const auto result = flashtwin::bench::run_registration_benchmark(
        o, [](const std::string& line) { std::fprintf(stderr, "%s\n", line.c_str()); });
    const std::string md = flashtwin::bench::to_markdown(o, result, command);
    write_file(fs::path(out_dir) / "registration.json", flashtwin::bench::to_json(o, result, command));
    write_file(fs::path(out_dir) / "registration.md", md);
    std::cout << md;
    std::fprintf(stderr, "wrote %s/registration.json and registration.md\n", out_dir.c_str());
  } catch (const flashtwin::InputError& e) {
    std::fprintf(stderr, "bench_registration: %s\n", e.what());
    return 2;
  } catch (const fs::filesystem_error& e) {
    std::fprintf(stderr, "bench_registration: %s\n", e.what());
    return 2;
  }
  return 0;
}
