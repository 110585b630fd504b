#pragma once
// The scenario pipeline (`flashtwin run`): cell → scan → registration → flash detection →
// (planning → execution, when enabled) → scoring against ground truth → metrics.json.
// Perception and planning only see what a real cell would give them (the scan, the CAD
// model, the calibrated scanner pose); the ground truth is read by scoring alone.
#include <functional>
#include <string>

#include <nlohmann/json.hpp>

#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/pipeline/execution.hpp"
#include "flashtwin/pipeline/video.hpp"
#include "flashtwin/perception/registration.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/scan_cell.hpp"

namespace flashtwin::pipeline {

struct RunOptions {
  std::string out_dir;        ///< everything is written here ("" = nothing written)
  bool write_scan = true;     ///< scan.ply (and the labelled scans)
  int threads = 2;            ///< threads of the scanner and of perception (results identical for any count)
  bool report = true;         ///< report.html with renders and plots (needs out_dir)
  /// MP4 of the execution when video.path is set (slows execution down: timings include it).
  VideoOptions video;
  /// Stage progress callback (stage name, fraction of the run done); may be empty.
  std::function<void(const std::string&, double)> progress;
};

/// What a run produced. `metrics` uses the flat dotted keys of DESIGN.md
/// ("registration.rotation_error_deg", ...).
struct RunResult {
  nlohmann::ordered_json metrics;
  bool refused = false;        ///< the pipeline refused (registration not confident, ...)
  std::string verdict;         ///< one line: what happened
  int exit_code = 0;           ///< 0 done, 1 refused/failed
  perception::DetectionResult detection;
  perception::RegistrationResult registration;
  ExecutionSummary execution;  ///< logs of the closed loop (empty when it did not run)
};

/// A scenario's cell written to disk and scanned.
struct ScenarioScan {
  CellSetup setup;
  sim::CellFiles files;
  sim::CellScan scan;  ///< X_WM_nominal is the calibrated mount, X_WM_true the perturbed one
  sim::ScanParams params;  ///< what was scanned: the scenario's, with the planned views
  bool planned = false;    ///< the views were planned (`views: auto`)
  bool surveyed = false;   ///< planned from the pose of a survey scan (random placement)
  sim::ViewPlan plan;      ///< when planned
};

/// Scoring (reads the truth): the share of the casting's true flash roots that no view of the
/// scan saw (`scan.unseen_parting_fraction`, see unseen_root_fraction).
double unseen_parting_fraction(const ScenarioScan& scan);

/// The scan registration sees: the scan in {M} without the points on the cell's fixture
/// blocks and riser (grown by 3 mm), which the cell knows for a casting at its nominal
/// placement; the whole scan for a randomly placed casting.
PointCloud registration_cloud(const Scenario& sc, const ScenarioScan& scan);

/// Flash detection (perception::detect_flash with sc.detection) on a scan of the cell of
/// `setup` without the points on its fixture (as registration_cloud leaves them out: the riser's
/// top seen through a bolt hole is not flash); labels and regions index the whole scan, the
/// fixture's points labelled kDetectIgnored.
perception::DetectionResult detect_off_fixture(const Scenario& sc, const CellSetup& setup,
                                               const PointCloud& cloud_M, const MeshBvh& cad_C,
                                               const Pose& X_CM);

/// Registration parameters for a cell scan: the table removed, normals facing {M}'s origin.
perception::RegistrationParams cell_registration_params();

/// Builds the scenario's cell in `cell_dir` and scans it with `threads` scanner threads (the
/// true scanner mount carries the scenario's calibration error).
ScenarioScan scan_scenario(const Scenario& scenario, const std::string& cell_dir, int threads);

/// Writes the scan as a sensor delivers it: `dir`/scan.ply (and scan.pcd when `pcd`), points
/// only (the simulator's exact normals are ground truth); the truth labels go apart, to
/// cell_dir/truth/scan_labels.ply.
void save_scan(const ScenarioScan& s, const std::string& dir, bool pcd);

/// Runs the scenario end to end and writes metrics.json (and the other outputs) into
/// options.out_dir. @throws InputError for bad scenario contents (missing meshes, ...).
RunResult run_scenario(const Scenario& scenario, const RunOptions& options);

/// The planner's input for a detected path (root points and wall normals in {C}, fin normal,
/// closed or not).
planner::GrindPath grind_path_of(const perception::FlashPath& path);

/// Writes detected paths as JSON ({C}: points, normals, closed, region) and PLY (vertices +
/// edges) next to each other: DIR/paths.json, DIR/paths.ply.
void write_paths(const std::string& dir, const perception::DetectionResult& detection);

/// A metric value for JSON, which has no inf/NaN: those become null.
nlohmann::ordered_json finite_or_null(double v);

/// The part against the scenario's `quality:` limits, from the run's metrics
/// (removal.flash_removed_fraction, removal.residual_flash_max_mm, removal.gouge_max_mm,
/// execution.paths_stopped_force_limit): one line per limit missed, naming it and by how much.
/// A part that was not ground (no metric of removal) with flash on it (casting.flash_volume_mm3
/// above zero) misses the removal limit: none of its flash was removed.
std::vector<std::string> quality_failures(const QualityLimits& limits,
                                          const nlohmann::ordered_json& metrics);

/// Checks the scenario's `expect:` bounds against metrics; returns one line per violation.
std::vector<std::string> check_expectations(const Scenario& scenario,
                                            const nlohmann::ordered_json& metrics);

}  // namespace flashtwin::pipeline
