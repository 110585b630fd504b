#include "flashtwin/core/transform.hpp"

#include <Eigen/SVD>
#include <algorithm>
#include <cmath>
#include <cstdio>

#include "flashtwin/core/errors.hpp"

namespace flashtwin {

Pose pose_from_xyz_rpy(const Vec3& xyz, const Vec3& rpy) {
  Pose X = Pose::Identity();
  X.linear() = (Eigen::AngleAxisd(rpy.z(), Vec3::UnitZ()) *
                Eigen::AngleAxisd(rpy.y(), Vec3::UnitY()) *
                Eigen::AngleAxisd(rpy.x(), Vec3::UnitX()))
                   .toRotationMatrix();
  X.translation() = xyz;
  return X;
}

Vec3 rpy_from_rotation(const Mat3& R) {
  // Pitch from -R(2,0); near pitch = ±90° roll and yaw are coupled: put it all in yaw.
  const double sp = std::clamp(-R(2, 0), -1.0, 1.0);
  const double pitch = std::asin(sp);
  if (std::abs(sp) > 1.0 - 1e-12) {
    const double yaw = std::atan2(-R(0, 1), R(1, 1));
    return {0.0, pitch, yaw};
  }
  return {std::atan2(R(2, 1), R(2, 2)), pitch, std::atan2(R(1, 0), R(0, 0))};
}

std::array<double, 16> to_row_major(const Pose& X) {
  std::array<double, 16> m{};
  const Eigen::Matrix4d M = X.matrix();
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) m[4 * r + c] = M(r, c);
  return m;
}

bool is_rigid(const Eigen::Matrix4d& M, double tol) {
  if (!M.allFinite()) return false;
  if (std::abs(M(3, 0)) > tol || std::abs(M(3, 1)) > tol || std::abs(M(3, 2)) > tol ||
      std::abs(M(3, 3) - 1.0) > tol)
    return false;
  const Mat3 R = M.topLeftCorner<3, 3>();
  if ((R.transpose() * R - Mat3::Identity()).cwiseAbs().maxCoeff() > tol) return false;
  return std::abs(R.determinant() - 1.0) <= tol;
}

Pose pose_from_row_major(const std::array<double, 16>& m, const std::string& what, double tol) {
  Eigen::Matrix4d M;
  for (int r = 0; r < 4; ++r)
    for (int c = 0; c < 4; ++c) M(r, c) = m[4 * r + c];
  if (!M.allFinite()) throw ArgumentError(what + ": expected finite numbers, got NaN or inf");
  if (!is_rigid(M, tol))
    throw ArgumentError(what +
                        ": expected a rigid transform (orthonormal rotation, det +1, last row "
                        "0 0 0 1), got a matrix that is not");
  Pose X = Pose::Identity();
  // Re-orthonormalise so that text round-off does not leak into later products.
  X.linear() = nearest_rotation(M.topLeftCorner<3, 3>());
  X.translation() = M.topRightCorner<3, 1>();
  return X;
}

double rotation_distance(const Mat3& R_a, const Mat3& R_b) {
  const Mat3 R = R_a.transpose() * R_b;
  // atan2 form stays accurate near 0 and pi, unlike acos((tr-1)/2).
  const Vec3 w(R(2, 1) - R(1, 2), R(0, 2) - R(2, 0), R(1, 0) - R(0, 1));
  return std::atan2(0.5 * w.norm(), 0.5 * (R.trace() - 1.0));
}

Mat3 nearest_rotation(const Mat3& M) {
  Eigen::JacobiSVD<Mat3> svd(M, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Mat3 D = Mat3::Identity();
  D(2, 2) = (svd.matrixU() * svd.matrixV().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixU() * D * svd.matrixV().transpose();
}

std::string quat_wxyz_string(const Mat3& R) {
  Eigen::Quaterniond q(R);
  q.normalize();
  char buf[128];
  std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g %.17g", q.w(), q.x(), q.y(), q.z());
  return buf;
}

std::string exact_number(double v) {
  char buf[40];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

std::string vec3_string(const Vec3& v) {
  char buf[96];
  std::snprintf(buf, sizeof buf, "%.17g %.17g %.17g", v.x(), v.y(), v.z());
  return buf;
}

}  // namespace flashtwin
