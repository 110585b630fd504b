#pragma once
// Stages of a run shared inside the pipeline library (run_scenario, run_job): not a public API.
#include <cstddef>
#include <filesystem>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/perception/registration.hpp"
#include "flashtwin/pipeline/execution.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"

namespace flashtwin::pipeline {

/// What perception made of one setup's scan.
struct Perception {
  perception::RegistrationResult registration;
  perception::DetectionResult detection;  ///< ran only with a confident pose
  Pose X_CM_est = Pose::Identity();       ///< the scanner {M} in the casting {C}, estimated
  std::vector<Vec3> flash_C;              ///< the detected flash regions' points in {C}
  double time_s = 0;
};

/// The points of detection's flash regions in {C} (scan points mapped by X_CM).
std::vector<Vec3> detected_flash_C(const perception::DetectionResult& det, const PointCloud& scan_M,
                                   const Pose& X_CM);

/// One setup's plans.
struct Plans {
  std::vector<PlannedPath> paths;  ///< every grinding motion (a path in pieces: one per piece)
  Pose X_WC_plan = Pose::Identity();  ///< where the plan puts the casting ({W}; a drill's offset undone)
  std::vector<Vec3> flash_C;  ///< the flash perception found ({C}): transits keep clear of it
  std::vector<std::size_t> failed_paths;  ///< detected paths that could not be planned
  std::string first_failure;
  double time_s = 0;
};

/// One grinding motion per detected path (or per piece of it), on the casting where perception
/// put it: X_BC = X_WB⁻¹·X_WM·X_CM_est⁻¹ from setup.spec (trajectory.* into `m`). Writes
/// DIR/plan/path_K/ (trajectory, plots with opt.report, the program in the robot's controller
/// language), DIR/plans.json and DIR/trajectory.csv; `dir` empty: nothing written.
Plans plan_setup(const Scenario& sc, const CellSetup& setup, const Perception& perc,
                 const RunOptions& opt, const std::filesystem::path& dir,
                 nlohmann::ordered_json& m);

}  // namespace flashtwin::pipeline
