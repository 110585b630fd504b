// A job's programs as the cell would run them (pipeline::program_motions): read from the files
// DIR/plans.json lists, interpolated as their controller runs them; a program the controller
// would stop is the result's failure, naming the file and the line; a missing or unreadable
// file is bad input naming it.
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/pipeline/job.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "test_util.hpp"

using namespace flashtwin;

namespace {

// A KRL program: the joint move to q0, then straight moves by each offset [m] in {B}.
std::string krl(const RobotModel& robot, const Vector6& q0, const std::vector<Vec3>& offsets) {
  std::string t = "DEF p( )\n  $VEL.CP = 0.02\n  $ACC.CP = 0.5\n  PTP {";
  for (int j = 0; j < 6; ++j)
    t += (j ? ", A" : "A") + std::to_string(j + 1) + " " + std::to_string(q0[j] * 180 / M_PI);
  t += "}\n";
  Pose X = planner::fk_tool(robot, q0);
  for (const Vec3& d : offsets) {
    X.translation() += d;
    const planner::KukaFrame f = planner::kuka_frame_from_pose(X);
    t += "  LIN {X " + std::to_string(f.x) + ", Y " + std::to_string(f.y) + ", Z " +
         std::to_string(f.z) + ", A " + std::to_string(f.a) + ", B " + std::to_string(f.b) +
         ", C " + std::to_string(f.c) + "}\n";
  }
  return t + "END\n";
}

}  // namespace

TEST(JobPrograms, RunsTheListedProgramsAndNamesTheOneThatWouldStop) {
  const RobotModel robot = ftest::ft6();
  const std::string d = ftest::temp_dir("job_programs");
  Vector6 q0;
  q0 << 0.0, -1.0, 0.5, 0.0, 1.0, 0.0;
  write_text_file(d + "/a.src", krl(robot, q0, {Vec3(0.02, 0, 0), Vec3(0, 0.02, 0)}));
  write_text_file(d + "/b.src", krl(robot, q0, {Vec3(0, 0, -0.01), Vec3(3.0, 0, 0)}));
  write_text_file(d + "/plans.json",
                  R"([{"path": 0, "motions": [{"program": "a.src", "tool_radius_mm": 3}]},
                      {"path": 1, "status": "tool_too_large"},
                      {"path": 2, "motions": [{"program": "b.src", "tool_radius_mm": 4}]}])");
  const pipeline::ProgramMotions pm = pipeline::program_motions(robot, d);
  EXPECT_EQ(pm.programs, 2u);
  ASSERT_EQ(pm.motions.size(), 1u);  // b.src would not run
  EXPECT_EQ(pm.motions[0].path, 0u);
  EXPECT_DOUBLE_EQ(pm.motions[0].tool_radius, 0.003);
  // 40 mm at 20 mm/s with 0.5 m/s² ramps: 2 s and a little more.
  EXPECT_GT(pm.time_s, 2.0);
  EXPECT_LT(pm.time_s, 2.2);
  EXPECT_EQ(pm.motions[0].trajectory.q.size(), pm.motions[0].tcp_B.size());
  EXPECT_FALSE(pm.ok());
  EXPECT_NE(pm.failure.find("b.src: program line 6: expected a reachable target"), std::string::npos)
      << pm.failure;

  // A listed program that is missing, and one that does not parse: bad input naming the file.
  write_text_file(d + "/plans.json", R"([{"path": 0, "motions": [{"program": "gone.src"}]}])");
  EXPECT_THROW(pipeline::program_motions(robot, d), IoError);
  write_text_file(d + "/c.src", "DEF c( )\n  LIN {X 1, Y 2}\nEND\n");
  write_text_file(d + "/plans.json", R"([{"path": 0, "motions": [{"program": "c.src"}]}])");
  try {
    pipeline::program_motions(robot, d);
    ADD_FAILURE() << "no error";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("c.src: program line 2"), std::string::npos) << e.what();
  }
  write_text_file(d + "/plans.json", "[{");
  EXPECT_THROW(pipeline::program_motions(robot, d), InputError);
}
