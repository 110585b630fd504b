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

ArcFit fit_arc(const std::vector<Vec3>& points, const Vec3& axis, const std::vector<Vec3>& normals) {
  ArcFit f;
  const std::size_t n = points.size();
  if (n < 3 || !(axis.norm() > 0)) return f;
  f.w = axis.normalized();
  f.u = f.w.unitOrthogonal();
  f.v = f.w.cross(f.u);
  // x² + y² + D x + E y + F = 0 in least squares.
  Eigen::MatrixXd A(n, 3);
  Eigen::VectorXd b(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double x = f.u.dot(points[i]), y = f.v.dot(points[i]);
    A(i, 0) = x;
    A(i, 1) = y;
    A(i, 2) = 1;
    b(i) = -(x * x + y * y);
  }
  const Eigen::Vector3d s = A.colPivHouseholderQr().solve(b);
  f.cu = -s(0) / 2;
  f.cv = -s(1) / 2;
  const double r2 = f.cu * f.cu + f.cv * f.cv - s(2);
  if (!(r2 > 0) || !std::isfinite(r2)) return f;
  f.radius = std::sqrt(r2);
  double res2 = 0, facing = 0;
  f.angle.resize(n);
  for (std::size_t i = 0; i < n; ++i) {
    const double x = f.u.dot(points[i]) - f.cu, y = f.v.dot(points[i]) - f.cv;
    const double d = std::hypot(x, y) - f.radius;
    res2 += d * d;
    f.angle[i] = std::atan2(y, x);
    if (i > 0) f.swept += std::remainder(f.angle[i] - f.angle[i - 1], 2 * M_PI);
    if (normals.size() == n && std::hypot(x, y) > 0)
      facing += normals[i].dot(-(x * f.u + y * f.v) / std::hypot(x, y));
  }
  f.rms = std::sqrt(res2 / static_cast<double>(n));
  f.facing = normals.size() == n ? facing / static_cast<double>(n) : 0.0;
  f.ok = true;
  return f;
}

}  // namespace flashtwin
