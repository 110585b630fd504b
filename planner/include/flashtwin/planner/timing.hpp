#pragma once
// Time parametrization of a joint path along its arc length s: a constant feed along s with
// jerk-limited (S-curve) start and end ramps, slowed locally where the joints' velocity or
// acceleration limits would be broken (reachability passes in the style of TOPP-RA), sampled at
// a fixed period. The joint path q(s) is a C2 cubic spline through the IK samples, and the timed
// positions lie on it exactly: q(t) = q(s(t)).
//
// Method: on a grid in s (every sample plus subdivisions of at most grid_step), the admissible
// (ṡ², s̈) set of each step is linear in the joint velocity and acceleration limits; a backward
// pass computes the largest controllable ṡ² at every grid point (Fourier–Motzkin elimination of
// s̈ per step) and a forward pass takes the greatest admissible s̈, capped by the feed and the
// S-curve ramps. Where the speed follows a ramp from rest it is played as the analytic S-curve
// (path jerk <= max_path_jerk); inside slowdowns s̈ is piecewise constant (acceleration-bounded,
// not jerk-limited).
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"

namespace flashtwin::planner {

/// C2 cubic spline q(s) through joint samples, per joint, in the path parameter s. End slopes
/// come from the parabola through the first (last) three samples, so samples of a polynomial of
/// degree <= 2 in s are reproduced exactly.
class JointPathSpline {
 public:
  JointPathSpline() = default;
  /// @pre s.size() == q.size() >= 2, s strictly increasing, all values finite.
  /// @throws ArgumentError otherwise ("expected X, got Y").
  JointPathSpline(std::vector<double> s, std::vector<Vector6> q);

  std::size_t size() const { return s_.size(); }  ///< number of samples
  double s_begin() const { return s_.front(); }
  double s_end() const { return s_.back(); }
  const std::vector<double>& knots() const { return s_; }

  /// Index i of the interval [s_i, s_i+1] holding s (clamped to the first/last interval).
  /// `hint` (may be null) is a starting guess that makes monotone sweeps O(1); updated.
  std::size_t interval(double s, std::size_t* hint = nullptr) const;
  /// q(s) [rad], q'(s) [rad/m], q''(s) [rad/m^2]; s is clamped to [s_begin, s_end].
  void evaluate(double s, Vector6& q, Vector6& dq_ds, Vector6& d2q_ds2,
                std::size_t* hint = nullptr) const;
  /// q(s) [rad] alone.
  Vector6 position(double s, std::size_t* hint = nullptr) const;

