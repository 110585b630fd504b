#pragma once
// The executor: runs a joint trajectory on the MuJoCo cell under real dynamics (position servos
// with torque limits, inverse-dynamics feed-forward) while the process model removes material
// and pushes back on the tool, and logs what happened (tracking, forces, flange F/T sensor,
// removal, joint ranges, speed). Only sim/ and its users that run the cell include this.
//
// Model names it relies on (the cell's contract, DESIGN.md): hinge joints joint1..joint6, position
// actuators act1..act6 on them, site `tcp` (tool frame {T}), body `tool` (the forces of the process
// model go into its xfrc_applied), body `casting` (frame {C}, fixed); sensors `flange_force` /
// `flange_torque` on a site of the tool body (the flange F/T sensor: required when the controller
// reads it, i.e. with load compensation, force control or a protective stop).
//
// The controller sees what a real cell measures: the joint encoders, the plan, and the flange
// F/T sensor through its model (ft_sensor.hpp: offset, drift, low-pass, noise, sampled every
// sensor.period) with the load estimated from it (the payload's weight and the tare removed).
// The process model's own wrench and contact normal are never read by the controller; they are
// the twin's measurements (force.*, the protective stop's diagnosis).
//
// One step of the loop (mj_step1 / set controls and forces / mj_step2, so controls see the
// current state; MuJoCo's split step integrates with Euler whatever the model's integrator):
//   1. reference q_ref(t), dq_ref, ddq_ref: cubic Hermite through the samples (q_k, dq_k), held
//      at the last sample after the end (settle phase);
//   2. optional admittance: a correction δ [m] along the sensed contact normal (the estimated
//      load's part across the tool axis and the reference's feed direction), mapped to joints by
//      the damped inverse of the TCP Jacobian (mj_jacSite) with zero rotation;
//   3. clamp to each joint's range shrunk by `limit_margin` (flagged the first time);
//   4. ctrl = q_ref + τ_ff / kp: the feed-forward torque τ_ff = inverse dynamics at the reference
//      (mj_inverse: inertia, Coriolis, gravity, joint damping) rides on the position servo, so the
//      actuator's forcerange (the robot's torque limits) still bounds the total torque. The
//      executor lifts the actuators' ctrlrange on its own copy of the model for that (it clamps
//      the references itself);
//   5. process model: X_CT = X_WC⁻¹·X_WT from site `tcp` and body `casting`; remove_material once
//      the tool has moved `removal_motion` voxels (`removal_contact_motion` while it penetrates
//      the body; or `removal_max_interval` has passed) since the last removal, with dt the time accumulated since; grinding_force, held until the next
//      removal step, its rate part applied as an implicit resistance to the feed
//      (implicit_rate_force) → world wrench at the tool body's COM in xfrc_applied. The contact
//      penalty (a stiff spring on the tool's penetration of the nominal body) follows the tool at
//      every step in between: the deepest body point found by the last removal step moves with
//      the tool, its depth measured against the tangent plane of the nominal surface there.
//      Where the grid tracks no body (away from the fins, below its band), an exact check of the
//      cutter against the CAD body every cad_check_motion gives the same kind of penalty contact.
#include <mujoco/mujoco.h>

#include <cstddef>
#include <functional>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/core/transform.hpp"
#include "flashtwin/sim/collision.hpp"
#include "flashtwin/sim/ft_sensor.hpp"
#include "flashtwin/sim/process.hpp"

