// The robot library (models/robots/): every arm loads, has the structure one of the analytic
// IK solvers handles, agrees with an independent product of its URDF joints as urdfdom reads
// them, and round-trips through the IK on 10,000 random configurations within its limits.
#include <gtest/gtest.h>
#include <urdf_parser/urdf_parser.h>

#include <set>
#include <string>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

RobotModel library_arm(const std::string& name) {
  return load_robot(ftest::source_path("models/robots/" + name + ".yaml"));
}

Vector6 random_q(const RobotModel& robot, Rng& rng) {
  Vector6 q;
  for (int i = 0; i < 6; ++i) q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
  return q;
}

double wrapped_max_diff(const Vector6& a, const Vector6& b) {
  double m = 0;
  for (int i = 0; i < 6; ++i) m = std::max(m, std::abs(std::remainder(a[i] - b[i], 2 * M_PI)));
  return m;
}

Pose urdf_pose(const urdf::Pose& p) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(p.position.x, p.position.y, p.position.z);
  X.linear() = Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z)
                   .normalized()
                   .toRotationMatrix();
  return X;
}

// The pose of link `tip` as the product of the URDF's joint origins and axis rotations, walked
// from `tip` up to the root with urdfdom's own quaternions (nothing of the D-H code); the i-th
// moving joint from the root turns by q[i].
Pose urdf_chain_pose(const urdf::ModelInterface& model, const std::string& tip, const Vector6& q) {
  std::vector<const urdf::Joint*> joints;
  for (auto l = model.getLink(tip); l && l->parent_joint; l = model.getLink(l->parent_joint->parent_link_name))
    joints.push_back(l->parent_joint.get());
  Pose X = Pose::Identity();
  int moving = 0;
  for (auto it = joints.rbegin(); it != joints.rend(); ++it) {
    const urdf::Joint& j = **it;
    X = X * urdf_pose(j.parent_to_joint_origin_transform);
    if (j.type == urdf::Joint::REVOLUTE)
      X = X * Eigen::AngleAxisd(q[moving++], Vec3(j.axis.x, j.axis.y, j.axis.z));
  }
  return X;
}

class RobotLibrary : public ::testing::TestWithParam<const char*> {};

}  // namespace

TEST_P(RobotLibrary, LoadsWithLimitsHomeAndAnIkSolver) {
  const RobotModel robot = library_arm(GetParam());
  EXPECT_EQ(robot.name, GetParam());
  EXPECT_TRUE(ik_supported(robot)) << robot.name;
  EXPECT_TRUE(robot.within_limits(robot.home));
  for (int i = 0; i < 6; ++i) {
    EXPECT_TRUE(robot.controller.sign[i] == 1 || robot.controller.sign[i] == -1);
    EXPECT_GT(robot.limits[i].velocity, 0);
  }
  // The spindle points down at home (the parking pose every shipped arm is given).
  const Pose X_BT = fk_tool(robot, robot.home);
  EXPECT_LT(X_BT.linear().col(2).z(), -0.9) << robot.name;
  // The program export writes in the controller's convention and language.
  const ProgramParams P = program_params_for(robot);
  EXPECT_EQ(P.joint_sign, robot.controller.sign);
  EXPECT_EQ(P.joint_offset, robot.controller.offset);
  if (robot.controller.language != "none")
    EXPECT_EQ(to_string(P.dialect), robot.controller.language) << robot.name;
}

TEST_P(RobotLibrary, FkEqualsTheUrdfJointProductReadByUrdfdom) {
  const RobotModel robot = library_arm(GetParam());
  const auto model = urdf::parseURDF(robot_urdf(robot));
  ASSERT_TRUE(model);
  Rng rng(11);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 1000; ++n) {
    const Vector6 q = random_q(robot, rng);
    const Pose X = urdf_chain_pose(*model, "tcp", q);
    const Pose X_BT = fk_tool(robot, q);
    worst_p = std::max(worst_p, (X.translation() - X_BT.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(X.linear(), X_BT.linear()));
  }
  EXPECT_LT(worst_p, 1e-9) << robot.name;
  EXPECT_LT(worst_r, 1e-9) << robot.name;
}

