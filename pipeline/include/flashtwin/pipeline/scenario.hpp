#pragma once
// Scenario files (scenarios/*.yaml): which robot, which cell, which casting, which seed.
#include <cstdint>
#include <string>

#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/executor.hpp"
#include "flashtwin/sim/process.hpp"
#include "flashtwin/sim/scan_cell.hpp"
#include "flashtwin/sim/scanner.hpp"

namespace flashtwin::pipeline {

/// Where the casting lies on the table (table-top frame; z is found by resting it on the top).
struct Placement {
  double x = 0, y = 0;           ///< [m] on the table top
  double yaw = 0;                ///< [rad] about the table normal
  double roll = 0, pitch = 0;    ///< [rad] tilts (free-form parts held by the fixture)
  bool random = false;           ///< draw x, y within ±xy_range and yaw in [-π, π) by the seed
  double xy_range = 0.06;        ///< [m]
  bool random_tilt = false;      ///< with random: any orientation in SO(3)
  /// with random: after grinding, the part is turned over for a second setup (turned_over)
  /// and scanned, perceived, planned and ground again: the faces that were turned towards the
  /// table face up then.
  bool turn_over = false;
};

/// One bound of the scenario's `expect:` block: a metric within [lo, hi], or a flag equal to
/// `flag` (for boolean metrics).
struct Expectation {
  std::string key;  ///< metrics.json key, e.g. "path.rmse_mm"
  double lo = -1e300, hi = 1e300;
  bool is_flag = false;
  bool flag = false;
};

/// One distribution bound of `expect_sweep:`: a statistic of a metric over the sweep's runs
/// within [lo, hi]. Statistics: min, p10, p50, p90, max (nearest rank on the sorted values).
struct SweepBound {
  std::string key;        ///< metrics.json key
  std::string statistic;  ///< "min", "p10", "p50", "p90" or "max"
  double lo = -1e300, hi = 1e300;
};

/// The scenario's regression check over a range of seeds (`expect_sweep:`), run by
/// `flashtwin sweep --check`: a single seed is an anecdote, its bounds are knife edges.
struct SweepExpectation {
  std::vector<std::uint64_t> seeds;  ///< empty: the scenario has no expect_sweep: block
  double min_pass_rate = 0;  ///< share of runs within every `expect:` bound (exit code included)
  std::vector<SweepBound> bounds;
};

/// The closed loop after planning (`execution:` and `process:` in the scenario file).
struct ExecutionSettings {
  bool enabled = true;            ///< run the planned paths in MuJoCo with the process model
  bool rescan = true;             ///< scan the ground part again and detect what flash is left
  /// Simulate the whole job: home → each path → home with collision-checked transits between
  /// them (planner/transit.hpp), run continuously; false: each path alone from rest (no moves
  /// between paths, no cycle time).
  bool transits = true;
  /// [m] `transit_clearance`: what transits keep clear of the cell and the CAD body where
  /// perception put it (15× the transits' worst tracking error, 0.34 mm on default seed 5001;
  /// the fixture, table and scanner are known exactly; the flash is not known to the planner
  /// and its contacts are measured in execution)
  double transit_clearance = 0.005;
  /// `transit_speed`: fraction of each joint's velocity and acceleration limits the transits use
  double transit_speed = 0.25;
  sim::ExecParams exec;           ///< servo loop, admittance force control
  sim::MaterialParams material;   ///< voxel grid of the flash and the body band
  sim::ForceParams force;         ///< grinding force model
};

/// `quality:` the limits of a good part (DESIGN.md `quality.pass`, `quality.failures`): a run
/// whose part misses any of them, or that was refused, exits 1. `expect:` stays the regression
/// check (`--check`).
struct QualityLimits {
  double min_removed_fraction = 0.99;  ///< `removed_min`: removal.flash_removed_fraction
  double max_residual_mm = 0.2;        ///< `residual_max_mm`: removal.residual_flash_max_mm
  double max_gouge_mm = 0.1;           ///< `gouge_max_mm`: removal.gouge_max_mm
  int max_protective_stops = 0;        ///< `protective_stops_max`: paths stopped by the force limit
  int max_collisions = 0;  ///< `collisions_max`: execution.collisions (steps in contact)
};

/// `faults:` what the cell gets wrong that perception and planning do not know: a drill, to
/// rehearse what a wrong pose or a worn burr does to the part. None by default.
struct Faults {
  /// `part_offset: {xyz: [m], rpy: [rad]}` in {C}: where the casting stands when the robot
  /// grinds it, from where it was scanned (moved in its clamps, or the robot and the scanner
  /// calibrated that far apart). The plan is made for the scanned pose and runs on this one.
  Pose part_offset_C = Pose::Identity();
  /// `tool_radius_error` [m]: the burr on the spindle less the one the plan was made for
  /// (worn: negative; a larger burr mounted by mistake: positive).
  double tool_radius_error = 0;
  /// `tcp_offset: [x, y, z]` [m] in {T}: the burr's TCP stands this far from where the
  /// controller's tool data puts it (a tool calibrated wrong, a burr seated deeper in its collet).
  Vec3 tcp_offset_T = Vec3::Zero();
  /// `sensor_bias: {force: [N], torque: [N*m]}` in the flange frame {E}: a step in the F/T
  /// sensor's zero right after each path's first tare (a cable pulled, a thermal shock), which the
  /// controller reads as load.
  sim::Wrench sensor_bias_E;
  bool any() const {
    return !part_offset_C.isApprox(Pose::Identity(), 0) || tool_radius_error != 0 ||
           tcp_offset_T != Vec3::Zero() || sensor_bias_E.force != Vec3::Zero() ||
           sensor_bias_E.torque != Vec3::Zero();
  }
};

struct Scenario {
  std::string name;
  std::string file;         ///< the scenario file it was read from
  std::string description;
  std::uint64_t seed = 1;   ///< master seed of every random choice of the run
  RobotModel robot;
  sim::CellSpec cell;       ///< X_WC is set by setup_cell from `placement`
  sim::CastingParams casting;
  Placement placement;
  sim::ScanParams scan;                ///< views, noise, seed, threads
  /// `views: auto` (the default): the views are planned from the CAD at the nominal placement
  /// (scan.views then only stands in where the placement is random: nothing to plan from).
  bool auto_views = true;
  sim::ViewPlanParams view_plan;       ///< `scanner.auto_views:` overrides
  double calibration_translation = 0;  ///< [m] true X_WM differs from the nominal one by this
  double calibration_rotation = 0;     ///< [rad]
  perception::DetectionParams detection;  ///< `perception.detection:` overrides
  planner::GrindParams grind;             ///< `planning:` overrides
  /// `planning.clearance_check`: every grinding sample's arm and tool (but the burr) checked
  /// against the cell and the CAD where perception put it (GrindParams::clearance). On: a cell
  /// never commands a collision (tilted seeds 401-408: the forearm through the scanner head on
  /// 5 of 8 without it); default seeds 5001-5050 ground as without it, planning p50 0.6 -> 5.7 s.
  bool clearance_check = true;
  /// `planning.floor_check`: the burr keeps planning.floor_clearance above the worktable's top
  /// (GrindParams::floor_C).
  bool floor_check = true;
  /// `tool_rack:` radii [m] of the ball burrs the cell's tool changer holds besides the mounted
  /// one (same length): a path in a hole too narrow for the mounted burr is planned with the
  /// largest rack burr that fits (a tool change in the job). Default: 8 and 6 mm burrs.
  std::vector<double> tool_rack{0.004, 0.003};
  ExecutionSettings execution;            ///< `execution:` and `process:` overrides
  /// `video:` how `flashtwin run --video` films the execution.
  struct VideoSettings {
    /// "follow": a camera that follows the burr from where the casting does not hide it
    /// (spindle translucent); otherwise the name of a cell camera ("casting_closeup", ...).
    std::string camera = "follow";
    double length = 12;          ///< [s] of video: the run is sped up to fit
    int width = 800, height = 600;  ///< [px], even
    int fps = 20;
  } video;
  QualityLimits quality;                  ///< `quality:` limits of a good part
  Faults faults;                          ///< `faults:` a drill (none by default)
  std::vector<Expectation> expect;        ///< `expect:` bounds checked by regression runs
  SweepExpectation expect_sweep;          ///< `expect_sweep:` distribution bounds over seeds
};

/// Reads and validates a scenario; relative paths inside are resolved against its folder.
/// @throws IoError (missing file), ConfigError (naming file and key: malformed, out of range,
/// unknown keys).
Scenario load_scenario(const std::string& path);

/// Same, with `overrides` applied to the YAML first: each "dotted.key=value" sets the key (maps
/// are created as needed; list elements by index, "scanner.views.0.range=[0.2, 0.5]"), the value
/// read as YAML ("0.5", "true", "[1, 2]"). Unknown keys are still reported by the loader.
/// @throws ConfigError naming the override when it is malformed or walks into a scalar.
Scenario load_scenario(const std::string& path, const std::vector<std::string>& overrides);

/// Sets the master seed and everything drawn from it (casting shape, placement, scan noise).
void set_seed(Scenario& scenario, std::uint64_t seed);

/// The casting of a scenario and the cell with the casting placed on the table.
struct CellSetup {
  sim::Casting casting;
  sim::CellSpec spec;
};

/// Generates the casting and places it (deterministic in the scenario seed).
/// @throws InputError/ArgumentError from the casting generator (bad mesh, impossible params).
CellSetup setup_cell(const Scenario& scenario);

/// The second setup of a part turned over (placement.turn_over): `now`, the part as the first
/// setup left it, laid down with `up_C` (a direction in {C}: where the cell wants to work next)
/// facing up, turned about the table normal by a yaw drawn by the seed, at a position drawn
/// within placement.xy_range, resting on the table. Perception is told nothing of the new pose.
/// @throws ConfigError when the turned part does not fit the cell (check_cell_layout).
CellSetup turned_over(const Scenario& scenario, const CellSetup& first, sim::Casting now,
                      const Vec3& up_C);

}  // namespace flashtwin::pipeline
