#pragma once
// Analytic inverse kinematics, all up to 8 solutions, of the two arm types industrial grinding
// cells use: spherical-wrist arms (PUMA/OPW type: KUKA, ABB, FANUC, the FT6) and offset-wrist
// arms (Universal Robots type).
#include <optional>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"

namespace flashtwin::planner {

/// Which of the 8 branches a solution is on.
struct IkBranch {
  bool front = true;     ///< wrist centre in front of the shoulder (else reaching over the back)
  bool elbow_up = true;  ///< elbow above the shoulder–wrist line
  bool flip = false;     ///< wrist flipped (θ5 < 0)
  /// Index 0..7 (front=0/back=4 + elbow up=0/down=2 + noflip=0/flip=1).
  int index() const { return (front ? 0 : 4) + (elbow_up ? 0 : 2) + (flip ? 1 : 0); }
  /// e.g. "front/up/noflip".
  std::string name() const;
};

/// One IK solution.
struct IkSolution {
  Vector6 q;
  IkBranch branch;
};

enum class IkStatus {
  kOk,                     ///< at least one solution within the joint limits
  kUnreachable,            ///< no solution at all (pose out of reach)
  kOutsideLimits,          ///< solutions exist, none within the joint limits
  kUnsupportedGeometry,    ///< the D-H table is of neither type the solvers handle
};

/// Options of the IK solver.
struct IkParams {
  /// Drop solutions outside the joint position limits (true) or return them all (false).
  bool within_limits_only = true;
  /// Reference configuration: each joint's 2π-equivalent nearest to it is chosen, and at a
  /// wrist singularity θ4 keeps its reference value. Without it, the nearest to 0.
  std::optional<Vector6> q_ref;
  /// |sin θ5| below which the wrist counts as singular [-].
  double wrist_tol = 1e-9;
  /// Distance [m] below which the wrist centre counts as on the shoulder singular surface;
  /// also the slack for poses at the edge of the reach.
  double length_tol = 1e-9;
  /// |sin ψ| below which the elbow counts as stretched/folded (singular) [-]. ψ comes from an
  /// acos, which turns round-off ε into sqrt(2ε) ≈ 1e-8 at the singularity: hence 1e-7.
  double elbow_tol = 1e-7;
};

/// What the solver found, including why there is no solution.
struct IkResult {
  IkStatus status = IkStatus::kUnreachable;
  std::vector<IkSolution> solutions;  ///< distinct branches, sorted by branch index
  int discarded_by_limits = 0;        ///< solutions dropped for the joint limits
  bool wrist_singular = false;        ///< θ4 and θ6 not unique (θ4 held at the reference)
  bool shoulder_singular = false;     ///< front and back branches coincide
  bool elbow_singular = false;        ///< elbow up and down coincide (arm stretched/folded)
  std::string message;                ///< human-readable account of the above
  bool ok() const { return status == IkStatus::kOk; }
};

/// True when one of the analytic solvers handles the D-H table.
bool ik_supported(const RobotModel& robot);

/// All IK solutions for a flange pose X_BE.
IkResult ik_flange(const RobotModel& robot, const Pose& X_BE, const IkParams& params = {});

/// All IK solutions for a tool pose X_BT (X_BE = X_BT · X_ETᵀ).
IkResult ik_tool(const RobotModel& robot, const Pose& X_BT, const IkParams& params = {});

std::string to_string(IkStatus s);

}  // namespace flashtwin::planner