TEST_P(RobotLibrary, IkRoundTripOnTenThousandRandomConfigurations) {
  const RobotModel robot = library_arm(GetParam());
  Rng rng(2026);
  int checked_original = 0;
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 10000; ++n) {
    const Vector6 q = random_q(robot, rng);
    const Pose X_BE = fk_flange(robot, q);
    const IkResult res = ik_flange(robot, X_BE);
    ASSERT_TRUE(res.ok()) << robot.name << " n=" << n << ": " << res.message;
    ASSERT_LE(res.solutions.size(), 8u);
    std::set<int> branches;
    bool found = false;
    for (const auto& s : res.solutions) {
      ASSERT_TRUE(robot.within_limits(s.q, 1e-12));
      const Pose X = fk_flange(robot, s.q);
      worst_p = std::max(worst_p, (X.translation() - X_BE.translation()).norm());
      worst_r = std::max(worst_r, rotation_distance(X.linear(), X_BE.linear()));
      EXPECT_TRUE(branches.insert(s.branch.index()).second) << "branch listed twice";
      found = found || wrapped_max_diff(s.q, q) < 1e-7;
    }
    const auto sing = check_singularity(robot, q);
    if (sing.wrist > 1e-3 && sing.elbow > 1e-3 && sing.shoulder > 1e-3) {
      ++checked_original;
      EXPECT_TRUE(found) << robot.name << ": original configuration not found at n=" << n;
    }
  }
  EXPECT_LT(worst_p, 1e-9) << robot.name;
  EXPECT_LT(worst_r, 1e-9) << robot.name;
  EXPECT_GT(checked_original, 9000) << robot.name;
  std::printf("%s IK round trip: worst %.3g m, %.3g rad; original found on %d of 10000\n",
              robot.name.c_str(), worst_p, worst_r, checked_original);
}

TEST_P(RobotLibrary, ItsUrdfReadBackGivesTheSameArm) {
  // robot_urdf writes the arm; robot_from_urdf derives a D-H table from the joint axes alone.
  const RobotModel robot = library_arm(GetParam());
  const RobotModel back = robot_from_urdf(robot_urdf(robot), robot.name + ".urdf");
  EXPECT_EQ(back.name, robot.name);
  EXPECT_EQ(arm_geometry(back), arm_geometry(robot));
  Rng rng(5);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 1000; ++n) {
    const Vector6 q = random_q(robot, rng);
    // The URDF's joint values are the written arm's θ; the read arm maps them by its controller
    // convention (θ = (A − offset) / sign).
    const Vector6 th = back.controller.joints(q);
    ASSERT_TRUE(back.within_limits(th, 1e-9)) << n;
    const Pose a = fk_tool(robot, q), b = fk_tool(back, th);
    worst_p = std::max(worst_p, (a.translation() - b.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(a.linear(), b.linear()));
  }
  EXPECT_LT(worst_p, 1e-9) << robot.name;
  EXPECT_LT(worst_r, 1e-9) << robot.name;
  double mass = 0, mass_back = 0;
  for (int i = 0; i < 6; ++i) {
    mass += robot.links[i].mass;
    mass_back += back.links[i].mass;
  }
  EXPECT_NEAR(mass_back, mass + robot.tool.inertial.mass, 1e-9)
      << "link 6 carries the written tool's mass (the URDF's flange link)";
}

INSTANTIATE_TEST_SUITE_P(Arms, RobotLibrary,
                         ::testing::Values("ft6", "kuka_kr16", "abb_irb4600", "fanuc_m20ia",
                                           "ur10e"));

