#pragma once
// The closed loop after planning: the planned grinding motions run one after another on the
// MuJoCo cell while the process model grinds the casting's material (one voxel grid for the
// whole run, over every setup of the part), then the ground part is scanned again and
// perception looks for flash left over.
// Writes the execution.*, force.*, removal.*, sim.* and rescan.* metrics.
#include <cstddef>
#include <functional>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include <nlohmann/json.hpp>

#include "flashtwin/core/transform.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/executor.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/process.hpp"

namespace flashtwin::pipeline {

struct Scenario;
struct ScenarioScan;
struct CellSetup;

/// A planned path: its index among the detected paths and its plan (ok()).
using PlannedPath = std::pair<std::size_t, planner::GrindResult>;

/// One grinding motion as the executor runs it: the joint motion the robot is commanded and the
/// tool poses it is meant to pass, from a plan or from a written program read back.
struct Motion {
  std::size_t path = 0;             ///< index of the detected path it grinds
  sim::JointTrajectory trajectory;  ///< t, q, dq; planned_tcp_W is filled by Execution
  std::vector<Pose> tcp_B;          ///< commanded tool pose per sample in the robot base {B}
  double tool_radius = 0;           ///< [m] the burr it was planned for; 0: the robot's tool
  /// A move between grinding motions (home → path, path → path, path → home), `path` the
  /// path it goes to (the last path's for the way home): no cutting planned, its tracking
  /// counted apart.
  bool transit = false;
};

/// A plan's motion: its trajectory and tool poses as planned.
Motion motion_of(const PlannedPath& plan);
/// [s] a motion's program time (its trajectory's span).
double duration_of(const Motion& m);

/// The planner's world: the cell's obstacles (robot base, table, fixture, scanner head) from
/// its layout, the casting's CAD where perception put it and, for transits, the flash
/// perception detected (never the true flash).
/// Its clearance function is what plan_grind and plan_transit check configurations against
/// (sim::CellCollision: the arm's links and the tool but the burr's cut). Not thread-safe.
class PlanningWorld {
 public:
  /// @param cad_C the casting's CAD tree in {C}, kept by reference
  /// @param X_WC_plan where the plan puts the casting ({W})
  /// @param burr_radius the burr planned with (its shank: sim::shank_radius_for)
  /// @param flash_C flash the planner knows of (detected points, {C}): obstacles of every robot
  ///        geom, the burr's too (sim::CellCollision::set_known_flash); empty for grinding
  ///        samples, whose burr cuts it
  /// @param burr_checks_body the burr is checked against the CAD body too (transits: between
  ///        paths it must not pass through the casting); false for grinding samples
  /// @throws InputError (the cell's MJCF)
  PlanningWorld(const Scenario& sc, const CellSetup& setup, const MeshBvh& cad_C,
                const Pose& X_WC_plan, double burr_radius, const std::vector<Vec3>& flash_C = {},
                bool burr_checks_body = false);
  PlanningWorld(const PlanningWorld&) = delete;
  PlanningWorld& operator=(const PlanningWorld&) = delete;
  /// The robot's clearance at a configuration (valid while this object lives); nothing nearer
  /// than `reach` reads as `reach` (a small reach is much faster: plan_grind only asks whether a
  /// sample comes within its min_clearance).
  planner::ClearanceFn clearance(double reach = sim::CellCollision::kReach);
  /// The torques the cell model's arm needs to move through (q, q̇, q̈): rigid-body inverse
  /// dynamics of its links and tool with armature and joint damping (what the executor's
  /// feedforward asks of the servos; valid while this object lives).
  planner::TorqueFn torque();

