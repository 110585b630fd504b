// Speed of the arm's kinematics: FK, analytic IK (all solutions), Jacobian.
#include <benchmark/benchmark.h>

#include <vector>

#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"

using namespace flashtwin;

namespace {

const RobotModel& robot() {
  static const RobotModel r = load_robot(std::string(FLASHTWIN_SOURCE_DIR) + "/models/robots/ft6.yaml");
  return r;
}

// 1024 random in-limit configurations, the same for every benchmark.
const std::vector<Vector6>& configs() {
  static const std::vector<Vector6> qs = [] {
    std::vector<Vector6> v;
    Rng rng(1);
    for (int n = 0; n < 1024; ++n) {
      Vector6 q;
      for (int i = 0; i < 6; ++i) q[i] = rng.uniform(robot().limits[i].lower, robot().limits[i].upper);
      v.push_back(q);
    }
    return v;
  }();
  return qs;
}

void BM_FkFlange(benchmark::State& state) {
  const auto& qs = configs();
  std::size_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(planner::fk_flange(robot(), qs[i++ & 1023]));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_FkFlange);

void BM_IkFlangeAllSolutions(benchmark::State& state) {
  std::vector<Pose> poses;
  for (const auto& q : configs()) poses.push_back(planner::fk_flange(robot(), q));
  std::size_t i = 0, sols = 0;
  for (auto _ : state) {
    const auto res = planner::ik_flange(robot(), poses[i++ & 1023]);
    sols += res.solutions.size();
    benchmark::DoNotOptimize(res);
  }
  state.SetItemsProcessed(state.iterations());
  state.counters["solutions_per_call"] =
      static_cast<double>(sols) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_IkFlangeAllSolutions);

void BM_IkToolWithReference(benchmark::State& state) {
  std::vector<Pose> poses;
  for (const auto& q : configs()) poses.push_back(planner::fk_tool(robot(), q));
  planner::IkParams p;
  std::size_t i = 0;
  for (auto _ : state) {
    p.q_ref = configs()[i & 1023];
    benchmark::DoNotOptimize(planner::ik_tool(robot(), poses[i++ & 1023], p));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_IkToolWithReference);

void BM_JacobianAndManipulability(benchmark::State& state) {
  const auto& qs = configs();
  std::size_t i = 0;
  for (auto _ : state) {
    const Matrix6 J = planner::jacobian(robot(), qs[i++ & 1023], robot().tool.X_ET);
    benchmark::DoNotOptimize(std::abs(J.determinant()));
  }
  state.SetItemsProcessed(state.iterations());
}
BENCHMARK(BM_JacobianAndManipulability);

}  // namespace

// The robot library: IK (all solutions) of each arm on 1024 of its own random in-limit
// configurations. Argument: 0 kuka_kr16, 1 abb_irb4600, 2 fanuc_m20ia (spherical wrist),
// 3 ur10e (offset wrist).
void BM_IkLibraryArm(benchmark::State& state) {
  static const char* names[] = {"kuka_kr16", "abb_irb4600", "fanuc_m20ia", "ur10e"};
  const std::string name = names[state.range(0)];
  const RobotModel arm =
      load_robot(std::string(FLASHTWIN_SOURCE_DIR) + "/models/robots/" + name + ".yaml");
  std::vector<Pose> poses;
  Rng rng(1);
  for (int n = 0; n < 1024; ++n) {
    Vector6 q;
    for (int i = 0; i < 6; ++i) q[i] = rng.uniform(arm.limits[i].lower, arm.limits[i].upper);
    poses.push_back(planner::fk_flange(arm, q));
  }
  std::size_t i = 0, sols = 0;
  for (auto _ : state) {
    const auto res = planner::ik_flange(arm, poses[i++ & 1023]);
    sols += res.solutions.size();
    benchmark::DoNotOptimize(res);
  }
  state.SetLabel(name);
  state.SetItemsProcessed(state.iterations());
  state.counters["solutions_per_call"] =
      static_cast<double>(sols) / static_cast<double>(state.iterations());
}
BENCHMARK(BM_IkLibraryArm)->DenseRange(0, 3);
