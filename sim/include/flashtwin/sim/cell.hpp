#pragma once
// The MuJoCo cell: robot on a pedestal, worktable, casting, cameras and lights, written as a
// self-contained MJCF (DESIGN.md contract: joints joint1..joint6, sites flange and tcp, body
// casting).
#include <string>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/sim/casting.hpp"

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
  /// Scanner frame {M} in {W} (true mount pose): above the table, z_M pointing down.
  Pose X_WM = Pose(Eigen::Translation3d(0.70, 0.0, 1.25)) *
              Pose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()));
  double timestep = 0.001;           ///< [s] MuJoCo step (≥ 1 kHz)
  /// Position-actuator stiffness per joint [N·m/rad]; torque-limited by the robot's limits.
  std::array<double, kNumJoints> kp{20000, 20000, 10000, 2000, 1500, 800};
  std::array<double, kNumJoints> damping{300, 300, 150, 20, 15, 8};  ///< joint damping [N·m·s/rad]
};

/// MJCF text of the robot's body chain (body `base` with links link1..link6, tool body `tool`,
/// sites `flange` and `tcp`), to be placed inside <worldbody>; `X_WB` places the base.
std::string arm_mjcf(const RobotModel& robot, const Pose& X_WB, const CellSpec& spec);

/// Mesh files of the casting the MJCF refers to (paths relative to the MJCF's folder).
struct CastingAssets {
  std::string nominal_stl;  ///< the casting body
  std::string flash_stl;    ///< all fins (empty: none)
  Vec3 lo = Vec3(-0.1, -0.1, 0), hi = Vec3(0.1, 0.1, 0.05);  ///< nominal bounds in {C} [m]
};

/// MJCF text of the whole cell; without assets the casting is a box of the default bounds.
std::string cell_mjcf(const RobotModel& robot, const CellSpec& spec,
                      const CastingAssets* casting = nullptr);

/// Summary of a compiled MuJoCo model, for users and tests.
struct ModelSummary {
  int nbody = 0, njnt = 0, nu = 0, ngeom = 0, nsite = 0, ncam = 0;
  double timestep = 0;
};

/// Files written by write_cell.
struct CellFiles {
  std::string mjcf;         ///< DIR/cell.xml (self-contained with DIR/meshes/)
  std::string urdf;         ///< DIR/robot.urdf
  std::string cad;          ///< DIR/casting_cad.stl: the nominal casting in {C} (the "CAD model")
  std::string truth;        ///< DIR/truth/: ground truth for scoring only
  ModelSummary model;       ///< what MuJoCo compiled from cell.xml
};

/// Writes the cell: DIR/cell.xml, DIR/meshes/*.stl, DIR/robot.urdf, DIR/casting_cad.stl and the
/// ground truth (DIR/truth/: fins.stl, flash_truth.json with each fin's volume and root
/// polyline in {C} and {W}); then loads cell.xml with MuJoCo to prove it compiles.
/// @throws IoError (cannot write), InputError (MuJoCo rejects it).
CellFiles write_cell(const RobotModel& robot, const CellSpec& spec, const Casting& casting,
                     const std::string& dir);

/// Writes DIR/<name>.xml: the cell of write_cell (which must have written DIR before: the nominal
/// mesh is reused) with the casting's flash replaced by `flash_C` (in {C}; empty: no flash),
/// saved as DIR/meshes/<name>_flash.stl. Used for the "after grinding" renders. Returns the path.
/// @throws IoError, InputError (MuJoCo rejects it).
std::string write_cell_variant(const RobotModel& robot, const CellSpec& spec,
                               const TriangleMesh& nominal, const TriangleMesh& flash_C,
                               const std::string& dir, const std::string& name);

/// Writes the ground truth of a casting placed at X_WC into `dir`: fins.stl ({C}) and
/// flash_truth.json (fin kinds, volumes, root polylines in {C}, X_WC). Scoring only.
void write_ground_truth(const Casting& casting, const Pose& X_WC, const std::string& dir);

/// The pose of {C} in {W} that rests the casting on the table top: given the position (x, y)
/// on the table [m] and an orientation R_TC relative to the table frame, z is chosen so the
/// lowest point of the rotated casting touches the table.
Pose rest_on_table(const CellSpec& spec, const TriangleMesh& nominal, double x, double y,
                   const Mat3& R_TC);

/// Compiles an MJCF file with MuJoCo. @throws InputError with MuJoCo's message.
ModelSummary check_mjcf(const std::string& path);

}  // namespace flashtwin::sim