 private:
  std::vector<double> s_;
  std::vector<Vector6> q_;
  std::vector<Vector6> m_;  ///< q''(s_i) [rad/m^2]
};

/// A time-sampled joint trajectory at a fixed period: all arrays have size() entries.
struct JointTrajectory {
  double dt = 0;              ///< sample period [s]
  std::vector<double> t;      ///< time [s], t[n] = n·dt
  std::vector<Vector6> q;     ///< joint positions [rad]
  std::vector<Vector6> dq;    ///< joint velocities [rad/s]
  std::vector<Vector6> ddq;   ///< joint accelerations [rad/s^2]
  std::vector<double> s;      ///< path parameter [m] (same origin as the input samples)
  std::vector<double> sdot;   ///< path speed, the feed [m/s]
  std::vector<double> sddot;  ///< path acceleration [m/s^2]
  std::size_t size() const { return t.size(); }
  double duration() const { return t.empty() ? 0.0 : t.back(); }
};

/// Options of the time parametrization.
struct TimingParams {
  double feed = 0.02;           ///< target speed along s [m/s]
  double max_path_accel = 0.5;  ///< bound on |s̈| everywhere; the ramps' acceleration [m/s^2]
  double max_path_jerk = 5.0;   ///< jerk of the start/end S-curve ramps [m/s^3]
  /// Planning uses this fraction of every joint velocity and acceleration limit (0, 1] [-].
  double limit_factor = 0.95;
  std::optional<Vector6> velocity_limits;      ///< replaces the robot's when set [rad/s]
  std::optional<Vector6> acceleration_limits;  ///< replaces the robot's when set [rad/s^2]
  double dt = 0.001;                           ///< output sample period [s]
  /// Largest spacing of the reachability grid along s [m]; each sample interval is split
  /// evenly into ceil(Δs / grid_step) grid steps.
  double grid_step = 0.0005;
  double position_tol = 0.0;  ///< slack on the joint position limits [rad]
  /// A larger jump of one joint between consecutive samples means the path is discontinuous
  /// (IK branch switch, angle wrap) [rad]; 0 disables the check.
  double max_joint_step = 0.5;
  /// The limits may not force the feed below this anywhere outside the end ramps [m/s]; 0: any
  /// slowdown down to 1e-6 m/s is accepted (slower counts as having to stop).
  double min_feed = 0.0;
  /// Relative drop below the nominal feed (feed and ramps) that counts as a reduction [-].
  double reduction_tol = 1e-3;
  double max_duration = 3600.0;  ///< longer trajectories are refused (Result) [s]
};

/// Which limit a report is about.
enum class LimitKind { kNone, kPosition, kVelocity, kAcceleration, kJointStep };

/// Outcome of the time parametrization.
enum class TimingStatus {
  kOk,             ///< trajectory produced
  kPositionLimit,  ///< a sample (or the spline between samples) leaves a joint's range
  kDiscontinuous,  ///< a joint jumps by more than max_joint_step between two samples
  kBelowMinFeed,   ///< the joint limits force the feed below min_feed (or to a stop)
  kTooLong,        ///< the trajectory would last longer than max_duration
};

/// A stretch of the path where the joint limits forced the feed below its nominal value.
struct FeedReduction {
  std::size_t first_sample = 0, last_sample = 0;  ///< path sample indices bracketing it
  double s_begin = 0, s_end = 0;                  ///< [m]
  double min_feed = 0;                            ///< lowest path speed in the stretch [m/s]
  double s_at_min = 0;                            ///< where it occurs [m]
  double nominal_feed = 0;                        ///< the unconstrained speed there [m/s]
  int joint = -1;                      ///< most loaded joint at the lowest speed, 0..5 (joint1..6)
  LimitKind limit = LimitKind::kNone;  ///< kVelocity or kAcceleration
};

struct TimingResult {
  TimingStatus status = TimingStatus::kOk;
  /// Empty when ok, else e.g. "sample 42: joint 4 position 3.2100 rad exceeds upper limit
  /// 3.1400 rad by 0.0700 rad" (joints named 1..6 in text).
  std::string message;
  // Failure details (status != kOk).
  int failed_sample = -1;  ///< first offending path sample (for a jump: the sample after it)
  int failed_joint = -1;   ///< 0..5
  LimitKind failed_limit = LimitKind::kNone;
  double failed_value = 0;   ///< the offending value (position [rad], step [rad], feed [m/s])
  double failed_bound = 0;   ///< the limit it breaks, same unit
  double failed_excess = 0;  ///< by how much, same unit (> 0)

  JointTrajectory trajectory;  ///< empty unless ok
  /// max over samples of |dq_j| / velocity limit_j and |ddq_j| / acceleration limit_j, against
  /// the full (unfactored) limits, from the sampled values.
  Vector6 max_velocity_ratio = Vector6::Zero();
  Vector6 max_accel_ratio = Vector6::Zero();
  double max_joint_velocity_ratio = 0;  ///< max over joints of the above
  double max_joint_accel_ratio = 0;
  std::vector<FeedReduction> reductions;  ///< in path order
  double total_time = 0;                  ///< [s], = trajectory.duration()
  /// Uniform slow-down applied after planning (>= 1): rounding the duration up to whole
  /// periods, and a fallback when the sampled trajectory would exceed its margin.
  double time_scale = 1;
  std::size_t grid_points = 0;  ///< size of the reachability grid
  bool ok() const { return status == TimingStatus::kOk; }
};

/// Times a joint path at a constant feed under the robot's joint limits.
/// `s`: N path parameters (arc length) [m], strictly increasing; `q`: N joint configurations
/// [rad], continuous (one IK branch, no 2π jumps). Position limits come from `robot`, velocity
/// and acceleration limits from `robot` unless overridden in `params`.
/// @throws ArgumentError on N < 2, size mismatch, non-increasing s, non-finite values or
/// parameters out of range.
TimingResult time_parametrize(const RobotModel& robot, const std::vector<double>& s,
                              const std::vector<Vector6>& q, const TimingParams& params = {});

std::string to_string(TimingStatus status);
std::string to_string(LimitKind kind);

}  // namespace flashtwin::planner
