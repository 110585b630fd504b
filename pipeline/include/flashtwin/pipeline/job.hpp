#pragma once
// `flashtwin job`: a scan from a real cell and the part's CAD (no ground truth anywhere) to the
// part's pose, its flash paths, their plans and the robot programs, or a refusal with the reason.
#include <string>

#include <nlohmann/json.hpp>

namespace flashtwin::pipeline {

/// Length units of an input file: metres, millimetres, or guessed from its size.
enum class Units { kAuto, kMetres, kMillimetres };

struct JobInputs {
  std::string scan;   ///< PLY/PCD point cloud in the scanner frame {M}
  std::string cad;    ///< STL/OBJ/PLY mesh of the part in its own frame {C}
  std::string cell;   ///< the cell: a scenario file (robot, cell frames, tool, planning,
                      ///< detection); its casting, scanner noise and expect blocks are not used
  std::string out_dir;
  Units scan_units = Units::kAuto;
  Units cad_units = Units::kAuto;
  int threads = 2;
};

struct JobResult {
  bool refused = false;         ///< pose not confident or a path not feasible: no program written
  std::string reason;           ///< one line, when refused
  nlohmann::ordered_json summary;  ///< what DIR/job.json holds
};

/// Registration (the cell's calibrated X_WM and the CAD), flash detection, planning in the
/// cell's robot base and one program per path in the robot's controller language, written to
/// DIR/plan/path_K/ with DIR/paths.json, DIR/plans.json and DIR/job.json. Refuses (no program
/// written) when the pose is not confident or any path cannot be planned. The rehearsal of the
/// programs on the twin is not implemented (job.json says so).
/// @throws InputError (missing/unreadable/malformed files, bad cell file), IoError.
JobResult run_job(const JobInputs& inputs);

}  // namespace flashtwin::pipeline