namespace flashtwin::sim {

/// A joint trajectory sampled at increasing times (from the planner's timing or any source).
struct JointTrajectory {
  std::vector<double> t;    ///< [s] strictly increasing sample times; shape N ≥ 1
  std::vector<Vector6> q;   ///< [rad] joint positions; shape N
  std::vector<Vector6> dq;  ///< [rad/s] joint velocities; shape N, or empty (then estimated by
                            ///< finite differences of q)
  /// Planned tool poses X_WT per sample (shape N) for the tracking metrics, or empty (no tracking).
  std::vector<Pose> planned_tcp_W;
  /// [s] times (strictly increasing, on the clock of t) where the plan stops the arm in free
  /// air: the controller zeroes its F/T sensor over sensor.tare_time from each, as it does at
  /// the start (entries before t.front() + sensor.tare_time are that first tare). The window
  /// opens at the stop; the plan has no dwell, so it runs on into the next move.
  std::vector<double> tare_t;
};

/// Admittance force control along the sensed contact normal.
struct ForceControlParams {
  bool enabled = false;
  /// [N] normal grinding force target; also the reference of ExecutionResult::force_rmse
  /// (used whether or not the control is enabled).
  double target_force = 20.0;
  /// [N] a sensed normal force above this counts as contact for the controller (the sensor's
  /// noise and drift stay below it).
  double contact_force = 5.0;
  double gain = 1e-4;            ///< [m/(N·s)] correction rate per newton of force error
  double max_correction = 3e-3;  ///< [m] bound on |δ| (the servos yield ~1 mm per 40 N)
  /// [s] δ keeps integrating this long after the last contact (the tool may bounce off), then
  /// returns to 0 with this time constant.
  double release_time = 0.05;
};

/// Where deflection compensation takes the load from (ExecParams::compensation_source).
enum class CompensationSource { kProcessModel, kSensor };

/// "process_model", "sensor".
const char* to_string(CompensationSource source);

/// Parameters of execute_trajectory (fields named `execution.<field>` in error messages).
struct ExecParams {
  double timestep = 0;       ///< [s] MuJoCo step; 0 = the model's. Must be ≤ 0.001 (≥ 1 kHz)
  double settle_time = 0.2;  ///< [s] the last sample is held this long after the trajectory
  bool feedforward = true;   ///< inverse-dynamics feed-forward torque at the reference
  /// Deflection compensation, as robots with a flange F/T sensor do: the load on the tool is
  /// cancelled through Jᵀ in the feed-forward torque (still bounded by the actuators' torque
  /// limits), so the servos hold the planned pose under the grinding load. Which load: see
  /// compensation_source.
  bool load_compensation = true;
  /// kSensor: the load the controller estimates from the flange sensor's latest sample (force at
  /// the flange, torque about it); it cannot tell cutting from the body pushing back, so both
  /// are compensated. kProcessModel: the process model's own grinding wrench of the previous
  /// step, without the contact penalty (the servos yield to it) — an oracle no real controller
  /// has, kept while the sensor-fed controller does not yet hold the quality limits.
  CompensationSource compensation_source = CompensationSource::kProcessModel;
  /// [N·s/m] active damping of the TCP's tracking-error velocity, from the encoders and the plan
  /// (0: off): τ += Jpᵀ·c·(v_ref − v). Compensating a sensed load one sample late makes a stiff
  /// contact act as negative damping (stiffness × delay: 2·10⁵ N/m × 3 ms ≈ 600 N·s/m), and the
  /// tool chatters into the wall; this damping takes it back. Explicit at the 1 ms step: a few
  /// thousand N·s/m destabilise the arm.
  double tcp_damping = 0;
  /// The flange F/T sensor the controller reads (`execution.sensor`).
  FtSensorParams sensor;
  /// Seed of this motion's sensor noise, offset and drift (the caller derives one per motion).
  std::uint64_t sensor_seed = 0;
  /// Fault drills (`faults:`), which the controller is not told. tcp_offset_T [m]: the burr
  /// stands this far from the TCP the controller's tool data gives, in {T} (a tool calibrated
  /// wrong, a burr seated deeper); the process model cuts with the burr where it stands.
  /// sensor_step_E: a step in the F/T sensor's zero right after the motion's first tare ({E});
  /// a re-tare at a stop in free air (JointTrajectory::tare_t) takes a step of up to
  /// LoadEstimator::kTareLimit out again, a larger one stays (its readings are refused).
  Vec3 tcp_offset_T = Vec3::Zero();
  Wrench sensor_step_E;
  ForceControlParams force_control;
  int log_decimation = 10;  ///< one log row every this many steps (≥ 1), plus the last step
  /// [rad] references are kept this far inside each joint's range, so the servo's overshoot
  /// stays in range; a reference beyond it is clamped and reported.
  double limit_margin = 0.01;
  double joint_tolerance = 1e-3;  ///< [rad] slack of the joint-range check (violation counting)
  /// [N] protective stop, as a robot's collision detection does: a sensed force above this (the
  /// flange sensor's latest reading less the payload, untared, its magnitude) stops the
  /// trajectory there. 0: off.
  double max_force = 2000;
  /// [voxels] tool motion (translation + rotation × cutter length) that triggers a removal step.
  double removal_motion = 0.5;
  /// [voxels] the same while the tool penetrates the nominal body: the penalty follows the tool
  /// in between (see step 5 above), but only a removal step sees the surface's shape change
  /// under the moving tool (a fillet, an edge); at the ½-voxel trigger single castings gouged
  /// up to 3.5× deeper than with a removal step every 1 kHz step.
  double removal_contact_motion = 0.1;
  double removal_max_interval = 0.01;  ///< [s] a removal step at least this often
  /// [m] tool motion (translation + rotation × cutter length) between exact checks of the cutter
  /// against the nominal (CAD) body where the voxel grid does not track it (away from the fins,
  /// and deeper than its body_band near them): such a contact pushes back with the same penalty
  /// spring (beyond the band: for the depth past it) and counts as a gouge
  /// (ExecutionResult::untracked_penetration_max); in between the contact follows the tool as
  /// the voxel penalty does. 0: off (then steel the voxels do not hold is air). Off by default
  /// until the tilted family's regression bounds are re-set from a sweep with it (2.5e-4 is the
  /// setting measured: README "Status").
  double cad_check_motion = 0;
  /// Apply the grinding (rate) part of the process force as a resistance to the feed, solved
  /// implicitly: the wrench per unit feed speed (impulse of the recent removal intervals / their
  /// net progress, see rate_window) times the TCP's speed along that travel at the end of each
  /// MuJoCo step (effective inertia from mj_solveM, servo and passive forces of the step); only a
  /// wrench that resists the feed is applied. Without it the wrench of each removal step is
  /// applied as computed and held until the next: a removal rate over whole voxels then acts like
  /// a damper far stiffer than the tool's effective mass allows over one step, and the tool
  /// chatters (stick-slip). The penalty part is elastic and always applied as computed.
  bool implicit_rate_force = true;
  /// [voxels] with implicit_rate_force, the per-speed wrench is averaged over removal intervals
  /// covering this much travel (≥ 0.5): removal comes in whole voxels, so the cut cross-section is
  /// only meaningful over a few.
  double rate_window = 8;
  /// Called after every step with the executor's model and data and the simulated time [s]
  /// (video frames); must not change the state. Empty: none.
  std::function<void(const mjModel*, mjData*, double)> on_step;
  /// The cell's collision geometry (the twin's measurement, never read by the controller): the
  /// robot is checked against it at every step (CollisionMonitor) and steps with a collision
  /// are counted (ExecutionResult::collision_steps). Null: not checked. Kept by reference.
  const CellCollision* collisions = nullptr;
  /// Start where a previous motion ended (its ExecutionResult::q_end / dq_end, the whole job
  /// run continuously) instead of at rest at q_0. Empty: at rest at q_0.
  std::vector<double> start_qpos, start_qvel;
  /// Fill ExecutionResult::residual (analyze_residual of the grid after the run). A caller
  /// running many trajectories on one grid turns it off and analyses once after the last.
  bool analyze_residual = true;
};

/// What happened to the references and the simulation.
enum class ExecStatus {
  kOk,                ///< ran to the end, no reference clamped
  kReferenceClamped,  ///< ran to the end; some reference left its joint's range and was clamped
  kUnstable,          ///< MuJoCo reported a bad state (NaN/huge acceleration); stopped early
  kForceLimit,        ///< protective stop: the sensed force exceeded ExecParams::max_force
};

/// "ok", "reference_clamped", "unstable", "force_limit".
const char* to_string(ExecStatus status);

/// Decimated time series (one row every log_decimation steps); all vectors have the same length
/// except the optional ones, which are empty when their source is absent.
struct ExecutionLog {
  std::vector<double> t;             ///< [s] simulated time of the row (trajectory time − t_0)
  std::vector<Vector6> q;            ///< [rad] executed joint positions
  std::vector<Vector6> q_ref;        ///< [rad] commanded positions (correction added, clamped)
  std::vector<Vec3> tcp_W;           ///< [m] executed TCP in {W}
  std::vector<Vec3> planned_tcp_W;   ///< [m] planned TCP, linear between samples (optional)
  std::vector<double> normal_force;  ///< [N] F_n + penalty as applied to the tool
  std::vector<double> tangential_force;  ///< [N] F_t as applied to the tool
  std::vector<Vec3> process_force_W;     ///< [N] force the process model puts on the tool, {W}
  std::vector<Vec3> sensor_force_E;      ///< [N] flange sensor's force reading, {E} (optional)
  std::vector<Vec3> sensor_torque_E;     ///< [N·m] its torque reading about the flange (optional)
  std::vector<Vec3> sensor_force_W;      ///< [N] the force reading rotated into {W} (optional)
  /// [N] the controller's estimate of the load force on the tool, {W} (optional: with a sensor)
  std::vector<Vec3> load_force_W;
  std::vector<double> removed_volume;    ///< [m^3] cumulative volume removed (flash + body)
  std::vector<double> correction;        ///< [m] admittance correction δ (into the material)
};

/// Outcome of one execution. Tracking compares the executed TCP with planned_tcp_W at the step
/// nearest each sample time; force statistics use every step in contact (the process model
/// pushes on the tool: material removed within the rate window while the tool feeds, or the tool
/// penetrating the nominal body).
struct ExecutionResult {
  ExecStatus status = ExecStatus::kOk;
  std::string message;            ///< what the status means for this run
  int first_clamp_joint = -1;     ///< 0-based joint of the first clamped reference (−1: none)
  double first_clamp_time = -1;   ///< [s] simulated time of the first clamp (−1: none)
  std::size_t clamped_steps = 0;  ///< steps with any reference clamped

