#include <gtest/gtest.h>

#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/planner/program_replay.hpp"
#include "flashtwin/planner/timing.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

// Distance from p to the polyline through pts.
double polyline_distance(const Vec3& p, const std::vector<Vec3>& pts) {
  double best = 1e300;
  for (std::size_t i = 1; i < pts.size(); ++i) {
    const Vec3 d = pts[i] - pts[i - 1];
    const double u = std::clamp(d.dot(p - pts[i - 1]) / std::max(d.squaredNorm(), 1e-30), 0.0, 1.0);
    best = std::min(best, (pts[i - 1] + u * d - p).norm());
  }
  return best;
}

// A planned grinding-like motion: the TCP runs 3/4 of a 20 mm circle (a hole ring) while the
// tool leans 10° towards the centre and turns with the tangent, timed at 30 mm/s.
struct Circle {
  RobotModel robot = ftest::ft6();
  JointTrajectory traj;
  std::vector<Vec3> tcp_B;  // planned TCP per sample

  Circle() {
    Vector6 seed;
    seed << 0.1, -1.0, 0.5, 0.0, 1.0, 0.0;
    const Pose X0 = fk_tool(robot, seed);
    const Vec3 centre = X0.translation() - 0.02 * X0.linear().col(0);
    std::vector<double> s;
    std::vector<Vector6> q;
    Vector6 prev = seed;
    for (int i = 0; i <= 400; ++i) {
      const double a = 1.5 * M_PI * i / 400;
      Pose X = X0;
      X.translation() = centre + 0.02 * (X0.linear() * Vec3(std::cos(a), std::sin(a), 0));
      X.linear() = X0.linear() * Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix() *
                   Eigen::AngleAxisd(0.17, Vec3::UnitY()).toRotationMatrix();
      IkParams ip;
      ip.q_ref = prev;
      const IkResult res = ik_tool(robot, X, ip);
      EXPECT_TRUE(res.ok()) << res.message;
      double best = 1e9;
      for (const auto& sol : res.solutions)
        if ((sol.q - prev).cwiseAbs().maxCoeff() < best) {
          best = (sol.q - prev).cwiseAbs().maxCoeff();
          prev = sol.q;
        }
      q.push_back(prev);
      s.push_back(0.02 * a);
    }
    TimingParams tp;
    tp.feed = 0.03;
    const TimingResult tr = time_parametrize(robot, s, q, tp);
    EXPECT_TRUE(tr.ok()) << tr.message;
    traj = tr.trajectory;
    for (const auto& qi : traj.q) tcp_B.push_back(fk_tool(robot, qi).translation());
  }
};

class ReplayDialect : public ::testing::TestWithParam<ProgramDialect> {};

// The written program, read back and interpolated as its controller would, moves the tool along
// the planned path (within the blend radius at the targets' corners), ends where the plan ends,
// takes about the plan's time and stays within the arm's joint limits.
TEST_P(ReplayDialect, FollowsThePlannedPath) {
  const Circle c;
  ProgramParams P = program_params_for(c.robot);
  P.dialect = GetParam();
  const RobotProgram prog = export_program(c.robot, c.traj, P);
  const ParsedProgram parsed = parse_program(prog.text, P);
  const ReplayedProgram r = replay_program(c.robot, parsed);
  const auto& tr = r.trajectory;
  ASSERT_GT(tr.size(), 100u);
  EXPECT_LT((tr.q.front() - c.traj.q.front()).cwiseAbs().maxCoeff(), 1e-6);
  double worst = 0, worst_rot = 0;
  for (std::size_t k = 0; k < tr.size(); ++k) {
    worst = std::max(worst, polyline_distance(r.X_BT[k].translation(), c.tcp_B));
    // The joint motion realises the commanded pose.
    const Pose X = fk_tool(c.robot, tr.q[k]);
    worst_rot = std::max(worst_rot, rotation_distance(X.linear(), r.X_BT[k].linear()));
    EXPECT_LT((X.translation() - r.X_BT[k].translation()).norm(), 1e-9);
  }
  // The targets stand close enough for the straight moves between them to stay within the
  // chordal tolerance of the planned path (2 mm chords of this 20 mm circle would sag 25 µm);
  // the blends round the corners inwards, towards the circle.
  EXPECT_LT(worst, 1.25 * P.chord_tolerance);
  EXPECT_LT(worst_rot, 1e-9);
  const Vec3 end = fk_tool(c.robot, tr.q.back()).translation();
  EXPECT_LT((end - c.tcp_B.back()).norm(), 1e-5);
  EXPECT_NEAR(r.path_length, c.traj.s.back() - c.traj.s.front(), 0.02 * c.traj.s.back());
  // Each move is programmed at the plan's pace between its targets: the controller takes the
  // plan's time, a little more for its ramps at each end.
  EXPECT_GT(tr.duration(), 0.98 * c.traj.duration());
  EXPECT_LT(tr.duration(), 1.06 * c.traj.duration());
  EXPECT_LE(r.max_joint_velocity_ratio, 1.0);
  EXPECT_LT(tr.dq.back().norm(), 0.05);  // at rest at the end
}

