// Speed of the time parametrization (spline, reachability passes, sampling at 1 ms) on a
// 2,000-sample IK path, and of the robot program export of its result.
#include <benchmark/benchmark.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/planner/timing.hpp"

using namespace flashtwin;

namespace {

const RobotModel& robot() {
  static const RobotModel r =
      load_robot(std::string(FLASHTWIN_SOURCE_DIR) + "/models/robots/ft6.yaml");
  return r;
}

struct Path {
  std::vector<double> s;
  std::vector<Vector6> q;
};

// 2,000 samples of a TCP circle (radius 0.15 m, tool pointing down, a slow spin about the tool
// axis) in front of the robot: 0.94 m of path, 0.47 mm between samples.
const Path& circle_path() {
  static const Path path = [] {
    Path p;
    const int n = 2000;
    const double radius = 0.15;
    const Vec3 centre(0.55, 0.0, 0.25);
    Mat3 down;
    down << 1, 0, 0, 0, -1, 0, 0, 0, -1;
    Vector6 prev = robot().home;
    for (int i = 0; i < n; ++i) {
      const double phi = 2 * M_PI * i / (n - 1);
      Pose X = Pose::Identity();
      X.translation() = centre + radius * Vec3(std::cos(phi), std::sin(phi), 0);
      X.linear() = down * Eigen::AngleAxisd(0.5 * phi, Vec3::UnitZ()).toRotationMatrix();
      planner::IkParams ip;
      ip.q_ref = prev;
      const auto res = planner::ik_tool(robot(), X, ip);
      if (res.solutions.empty()) {
        std::fprintf(stderr, "IK failed at sample %d: %s\n", i, res.message.c_str());
        std::abort();
      }
      double best = 1e9;
      Vector6 nearest = prev;
      for (const auto& sol : res.solutions) {
        const double d = (sol.q - prev).cwiseAbs().maxCoeff();
        if (d < best) {
          best = d;
          nearest = sol.q;
        }
      }
      prev = nearest;
      p.s.push_back(radius * phi);
      p.q.push_back(prev);
    }
    return p;
  }();
  return path;
}

// Argument: feed [mm/s]. Grinding feeds (20, 100 mm/s) with the default ramps; 1,000 mm/s
// with 10 m/s² and 100 m/s³ ramps, where the joint limits slow the feed on parts of the circle.
void BM_TimeParametrize2000(benchmark::State& state) {
  const Path& path = circle_path();
  planner::TimingParams params;
  params.feed = static_cast<double>(state.range(0)) / 1000.0;
  if (params.feed >= 1.0) {
    params.max_path_accel = 10.0;
    params.max_path_jerk = 100.0;
  }
  planner::TimingResult res;
  for (auto _ : state) {
    res = planner::time_parametrize(robot(), path.s, path.q, params);
    benchmark::DoNotOptimize(res.trajectory.q.data());
  }
  if (!res.ok()) state.SkipWithError(res.message.c_str());
  state.counters["samples_out"] = static_cast<double>(res.trajectory.size());
  state.counters["grid_points"] = static_cast<double>(res.grid_points);
  state.counters["duration_s"] = res.total_time;
  state.counters["reductions"] = static_cast<double>(res.reductions.size());
  state.counters["max_v_ratio"] = res.max_joint_velocity_ratio;
  state.counters["max_a_ratio"] = res.max_joint_accel_ratio;
}
BENCHMARK(BM_TimeParametrize2000)->Arg(20)->Arg(100)->Arg(1000)->Unit(benchmark::kMillisecond);

// Argument: dialect (0 KRL LIN, 1 URScript movel); 2 mm point spacing.
void BM_ExportProgram(benchmark::State& state) {
  const Path& path = circle_path();
  planner::TimingParams tp;
  tp.feed = 0.02;
  const auto timed = planner::time_parametrize(robot(), path.s, path.q, tp);
  planner::ProgramParams pp;
  pp.dialect =
      state.range(0) == 0 ? planner::ProgramDialect::kKrl : planner::ProgramDialect::kUrScript;
  std::size_t points = 0, bytes = 0;
  for (auto _ : state) {
    const auto prog = planner::export_program(robot(), timed.trajectory, pp);
    points = prog.samples.size();
    bytes = prog.text.size();
    benchmark::DoNotOptimize(prog.text.data());
  }
  state.counters["points"] = static_cast<double>(points);
  state.counters["bytes"] = static_cast<double>(bytes);
}
BENCHMARK(BM_ExportProgram)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace

BENCHMARK_MAIN();