 private:
  sim::MjModelPtr model_;
  sim::MjDataPtr data_;
  sim::MjDataPtr dynamics_data_;
  std::vector<mjtNum> tau_;  // the inverse dynamics' output, reused across calls
  std::unique_ptr<sim::CellCollision> cell_;
  int qadr_[kNumJoints] = {};
  int dadr_[kNumJoints] = {};
};

/// One setup's whole job as motions in order: home → the first path's approach, each path,
/// a transit to the next, the last retract → home (planner::plan_transit against the cell's
/// obstacles and the casting's CAD where perception put it, never where it truly is).
struct JobMotions {
  std::vector<Motion> motions;
  std::size_t transits = 0;             ///< planned
  std::size_t lifted = 0;               ///< of them re-planned over a lift
  std::vector<std::size_t> refused_paths;  ///< paths dropped: no clear transit reaches them
  std::string first_refusal;            ///< why the first was dropped ("" none)
  bool home_refused = false;            ///< no clear way home from the last path
  double transit_time = 0;              ///< [s] program time of the transits
  double min_clearance = 0;             ///< [m] least planned clearance of a transit
};
/// @param X_WC_plan the casting's pose the plan was made for ({W})
/// @param cad_C the casting's CAD tree in {C}
/// @param flash_C the flash perception found ({C}): transits keep their clearance from it too
/// @throws InputError (the cell's MJCF), ArgumentError (transit settings)
JobMotions plan_job_motions(const Scenario& sc, const ScenarioScan& ss, const Pose& X_WC_plan,
                            const MeshBvh& cad_C, const std::vector<PlannedPath>& plans,
                            const std::vector<Vec3>& flash_C = {});

/// What execution and the re-scan produced, for the metrics, the report and the video.
struct ExecutionSummary {
  bool ran = false;
  bool failed = false;        ///< a path's simulation went unstable
  std::string failure;        ///< one line, when failed
  // Decimated logs of all paths back to back (time runs on over the paths).
  std::vector<double> t;                  ///< [s] simulated time
  std::vector<double> normal_force;       ///< [N]
  std::vector<double> tangential_force;   ///< [N]
  std::vector<double> tracking_error;     ///< [m] |executed − planned TCP| (position)
  std::vector<double> sensor_force;       ///< [N] |flange F/T force| (0 without the sensor)
  std::vector<Vector6> q;                 ///< [rad] executed joint positions (the 3D view)
  std::vector<int> path;                  ///< index of the detected path each row belongs to
                                          ///< (a second setup's follow the first's)
  std::vector<int> setup;                 ///< the setup each row belongs to (0, 1)
  std::vector<Pose> X_CB;                 ///< per setup: the robot base in {C} (true placement)
  double target_force = 0;                ///< [N]
  /// [m] deepest the cutter went into steel the voxel grid does not track (away from the fins;
  /// sim::ExecutionResult::untracked_penetration_max over all paths): part of the gouge.
  double untracked_gouge_max = 0;
  sim::ResidualReport residual;
  /// The material after grinding (residual and gouge maps are read from it; null when
  /// execution did not run).
  std::shared_ptr<const sim::MaterialGrid> grid;
  TriangleMesh remaining_flash_C;         ///< surface of the remaining flash ({C})
  std::vector<Vec3> rescan_flash_C;       ///< re-scan points perception calls flash ({C}, est.)
};

/// Optional per-frame hook for the video: called with the MuJoCo model/data of the running
/// execution, the simulated time since the run's start, the material grid and the index of
/// the detected path being ground.
using FrameHook = std::function<void(const mjModel* model, mjData* data, double t,
                                     const sim::MaterialGrid& grid, std::size_t path)>;

/// The closed loop's material and logs over one or more setups of the part: each setup's
/// planned paths run on that setup's MuJoCo cell (the casting where that setup put it) against
/// the casting's one voxel grid, kept in {C}, so what one setup ground stays ground in the next.
class Execution {
 public:
  /// The grid of `casting` (its nominal body and fins) with the scenario's material settings.
  /// @throws ArgumentError for bad material parameters.
  Execution(const Scenario& scenario, const sim::Casting& casting);