  ExecutionLog log;

  std::size_t tracking_samples = 0;  ///< samples compared (0 without planned_tcp_W)
  double tracking_rmse = 0;          ///< [m] executed vs planned TCP position
  double tracking_max = 0;           ///< [m]
  double tracking_max_rotation = 0;  ///< [rad] executed vs planned tool orientation
  double final_error = 0;  ///< [m] TCP vs the last planned pose after settling (0 without plan)

  std::size_t joint_limit_violations = 0;  ///< steps with any joint beyond range + tolerance
  double max_limit_excess = 0;             ///< [rad] worst excursion beyond a range (0: none)

  double contact_time = 0;          ///< [s] simulated time in contact
  double force_mean = 0;            ///< [N] mean normal force in contact
  double force_rmse = 0;            ///< [N] RMS of (normal force − target) in contact
  double force_max = 0;             ///< [N] max normal force
  /// [N] the controller's estimate vs the process model's force on the tool: RMS of the
  /// difference over the samples in contact after the tare (0: none).
  double load_estimate_rmse = 0;
  double removed_flash_volume = 0;  ///< [m^3] during this run
  double removed_body_volume = 0;   ///< [m^3] during this run (gouging)
  double max_penetration = 0;       ///< [m] deepest the tool reached into the nominal body
  double max_penetration_time = -1; ///< [s] when (−1: never)
  /// [m] executed vs planned TCP at that time (0 without a plan): a deep penetration with a small
  /// tracking error was planned, one with a large error is the arm's.
  double max_penetration_tracking = 0;
  /// [m] deepest the cutter reached into the nominal body where the voxel grid does not track it
  /// or deeper than its band (cad_check_motion), full depth below the CAD surface: a gouge the
  /// voxels cannot see (0: none).
  double untracked_penetration_max = 0;
  double untracked_penetration_time = -1;  ///< [s] when (−1: never)
  std::size_t removal_steps = 0;    ///< remove_material calls
  bool has_residual = false;        ///< residual is filled (a grid was given, analyze_residual on)
  ResidualReport residual;          ///< analyze_residual of the grid after the run

