#pragma once
// Forward kinematics, geometric Jacobian and manipulability of the D-H arm.
#include <array>

#include "flashtwin/core/robot.hpp"

namespace flashtwin::planner {

/// D-H link transform of row `row` at joint angle theta: Rot_z(θ)·Trans_z(d)·Trans_x(a)·Rot_x(α).
Pose dh_link(const DhRow& row, double theta);

/// All D-H frames in the base: X_B[0] = {0} = identity, X_B[i] = frame {i}; X_B[6] = X_BE.
std::array<Pose, kNumJoints + 1> fk_frames(const RobotModel& robot, const Vector6& q);

/// Flange pose X_BE.
Pose fk_flange(const RobotModel& robot, const Vector6& q);

/// Tool pose X_BT = X_BE · X_ET.
Pose fk_tool(const RobotModel& robot, const Vector6& q);

/// Frame in which a Jacobian's rows are expressed.
enum class JacobianFrame { kBase, kTool };

/// Geometric Jacobian (6x6, rows: linear velocity then angular velocity) of the point at
/// X_EP (a frame fixed to the flange; identity = flange, robot.tool.X_ET = TCP), expressed in
/// the base frame or in that point's own frame.
Matrix6 jacobian(const RobotModel& robot, const Vector6& q, const Pose& X_EP,
                 JacobianFrame frame = JacobianFrame::kBase);

/// Yoshikawa manipulability sqrt(det(J·Jᵀ)) = |det J| of the 6x6 Jacobian (independent of the
/// reference point and frame for a 6-DOF arm).
double manipulability(const RobotModel& robot, const Vector6& q);

/// Distances to the three singularities of a PUMA-type arm, each 0 at the singularity.
struct SingularityReport {
  double manipulability = 0;  ///< |det J|
  double wrist = 0;           ///< |sin θ5|: axes 4 and 6 aligned at 0
  double elbow = 0;           ///< |sin ψ|: arm stretched or folded at 0
  double shoulder = 0;        ///< [m] distance of the wrist centre from the shoulder singular
                              ///< surface (where both shoulder IK branches meet)
  bool singular = false;      ///< manipulability below the threshold
};

/// Singularity indicators at q; `threshold` is the manipulability below which q counts as
/// singular.
SingularityReport check_singularity(const RobotModel& robot, const Vector6& q,
                                    double threshold = 1e-3);

}  // namespace flashtwin::planner