TEST(OffsetWristIk, BranchesHaveTheirGeometricMeaning) {
  const RobotModel robot = library_arm("ur10e");
  IkParams p;
  p.within_limits_only = false;
  Rng rng(8);
  int poses_with_eight = 0, checked = 0;
  for (int n = 0; n < 300; ++n) {
    const Vector6 q = random_q(robot, rng);
    const auto sing = check_singularity(robot, q);
    if (sing.wrist < 1e-2 || sing.elbow < 1e-2 || sing.shoulder < 1e-2) continue;
    const Pose X_BE = fk_flange(robot, q);
    const IkResult res = ik_flange(robot, X_BE, p);
    ASSERT_TRUE(res.ok()) << res.message;
    poses_with_eight += res.solutions.size() == 8u;
    for (const auto& s : res.solutions) {
      ++checked;
      EXPECT_LT((fk_flange(robot, s.q).translation() - X_BE.translation()).norm(), 1e-9);
      const auto F = fk_frames(robot, s.q);
      // In the arm's plane (frame {1}: y1 is up): the elbow (frame {2}'s origin) and the wrist
      // (frame {3}'s origin, joint 4's axis).
      const Vec3 elbow = F[1].inverse() * F[2].translation();
      const Vec3 wrist = F[1].inverse() * F[3].translation();
      const double side = wrist.x() * elbow.y() - wrist.y() * elbow.x();
      // Front: frame {5}'s origin is reached along −x1 (the UR zero configuration's way).
      const bool front = (F[1].inverse() * F[5].translation()).x() < 0;
      EXPECT_EQ(s.branch.front, front) << s.branch.name();
      // Elbow up: the elbow above the line from the shoulder to the wrist.
      if (std::abs(wrist.x()) > 0.05 && front == (wrist.x() < 0))
        EXPECT_EQ(s.branch.elbow_up, side / wrist.x() > 0) << s.branch.name();
      EXPECT_EQ(s.branch.flip, s.q[4] < 0) << s.branch.name();
    }
  }
  EXPECT_GT(poses_with_eight, 50);
  EXPECT_GT(checked, 1000);
}

