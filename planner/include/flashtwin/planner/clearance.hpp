#pragma once
// The planner's view of the cell's geometry: a clearance function the caller supplies (the
// planner knows no geometry of its own; the pipeline gives it the cell's obstacles and the
// casting's CAD at the estimated pose, sim/collision.hpp); and of the arm's dynamics: a torque
// function (the cell model's inverse dynamics).
#include <functional>
#include <string>

#include "flashtwin/core/robot.hpp"

namespace flashtwin::planner {

/// What a configuration's clearance check found.
struct Clearance {
  double distance = 0;  ///< [m] signed: < 0 a penetration
  std::string what;     ///< e.g. "spindle – fixture_left"
};
/// Clearance of the robot at a configuration (the caller's world model).
using ClearanceFn = std::function<Clearance(const Vector6& q)>;
/// The joint torques [N·m] the arm needs to move through q with velocities dq and accelerations
/// ddq (the caller's rigid-body model: links, tool, armature, joint damping).
using TorqueFn = std::function<Vector6(const Vector6& q, const Vector6& dq, const Vector6& ddq)>;

}  // namespace flashtwin::planner
