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

}  // namespace flashtwin