TEST(OffsetWristIk, ExactWristSingularityKeepsTheReferenceTheta6) {
  const RobotModel robot = library_arm("ur10e");
  Vector6 q;
  q << 0.2, -1.0, 1.0, -0.7, 0.0, 0.3;
  IkParams p;
  p.q_ref = q;
  const IkResult res = ik_flange(robot, fk_flange(robot, q), p);
  ASSERT_TRUE(res.ok()) << res.message;
  EXPECT_TRUE(res.wrist_singular);
  double best = 1e9;
  for (const auto& s : res.solutions) {
    EXPECT_LT((fk_flange(robot, s.q).translation() - fk_flange(robot, q).translation()).norm(),
              1e-9);
    best = std::min(best, (s.q - q).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(best, 1e-9);
}

TEST(OffsetWristIk, OutOfReachSaysHowFar) {
  const RobotModel robot = library_arm("ur10e");
  Pose X = Pose::Identity();
  X.translation() = Vec3(2.0, 0.3, 0.4);
  const IkResult res = ik_flange(robot, X);
  EXPECT_EQ(res.status, IkStatus::kUnreachable);
  EXPECT_NE(res.message.find("out of reach"), std::string::npos) << res.message;
}

namespace {

// A URDF of `n` revolute joints in a row (x offsets, axes z, y, y, x, y, x), with `extra`
// spliced in before </robot>.
std::string chain_urdf(int n, const std::string& joint1_origin = "0 0 0.4",
                       const std::string& extra = "") {
  const char* axes[] = {"0 0 1", "0 1 0", "0 1 0", "1 0 0", "0 1 0", "1 0 0"};
  const char* origins[] = {"", "0.1 0 0", "0.5 0 0", "0.4 0 0.05", "0 0 0", "0 0 0"};
  std::string s = "<robot name=\"chain\"><link name=\"base_link\"/>";
  for (int i = 0; i < n; ++i) {
    const std::string c = "l" + std::to_string(i + 1), p = i ? "l" + std::to_string(i) : "base_link";
    s += "<link name=\"" + c + "\"/><joint name=\"j" + std::to_string(i + 1) +
         "\" type=\"revolute\"><parent link=\"" + p + "\"/><child link=\"" + c +
         "\"/><origin xyz=\"" + (i ? origins[i] : joint1_origin) + "\"/><axis xyz=\"" + axes[i] +
         "\"/><limit lower=\"-3\" upper=\"3\" velocity=\"2\" effort=\"100\"/></joint>";
  }
  return s + extra + "</robot>";
}

std::string urdf_error(const std::string& xml) {
  try {
    robot_from_urdf(xml, "arm.urdf");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

}  // namespace

TEST(UrdfIn, ASphericalWristChainIsReadAndRoundTrips) {
  const RobotModel r = robot_from_urdf(chain_urdf(6), "arm.urdf");
  EXPECT_EQ(arm_geometry(r), ArmGeometry::kSphericalWrist);
  const auto model = urdf::parseURDF(chain_urdf(6));
  Rng rng(3);
  double worst = 0;
  for (int n = 0; n < 200; ++n) {
    Vector6 qu;
    for (int i = 0; i < 6; ++i) qu[i] = rng.uniform(-3, 3);
    // The URDF's joint values are the controller's axis values.
    const Vector6 th = r.controller.joints(qu);
    ASSERT_TRUE(r.within_limits(th, 1e-9));
    // The last link l6 is the flange; the tool sits 0.22 m along its z.
    const Pose X = urdf_chain_pose(*model, "l6", qu) * Eigen::Translation3d(0, 0, 0.22);
    worst = std::max(worst, (X.translation() - fk_tool(r, th).translation()).norm());
  }
  EXPECT_LT(worst, 1e-9);
}

TEST(UrdfIn, ChainsThatDoNotFitAreRefusedNamingWhy) {
  EXPECT_NE(urdf_error(chain_urdf(5)).find("expected a serial chain of 6 revolute joints, found 5"),
            std::string::npos);
  EXPECT_NE(urdf_error(chain_urdf(6, "0.2 0 0.4")).find("joint 'j1': expected the first joint's axis"),
            std::string::npos);
  EXPECT_NE(urdf_error(chain_urdf(6, "0 0 0.4",
                                  "<link name=\"s\"/><joint name=\"slide\" type=\"prismatic\">"
                                  "<parent link=\"l6\"/><child link=\"s\"/><axis xyz=\"1 0 0\"/>"
                                  "<limit lower=\"0\" upper=\"1\" velocity=\"1\" effort=\"1\"/>"
                                  "</joint>"))
                .find("joint 'slide': expected revolute"),
            std::string::npos);
  EXPECT_NE(urdf_error(chain_urdf(6, "0 0 0.4",
                                  "<link name=\"b\"/><joint name=\"jb\" type=\"revolute\">"
                                  "<parent link=\"l2\"/><child link=\"b\"/><axis xyz=\"1 0 0\"/>"
                                  "<limit lower=\"-1\" upper=\"1\" velocity=\"1\" effort=\"1\"/>"
                                  "</joint>"))
                .find("link 'l2' branches into 2 chains"),
            std::string::npos);
  // A wrist whose last axis misses the others by 3 cm: no analytic IK applies.
  std::string offset = chain_urdf(6);
  const auto p = offset.find("<joint name=\"j6\"");
  offset.replace(offset.find("<origin xyz=\"0 0 0\"/>", p), 21, "<origin xyz=\"0 0.03 0.02\"/>");
  EXPECT_NE(urdf_error(offset).find("fits neither analytic IK"), std::string::npos);
  EXPECT_NE(urdf_error("<robot name=\"x\"><link name=\"a\"/>").find("arm.urdf: expected a URDF"),
            std::string::npos);
}

TEST(UrdfIn, TheRosIndustrialStyleKr16IsTheSameArmAsTheLibrarysForEveryAxisValue) {
  // models/robots/urdf/kuka_kr16_2.urdf counts KUKA's A1..A6 (axes against z, zero stretched
  // out); kuka_kr16.yaml is a D-H table with its controller mapping written by hand. Both map a
  // KUKA axis value to the same flange pose, and the URDF's joint zero and directions become
  // the same controller convention.
  const RobotModel yaml = library_arm("kuka_kr16");
  const RobotModel urdf_arm = load_robot(ftest::source_path("models/robots/urdf/kuka_kr16_2.urdf"));
  EXPECT_EQ(arm_geometry(urdf_arm), ArmGeometry::kSphericalWrist);
  Rng rng(16);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 2000; ++n) {
    Vector6 A;
    for (int i = 0; i < 6; ++i) {
      const double lo = yaml.controller.sign[i] * yaml.limits[i].lower + yaml.controller.offset[i];
      const double hi = yaml.controller.sign[i] * yaml.limits[i].upper + yaml.controller.offset[i];
      A[i] = rng.uniform(std::min(lo, hi), std::max(lo, hi));
    }
    const Vector6 th_y = yaml.controller.joints(A);
    const Vector6 th_u = urdf_arm.controller.joints(A);
    ASSERT_TRUE(urdf_arm.within_limits(th_u, 1e-9)) << n;
    const Pose a = fk_flange(yaml, th_y) * yaml.tool.X_ET;
    const Pose b = fk_flange(urdf_arm, th_u) * urdf_arm.tool.X_ET;
    worst_p = std::max(worst_p, (a.translation() - b.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(a.linear(), b.linear()));
    // The derived table (another valid D-H choice: d4 < 0) goes through the IK as well.
    const IkResult ik = ik_flange(urdf_arm, fk_flange(urdf_arm, th_u));
    ASSERT_TRUE(ik.ok()) << ik.message;
    double best = 1e9;
    for (const auto& s : ik.solutions) {
      worst_p = std::max(worst_p, (fk_flange(urdf_arm, s.q).translation() -
                                   fk_flange(urdf_arm, th_u).translation()).norm());
      best = std::min(best, wrapped_max_diff(s.q, th_u));
    }
    const auto sing = check_singularity(urdf_arm, th_u);
    if (sing.wrist > 1e-3 && sing.elbow > 1e-3 && sing.shoulder > 1e-3) EXPECT_LT(best, 1e-7) << n;
  }
  EXPECT_LT(worst_p, 1e-9);
  EXPECT_LT(worst_r, 1e-9);
  // Velocity limits carried over joint by joint.
  for (int i = 0; i < 6; ++i)
    EXPECT_DOUBLE_EQ(urdf_arm.limits[i].velocity, yaml.limits[i].velocity);
}

TEST(UrdfIn, TheRosStyleUr10eIsTheSameArmAsTheLibrarysForEveryJointValue) {
  // models/robots/urdf/ur10e.urdf as UR's ROS description lays it out: base_link turned 180°
  // from the controller's base, rpy written as 1.570796327, 1e-11 m offsets. Read as a UR-type
  // (offset-wrist) arm whose joint values are the controller's, it is ur10e.yaml seen from
  // base_link.
  const RobotModel yaml = library_arm("ur10e");
  const RobotModel arm = load_robot(ftest::source_path("models/robots/urdf/ur10e.urdf"));
  ASSERT_EQ(arm_geometry(arm), ArmGeometry::kOffsetWrist);
  Pose X_baselink_base = Pose::Identity();
  X_baselink_base.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitZ()).toRotationMatrix();
  Rng rng(10);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 2000; ++n) {
    Vector6 q;  // controller joint values within the URDF's limits (elbow ±π)
    for (int i = 0; i < 6; ++i) q[i] = rng.uniform(i == 2 ? -M_PI : -2 * M_PI, i == 2 ? M_PI : 2 * M_PI);
    const Vector6 th = arm.controller.joints(q);
    ASSERT_TRUE(arm.within_limits(th, 1e-9)) << n;
    const Pose a = X_baselink_base * fk_tool(yaml, q), b = fk_tool(arm, th);
    worst_p = std::max(worst_p, (a.translation() - b.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(a.linear(), b.linear()));
    const IkResult ik = ik_flange(arm, fk_flange(arm, th));
    ASSERT_TRUE(ik.ok()) << ik.message;
    for (const auto& s : ik.solutions)
      worst_p = std::max(worst_p, (fk_flange(arm, s.q).translation() -
                                   fk_flange(arm, th).translation()).norm());
  }
  // The URDF's rounded right angles (3e-10 rad) and 2e-11 m offsets are snapped to the table.
  EXPECT_LT(worst_p, 1e-8);
  EXPECT_LT(worst_r, 1e-8);
}
