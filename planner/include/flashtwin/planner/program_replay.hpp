#pragma once
// A robot program run the way its controller runs it: the joint move to the start, then the
// Cartesian moves through the program's targets — straight lines, corners rounded within each
// target's approximation (blend) radius, at the programmed path speed with ramps at the
// programmed Cartesian acceleration, slowed where the programmed orientation speed binds — and
// the joint motion that follows from the controller's inverse kinematics, sample by sample, on
// the configuration the start put the arm in.
//
// This reads what was written (parse_program), never the plan behind it: what the replay
// grinds is what a real cell would grind with the file.
//
// Frames as in program_export.hpp: targets X_WT are the tool {T} in the work frame {W}; {W} is
// X_BW in the robot base {B}; the tool is X_ET in the flange {E}.
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/planner/timing.hpp"

namespace flashtwin::planner {

/// What the controller does that a program does not state.
struct ReplayParams {
  double dt = 0.001;  ///< interpolation period of the output [s]
  /// Cartesian ramp acceleration when the program states none (RAPID without AccSet) [m/s^2].
  double default_accel = 0.5;
  /// Rotation speed of the tool when the program states none (URScript's movel) [rad/s].
  double default_ori_speed = 1.0;
  double path_step = 5e-5;  ///< spacing of the internal path samples [m]
  /// A joint moving more than this between two output samples means the interpolated motion
  /// passes a singularity or changes configuration: the replay stops there [rad].
  double max_joint_step = 0.05;
};

/// The motion a program commands.
struct ReplayedProgram {
  /// Joint motion from the start target (at rest) to the last target (at rest): t, q, dq, ddq;
  /// s, sdot, sddot along the interpolation parameter (the TCP path length where position
  /// governs, [m]).
  JointTrajectory trajectory;
  std::vector<Pose> X_BT;  ///< commanded tool pose per sample, in the robot base {B}
  Pose X_ET = Pose::Identity();  ///< the tool frame used (declared, else the robot's)
  Pose X_BW = Pose::Identity();  ///< the work frame used (declared, else {B})
  double path_length = 0;        ///< TCP path length after blending [m]
  /// Largest |q̇_j| / velocity limit_j and |q̈_j| / acceleration limit_j over the motion [-].
  double max_joint_velocity_ratio = 0, max_joint_accel_ratio = 0;
};

/// Interpolates `program` as its controller would. The first motion must be a joint move (PTP,
/// movej, MoveAbsJ: the start); every later one a Cartesian move (LIN, SPL, movel, movep,
/// MoveL; SPL and movep are run as straight lines with blending).
/// @throws ArgumentError naming the program line: no motion, a first motion that is not a joint
/// move, a later joint move (not interpolated here), a target the arm cannot reach on its
/// configuration or reaches only through a singularity or a configuration change, a joint
/// outside its position limits, or non-positive parameters.
ReplayedProgram replay_program(const RobotModel& robot, const ParsedProgram& program,
                               const ReplayParams& params = {});

}  // namespace flashtwin::planner
