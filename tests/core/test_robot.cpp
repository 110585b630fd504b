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
  // The kinematics of the written URDF: RobotLibrary.FkEqualsTheUrdfJointProductReadByUrdfdom
  // (every arm of the library, this one included).
}
