#pragma once
// The robot description: one file under models/robots/ (YAML) holds the standard D-H table,
// joint limits, link inertias and the tool transform; URDF and MJCF are generated from it.
#include <array>
#include <string>

#include "flashtwin/core/transform.hpp"

namespace flashtwin {

constexpr int kNumJoints = 6;
using Vector6 = Eigen::Matrix<double, 6, 1>;
using Matrix6 = Eigen::Matrix<double, 6, 6>;

/// One row of the standard D-H table; link transform Rot_z(θ)·Trans_z(d)·Trans_x(a)·Rot_x(α).
struct DhRow {
  double alpha = 0;  ///< [rad]
  double a = 0;      ///< [m]
  double d = 0;      ///< [m]
};

/// Limits of one revolute joint.
struct JointLimits {
  double lower = 0, upper = 0;  ///< position [rad]
  double velocity = 0;          ///< [rad/s]
  double acceleration = 0;      ///< [rad/s^2]
  double torque = 0;            ///< [N·m]
  /// True when lower <= q <= upper (inclusive, `tol` [rad] slack).
  bool contains(double q, double tol = 0) const { return q >= lower - tol && q <= upper + tol; }
};

/// Mass properties of a rigid body, expressed in the body's own frame.
struct Inertial {
  double mass = 0;                    ///< [kg]
  Vec3 com = Vec3::Zero();            ///< centre of mass [m]
  Vec3 inertia = Vec3::Zero();        ///< principal moments about the COM, frame-aligned [kg·m^2]
};

/// The tool (spindle + grinding burr/disc) fixed to the flange.
struct ToolDescription {
  std::string name = "tool";
  Pose X_ET = Pose::Identity();  ///< tool frame {T} in flange frame {E}
  Inertial inertial;             ///< in the flange frame {E}
  double radius = 0.005;         ///< cutting radius of the burr/disc [m]
  double length = 0.02;          ///< cutting length along the tool axis [m]
  /// The slim end of the tool between the spindle body and the burr, along the tool axis from
  /// the burr up: the burr's exposed shank, then the collet nut. Defaults: a long-shank carbide
  /// burr (6 mm shank; such burrs come 100–150 mm overall, standard ones 50–70 mm) standing
  /// 40 mm out of a straight die grinder's collet nut of 25 mm diameter and 45 mm length: the
  /// collet clears walls up to 60 mm above the fin with the shank upright beside them (a 25 mm
  /// shank let the collet touch the default plate's 54 mm ribs). The spindle body (radius
  /// kSpindleRadius in the cell) takes the rest up to the flange.
  double shank_radius = 0.003;   ///< [m]
  double shank_length = 0.040;   ///< [m] exposed, from the burr's end to the collet
  double collet_radius = 0.0125; ///< [m]
  double collet_length = 0.045;  ///< [m]
  /// A smaller burr from the cell's tool rack stands in a slim extension holder instead of the
  /// collet nut (same length): an ER11 mini collet nut, 16 mm in diameter (DIN 6499 ER11, the
  /// "M" nut), on an extension of that diameter. With the 25 mm nut the collet stood up to 3 mm
  /// into the housing's walls, 6 mm beside its bolt holes, all round the holes (seeds 601-608).
  double rack_collet_radius = 0.008;  ///< [m]
};

/// The robot's own controller: how it counts its axes (what a KRL PTP, RAPID MoveAbsJ or
/// URScript movej takes): A_i = sign_i·θ_i + offset_i, with the vendor's zero position and
/// directions; and the language its programs are written in.
struct Controller {
  Vector6 sign = Vector6::Ones();     ///< ±1
  Vector6 offset = Vector6::Zero();   ///< [rad]
  /// "krl" (KUKA), "rapid" (ABB), "urscript" (Universal Robots) or "none" (no exporter for it:
  /// the trajectory CSV carries the motion).
  std::string language = "krl";

