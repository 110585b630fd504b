#include <gtest/gtest.h>

#include <regex>

#include <cmath>
#include <fstream>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/planner/timing.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

constexpr double kDeg = M_PI / 180;

Mat3 rz(double a) {
  return Eigen::AngleAxisd(a, Vec3::UnitZ()).toRotationMatrix();
}
Mat3 ry(double a) {
  return Eigen::AngleAxisd(a, Vec3::UnitY()).toRotationMatrix();
}
Mat3 rx(double a) {
  return Eigen::AngleAxisd(a, Vec3::UnitX()).toRotationMatrix();
}

Pose make_pose(const Vec3& p, const Mat3& R) {
  Pose X = Pose::Identity();
  X.translation() = p;
  X.linear() = R;
  return X;
}

Mat3 random_rotation(Rng& rng) {
  Eigen::Quaterniond q(rng.normal(), rng.normal(), rng.normal(), rng.normal());
  return q.normalized().toRotationMatrix();
}

double rot_err_deg(const Mat3& a, const Mat3& b) {
  return rotation_distance(a, b) / kDeg;
}
double pos_err_mm(const Pose& a, const Pose& b) {
  return (a.translation() - b.translation()).norm() * 1000;
}

// Rounds a KUKA frame as the program text does (mm to 1e-4, deg to 1e-5).
KukaFrame printed(const KukaFrame& f) {
  const auto r = [](double v, double q) { return std::round(v / q) * q; };
  return {r(f.x, 1e-4), r(f.y, 1e-4), r(f.z, 1e-4), r(f.a, 1e-5), r(f.b, 1e-5), r(f.c, 1e-5)};
}

// A timed trajectory: the TCP moves 0.1 m along a line while the tool tilts and spins, solved by
// IK on one branch and timed at 0.05 m/s.
struct Fixture {
  RobotModel robot = ftest::ft6();
  Pose X_ET = make_pose(Vec3(0.01, -0.005, 0.21), ry(0.3) * rz(0.2));  // a tilted tool
  Pose X_BW = make_pose(Vec3(0.6, -0.1, 0.2), rz(1.0) * ry(-0.2) * rx(0.1));
  JointTrajectory traj;

  Fixture() {
    RobotModel r = robot;
    r.tool.X_ET = X_ET;
    Vector6 seed;
    seed << 0.2, -1.0, -1.9, 0.1, -1.0, 0.3;
    const Pose X0 = fk_tool(r, seed);
    std::vector<double> s;
    std::vector<Vector6> q;
    Vector6 prev = seed;
    for (int i = 0; i <= 100; ++i) {
      const double si = i * 0.001;
      Pose X = X0;
      X.translation() += Vec3(-0.2, -1.0, -0.3).normalized() * si;
      X.linear() = X0.linear() * rx(2.0 * si) * rz(6.0 * si);
      IkParams ip;
      ip.q_ref = prev;
      const IkResult res = ik_tool(r, X, ip);
      EXPECT_TRUE(res.ok()) << res.message;
      double best = 1e9;
      Vector6 nearest = prev;
      for (const auto& sol : res.solutions)
        if ((sol.q - prev).cwiseAbs().maxCoeff() < best) {
          best = (sol.q - prev).cwiseAbs().maxCoeff();
          nearest = sol.q;
        }
      prev = nearest;
      s.push_back(si);
      q.push_back(prev);
    }
    TimingParams tp;
    tp.feed = 0.05;
    const TimingResult tr = time_parametrize(robot, s, q, tp);
    EXPECT_TRUE(tr.ok()) << tr.message;
    traj = tr.trajectory;
  }

  ProgramParams params(ProgramDialect d, ProgramMotion m) const {
    ProgramParams p;
    p.dialect = d;
    p.motion = m;
    p.name = "flash_seg_07";
    p.X_ET = X_ET;
    p.X_BW = X_BW;
    return p;
  }

