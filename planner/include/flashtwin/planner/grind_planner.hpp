#pragma once
// Grinding trajectory of one flash path: quintic B-spline through the path points, tool poses
// that hold the burr's side flush against the wall with the cutter straddling the fin, one IK
// branch for the whole motion (approach, passes, retract) with re-orientation around
// singularities and joint limits, and time parametrization under the joint limits.
//
// Geometry (all per sample, in the casting frame {C}):
//   f    fin normal (unit), the fin plane's normal, pointing to the side the tool comes from;
//   n    wall normal: the input normals interpolated between the nearest path points, with the
//        component along f removed (re-orthogonalized), unit;
//   t    travel direction: ±(n × f), the sign of the spline tangent (unit, ⟂ n and f);
//   p    root point on the spline (on the fin's root curve, in the fin mid-plane).
// The burr is a cylinder of radius r and cutting length L (robot.tool) running from the tip {T}
// back toward the flange along −z_T. Its shank direction −z_T is
//   w = cos(tilt)·(cos(lead)·f + sin(lead)·t) + sin(tilt)·n,
// i.e. lead leans the shank toward the travel direction (a rotation about n, which keeps the
// cylinder parallel to the wall), tilt leans it away from the wall (a rotation about t).
// The axis crosses the fin plane at p + o·n, and the tip lies d_tip further along z_T:
//   tip = p + o·n + d_tip·z_T,   o = e + r·sqrt(1 − c²) − min(d_tip·c, (d_tip − L)·c),  c = z_T·n
// where e is the pass's extra offset. For lead = tilt = 0 this is tip = p + (r + e)·n − d_tip·f:
// the cutter is tangent to the wall (e = 0) and straddles the fin. Under a tilt, o is the
// smallest offset at which no part of the cutting length enters the wall plane (no gouge).
// x_T is a fixed reference direction (the first travel direction, projected ⟂ z_T) turned about
// z_T by the spin angle; the burr is axisymmetric, so the spin is free and the planner picks it.
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "flashtwin/core/plot.hpp"
#include "flashtwin/core/robot.hpp"
#include "flashtwin/planner/clearance.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/timing.hpp"

