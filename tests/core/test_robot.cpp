#include <gtest/gtest.h>
#include <urdf_parser/urdf_parser.h>

#include <functional>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "test_util.hpp"

using namespace flashtwin;

TEST(Robot, LoadsTheShippedDescription) {
  const RobotModel r = ftest::ft6();
  EXPECT_EQ(r.name, "ft6");
  EXPECT_DOUBLE_EQ(r.dh[1].a, 0.5);
  EXPECT_DOUBLE_EQ(r.dh[2].d, 0.15);
  EXPECT_DOUBLE_EQ(r.dh[3].d, 0.5);
  for (const auto& L : r.limits) {
    EXPECT_LT(L.lower, L.upper);
    EXPECT_GT(L.velocity, 0);
    EXPECT_GT(L.acceleration, 0);
    EXPECT_GT(L.torque, 0);
  }
  EXPECT_GT(r.tool.X_ET.translation().norm(), 0.0);
}

namespace {
std::string shipped_text() { return read_text_file(ftest::source_path("models/robots/ft6.yaml")); }

std::string error_for(const std::string& text) {
  try {
    parse_robot(text, "bad_robot.yaml");
  } catch (const ConfigError& e) {
    return e.what();
  }
  return "";
}

std::string replace(std::string s, const std::string& from, const std::string& to) {
  const auto p = s.find(from);
  EXPECT_NE(p, std::string::npos) << from;
  if (p != std::string::npos) s.replace(p, from.size(), to);
  return s;
}
}  // namespace

TEST(Robot, MalformedDescriptionsNameTheField) {
  const std::string ok = shipped_text();
  EXPECT_NE(error_for(replace(ok, "velocity: 2.6179938779914944", "velocity: -1"))
                .find("joints[0].velocity"),
            std::string::npos);
  EXPECT_NE(error_for(replace(ok, "upper: 0.6108652381980153", "upper: -5.0")).find("joints[1]"),
            std::string::npos);
  EXPECT_NE(error_for(replace(ok, "  - {alpha: 0.0,                 a: 0.0,   d: 0.0}\n", ""))
                .find("expected a list of 6 D-H rows"),
            std::string::npos);
  EXPECT_NE(error_for(replace(ok, "radius: 0.006", "radius: 0.006\n  colour: red"))
                .find("tool.colour"),
            std::string::npos);
  EXPECT_NE(error_for(replace(ok, "inertia: [0.35, 0.25, 0.35]", "inertia: [0.1, 0.1, 0.5]"))
                .find("triangle inequality"),
            std::string::npos);
  EXPECT_NE(error_for("name: x\n").find("missing required key 'dh'"), std::string::npos);
  EXPECT_THROW(load_robot("/nonexistent/robot.yaml"), IoError);
}

// FK through the URDF as urdfdom reads it: chain of joint origins and axis rotations.
TEST(Robot, UrdfReadBackByUrdfdomGivesTheSameKinematics) {
  const RobotModel robot = ftest::ft6();
  const auto model = urdf::parseURDF(robot_urdf(robot));
  ASSERT_TRUE(model);
  EXPECT_EQ(model->getName(), "ft6");
  for (int i = 1; i <= 6; ++i) {
    const auto j = model->getJoint("joint" + std::to_string(i));
    ASSERT_TRUE(j);
    EXPECT_EQ(j->type, urdf::Joint::REVOLUTE);
    ASSERT_TRUE(j->limits);
    EXPECT_DOUBLE_EQ(j->limits->lower, robot.limits[i - 1].lower);
    EXPECT_DOUBLE_EQ(j->limits->velocity, robot.limits[i - 1].velocity);
    EXPECT_DOUBLE_EQ(j->limits->effort, robot.limits[i - 1].torque);
  }
  auto to_pose = [](const urdf::Pose& p) {
    Pose X = Pose::Identity();
    X.translation() = Vec3(p.position.x, p.position.y, p.position.z);
    X.linear() = Eigen::Quaterniond(p.rotation.w, p.rotation.x, p.rotation.y, p.rotation.z)
                     .normalized()
                     .toRotationMatrix();
    return X;
  };
  Rng rng(7);
  double worst_p = 0, worst_r = 0;
  for (int n = 0; n < 1000; ++n) {
    Vector6 q;
    for (int i = 0; i < 6; ++i) q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
    Pose X = Pose::Identity();
    std::string link = "tool0";
    // Walk up from tool0 to base_link, composing parent-to-child transforms.
    std::vector<Pose> chain;
    while (link != "base_link") {
      const auto l = model->getLink(link);
      ASSERT_TRUE(l && l->parent_joint);
      const auto& j = *l->parent_joint;
      Pose Xj = to_pose(j.parent_to_joint_origin_transform);
      if (j.type == urdf::Joint::REVOLUTE) {
        const int idx = std::stoi(j.name.substr(5)) - 1;
        const Vec3 axis(j.axis.x, j.axis.y, j.axis.z);
        Xj = Xj * Eigen::AngleAxisd(q[idx], axis);
      }
      chain.push_back(Xj);
      link = j.parent_link_name;
    }
    for (auto it = chain.rbegin(); it != chain.rend(); ++it) X = X * *it;
    const Pose X_BT = planner::fk_tool(robot, q);
    worst_p = std::max(worst_p, (X.translation() - X_BT.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(X.linear(), X_BT.linear()));
  }
  // URDF stores rpy; 17 significant digits keep it at round-off level.
  EXPECT_LT(worst_p, 1e-9);
  EXPECT_LT(worst_r, 1e-9);
}