  Pose X_WT(std::size_t n) const { return X_BW.inverse() * fk_flange(robot, traj.q[n]) * X_ET; }
};

int count_lines_equal(const std::string& text, const std::string& line) {
  std::istringstream in(text);
  std::string l;
  int n = 0;
  while (std::getline(in, l)) n += l == line;
  return n;
}

int count_substr(const std::string& text, const std::string& needle) {
  int n = 0;
  for (auto p = text.find(needle); p != std::string::npos; p = text.find(needle, p + 1)) ++n;
  return n;
}

std::vector<std::string> lines_of(const std::string& text) {
  std::vector<std::string> out;
  std::istringstream in(text);
  std::string l;
  while (std::getline(in, l)) out.push_back(l);
  return out;
}

// The declared frames come back within print precision.
void check_frames(const ParsedProgram& pp, const Fixture& f) {
  EXPECT_TRUE(pp.tool_declared);
  EXPECT_TRUE(pp.base_declared);
  EXPECT_LT(pos_err_mm(pp.X_ET, f.X_ET), 0.01);
  EXPECT_LT(rot_err_deg(pp.X_ET.linear(), f.X_ET.linear()), 0.001);
  EXPECT_LT(pos_err_mm(pp.X_BW, f.X_BW), 0.01);
  EXPECT_LT(rot_err_deg(pp.X_BW.linear(), f.X_BW.linear()), 0.001);
}

// Each parsed point reproduces its trajectory sample: Cartesian targets against FK of the
// trajectory (also composed through the parsed frames), joint targets through FK.
void check_points(const ParsedProgram& pp, const RobotProgram& prog, const Fixture& f,
                  bool cartesian) {
  ASSERT_EQ(pp.points.size(), prog.samples.size());
  ASSERT_GE(pp.points.size(), 3u);
  EXPECT_EQ(prog.samples.front(), 0u);
  EXPECT_EQ(prog.samples.back(), f.traj.size() - 1);
  // The first motion is the joint move to the start.
  EXPECT_FALSE(pp.points[0].cartesian);
  EXPECT_LT((pp.points[0].q - f.traj.q[0]).cwiseAbs().maxCoeff(), 1e-6);
  double worst_mm = 0, worst_deg = 0;
  for (std::size_t i = 1; i < pp.points.size(); ++i) {
    const ProgramPoint& pt = pp.points[i];
    const std::size_t n = prog.samples[i];
    ASSERT_EQ(pt.cartesian, cartesian) << "point " << i;
    const Pose expected = f.X_WT(n);
    const Pose got = cartesian ? pt.X_WT : f.X_BW.inverse() * fk_flange(f.robot, pt.q) * f.X_ET;
    worst_mm = std::max(worst_mm, pos_err_mm(got, expected));
    worst_deg = std::max(worst_deg, rot_err_deg(got.linear(), expected.linear()));
    // Through the parsed frames: base · X_WT = flange · tool.
    if (cartesian) {
      const Pose lhs = pp.X_BW * pt.X_WT;
      const Pose rhs = fk_flange(f.robot, f.traj.q[n]) * pp.X_ET;
      EXPECT_LT(pos_err_mm(lhs, rhs), 0.01);
      EXPECT_LT(rot_err_deg(lhs.linear(), rhs.linear()), 0.001);
    }
  }
  EXPECT_LT(worst_mm, 0.01);
  EXPECT_LT(worst_deg, 0.001);
}

}  // namespace