namespace flashtwin::planner {

/// One flash path as perception delivers it, in the casting frame {C}.
struct GrindPath {
  std::vector<Vec3> points_C;  ///< ordered root points on the CAD surface [m], N ≥ 2 (closed: ≥ 6)
  std::vector<Vec3> normals_C;  ///< outward CAD surface (wall) normal at each point, N, any length
  Vec3 fin_normal_C = Vec3::UnitZ();  ///< fin plane normal, toward the tool's side (e.g. up)
  bool closed = false;                ///< closed loop (flash around a hole)
  double fin_height = 0;  ///< how far the fin sticks out of the wall [m] (as detection measured
                          ///< it); 0: unknown → one pass
};

/// Options of plan_grind (defaults for a 12 mm burr on steel flash).
struct GrindParams {
  double limit_margin = 0.02;   ///< [rad] the plan's samples keep this far inside each joint's
                                ///< position range, the timed motion between them half as far
                                ///< (the executor clamps its reference 0.01 rad inside)
  double spacing = 0.0005;      ///< arc-length spacing of the samples along the path [m]; the input
                                ///< points are thinned to at least this spacing first
  double feed = 0.005;          ///< cutting feed of the finishing pass and pass links [m/s]: the
                                ///< speed of the burr's contact along the wall (in a hole the tool
                                ///< centre moves slower by (R − r − e)/(R − e))
                                ///< (10 mm/s doubled the grinding force and, with the arm's
                                ///< deflection, gouged 0.56 mm into the hole walls; 5 mm/s 0.09 mm)
  double approach_feed = 0.02;  ///< feed of the approach and retract moves [m/s]
  /// Feed of the approach's last stretch, where the cutter plunges through the fin to its
  /// working depth (tip depth + 2 mm above the fin plane down to it) [m/s]: removal there is a
  /// whole cutter cross-section of fin per millimetre.
  double plunge_feed = 0.003;
  double approach_distance = 0.03;  ///< approach/retract height along the fin normal [m]
  /// Before the finishing pass of a path with roughing passes the burr leaves the part (the
  /// lead-out, a lift by tip depth + 2 mm, capped by approach_distance: the tip 2 mm above the
  /// fin plane), stops there in free air and comes back (the descent and the lead-in), instead
  /// of stepping in at the path's end: a controller that estimates the load from a flange F/T
  /// sensor re-zeroes it there, so the pass that sets the wall sees only the sensor's drift
  /// since (a plate's passes otherwise run 100–300 s in the material, ≈3 N of drift, ≈0.08 mm
  /// against the arm's ≈40 N/mm). Each such stop starts a run of kApproach segments, which
  /// pipeline::motion_of hands the executor as tare times (sim::JointTrajectory::tare_t). Needs
  /// approach_distance > 0. Limits: a path cut in one pass (fin height unknown or within
  /// finish_depth) gets no stop; with lead_clearance 0 the stop is beside the wall, not off it.
  /// Off by default (the scenario turns it on when the controller reads the sensor).
  bool retare_before_finish = false;
  /// With retare_before_finish, a longer finishing pass stops in free air again after each
  /// retare_length of path (the lead-out, the lift, the zero, down again at the same path
  /// sample), none within a quarter of it of the pass's end [m]; 0: only before the pass.
  double retare_length = 0.1;
  /// The pieces of a finishing pass split by such stops come to rest on the wall and start from
  /// it: their feed ramps up and down over at least this long [s] (the S-curve's jerk and
  /// acceleration lowered to fit). The process force follows the feed, and a controller that
  /// reads it from the sensor a few milliseconds late lets the arm spring into the wall when it
  /// falls fast (default plate 5019: 75 N gone in 60 ms put the burr 0.1 mm into the wall).
  double retare_ramp_time = 0.5;
  /// Lead-in/lead-out [m]: the approach comes down this far off the first pass's wall offset
  /// and steps in radially; the last pass steps off as far before the retract, so the burr
  /// never plunges or lifts along the wall it grinds (in a hole at most to the hole's centre).
  /// A hole must leave the burr at least this much room (and 0.2 mm): kToolTooLarge otherwise.
  double lead_clearance = 0.5e-3;
  double lead = 0;                  ///< lead angle (shank toward the travel direction) [rad]
  double tilt = 0;                  ///< tilt angle (shank away from the wall) [rad]
  /// Axial distance from the fin mid-plane crossing to the tip [m]; unset: tool length / 2.
  std::optional<double> tip_depth;
  /// The surface the casting stands on (the worktable's top), as a point and its upward unit
  /// normal in {C}; the burr keeps floor_clearance above it: where a fin stands lower than the
  /// tip depth, the burr slides up its axis (down to the tip depth that still keeps the fin on
  /// the burr's straight side: its radius and 1 mm above the tip). Unset: no floor.
  std::optional<std::pair<Vec3, Vec3>> floor_C;
  /// A block the casting stands on (the cell's riser), a floor of its own where the burr comes
  /// over it: X_CR places its top face's centre in {C} (z_R up), half its in-plane extents.
  /// Where the burr's lowest point lies within half + burr radius + floor_clearance of the
  /// centre (along x_R and y_R) the burr keeps floor_clearance above that top as above floor_C.
  struct Riser {
    Pose X_CR = Pose::Identity();
    Eigen::Vector2d half = Eigen::Vector2d::Zero();
  };
  std::optional<Riser> riser_C;
  double floor_clearance = 1e-3;  ///< [m]
  /// The arm and the tool (but the burr, which cuts) against the cell and the casting's CAD at
  /// each sample's configuration: a sample nearer than min_clearance is bad and re-oriented like
  /// one beyond a joint limit (spin, lead, lean), else the path fails with kCollision. Empty:
  /// not checked.
  ClearanceFn clearance;
  double min_clearance = 0.3e-3;  ///< [m]
  /// The torques each timed motion needs (inverse dynamics): where a segment (cut, link,
  /// approach, retract) would ask more than torque_factor of a joint's torque limit it is timed
  /// again more slowly (velocity limits / k, acceleration limits / k²). Timing bounds joint velocities and
  /// accelerations only: a lift that swung the shoulder at its acceleration limit asked 400 N·m
  /// of a 400 N·m joint, the servo saturated and the burr fell 10 mm into the table (tilted
  /// 8032). Empty: not checked.
  TorqueFn torque;
  /// Fraction of each joint's torque limit a timed motion may ask, the rest kept for the process
  /// force and the servo's corrections [-].
  double torque_factor = 0.7;
  double max_depth_of_cut = 0.002;  ///< largest radial depth of cut of a roughing pass [m]
  /// Radial depth of the last (finishing) pass when the fin height is known [m]: the roughing
  /// passes take the fin down to this, the last pass cuts it to the wall under a light load,
  /// so the arm's deflection under the grinding force no longer leaves a layer of flash.
  double finish_depth = 0.3e-3;
  /// Feed of the roughing passes [m/s] (each removes at most max_depth_of_cut: at 10 mm/s
  /// about the removal rate of a 4 mm fin cut in one pass at 5 mm/s).
  double roughing_feed = 0.01;
  /// Run-out past each end of an open path, straight along its end tangent [m]: at the last
  /// path point the burr touches the wall at one point only, so the flash just beyond it
  /// would stay. Shortened (to whole samples, possibly none) where the wall curves round the
  /// burr near the end, so the straight run-out cuts at most 20 µm into it.
  double overrun = 0.002;
  /// Radial stock left on the wall by the last pass [m]: the burr runs this far off the CAD
  /// wall. 0 by default: with the light finishing pass and the lead-in/out the arm's deflection
  /// no longer cuts into the wall (default scenario, seeds 5001–5050: deepest gouge p50 0.06 mm,
  /// p90 0.08 mm), while 0.03 mm left the flash's first 0.1 mm voxel layer standing on the
  /// outer walls (removed p50 99.2 %, 1 in 3 castings under 99 %).
  double stock_allowance = 0;
  /// Manipulability |det J| below which a sample counts as near-singular [-] (the FT6 reaches
  /// about 0.12 in comfortable poses).
  double manipulability_threshold = 0.01;
  /// Largest extra lean of the tool axis (lead and tilt combined) allowed to escape a
  /// singularity or a joint limit [rad]; rotations about the tool axis are always allowed.
  double max_extra_tilt = 0.26;
  /// Largest extra lead alone (the axis turned within the wall's tangent plane, toward or
  /// against the travel) [rad], tried after the leans within max_extra_tilt and before any
  /// tilt, in the same steps. A lead keeps the burr's side on the wall, so every root point is
  /// still cut flush as the contact line passes it; a tilt of the shank away from the wall
  /// slides the burr up until its ball end cuts at the root (t²/8r of a fin t thick left), one
  /// toward the wall puts the upper end's rim there. Round a dome the wrist needs more lead
  /// than a tilt could be allowed.
  double max_extra_lead = 0.8;
  int reorient_steps = 4;  ///< extra leans tried: max_extra_tilt·k / reorient_steps, k = 1..
  /// Path length over which a re-orientation fades in and out on each side of the range that
  /// needs it [m] (quintic smoothstep), so the joint path stays smooth; doubled (up to ×4) when
  /// the wrist cannot follow the fade within max_joint_jump per sample.
  double blend_length = 0.01;
  int spin_candidates = 4;  ///< base spins tried per IK branch: 2π·k / spin_candidates (≥ 1)
  unsigned branch_mask = 0xFF;  ///< IK branches allowed, bit IkBranch::index() (0xFF: all)
  /// Largest joint change between consecutive samples [rad]: more is a discontinuity (a wrist
  /// flip turns joints 4 and 6 by about π). A wrist passing near its singular pose turns them
  /// by up to 0.15 rad per 0.5 mm sample (cover seed 9003), which the timing slows to the
  /// joints' speeds; at 0.1 such stretches had to lean with tilt and left a wedge of flash.
  double max_joint_jump = 0.2;
  /// Time parametrization; its `feed` is ignored (each segment gets feed or approach_feed).
  TimingParams timing;
};

/// What a sample belongs to.
enum class SampleKind {
  kApproach,  ///< straight move down along the fin normal to the start of the first pass (the
              ///< last stretch, through the fin, as its own segment at the plunge feed), then
              ///< the lead-in: a radial step to the wall offset at the cutting feed
  kCut,       ///< a pass along the path
  kLink,      ///< radial step-in between passes at the same path point (cutting feed); open
              ///< paths alternate direction pass by pass, closed ones restart at the seam
  kRetract,   ///< lead-out (a radial step off the wall at the cutting feed), then a straight
              ///< move up along the fin normal from the end of the last pass
};

/// One planned sample (IK node) of the motion.
struct GrindSample {
  SampleKind kind = SampleKind::kCut;
  int pass = 0;                  ///< pass 0..passes−1 (approach: 0, retract: the last)
  int path_index = 0;            ///< nearest input point (points_C index)
  double s = 0;                  ///< tool path length from the start [m] (TCP travel)
  Pose X_CT = Pose::Identity();  ///< tool pose in the casting frame
  Pose X_BT = Pose::Identity();  ///< tool pose in the robot base, X_BC·X_CT
  Vector6 q = Vector6::Zero();   ///< joint configuration [rad] (on failure: as far as tracked)
  double manipulability = 0;     ///< |det J| at q
  double axis_offset = 0;        ///< o: axis distance from the root along n at the fin plane [m]
  /// Re-orientation applied here [rad] (the lead toward this sample's travel).
  double extra_lead = 0, extra_tilt = 0, extra_spin = 0;
};

/// A consecutive run of samples timed as one move (starts and ends at rest).
struct GrindSegment {
  SampleKind kind = SampleKind::kCut;
  int pass = 0;
  std::size_t first_sample = 0, last_sample = 0;  ///< inclusive; neighbours share a sample
  std::size_t first_step = 0, last_step = 0;      ///< inclusive trajectory sample indices
  double feed = 0;                                ///< [m/s]
  /// [s] the ramps from and to rest take at least this long (0: as the timing's own jerk and
  /// acceleration bounds give them)
  double ramp_time = 0;
};

enum class GrindStatus {
  kOk,
  kUnreachable,    ///< a pose is out of reach for every branch and re-orientation
  kJointLimit,     ///< a pose needs a joint beyond its range for every branch and re-orientation
  kSingular,       ///< manipulability stays below the threshold for every allowed re-orientation
  kDiscontinuous,  ///< the chosen branch jumps (or is lost) between samples, not repairable
  kTimingFailed,   ///< time_parametrize refused the joint path (see message)
  kToolTooLarge,   ///< a hole (closed loop or open arc of ≥ 45°, wall facing inward) narrower
                   ///< than the burr + max(lead_clearance, 0.2 mm): no room to step in
  kCollision,      ///< the arm or tool comes nearer the cell than GrindParams::min_clearance
                   ///< for every branch and re-orientation
};

/// Why a range of samples was re-oriented (or could not be).
enum class ReorientReason { kSingular, kJointLimit, kUnreachable, kDiscontinuous, kCollision };

/// A range of samples that needed a re-orientation, and the one applied (at full weight inside
/// the range; faded in and out over blend_length around it).
struct ReorientedRange {
  ReorientReason reason = ReorientReason::kSingular;
  std::size_t first_sample = 0, last_sample = 0;  ///< inclusive, the samples that were bad
  int first_path_index = 0, last_path_index = 0;  ///< their nearest input points
  int pass = 0;                                   ///< pass of the first sample
  double nominal_min_manipulability = 0;          ///< lowest manipulability before (0 where no IK)
  double min_manipulability = 0;  ///< lowest manipulability after, over the blend window
  /// The re-orientation [rad]; its lead turns the shank toward the path's own direction (the
  /// order of points_C), on every pass alike.
  double extra_lead = 0, extra_tilt = 0, extra_spin = 0;
  double blend_length = 0;  ///< fade length used on each side [m] (blend_length ×1, ×2 or ×4)
};

/// Outcome of plan_grind. Samples are filled even on failure (with the nominal poses), so a
/// caller can show where it failed; trajectory and tcp_B only when ok.
struct GrindResult {
  GrindStatus status = GrindStatus::kOk;
  std::string message;  ///< empty when ok; else names the path index, sample, pass and reason
  // Failure details (status != kOk).
  int failed_sample = -1;      ///< first bad sample (index into samples)
  int failed_path_index = -1;  ///< its nearest input point
  int failed_pass = -1;
  int failed_joint = -1;     ///< 0..5 for kJointLimit (timing: the joint named by it)
  double failed_excess = 0;  ///< [rad] beyond the limit (kJointLimit); manipulability (kSingular)