INSTANTIATE_TEST_SUITE_P(Dialects, ReplayDialect,
                         ::testing::Values(ProgramDialect::kKrl, ProgramDialect::kUrScript,
                                           ProgramDialect::kRapid));

// A hand-written KRL program: a 200 mm straight move at 0.1 m/s with $ACC.CP = 1 takes
// L/v + v/a = 2.1 s (trapezoid), and a 90° corner with a 5 mm approximation distance is cut at
// 0.354 x 5 mm from the corner (the quadratic blend's middle), never more than 5 mm.
TEST(Replay, TrapezoidTimingAndCornerBlend) {
  const RobotModel robot = ftest::ft6();
  Vector6 q0;
  q0 << 0.0, -1.0, 0.5, 0.0, 1.0, 0.0;
  const Pose X0 = fk_tool(robot, q0);
  const auto frame = [](const Pose& X) {
    const KukaFrame f = kuka_frame_from_pose(X);
    return "{X " + std::to_string(f.x) + ", Y " + std::to_string(f.y) + ", Z " +
           std::to_string(f.z) + ", A " + std::to_string(f.a) + ", B " + std::to_string(f.b) +
           ", C " + std::to_string(f.c) + "}";
  };
  std::string axes = "{";
  for (int j = 0; j < 6; ++j)
    axes += (j ? ", A" : "A") + std::to_string(j + 1) + " " + std::to_string(q0[j] * 180 / M_PI);
  axes += "}";
  Pose X1 = X0, X2 = X0;
  X1.translation() += Vec3(0.0, 0.2, 0.0);
  X2.translation() = X1.translation() + Vec3(0.0, 0.0, 0.1);
  const std::string head = "DEF t( )\n  $ACC.CP = 1.0\n  $APO.CDIS = 5\n  $VEL.CP = 0.1\n  PTP " + axes + "\n";
  {
    const ParsedProgram p = parse_program(head + "  LIN " + frame(X1) + "\nEND\n");
    const ReplayedProgram r = replay_program(robot, p);
    EXPECT_NEAR(r.trajectory.duration(), 2.1, 2e-3);
    EXPECT_NEAR(r.path_length, 0.2, 1e-6);
    double vmax = 0;
    for (double v : r.trajectory.sdot) vmax = std::max(vmax, v);
    EXPECT_NEAR(vmax, 0.1, 1e-3);
  }
  {
    const ParsedProgram p = parse_program(head + "  LIN " + frame(X1) + " C_DIS\n  LIN " + frame(X2) + "\nEND\n");
    ASSERT_EQ(p.points.size(), 3u);
    EXPECT_NEAR(p.points[1].blend, 0.005, 1e-12);
    EXPECT_EQ(p.points[2].blend, 0.0);
    EXPECT_NEAR(p.points[1].accel, 1.0, 1e-12);
    const ReplayedProgram r = replay_program(robot, p);
    double closest = 1e9;
    for (const Pose& X : r.X_BT) {
      closest = std::min(closest, (X.translation() - X1.translation()).norm());
      EXPECT_LT(polyline_distance(X.translation(), {X0.translation(), X1.translation(), X2.translation()}), 0.005);
    }
    EXPECT_NEAR(closest, 0.25 * std::sqrt(2.0) * 0.005, 1e-5);
    // No stop at the corner: the blend keeps the speed up (the exact stop would take 0.1 s more).
    EXPECT_LT(r.trajectory.duration(), 0.3 / 0.1 + 0.1 / 1.0 + 0.05);
  }
  // A program that does not start with a joint move, a joint move after the start, and a target
  // out of reach are refused with the line.
  const auto message = [&](const std::string& text) {
    try {
      replay_program(robot, parse_program(text));
    } catch (const ArgumentError& e) {
      return std::string(e.what());
    }
    return std::string("no error");
  };
  EXPECT_NE(message("DEF t( )\n  $VEL.CP = 0.1\n  LIN " + frame(X1) + "\nEND\n").find("line 3"),
            std::string::npos);
  EXPECT_NE(message(head + "  PTP " + axes + "\nEND\n").find("line 6: expected a Cartesian move"),
            std::string::npos);
  Pose far = X0;
  far.translation() += Vec3(5.0, 0, 0);
  EXPECT_NE(message(head + "  LIN " + frame(far) + "\nEND\n").find("line 6: expected a reachable"),
            std::string::npos);
}

}  // namespace