TEST(KukaFrame, ConventionIsZYX) {
  // Single rotations: A about z, B about y, C about x; composed as Rz(A)·Ry(B)·Rx(C).
  const Pose Xa = pose_from_kuka_frame({0, 0, 0, 30, 0, 0});
  const Pose Xb = pose_from_kuka_frame({0, 0, 0, 0, 30, 0});
  const Pose Xc = pose_from_kuka_frame({0, 0, 0, 0, 0, 30});
  EXPECT_LT((Xa.linear() - rz(30 * kDeg)).norm(), 1e-15);
  EXPECT_LT((Xb.linear() - ry(30 * kDeg)).norm(), 1e-15);
  EXPECT_LT((Xc.linear() - rx(30 * kDeg)).norm(), 1e-15);
  const Pose X = pose_from_kuka_frame({100, -200, 300, 90, 0, 90});
  EXPECT_LT((X.linear() - rz(M_PI / 2) * rx(M_PI / 2)).norm(), 1e-15);
  EXPECT_LT((X.translation() - Vec3(0.1, -0.2, 0.3)).norm(), 1e-15);
  // Rz(90°)·Rx(90°) maps x to y and z to x.
  EXPECT_LT((X.linear() * Vec3::UnitX() - Vec3::UnitY()).norm(), 1e-15);
  EXPECT_LT((X.linear() * Vec3::UnitZ() - Vec3::UnitX()).norm(), 1e-15);
  // Known angles come back away from gimbal lock.
  const KukaFrame f = kuka_frame_from_pose(pose_from_kuka_frame({1, 2, 3, -150, 40, 170}));
  EXPECT_NEAR(f.a, -150, 1e-12);
  EXPECT_NEAR(f.b, 40, 1e-12);
  EXPECT_NEAR(f.c, 170, 1e-12);
  EXPECT_NEAR(f.x, 1, 1e-12);
  EXPECT_NEAR(f.z, 3, 1e-12);
}

TEST(KukaFrame, RoundTripIncludingGimbalLock) {
  Rng rng(11);
  double worst = 0, worst_printed = 0;
  const auto check = [&](const Pose& X) {
    const KukaFrame f = kuka_frame_from_pose(X);
    EXPECT_GT(f.a, -180.0);
    EXPECT_LE(f.a, 180.0);
    EXPECT_GE(f.b, -90.0);
    EXPECT_LE(f.b, 90.0);
    EXPECT_GT(f.c, -180.0);
    EXPECT_LE(f.c, 180.0);
    const Pose Y = pose_from_kuka_frame(f);
    worst = std::max(worst, rot_err_deg(X.linear(), Y.linear()));
    EXPECT_LT((X.translation() - Y.translation()).norm(), 1e-12);
    // As printed in a program: 1e-5 deg and 1e-4 mm.
    const Pose Z = pose_from_kuka_frame(printed(f));
    worst_printed = std::max(worst_printed, rot_err_deg(X.linear(), Z.linear()));
    EXPECT_LT(pos_err_mm(X, Z), 0.001);
  };
  for (int n = 0; n < 2000; ++n)
    check(make_pose(Vec3(rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(-2, 2)),
                    random_rotation(rng)));
  // At and near B = ±90°, with arbitrary A and C.
  for (double sign : {1.0, -1.0})
    for (double off : {0.0, 1e-14, 1e-12, 1e-10, 1e-9, 1e-8, 1e-7, 1e-6, 1e-4, 1e-2}) {
      for (int n = 0; n < 50; ++n) {
        const double a = rng.uniform(-M_PI, M_PI), c = rng.uniform(-M_PI, M_PI);
        const double b = sign * (M_PI / 2 - off);
        check(make_pose(Vec3(0.1, 0.2, 0.3), rz(a) * ry(b) * rx(c)));
      }
    }
  EXPECT_LT(worst, 1e-6);  // [deg]
  EXPECT_LT(worst_printed, 0.001);
  // Exactly at the lock C is zero and B is ±90.
  const KukaFrame lock =
      kuka_frame_from_pose(make_pose(Vec3::Zero(), rz(0.7) * ry(M_PI / 2) * rx(0.2)));
  EXPECT_NEAR(lock.b, 90, 1e-9);
  EXPECT_EQ(lock.c, 0.0);
  EXPECT_NEAR(lock.a, (0.7 - 0.2) / kDeg, 1e-6);
  std::printf("KUKA ABC round trip: worst %.3g deg exact, %.3g deg as printed\n", worst,
              worst_printed);
}