  /// The controller's axis values of D-H angles q.
  Vector6 axes(const Vector6& q) const { return sign.cwiseProduct(q) + offset; }
  /// The D-H angles of the controller's axis values a.
  Vector6 joints(const Vector6& a) const { return (a - offset).cwiseQuotient(sign); }
};

/// Radii [m] of the cylinders drawn along each link's D-H offsets (links 1..6), in the URDF's
/// visuals and the cell's MJCF.
constexpr std::array<double, kNumJoints> kLinkDrawRadii{0.08, 0.07, 0.06, 0.05, 0.045, 0.04};

/// Immutable robot description (Model apart from Data: no state in here).
struct RobotModel {
  std::string name;
  std::string source;  ///< file it was read from
  std::array<DhRow, kNumJoints> dh;
  std::array<JointLimits, kNumJoints> limits;
  /// Link i's inertial in D-H frame {i} (index 0 is link 1).
  std::array<Inertial, kNumJoints> links;
  Inertial base;  ///< the fixed base link, in frame {0}={B}
  ToolDescription tool;
  Vector6 home = Vector6::Zero();  ///< parking configuration [rad] (MJCF keyframe `home`)
  Controller controller;           ///< its controller's axis convention and language (YAML `controller:`)
  /// The twin's position servos for this arm (YAML `servo: {kp, damping}`): stiffness
  /// [N·m/rad] and joint damping [N·m·s/rad] per joint; unset (0): the cell's defaults, tuned
  /// for the FT6. A model of the drives, not a vendor figure.
  std::array<double, kNumJoints> servo_kp{};
  std::array<double, kNumJoints> servo_damping{};

  Vector6 lower() const;
  Vector6 upper() const;
  /// True when every joint is within its position range (with `tol` [rad] slack).
  bool within_limits(const Vector6& q, double tol = 0) const;
};

/// Which closed-form solver an arm's D-H table admits.
enum class ArmGeometry {
  /// α = −π/2, 0, −π/2, π/2, −π/2, 0; a4 = a5 = a6 = 0, d5 = 0 (axes 4–6 meet in the wrist
  /// centre); d1, a1, d2 + d3 (lateral offset), a2 ≠ 0, a3, d4, d6 free. Covers the OPW
  /// parameters (Brandstötter et al., 2014) of KUKA, ABB and FANUC arms.
  kSphericalWrist,
  /// α = π/2, 0, 0, π/2, −π/2, 0; a4 = a5 = a6 = 0; a2, a3 ≠ 0 (joints 2–4 parallel, wrist
  /// offsets d5, d6): the Universal Robots arms.
  kOffsetWrist,
  kUnsupported,
};

/// The arm type of a D-H table (see ArmGeometry): which analytic IK applies.
ArmGeometry arm_geometry(const RobotModel& robot);

/// Reads and validates a robot description file: YAML (the project's format), or URDF when the
/// name ends in `.urdf` (robot_from_urdf).
/// @throws IoError (missing file), ConfigError (naming the field: malformed value, lower >=
/// upper, non-positive velocity/acceleration/torque/mass, inertia violating the triangle
/// inequality, unknown keys).
RobotModel load_robot(const std::string& path);

/// A robot description from URDF text (urdfdom): a serial chain of six revolute/continuous
/// joints (fixed joints anywhere), joint 1 about the root link's z axis through its origin. The
/// D-H table is derived from the joint axes (the URDF's joint zero and directions become the
/// controller's axis convention, `controller`); accelerations, absent from URDF, are the FT6's;
/// the tool is the FT6's spindle on the `tool0` (else `flange`, else the last) link.
/// @throws ConfigError naming the file and what does not fit (branching chain, prismatic joint,
/// not six joints, joint 1 off the base z axis, a D-H table neither IK solver handles, missing
/// velocity or effort limit).
RobotModel robot_from_urdf(const std::string& urdf_text, const std::string& name);

/// Parses a robot description from YAML text (`name` stands in for the file in messages).
RobotModel parse_robot(const std::string& yaml_text, const std::string& name);

/// URDF text of the arm: links base_link, link1..link6, flange (D-H frame 6, {E}), tcp (tool
/// frame {T});
/// revolute joints joint1..joint6 with the description's limits. Joint zero = D-H θ zero.
std::string robot_urdf(const RobotModel& robot);

/// The constant part of D-H link i (0-based): Trans_z(d)·Trans_x(a)·Rot_x(α).
Pose dh_constant(const DhRow& row);

}  // namespace flashtwin
