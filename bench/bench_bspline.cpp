// Speed of the planner's curve module on the thesis' 1,273-point contour: quintic B-spline
// interpolation (open and closed) against the two baselines, plus evaluation.
#include <benchmark/benchmark.h>

#include <cmath>
#include <vector>

#include "flashtwin/planner/bspline.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

constexpr int kThesisPoints = 1273;

// A wavy 3-D contour of about 1 m: a lobed ellipse with a height ripple, slightly uneven
// spacing. `span` = 2π closes it (the closed fit joins the last point to the first).
std::vector<Vec3> contour(double span) {
  std::vector<Vec3> p(kThesisPoints);
  for (int k = 0; k < kThesisPoints; ++k) {
    const double a = span * k / kThesisPoints + 0.3 * span / kThesisPoints * std::sin(13.0 * k);
    const double r = 0.175 * (1.0 + 0.08 * std::sin(7 * a));
    p[k] = Vec3(r * std::cos(a), 0.8 * r * std::sin(a), 0.01 * std::sin(5 * a));
  }
  return p;
}

const std::vector<Vec3>& open_path() {
  static const std::vector<Vec3> p = contour(1.95 * M_PI);
  return p;
}

const std::vector<Vec3>& closed_path() {
  static const std::vector<Vec3> p = contour(2 * M_PI);
  return p;
}

void BM_QuinticOpen(benchmark::State& state) {
  for (auto _ : state) benchmark::DoNotOptimize(interpolate_quintic(open_path()));
  state.SetItemsProcessed(state.iterations() * kThesisPoints);
}
BENCHMARK(BM_QuinticOpen)->Unit(benchmark::kMicrosecond);

void BM_QuinticClosed(benchmark::State& state) {
  BSplineParams p;
  p.closed = true;
  for (auto _ : state) benchmark::DoNotOptimize(interpolate_quintic(closed_path(), p));
  state.SetItemsProcessed(state.iterations() * kThesisPoints);
}
BENCHMARK(BM_QuinticClosed)->Unit(benchmark::kMicrosecond);

void BM_Polynomial5(benchmark::State& state) {
  for (auto _ : state) benchmark::DoNotOptimize(fit_polynomial(open_path()));
  state.SetItemsProcessed(state.iterations() * kThesisPoints);
}
BENCHMARK(BM_Polynomial5)->Unit(benchmark::kMicrosecond);

void BM_NaturalCubic(benchmark::State& state) {
  for (auto _ : state) benchmark::DoNotOptimize(interpolate_natural_cubic(open_path()));
  state.SetItemsProcessed(state.iterations() * kThesisPoints);
}
BENCHMARK(BM_NaturalCubic)->Unit(benchmark::kMicrosecond);

// Derivatives 0..3 (what curvature and jerk need) at 1,000 parameters per iteration.
void BM_QuinticEvaluateOrder3(benchmark::State& state) {
  const BSplineCurve c = interpolate_quintic(open_path()).curve;
  for (auto _ : state)
    for (int i = 0; i < 1000; ++i) benchmark::DoNotOptimize(bspline_derivatives(c, i * 1e-3, 3));
  state.SetItemsProcessed(state.iterations() * 1000);
}
BENCHMARK(BM_QuinticEvaluateOrder3)->Unit(benchmark::kMicrosecond);

void BM_QuinticArcLengthTable(benchmark::State& state) {
  const CurveView v = view(interpolate_quintic(open_path()).curve);
  for (auto _ : state) benchmark::DoNotOptimize(arc_length_table(v));
  state.SetItemsProcessed(state.iterations() * kThesisPoints);
}
BENCHMARK(BM_QuinticArcLengthTable)->Unit(benchmark::kMicrosecond);

}  // namespace

BENCHMARK_MAIN();