TEST(UrPose, RotationVectorRoundTrip) {
  Rng rng(5);
  const auto check = [](const Mat3& R) {
    const Pose X = make_pose(Vec3(0.3, -0.2, 0.5), R);
    const UrPose p = ur_pose_from_pose(X);
    const Vec3 r(p[3], p[4], p[5]);
    EXPECT_LE(r.norm(), M_PI + 1e-12);
    const Pose Y = pose_from_ur_pose(p);
    EXPECT_LT(rotation_distance(X.linear(), Y.linear()), 1e-12);
    EXPECT_LT((X.translation() - Y.translation()).norm(), 1e-15);
  };
  for (int n = 0; n < 1000; ++n) check(random_rotation(rng));
  check(Mat3::Identity());
  check(rx(M_PI));
  check(rz(M_PI - 1e-9));
  check(Eigen::AngleAxisd(M_PI, Vec3(1, 1, 0).normalized()).toRotationMatrix());
  check(rx(1e-12));
  // Known value: 90° about z.
  const UrPose p = ur_pose_from_pose(make_pose(Vec3::Zero(), rz(M_PI / 2)));
  EXPECT_NEAR(p[5], M_PI / 2, 1e-15);
  EXPECT_NEAR(std::abs(p[3]) + std::abs(p[4]), 0, 1e-15);
}

TEST(ProgramExport, KrlLinProgram) {
  const Fixture f;
  ASSERT_GT(f.traj.size(), 100u);
  const ProgramParams P = f.params(ProgramDialect::kKrl, ProgramMotion::kLinear);
  const RobotProgram prog = export_program(f.robot, f.traj, P);
  const auto lines = lines_of(prog.text);
  // Structure: header, one DEF and one END closing it at the end, declarations before motion.
  ASSERT_GE(lines.size(), 10u);
  EXPECT_EQ(lines[0], "&ACCESS RVP");
  EXPECT_EQ(count_lines_equal(prog.text, "DEF flash_seg_07( )"), 1);
  EXPECT_EQ(count_lines_equal(prog.text, "END"), 1);
  EXPECT_EQ(lines.back(), "END");
  const auto def_at = prog.text.find("DEF flash_seg_07( )");
  const auto tool_at = prog.text.find("$TOOL = {X ");
  const auto base_at = prog.text.find("$BASE = {X ");
  const auto ptp_at = prog.text.find("PTP {A1 ");
  const auto lin_at = prog.text.find("LIN {X ");
  EXPECT_LT(def_at, tool_at);
  EXPECT_LT(tool_at, ptp_at);
  EXPECT_LT(base_at, ptp_at);
  EXPECT_LT(ptp_at, lin_at);
  EXPECT_NE(prog.text.find("$VEL.CP = "), std::string::npos);
  EXPECT_NE(prog.text.find("$APO.CDIS = 0.5000"), std::string::npos);
  // Counts: one PTP, then a LIN every 2 mm of path plus the end point.
  const int lins = count_substr(prog.text, "  LIN {");
  EXPECT_EQ(count_substr(prog.text, "PTP {"), 1);
  EXPECT_EQ(static_cast<std::size_t>(lins) + 1, prog.samples.size());
  EXPECT_NEAR(lins, 0.1 / 0.002, 1.0);
  EXPECT_EQ(count_substr(prog.text, "C_DIS"), lins - 1);  // the last point is an exact stop

  const ParsedProgram pp = parse_program(prog.text, P);
  EXPECT_EQ(pp.name, "flash_seg_07");
  EXPECT_EQ(pp.routines, 1);
  check_frames(pp, f);
  check_points(pp, prog, f, true);
  // Programmed speeds: positive, never above the feed (the TCP path is the timed path).
  for (std::size_t i = 1; i < pp.points.size(); ++i) {
    EXPECT_EQ(pp.points[i].instruction, "LIN");
    EXPECT_GE(pp.points[i].speed, P.min_speed);
    EXPECT_LE(pp.points[i].speed, 0.05 * 1.001);
  }
  // Consecutive targets about 2 mm apart along the straight TCP line.
  for (std::size_t i = 2; i + 1 < pp.points.size(); ++i) {
    const double d = pos_err_mm(pp.points[i].X_WT, pp.points[i - 1].X_WT);
    EXPECT_GE(d, 1.999);
    EXPECT_LE(d, 2.2);
  }
}

