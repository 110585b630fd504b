#pragma once
// Registration comparison harness: the project's register_scan against the PCL baselines on the
// Stanford models and a generated casting, under random poses, noise and partial views.
// Writes one JSON file (every trial) and one Markdown table (aggregates). No PCL here.
#include <cstdint>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::bench {

/// What to run. Trial counts are per method: `trials` for the project's method ("ours"),
/// `baseline_trials` for the PCL baselines unless `method_trials` names a method explicitly.
struct HarnessOptions {
  std::vector<std::string> datasets{"bunny", "dragon", "armadillo", "casting"};
  std::vector<std::string> methods{"ours", "sacia-ndt", "ndt-icp", "iss-3dsc-icp", "fpcs-icp"};
  int trials = 100;                         ///< trials of "ours" per configuration
  int baseline_trials = 20;                 ///< trials of each PCL baseline per configuration
  std::map<std::string, int> method_trials; ///< explicit per-method counts (override the two)
  std::vector<double> noise{0.0, 0.001, 0.005};  ///< Gaussian σ per coordinate, fraction of d
  std::vector<std::string> overlaps{"full", "partial"};
  std::string data_dir;                     ///< folder with bunny/, dragon/, armadillo/
  std::uint64_t seed = 1;
  int casting_samples = 60000;              ///< area-uniform model points of the casting (as
                                            ///< many as ours samples on a mesh target)
  bool verbose = false;                     ///< one line per trial on the progress callback

  /// Trials of `method` per configuration.
  int trials_for(const std::string& method) const;
};

/// Throws ArgumentError naming the option when a dataset, method, overlap, noise level or
/// trial count is not valid.
void validate(const HarnessOptions& options);

/// A model to register against, centred on its bounding-box centre (frame {T} of the target).
struct Dataset {
  std::string name;
  std::string origin;              ///< file (and scale) or generator that produced it
  TriangleMesh mesh;               ///< [m], centred
  std::vector<Vec3> points;        ///< model points: mesh vertices, or area samples (casting)
  double diagonal = 0;             ///< bounding-box diagonal d [m]
  bool from_above = false;         ///< partial views only from its +z side (parts on a table)
};

/// Loads "bunny", "dragon", "armadillo" from data_dir or generates "casting" (flanged plate).
/// @throws ArgumentError (unknown name), IoError/InputError (unreadable file).
Dataset load_dataset(const std::string& name, const std::string& data_dir, std::uint64_t seed,
                     int casting_samples);

/// Rotation uniform in SO(3) (Shoemake's quaternion method) and translation uniform in
/// [−0.5 d, 0.5 d]³.
Pose random_pose(std::uint64_t seed, double diagonal);

/// One trial's outcome for one method.
struct TrialRecord {
  std::string method, dataset, overlap;
  double noise = 0;            ///< σ as a fraction of d
  int trial = 0;
  std::size_t source_points = 0;
  double coverage = 0;         ///< share of model points with a source point within ~d/100
  bool ran = false, confident = false, success = false;
  double rotation_error_deg = 0;
  double translation_error_m = 0;
  double translation_error_pct = 0;  ///< of d
  double gt_rmse_m = 0;        ///< RMS over model points of |T_est s − T_true s|
  double residual_rmse_m = 0;  ///< the method's own inlier RMSE
  double fitness = 0;
  double time_s = 0;
  std::string stage, message;
};

/// Aggregate over the trials of one (method, dataset, overlap, noise).
struct Summary {
  std::string method, dataset, overlap;
  double noise = 0;
  int trials = 0;
  double diagonal = 0;
  double mean_source_points = 0, mean_coverage = 0;
  double success_rate = 0, confident_rate = 0, ran_rate = 0;
  double rotation_median_deg = 0, rotation_mean_deg = 0;
  double translation_median_m = 0, translation_median_pct = 0;
  double gt_rmse_median_m = 0, residual_rmse_median_m = 0;
  double time_median_s = 0, time_p95_s = 0;
};

/// Success criterion: ran, rotation error < 1°, translation error < 0.5 % of d.
bool is_success(const TrialRecord& r);

struct HarnessOutput {
  std::vector<Dataset> datasets;  ///< meshes cleared (only names, origins, sizes kept)
  std::vector<std::size_t> triangles;
  std::vector<double> target_build_s;  ///< "ours": ModelTarget::from_mesh time per dataset
  std::vector<TrialRecord> trials;
  std::vector<Summary> summaries;
  double wall_s = 0;
};

/// Runs the protocol. The same poses, noise and scans are shared by all methods (paired
/// trials). `progress` receives human-readable lines.
HarnessOutput run_registration_benchmark(const HarnessOptions& options,
                                         const std::function<void(const std::string&)>& progress);

/// Aggregates trials per (method, dataset, overlap, noise), in first-seen order.
std::vector<Summary> summarize(const std::vector<TrialRecord>& trials,
                               const std::vector<Dataset>& datasets);

/// "2-core AMD EPYC, 23 GiB, Linux 6.1, g++ 12.2.0"
std::string machine_description();

/// The JSON document (options, machine, datasets, summaries, every trial).
std::string to_json(const HarnessOptions& options, const HarnessOutput& out,
                    const std::string& command_line);

/// The Markdown report: protocol, machine, datasets and the aggregate table.
std::string to_markdown(const HarnessOptions& options, const HarnessOutput& out,
                        const std::string& command_line);

}  // namespace flashtwin::bench