  /// Runs one setup's planned paths, in order, each from rest at its first sample (moves between
  /// paths are not simulated; run_motions with plan_job_motions' motions simulates them). Logged path indices are the plans' own plus `path_offset` (a
  /// second setup's paths follow the first's). Stops at a path whose simulation went unstable
  /// (failed() then). @throws the executor's ArgumentError/InputError (bad parameters, names).
  void run(const ScenarioScan& scan, const std::vector<PlannedPath>& plans,
           const FrameHook& frame_hook = {}, std::size_t path_offset = 0);
  /// As run, with the motions given (e.g. written programs read back and interpolated, or a
  /// whole job with its transits). A motion that starts where the previous one was planned to
  /// end continues from the state the arm was left in (the job runs continuously); others start
  /// at rest. Every step is checked for collisions of the robot with the cell (the true
  /// casting, its standing flash, fixture, table, scanner: execution.collisions).
  void run_motions(const ScenarioScan& scan, const std::vector<Motion>& motions,
                   const FrameHook& frame_hook = {}, std::size_t path_offset = 0);

  bool failed() const { return summary_.failed; }
  const sim::MaterialGrid& grid() const { return *grid_; }

  /// Analyses the residual and writes the execution.*, force.*, removal.* and sim.* metrics
  /// over every setup run; returns the logs and the material.
  ExecutionSummary finish(nlohmann::ordered_json& m);

 private:
  const Scenario& sc_;
  std::shared_ptr<sim::MaterialGrid> grid_;
  ExecutionSummary summary_;
  double sim_time_ = 0, wall_ = 0, track_sq_ = 0, track_max_ = 0, track_rot_max_ = 0;
  double contact_ = 0, f_sum_ = 0, f_sq_ = 0, f_max_ = 0, limit_excess_ = 0;
  double load_est_sq_ = 0, load_est_n_ = 0;  // the controller's load estimate vs the process force
  std::size_t track_n_ = 0, violations_ = 0, clamped_ = 0, steps_ = 0, executed_ = 0, force_stops_ = 0;
  std::string status_ = "ok";
  // The whole job: transits run, their worst tracking, program time, collisions.
  std::size_t transits_ = 0, collision_steps_ = 0;
  double transit_track_max_ = 0, cycle_time_ = 0, collision_depth_ = 0;
  double min_clearance_ = sim::CellCollision::kReach;
  std::string first_collision_;
};

/// The part as it stands after grinding, for scanning it again: `casting`'s nominal body and
/// what is left of its flash (`remaining_C`, the voxel surface sim::remaining_flash_mesh gives,
/// in {C}, of `volume` m^3) as one fin without a root polyline.
sim::Casting casting_with_residual(const sim::Casting& casting, const TriangleMesh& remaining_C,
                                   double volume);

/// One setup: Execution(scenario, scan.setup.casting), run(scan, plans, frame_hook), finish(m).
ExecutionSummary execute_plans(const Scenario& scenario, const ScenarioScan& scan,
                               const std::vector<PlannedPath>& plans, nlohmann::ordered_json& m,
                               const FrameHook& frame_hook = {});

/// Scans the ground part (nominal body + what is left of the flash) with the scenario's
/// scanner and runs flash detection on it with the pose perception estimated before; fills
/// rescan.* metrics and summary.rescan_flash_C.
void rescan_after(const Scenario& scenario, const ScenarioScan& scan, const Pose& X_CM_est,
                  ExecutionSummary& summary, nlohmann::ordered_json& m);

/// Ground truth maps of the material after grinding, for review in a point viewer: writes
/// DIR/residual_flash.ply (remaining flash voxel centres, {C}, m; `height_mm` above the CAD,
/// `loose` 1 for chips cut loose) and DIR/gouges.ply (removed body voxel centres; `depth_mm`
/// below the CAD), binary little-endian PLY.
/// @throws IoError when a file cannot be written.
void write_material_maps(const std::string& dir, const sim::MaterialGrid& grid);

}  // namespace flashtwin::pipeline