TEST(ProgramExport, KrlSplineAndPtpPrograms) {
  const Fixture f;
  {
    const ProgramParams P = f.params(ProgramDialect::kKrl, ProgramMotion::kSpline);
    const RobotProgram prog = export_program(f.robot, f.traj, P);
    EXPECT_EQ(count_lines_equal(prog.text, "  SPLINE"), 1);
    EXPECT_EQ(count_lines_equal(prog.text, "  ENDSPLINE"), 1);
    EXPECT_LT(prog.text.find("  SPLINE"), prog.text.find("  ENDSPLINE"));
    const int spl = count_substr(prog.text, "    SPL {X ");
    EXPECT_EQ(static_cast<std::size_t>(spl) + 1, prog.samples.size());
    EXPECT_EQ(count_substr(prog.text, "WITH $VEL.CP = "), spl);
    const ParsedProgram pp = parse_program(prog.text, P);
    check_frames(pp, f);
    check_points(pp, prog, f, true);
    for (std::size_t i = 1; i < pp.points.size(); ++i) EXPECT_GT(pp.points[i].speed, 0);
  }
  {
    ProgramParams P = f.params(ProgramDialect::kKrl, ProgramMotion::kJoint);
    P.point_spacing = 0.005;
    const RobotProgram prog = export_program(f.robot, f.traj, P);
    const int ptp = count_substr(prog.text, "PTP {A1 ");
    EXPECT_EQ(static_cast<std::size_t>(ptp), prog.samples.size());
    EXPECT_NEAR(ptp, 0.1 / 0.005 + 2, 1.0);
    EXPECT_EQ(count_substr(prog.text, " C_PTP"), ptp - 2);  // not the approach, not the last
    EXPECT_EQ(count_substr(prog.text, "$VEL_AXIS["), 12);   // approach and trajectory speeds
    const ParsedProgram pp = parse_program(prog.text, P);
    check_frames(pp, f);
    check_points(pp, prog, f, false);
  }
}

TEST(ProgramExport, UrScriptMovelProgram) {
  const Fixture f;
  const ProgramParams P = f.params(ProgramDialect::kUrScript, ProgramMotion::kLinear);
  const RobotProgram prog = export_program(f.robot, f.traj, P);
  const auto lines = lines_of(prog.text);
  EXPECT_EQ(lines.front(), "def flash_seg_07():");
  EXPECT_EQ(lines.back(), "end");
  EXPECT_EQ(count_lines_equal(prog.text, "end"), 1);
  EXPECT_EQ(count_substr(prog.text, "  set_tcp(p["), 1);
  EXPECT_EQ(count_substr(prog.text, "  base_frame = p["), 1);
  EXPECT_EQ(count_substr(prog.text, "  movej(["), 1);
  const int movel = count_substr(prog.text, "  movel(pose_trans(base_frame, p[");
  EXPECT_EQ(static_cast<std::size_t>(movel) + 1, prog.samples.size());
  EXPECT_EQ(count_substr(prog.text, ", r=0)"), 1);  // only the last stops exactly
  const ParsedProgram pp = parse_program(prog.text, P);
  EXPECT_EQ(pp.name, "flash_seg_07");
  EXPECT_EQ(pp.routines, 1);
  check_frames(pp, f);
  check_points(pp, prog, f, true);
  for (std::size_t i = 1; i < pp.points.size(); ++i) {
    EXPECT_EQ(pp.points[i].instruction, "movel");
    EXPECT_GT(pp.points[i].speed, 0);
    // The tool turns sqrt(2² + 6²) rad per metre of the path (0.32 rad/s at the feed), faster
    // than a UR turns it at 0.05 m/s (4 rad/s per m/s): the turn sets the speed.
    EXPECT_LE(pp.points[i].speed, std::sqrt(40.0) * 0.05 / 4 * 1.001);
    if (i > 10 && i + 10 < pp.points.size())  // off the ramps
      EXPECT_NEAR(pp.points[i].speed, std::sqrt(40.0) * 0.05 / 4, 0.001);
    EXPECT_NEAR(pp.points[i].ori_speed, 4 * pp.points[i].speed, 1e-9);
  }

  // movep (process move at constant speed) is the spline flavour.
  const ProgramParams Pp = f.params(ProgramDialect::kUrScript, ProgramMotion::kSpline);
  const RobotProgram pprog = export_program(f.robot, f.traj, Pp);
  EXPECT_EQ(static_cast<std::size_t>(count_substr(pprog.text, "  movep(")) + 1,
            pprog.samples.size());
  check_points(parse_program(pprog.text, Pp), pprog, f, true);
}

