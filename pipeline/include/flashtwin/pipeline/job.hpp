#pragma once
// `flashtwin job`: a scan from a real cell and the part's CAD (no ground truth anywhere) to the
// part's pose, its flash paths, their plans, a rehearsal of them on the twin and the robot
// programs, or a refusal with the reason.
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/pipeline/execution.hpp"

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
  bool refused = false;  ///< pose not confident, a path not feasible or the rehearsal failed: no program
  std::string reason;           ///< one line, when refused
  nlohmann::ordered_json summary;  ///< what DIR/job.json holds
};

/// A job's written programs as the robot's controller runs them.
struct ProgramMotions {
  std::vector<Motion> motions;  ///< one per program, in DIR/plans.json's order
  std::string failure;          ///< one line naming the program and its line, when one would not run
  std::size_t programs = 0;     ///< programs read
  double time_s = 0;            ///< [s] their motions' durations, summed
  double max_joint_velocity_ratio = 0;  ///< largest |q̇_j| / limit_j the programs command
  bool ok() const { return failure.empty(); }
};

/// Reads the programs DIR/plans.json lists (`motions[].program`, relative to DIR, with the burr
/// each was planned for) and interpolates each as its controller would
/// (planner::replay_program): the motions a cell running those files would make. A program the
/// controller would stop (a target out of reach, a singularity or configuration change on the
/// way, a joint limit) is the result's failure.
/// @throws InputError naming the file: no plans.json or a malformed one, a listed program
/// missing or not parsing in the robot's controller language, a motion without a program.
ProgramMotions program_motions(const RobotModel& robot, const std::string& dir);

struct Scenario;

/// What `flashtwin replay` measured.
struct ReplayResult {
  nlohmann::ordered_json metrics;  ///< what OUT/metrics.json holds
  bool pass = false;               ///< the part meets the scenario's quality limits
  std::string reason;              ///< one line, when it does not (or a program would not run)
};

/// `flashtwin replay`: a job's written programs run on the twin's own part for the scenario's
/// seed — its true casting, flash and placement, the part `flashtwin scan` scanned with that
/// seed. The programs are read back and interpolated as the controller runs them
/// (program_motions), ground in MuJoCo against the true material and scored against the truth:
/// OUT/metrics.json (program.*, execution.*, removal.*, force.*, quality.*) and OUT/cell/.
/// @throws InputError naming the file: a job folder without job.json/plans.json or programs, a
/// refused job, a job for another robot than the scenario's.
ReplayResult replay_job(const Scenario& scenario, const std::string& job_dir,
                        const std::string& out_dir);

/// Registration (the cell's calibrated X_WM and the CAD), flash detection, planning in the
/// cell's robot base, then the rehearsal: the flash the scan shows rebuilt as material on the
/// CAD part (one slab per detected path: its root, the heights of its region's flash points,
/// the region's thickness) at the estimated pose, ground in MuJoCo with the plans
/// (rehearsal.removal.*, execution.*, force.*, quality.*; DIR/rehearsal/cell/). One program per
/// path in the robot's controller language, written to DIR/plan/path_K/ with DIR/paths.json,
/// DIR/plans.json and DIR/job.json. Refuses (no program written, job.json says why) when the
/// pose is not confident, a path cannot be planned or the rehearsal's part misses the cell
/// file's quality limits. Moves between paths are not rehearsed (as in `run`).
/// @throws InputError (missing/unreadable/malformed files, bad cell file), IoError.
JobResult run_job(const JobInputs& inputs);

}  // namespace flashtwin::pipeline