  IkBranch branch;       ///< the one configuration branch of the whole motion
  double base_spin = 0;  ///< chosen rotation of x_T about z_T from the reference [rad]
  int seeds_tried = 0, seeds_completed = 0;  ///< (branch, spin) seeds tracked / that completed

  double tool_radius = 0;  ///< [m] the burr this plan is for (the robot's tool when planned)
  /// [m] radius of the hole the path runs round (closed, wall facing its centre, or an open arc
  /// of at least 45° of one); 0: not in a hole.
  double hole_radius = 0;
  int passes = 0;
  std::vector<double> pass_offsets;  ///< extra axis offset e of each pass [m], the last one
                                     ///< GrindParams::stock_allowance
  std::vector<GrindSample> samples;
  std::vector<GrindSegment> segments;
  std::vector<ReorientedRange> reoriented_ranges;

  JointTrajectory trajectory;  ///< all segments concatenated (t, q, dq, ddq, s, sdot, sddot)
  std::vector<Pose> tcp_B;     ///< FK of trajectory.q: planned TCP pose X_BT over time
  std::vector<FeedReduction> feed_reductions;  ///< sample indices into `samples`, s global

  double max_joint_velocity_ratio = 0;  ///< trajectory.max_joint_velocity_ratio
  double max_joint_accel_ratio = 0;     ///< trajectory.max_joint_accel_ratio
  double min_manipulability = 0;        ///< trajectory.min_manipulability (over the samples)
  double total_time = 0;                ///< [s]
  double path_length = 0;               ///< total TCP travel [m]
  double cut_length = 0;                ///< TCP travel while cutting (passes + links) [m]
  bool ok() const { return status == GrindStatus::kOk; }
};

/// Plans the grinding motion of one path on the casting at X_BC: spline, samples, passes
/// (with a known fin height: roughing passes of equal depths ≤ max_depth_of_cut at the
/// roughing feed down to finish_depth, then one finishing pass at the cutting feed flush with
/// the wall; in a hole the passes start no farther from the wall than the hole's centre), one IK branch chosen over all (branch, base spin) seeds of the first pose — among the
/// seeds that complete, those that keep the burr flush (no tilt) if any, of them those within
/// 10 % of the best minimum manipulability, then the fewest
/// re-orientations, then the largest joint-limit margin — re-orientation of bad ranges (spin about
/// z_T first, then leads of growing size, which keep the burr flush, then leans with tilt), and time parametrization segment by segment (each
/// starts and ends at rest; all share one sample period).
/// @throws ArgumentError on malformed input: size mismatch, non-finite values, a zero fin
/// normal, a wall normal (nearly) parallel to the fin normal, too few points after thinning,
/// more than 100 passes, parameters out of range, or a robot the analytic IK does not handle.
GrindResult plan_grind(const RobotModel& robot, const Pose& X_BC, const GrindPath& path,
                       const GrindParams& params = {});

/// Tool pose X_CT of the geometry above (exposed for tests and for other planners). The burr is
/// ball-ended (a hemisphere of `radius` at the tip, as every cell burr is): upright or with a
/// lead its straight side lies on the wall, the fin `tip_depth` above the tip; leaning away from
/// the wall (tilt > 0) the ball touches the wall at the root; leaning toward it, the upper end.
/// `x_ref` is the reference for x_T (projected ⟂ z_T). @pre f, n, t orthonormal.
Pose grind_tool_pose(const Vec3& p, const Vec3& n, const Vec3& t, const Vec3& f, const Vec3& x_ref,
                     double extra_offset, double lead, double tilt, double spin, double radius,
                     double length, double tip_depth, double* axis_offset = nullptr);

/// trajectory.csv text: t, q1..q6, dq1..dq6, ddq1..ddq6, x y z qw qx qy qz of the TCP in {B}
/// (SI units, one header line). @pre result.ok().
std::string trajectory_csv(const GrindResult& result);

/// JSON object with status, message, branch and the trajectory.* metrics (DESIGN.md keys plus
/// total time, lengths, passes, re-oriented ranges and feed reductions).
std::string grind_summary_json(const GrindResult& result);

/// The smallest e ≥ v (in place) whose change between neighbouring points is at most `slope` ×
/// their distance: e_k = max_j (v_j − slope · d_kj), d_kj the length along the polyline
/// `points` (round the shorter way when `closed`). The planner eases a clearance in and out with
/// it. `points` has v's size.
void upper_envelope_along(std::vector<double>& v, const std::vector<Vec3>& points, double slope,
                          bool closed);

/// Which joint quantity a plot shows.
enum class JointQuantity { kPosition, kVelocity, kAcceleration };

/// Joints 1..6 of one quantity over time, one line each.
Image plot_joint_trajectory(const JointTrajectory& trajectory, JointQuantity quantity,
                            int width = 900, int height = 500);

/// Writes DIR/trajectory.csv, DIR/grind_summary.json and, when `plots` and the plan is ok,
/// DIR/joint_positions.png, DIR/joint_velocities.png, DIR/joint_accelerations.png. Creates DIR.
/// `csv`: trajectory_csv(result) when the caller has it already ("" = format it here).
/// @throws IoError when a file cannot be written.
void write_grind_outputs(const GrindResult& result, const std::string& dir, bool plots = true,
                         const std::string& csv = "");

std::string to_string(GrindStatus status);
std::string to_string(SampleKind kind);
std::string to_string(ReorientReason reason);

}  // namespace flashtwin::planner