TEST(ProgramExport, UrScriptServojAtATimeStep) {
  const Fixture f;
  ProgramParams P = f.params(ProgramDialect::kUrScript, ProgramMotion::kServo);
  P.time_step = 0.008;
  const RobotProgram prog = export_program(f.robot, f.traj, P);
  const std::size_t K = f.traj.size();
  // A point every 8 samples, plus the start (movej) and the end.
  const std::size_t expected = (K - 2) / 8 + 2;
  EXPECT_EQ(prog.samples.size(), expected);
  EXPECT_EQ(static_cast<std::size_t>(count_substr(prog.text, "  servoj([")) + 1, expected);
  EXPECT_NE(prog.text.find("  stopj("), std::string::npos);
  const ParsedProgram pp = parse_program(prog.text, P);
  check_points(pp, prog, f, false);
  // servoj times are the sample spacing; joint values to print precision (1e-7 rad).
  for (std::size_t i = 1; i < pp.points.size(); ++i) {
    const double dt = (prog.samples[i] - prog.samples[i - 1]) * f.traj.dt;
    EXPECT_NEAR(pp.points[i].period, dt, 1e-9);
    EXPECT_LT((pp.points[i].q - f.traj.q[prog.samples[i]]).cwiseAbs().maxCoeff(), 1e-7);
    if (i + 1 < pp.points.size()) {
      EXPECT_NEAR(pp.points[i].period, 0.008, 1e-9);
    }
  }
  // movej variant.
  ProgramParams Pj = f.params(ProgramDialect::kUrScript, ProgramMotion::kJoint);
  const RobotProgram jprog = export_program(f.robot, f.traj, Pj);
  const ParsedProgram jp = parse_program(jprog.text, Pj);
  check_points(jp, jprog, f, false);
  for (std::size_t i = 1; i < jp.points.size(); ++i) EXPECT_GT(jp.points[i].speed, 0);
}

