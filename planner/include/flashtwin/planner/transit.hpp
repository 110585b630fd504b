#pragma once
// Moves between grinding motions (home → first path, path → path, last path → home): joint-space
// minimum-jerk moves that start and end at rest, checked against the cell through a clearance
// function the caller supplies (the planner knows no geometry of its own: the pipeline gives it
// the cell's obstacles and the casting's CAD at the estimated pose). A direct move that comes
// closer than the required clearance is re-planned over a lift: the tool rises along the cell's
// up direction from both ends (IK on the same branch), crosses over at that height, and comes
// down. Higher lifts are tried in turn, then routes through the parking configurations given
// (home), then a route sampled by RRT-connect; when none is clear the transit is refused, naming
// the closest approach.
#include <cstdint>
#include <functional>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/planner/clearance.hpp"
#include "flashtwin/planner/timing.hpp"

namespace flashtwin::planner {

/// Options of plan_transit (fields named `transit.<field>` in error messages).
struct TransitParams {
  /// [m] clearance the move keeps from everything; where an end stands nearer than twice this
  /// (the start of a path beside its fin), half that end's clearance.
  double clearance = 0.015;
  /// [m] the least clearance an end may have (nearer: the transit is refused). 0: an end only
  /// must not penetrate (a grinding path may start with its collet a hair off a wall; the path
  /// itself is what then touches, and execution measures it).
  double min_end_clearance = 0;
  /// [m] lifts tried, in turn, when the direct move is not clear.
  std::vector<double> lifts{0.1, 0.2, 0.35};
  Vec3 up_B = Vec3::UnitZ();  ///< the cell's up direction in the robot base frame {B}
  /// Parking configurations (e.g. the robot's home) a transit may pass through when neither the
  /// direct move nor a lift is clear: tried in turn, straight and over each lift.
  std::vector<Vector6> via;
  /// Last resort: RRT-connect in joint space (near the ends, within the joint limits) for at most this many
  /// iterations, then shortcut; 0: none.
  int rrt_iterations = 2000;
  double rrt_step = 0.3;           ///< [rad] longest extension of a tree
  /// [rad] the sampler draws each joint within this margin of the span of the two ends
  double rrt_margin = 1.0;
  std::uint64_t rrt_seed = 0x7A5;  ///< the sampler's seed (the same transit, the same route)
  /// Fraction of each joint's velocity and acceleration limits the moves use.
  double speed_ratio = 0.25;
  double dt = 0.01;  ///< [s] sample period of the trajectory
};

/// A planned transit.
struct TransitResult {
  bool ok = false;
  std::string message;     ///< why not, or "direct" / "over a lift of 0.10 m"
  bool lifted = false;     ///< re-planned over a lift
  JointTrajectory trajectory;  ///< t from 0, q, dq, ddq (s, sdot, sddot empty)
  std::vector<Pose> tcp_B;     ///< FK of trajectory.q
  double min_clearance = 0;    ///< [m] least clearance found along the move
  std::size_t checks = 0;      ///< clearance checks made
  double duration() const { return trajectory.duration(); }
};

/// @throws ArgumentError naming the field for bad params or non-finite configurations.
TransitResult plan_transit(const RobotModel& robot, const Vector6& q_from, const Vector6& q_to,
                           const ClearanceFn& clearance, const TransitParams& params = {});

/// Bound on how far any point of the arm or tool moves when the joints move by dq [m]:
/// Σ |dq_i| · reach_i, reach_i the sum of the D-H offsets beyond joint i, the tool's length and
/// `radius` (the geometry's thickness).
double motion_bound(const RobotModel& robot, const Vector6& dq, double radius = 0.1);

}  // namespace flashtwin::planner
