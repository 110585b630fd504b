#pragma once
// Rigid transforms named by their frames (Drake's monogram style): X_AB is the pose of
// frame {B} in frame {A}; p_AQ a point Q in {A}. X_AC = X_AB * X_BC only when inner frames match.
#include <Eigen/Geometry>
#include <array>
#include <string>

namespace flashtwin {

using Vec3 = Eigen::Vector3d;
using Mat3 = Eigen::Matrix3d;
using Pose = Eigen::Isometry3d;  ///< rigid transform X_AB

/// Pose from a translation [m] and roll-pitch-yaw [rad] (R = Rz(yaw)·Ry(pitch)·Rx(roll), URDF).
Pose pose_from_xyz_rpy(const Vec3& xyz, const Vec3& rpy);

/// Roll-pitch-yaw [rad] of a rotation matrix (inverse of the URDF convention above).
Vec3 rpy_from_rotation(const Mat3& R);

/// The 16 entries of the 4x4 homogeneous matrix, row-major.
std::array<double, 16> to_row_major(const Pose& X);

/// Pose from 16 row-major numbers.
/// @throws ArgumentError naming `what` when the matrix is not a rigid transform (orthonormal
/// rotation with det +1 within `tol`, last row 0 0 0 1) or holds NaN/inf.
Pose pose_from_row_major(const std::array<double, 16>& m, const std::string& what,
                         double tol = 1e-6);

/// True when the matrix part of X is a proper rotation within `tol` and all entries are finite.
bool is_rigid(const Eigen::Matrix4d& M, double tol = 1e-6);

/// Angle [rad] of the relative rotation between two poses' rotations.
double rotation_distance(const Mat3& R_a, const Mat3& R_b);

/// Rotation matrix orthonormalised by SVD (nearest proper rotation).
Mat3 nearest_rotation(const Mat3& M);

/// "w x y z" quaternion text with full double precision (MJCF `quat` attribute).
std::string quat_wxyz_string(const Mat3& R);

/// A double as text with full precision (%.17g): round-trips exactly through files.
std::string exact_number(double v);

/// "x y z" text with full double precision.
std::string vec3_string(const Vec3& v);

/// A circle fitted to points of a curve, in the plane across `axis` (Kåsa algebraic fit).
struct ArcFit {
  bool ok = false;               ///< false: fewer than 3 points or degenerate (collinear)
  Vec3 u = Vec3::UnitX(), v = Vec3::UnitY(), w = Vec3::UnitZ();  ///< plane basis, w = axis
  double cu = 0, cv = 0;         ///< centre in (u, v) [m]
  double radius = 0;             ///< [m]
  double rms = 0;                ///< RMS radial residual [m]
  double swept = 0;              ///< signed angle swept from the first to the last point [rad]
  double facing = 0;             ///< mean of normal · (unit vector to the centre); 1: a hole
                                 ///< wall facing the centre, −1: an outer contour (needs normals)
  std::vector<double> angle;     ///< polar angle of each point [rad]
  Vec3 point(double a, double height) const {  ///< the circle's point at angle a, height along w
    return (cu + radius * std::cos(a)) * u + (cv + radius * std::sin(a)) * v + height * w;
  }
};
/// Fits a circle to ordered points (across `axis`); `normals` (optional, same length) give
/// ArcFit::facing.
ArcFit fit_arc(const std::vector<Vec3>& points, const Vec3& axis,
               const std::vector<Vec3>& normals = {});

}  // namespace flashtwin