TEST(ProgramExport, RapidMoveLAndMoveAbsJPrograms) {
  const Fixture f;
  const ProgramParams P = f.params(ProgramDialect::kRapid, ProgramMotion::kLinear);
  const RobotProgram prog = export_program(f.robot, f.traj, P);
  const auto lines = lines_of(prog.text);
  ASSERT_GE(lines.size(), 10u);
  EXPECT_EQ(lines[0], "MODULE flash_seg_07");
  EXPECT_EQ(lines.back(), "ENDMODULE");
  EXPECT_EQ(count_lines_equal(prog.text, "  PROC main()"), 1);
  EXPECT_EQ(count_lines_equal(prog.text, "  ENDPROC"), 1);
  EXPECT_LT(prog.text.find("PERS tooldata"), prog.text.find("MoveAbsJ"));
  EXPECT_LT(prog.text.find("PERS wobjdata"), prog.text.find("MoveAbsJ"));
  const int movel = count_substr(prog.text, "    MoveL [[");
  EXPECT_EQ(count_substr(prog.text, "MoveAbsJ"), 1);
  EXPECT_EQ(static_cast<std::size_t>(movel) + 1, prog.samples.size());
  EXPECT_EQ(count_substr(prog.text, ", fine, tFlashtwin"), 2);  // the approach and the last point
  const ParsedProgram pp = parse_program(prog.text, P);
  EXPECT_EQ(pp.name, "flash_seg_07");
  EXPECT_EQ(pp.routines, 1);
  check_frames(pp, f);
  check_points(pp, prog, f, true);
  for (std::size_t i = 1; i < pp.points.size(); ++i) {
    EXPECT_EQ(pp.points[i].instruction, "MoveL");
    EXPECT_GE(pp.points[i].speed, P.min_speed * 0.999);
    EXPECT_LE(pp.points[i].speed, 0.05 * 1.001);
  }
  // confdata's cfx agrees with the IK branch of each sample: wrist centre behind axis 1 (+4)
  // is the back branch, a negative axis 5 (+1) the flipped wrist.
  std::istringstream in(prog.text);
  std::string l;
  std::size_t i = 0, matched = 0;
  while (std::getline(in, l)) {
    if (l.rfind("    MoveL ", 0) != 0) continue;
    ++i;
    std::smatch m;  // confdata [cf1, cf4, cf6, cfx] just before the external axes
    ASSERT_TRUE(std::regex_search(l, m, std::regex(R"(\[(-?\d+), (-?\d+), (-?\d+), (\d)\], \[9E9)")))
        << l;
    const int cfx = std::stoi(m[4].str());
    const Vector6 q = f.traj.q[prog.samples[i]];
    const IkResult ik = ik_flange(f.robot, fk_flange(f.robot, q));
    for (const auto& s : ik.solutions)
      if ((s.q - q).cwiseAbs().maxCoeff() < 1e-6) {
        ++matched;
        EXPECT_EQ(cfx >= 4, !s.branch.front) << l;
        EXPECT_EQ(cfx % 2 == 1, s.branch.flip) << l;
      }
  }
  EXPECT_EQ(i, static_cast<std::size_t>(movel));
  EXPECT_EQ(matched, i);

  // Joint moves: MoveAbsJ through every exported sample.
  const ProgramParams Pj = f.params(ProgramDialect::kRapid, ProgramMotion::kJoint);
  const RobotProgram jprog = export_program(f.robot, f.traj, Pj);
  const ParsedProgram jp = parse_program(jprog.text, Pj);
  check_frames(jp, f);
  check_points(jp, jprog, f, false);
  EXPECT_EQ(jprog.text.find("MoveL"), std::string::npos);

  // RAPID has no spline or servo motion here; malformed modules name the line.
  ProgramParams bad = P;
  bad.motion = ProgramMotion::kSpline;
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  const auto error_of = [&](const std::string& t) {
    try {
      parse_program(t, P);
    } catch (const ArgumentError& e) {
      return std::string(e.what());
    }
    return std::string();
  };
  EXPECT_NE(error_of(prog.text.substr(0, prog.text.rfind("  ENDPROC"))).find("ENDPROC"),
            std::string::npos);
  EXPECT_NE(error_of("MODULE m\n  MoveL [[1, 2, 3], [1, 0, 0, 0]], v10, fine, t;\nENDMODULE\n")
                .find("inside PROC"),
            std::string::npos);
  EXPECT_NE(error_of("MODULE m\n  PROC main()\n    MoveL [[1, 2], [1, 0, 0, 0]], v10, fine, t;\n"
                     "  ENDPROC\nENDMODULE\n")
                .find("[x, y, z]"),
            std::string::npos);
}

