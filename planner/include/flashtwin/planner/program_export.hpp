#pragma once
// Robot programs from a timed trajectory: KUKA KRL (.src) and Universal Robots URScript, and
// parsers that read them back (to check them, and to import programs written by this module).
//
// Frames: the program's tool frame is {T} in the flange {E} (X_ET; KRL $TOOL, UR set_tcp); its
// work frame is {W} in the robot base {B} (X_BW; KRL $BASE, UR variable `base_frame`); Cartesian
// targets are X_WT, the tool in the work frame. Joint values are the D-H angles mapped to the
// controller's axes by value = sign·q + offset (identity by default).
#include <array>
#include <cmath>
#include <cstddef>
#include <optional>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/planner/timing.hpp"

namespace flashtwin::planner {

/// KUKA frame: position [mm] and angles [deg] with R = Rz(A)·Ry(B)·Rx(C).
struct KukaFrame {
  double x = 0, y = 0, z = 0;  ///< [mm]
  double a = 0, b = 0, c = 0;  ///< [deg], A and C in (-180, 180], B in [-90, 90]
};

/// KUKA frame of a pose (metres to millimetres). At B = ±90° (gimbal lock) C is set to 0.
KukaFrame kuka_frame_from_pose(const Pose& X);
/// Pose of a KUKA frame.
Pose pose_from_kuka_frame(const KukaFrame& f);

/// UR pose p[x, y, z, rx, ry, rz]: position [m] and rotation vector (axis·angle) [rad].
using UrPose = std::array<double, 6>;
/// UR pose of a pose; the rotation vector's angle is in [0, π].
UrPose ur_pose_from_pose(const Pose& X);
/// Pose of a UR pose.
Pose pose_from_ur_pose(const UrPose& p);

enum class ProgramDialect { kKrl, kUrScript, kRapid };

/// How the points are moved through.
enum class ProgramMotion {
  kLinear,  ///< Cartesian straight lines with blending: KRL LIN ... C_DIS, UR movel(..., r=)
  kSpline,  ///< Cartesian spline/process move: KRL SPLINE block of SPL, UR movep
  kJoint,   ///< joint moves with blending: KRL PTP {A1..A6} C_PTP, UR movej([...], r=)
  kServo,   ///< UR servoj at the point period (URScript only)
};

/// Options of the program export (one struct for both dialects; each uses what applies).
struct ProgramParams {
  ProgramDialect dialect = ProgramDialect::kKrl;
  ProgramMotion motion = ProgramMotion::kLinear;
  /// Program name: a letter then letters, digits or '_', at most 24 characters (KRL's limit).
  std::string name = "flashtwin_path";
  std::optional<Pose> X_ET;      ///< tool frame {T} in the flange {E}; robot.tool.X_ET when unset
  Pose X_BW = Pose::Identity();  ///< work frame {W} in the robot base {B}
  /// Distance along the path between exported points [m] (decimation by path length).
  double point_spacing = 0.002;
  /// When > 0, decimate by time instead: a point every round(time_step / dt) samples [s].
  double time_step = 0.0;
  /// Linear and spline motions: a target is added wherever the straight moves between targets
  /// would leave the planned TCP path by more than this (0: spacing alone) [m].
  double chord_tolerance = 2e-5;
  /// ... or turn the tool more than this away from the planned orientation [rad] (0.2°).
  double angle_tolerance = 0.2 * M_PI / 180;
  double blend_radius = 0.0005;  ///< approximation (KRL $APO.CDIS) / UR blend radius r [m]
  /// Programmed speeds below this are raised to it [m/s]. Each move is programmed at the plan's
  /// pace between its targets (chord / time, and the tool's turn / time as the orientation
  /// speed where the dialect states one: KRL $VEL.ORI1/2, RAPID v_ori).
  double min_speed = 1e-5;
  /// KRL: a new $VEL.CP is programmed when the speed changes by more than this fraction [-].
  double speed_change = 0.02;
  /// Controller axis = sign·q + offset; program_params_for(robot) takes the robot
  /// description's `controller:` mapping.
  Vector6 joint_sign = Vector6::Ones();
  Vector6 joint_offset = Vector6::Zero();  ///< [rad]
  /// Speed of the joint move to the first point, as a fraction of each joint's limit [-].
  double approach_speed = 0.2;
  double servo_lookahead = 0.1;  ///< UR servoj lookahead_time, 0.03 to 0.2 [s]
  double servo_gain = 300;       ///< UR servoj gain, 100 to 2000 [-]
};

/// Default options for `robot`: its controller's axis convention and language
/// (robot.controller).
ProgramParams program_params_for(const RobotModel& robot);

/// A program as text, with the trajectory sample behind each motion instruction.
struct RobotProgram {
  ProgramDialect dialect = ProgramDialect::kKrl;
  std::string name;
  std::string text;
  /// Trajectory sample index of each motion instruction, in program order; the first is the
  /// joint move to the start (sample 0).
  std::vector<std::size_t> samples;
};

/// Writes the trajectory as a robot program. Cartesian targets are fk_flange(q)·X_ET in {W}.
/// @throws ArgumentError when the trajectory is empty or inconsistent, the name is not a valid
/// identifier, a parameter is out of range, or kServo is asked of KRL.
RobotProgram export_program(const RobotModel& robot, const JointTrajectory& trajectory,
                            const ProgramParams& params = {});

/// Writes program.text to `path`. @throws IoError when the file cannot be written.
void write_program(const RobotProgram& program, const std::string& path);

/// File extension of a dialect's programs: ".src" (KRL), ".script" (URScript), ".mod" (RAPID).
std::string program_extension(ProgramDialect dialect);

/// Exports the trajectory with `params` and writes it to DIR/<params.name><extension>; returns
/// the file's path. @throws as export_program and write_program.
std::string export_program_file(const RobotModel& robot, const JointTrajectory& trajectory,
                                const ProgramParams& params, const std::string& dir);

/// One motion instruction read back from a program.
struct ProgramPoint {
  bool cartesian = false;        ///< target is a pose (else joint values)
  Pose X_WT = Pose::Identity();  ///< Cartesian target: tool {T} in the work frame {W}
  Vector6 q = Vector6::Zero();   ///< joint target in D-H angles [rad] (sign/offset undone)
  double speed = 0;              ///< programmed speed: [m/s] Cartesian, [rad/s] UR movej; 0 if none
  double period = 0;             ///< UR servoj time t [s]; 0 otherwise
  /// Cartesian acceleration of the move's ramps [m/s^2]: KRL $ACC.CP, UR a=; 0 if none stated.
  double accel = 0;
  /// Bound on the tool's rotation speed [rad/s]: KRL $VEL.ORI1, RAPID speeddata v_ori; 0 if none.
  double ori_speed = 0;
  /// Bound on the tool's angular acceleration [rad/s^2]: KRL $ACC.ORI1, UR 4·a; 0 if none.
  double ori_accel = 0;
  /// Approximation (blend) radius at the target [m]: KRL $APO.CDIS on a C_DIS move, UR r=,
  /// RAPID zone (pzone_tcp or zN); 0 = an exact stop (no C_DIS, r=0, fine).
  double blend = 0;
  std::string instruction;       ///< LIN, SPL, PTP, movel, movep, movej, servoj
  int line = 0;                  ///< 1-based line number in the text
};

/// What a program declares and moves through.
struct ParsedProgram {
  std::string name;  ///< of the (first) DEF / def
  bool tool_declared = false, base_declared = false;
  Pose X_ET = Pose::Identity();  ///< declared tool frame
  Pose X_BW = Pose::Identity();  ///< declared work/base frame
  std::vector<ProgramPoint> points;
  int routines = 0;  ///< DEF ... END (def ... end) pairs
};

/// Reads a program written by export_program (and plain hand-written ones in the same subset).
/// `params` gives the dialect and the joint sign/offset to undo.
/// @throws ArgumentError naming the line when the text is malformed: unpaired DEF/END (or
/// SPLINE/ENDSPLINE), a motion outside a routine, an aggregate or pose with missing or
/// non-numeric fields.
ParsedProgram parse_program(const std::string& text, const ProgramParams& params = {});

std::string to_string(ProgramDialect dialect);

}  // namespace flashtwin::planner
