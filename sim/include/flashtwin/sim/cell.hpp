#pragma once
// The MuJoCo cell: robot on a pedestal, worktable, casting, cameras and lights, written as a
// self-contained MJCF (DESIGN.md contract: joints joint1..joint6, sites flange and tcp, body
// casting).
#include <string>

#include "flashtwin/core/robot.hpp"

namespace flashtwin::sim {

/// Geometry of the cell (world frame {W}: z up, floor at z = 0).
struct CellSpec {
  /// Robot base {B} (D-H frame 0, at the shoulder) in {W}.
  Pose X_WB = Pose(Eigen::Translation3d(0.0, 0.0, 0.95));
  double base_height = 0.35;  ///< [m] robot base housing below {B}, on top of the pedestal
  /// Worktable top centre in {W} (z = top surface).
  Pose X_WTable = Pose(Eigen::Translation3d(0.75, 0.0, 0.78));
  Vec3 table_size{0.8, 0.9, 0.05};  ///< [m] top plate extents (x, y, thickness)
  /// Casting frame {C} in {W}.
  Pose X_WC = Pose(Eigen::Translation3d(0.70, 0.0, 0.78));
  Vec3 casting_size{0.25, 0.18, 0.06};  ///< [m] placeholder box extents, {C} at its bottom centre
  double timestep = 0.001;           ///< [s] MuJoCo step (≥ 1 kHz)
  /// Position-actuator stiffness per joint [N·m/rad]; torque-limited by the robot's limits.
  std::array<double, kNumJoints> kp{20000, 20000, 10000, 2000, 1500, 800};
  std::array<double, kNumJoints> damping{300, 300, 150, 20, 15, 8};  ///< joint damping [N·m·s/rad]
};

/// MJCF text of the robot's body chain (body `base` with links link1..link6, tool body `tool`,
/// sites `flange` and `tcp`), to be placed inside <worldbody>; `X_WB` places the base.
std::string arm_mjcf(const RobotModel& robot, const Pose& X_WB, const CellSpec& spec);

/// MJCF text of the whole cell.
std::string cell_mjcf(const RobotModel& robot, const CellSpec& spec);

/// Files written by write_cell.
struct CellFiles {
  std::string mjcf;  ///< DIR/cell.xml
  std::string urdf;  ///< DIR/robot.urdf
};

/// Writes DIR/cell.xml (self-contained) and DIR/robot.urdf, then loads cell.xml with MuJoCo
/// to prove it compiles. @throws IoError (cannot write), InputError (MuJoCo rejects it).
CellFiles write_cell(const RobotModel& robot, const CellSpec& spec, const std::string& dir);

/// Summary of a compiled MuJoCo model, for users and tests.
struct ModelSummary {
  int nbody = 0, njnt = 0, nu = 0, ngeom = 0, nsite = 0, ncam = 0;
  double timestep = 0;
};

/// Compiles an MJCF file with MuJoCo. @throws InputError with MuJoCo's message.
ModelSummary check_mjcf(const std::string& path);

}  // namespace flashtwin::sim