TEST(ProgramExport, JointSignAndOffsetMapping) {
  const Fixture f;
  ProgramParams P = f.params(ProgramDialect::kKrl, ProgramMotion::kJoint);
  P.joint_sign << 1, -1, 1, -1, 1, -1;
  P.joint_offset << 0, M_PI / 2, -M_PI / 2, 0, 0, M_PI;
  const RobotProgram prog = export_program(f.robot, f.traj, P);
  const ParsedProgram pp = parse_program(prog.text, P);
  check_points(pp, prog, f, false);
  // The text holds the controller values: A2 of the first point is -q2 + 90°.
  const ParsedProgram raw =
      parse_program(prog.text, f.params(ProgramDialect::kKrl, ProgramMotion::kJoint));
  EXPECT_NEAR(raw.points[0].q[1], -f.traj.q[0][1] + M_PI / 2, 1e-6);
  EXPECT_NEAR(raw.points[0].q[5], -f.traj.q[0][5] + M_PI, 1e-6);
}

TEST(ProgramExport, MalformedProgramsAndBadInputAreRejected) {
  const Fixture f;
  const ProgramParams krl = f.params(ProgramDialect::kKrl, ProgramMotion::kLinear);
  const ProgramParams urs = f.params(ProgramDialect::kUrScript, ProgramMotion::kLinear);
  const std::string text = export_program(f.robot, f.traj, krl).text;
  const auto expect_parse_error = [](const std::string& t, const ProgramParams& p,
                                     const std::string& needle) {
    try {
      parse_program(t, p);
      ADD_FAILURE() << "accepted a program lacking " << needle;
    } catch (const ArgumentError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
    }
  };
  // Missing END, END without DEF, motion outside the routine, incomplete frames.
  expect_parse_error(text.substr(0, text.rfind("END")), krl,
                     "expected END closing DEF flash_seg_07");
  expect_parse_error("END\n", krl, "expected DEF before END");
  expect_parse_error(text + "LIN {X 1, Y 2, Z 3, A 0, B 0, C 0}\n", krl, "inside DEF");
  expect_parse_error("DEF p( )\n  LIN {X 1, Y 2, Z 3, A 0, B 0}\nEND\n", krl, "field C");
  expect_parse_error("DEF p( )\n  $TOOL = {X 1, Y 2, Z abc, A 0, B 0, C 0}\nEND\n", krl,
                     "a number for Z");
  expect_parse_error("DEF p( )\n  SPLINE\n  SPL {X 1, Y 2, Z 3, A 0, B 0, C 0}\nEND\n", krl,
                     "ENDSPLINE");
  const std::string ur = export_program(f.robot, f.traj, urs).text;
  expect_parse_error(ur.substr(0, ur.rfind("end")), urs, "end closing def flash_seg_07");
  expect_parse_error("def p():\n  movel(p[1, 2, 3], a=1, v=1)\nend\n", urs, "6 numbers");

  // Export input errors.
  ProgramParams bad = krl;
  bad.name = "9lives";
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  bad.name = "a_name_longer_than_24_chars";
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  bad = krl;
  bad.motion = ProgramMotion::kServo;
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  bad = urs;
  bad.motion = ProgramMotion::kServo;
  bad.servo_gain = 50;
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  bad = krl;
  bad.point_spacing = 0;
  EXPECT_THROW(export_program(f.robot, f.traj, bad), ArgumentError);
  EXPECT_THROW(export_program(f.robot, JointTrajectory{}, krl), ArgumentError);
  JointTrajectory broken = f.traj;
  broken.dq.pop_back();
  EXPECT_THROW(export_program(f.robot, broken, krl), ArgumentError);
}

TEST(ProgramExport, WriteProgramToFile) {
  const Fixture f;
  const RobotProgram prog =
      export_program(f.robot, f.traj, f.params(ProgramDialect::kKrl, ProgramMotion::kLinear));
  const std::string dir = ftest::temp_dir("program_export");
  const std::string path = dir + "/flash_seg_07.src";
  write_program(prog, path);
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  EXPECT_EQ(ss.str(), prog.text);
  EXPECT_THROW(write_program(prog, dir + "/missing_folder/x.src"), IoError);
}
