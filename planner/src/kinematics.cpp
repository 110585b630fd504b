#include "flashtwin/planner/kinematics.hpp"

#include <algorithm>
#include <cmath>

namespace flashtwin::planner {

Pose dh_link(const DhRow& row, double theta) {
  const double ct = std::cos(theta), st = std::sin(theta);
  const double ca = std::cos(row.alpha), sa = std::sin(row.alpha);
  Eigen::Matrix4d M;
  M << ct, -st * ca, st * sa, row.a * ct,  //
      st, ct * ca, -ct * sa, row.a * st,   //
      0, sa, ca, row.d,                    //
      0, 0, 0, 1;
  Pose X;
  X.matrix() = M;
  return X;
}

std::array<Pose, kNumJoints + 1> fk_frames(const RobotModel& robot, const Vector6& q) {
  std::array<Pose, kNumJoints + 1> X;
  X[0] = Pose::Identity();
  for (int i = 0; i < kNumJoints; ++i) X[i + 1] = X[i] * dh_link(robot.dh[i], q[i]);
  return X;
}

Pose fk_flange(const RobotModel& robot, const Vector6& q) {
  Pose X = Pose::Identity();
  for (int i = 0; i < kNumJoints; ++i) X = X * dh_link(robot.dh[i], q[i]);
  return X;
}

Pose fk_tool(const RobotModel& robot, const Vector6& q) {
  return fk_flange(robot, q) * robot.tool.X_ET;
}

Matrix6 jacobian(const RobotModel& robot, const Vector6& q, const Pose& X_EP,
                 JacobianFrame frame) {
  const auto X = fk_frames(robot, q);
  const Pose X_BP = X[kNumJoints] * X_EP;
  const Vec3 p_BP = X_BP.translation();
  Matrix6 J;
  // Joint i+1 turns about z of frame {i}, through that frame's origin.
  for (int i = 0; i < kNumJoints; ++i) {
    const Vec3 z = X[i].linear().col(2);
    const Vec3 o = X[i].translation();
    J.block<3, 1>(0, i) = z.cross(p_BP - o);
    J.block<3, 1>(3, i) = z;
  }
  if (frame == JacobianFrame::kTool) {
    const Mat3 R_PB = X_BP.linear().transpose();
    J.topRows<3>() = R_PB * J.topRows<3>();
    J.bottomRows<3>() = R_PB * J.bottomRows<3>();
  }
  return J;
}

double manipulability(const RobotModel& robot, const Vector6& q) {
  return std::abs(jacobian(robot, q, Pose::Identity()).determinant());
}

SingularityReport check_singularity(const RobotModel& robot, const Vector6& q, double threshold) {
  SingularityReport r;
  r.manipulability = manipulability(robot, q);
  r.wrist = std::abs(std::sin(q[4]));
  const auto X = fk_frames(robot, q);
  if (arm_geometry(robot) == ArmGeometry::kOffsetWrist) {
    // Joints 2–4 parallel: the elbow is singular when the two links a2, a3 line up; the
    // shoulder when frame {5}'s origin comes within the lateral offset of joint 1's axis.
    r.elbow = std::abs(std::sin(q[2]));
    const Vec3 p5 = X[5].translation();
    const double dl = robot.dh[1].d + robot.dh[2].d + robot.dh[3].d;
    r.shoulder = std::sqrt(std::max(0.0, p5.head<2>().squaredNorm() - dl * dl));
  } else {
    // Elbow: angle psi between the upper arm and the shoulder-wrist "virtual forearm".
    const double a3 = robot.dh[2].a, d4 = robot.dh[3].d;
    r.elbow = std::abs(std::sin(q[2] + std::atan2(d4, a3)));
    // Shoulder: the wrist centre's coordinate along x1 (it is zero on the singular surface).
    const Vec3 p_1w = X[1].inverse() * X[4].translation();
    r.shoulder = std::abs(p_1w.x());
  }
  r.singular = r.manipulability < threshold;
  return r;
}

}  // namespace flashtwin::planner