  /// Steps in which a robot geom penetrated an obstacle (ExecParams::collisions; 0 unchecked).
  std::size_t collision_steps = 0;
  CollisionHit first_collision;   ///< the first such contact (clearance ≥ 0: none)
  double first_collision_time = -1;  ///< [s] when (−1: never)
  double collision_max_depth = 0;    ///< [m] deepest penetration of an obstacle
  CollisionHit deepest_collision;    ///< the contact of that depth
  double deepest_collision_time = -1;  ///< [s] when (−1: never)
  /// [m] least robot–obstacle clearance the checks found (CollisionMonitor checks a geom again
  /// once it could have come nearer than its last clearance: a lower bound on the clearance is
  /// kept between checks, not the clearance itself, so this can stay above the true least).
  double min_clearance = CellCollision::kReach;
  std::vector<double> q_end, qvel_end;  ///< the model's qpos / qvel at the end (ExecParams::start_*)

  std::size_t steps = 0;       ///< MuJoCo steps taken
  double timestep = 0;         ///< [s] the step used
  double sim_time = 0;         ///< [s]
  double wall_time = 0;        ///< [s] of the loop
  double realtime_factor = 0;  ///< sim_time / wall_time
  double step_cost = 0;        ///< [s] wall time per step
};

/// Runs `trajectory` on a copy of `model` (its timestep, ctrl ranges changed as described above),
/// starting at rest at q_0 (velocities dq_0) with the other DOFs at qpos0; removes material from
/// `grid` (in {C}; nullptr: no process model, free motion).
/// @pre the model has the names listed at the top of this header; `grid` outlives the call.
/// @throws ArgumentError (trajectory shapes, non-increasing or non-finite times/values, bad
///   params, timestep > 0.001 s, bad tool/force params), InputError (a name missing from the
///   model, an actuator that is not a position servo on its joint).
ExecutionResult execute_trajectory(const mjModel& model, const JointTrajectory& trajectory,
                                   MaterialGrid* grid, const ToolParams& tool,
                                   const ForceParams& force, const ExecParams& params = {});

/// Same, loading the MJCF file first (e.g. the cell.xml of write_cell).
/// @throws InputError when MuJoCo cannot load the file, and as above.
ExecutionResult execute_trajectory(const std::string& mjcf_path, const JointTrajectory& trajectory,
                                   MaterialGrid* grid, const ToolParams& tool,
                                   const ForceParams& force, const ExecParams& params = {});

/// Validates params. @throws ArgumentError naming the field (`execution.settle_time`, ...).
void check_exec_params(const ExecParams& params);

}  // namespace flashtwin::sim
