#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <cmath>
#include <limits>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/bspline.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

std::vector<Vec3> random_points(int n, std::uint64_t seed) {
  Rng rng(seed);
  std::vector<Vec3> p(n);
  for (auto& q : p) q = Vec3(rng.uniform(), rng.uniform(), rng.uniform());
  return p;
}

// n points on a circle of radius r in a tilted plane, with Gaussian noise of sigma [m]; the
// angles cover [0, span), their spacing jittered by ±jitter of a step.
std::vector<Vec3> noisy_circle(int n, double r, double sigma, double span, std::uint64_t seed,
                               double jitter = 0.3) {
  Rng rng(seed);
  const Mat3 R = Eigen::AngleAxisd(0.4, Vec3(1, 2, 3).normalized()).toRotationMatrix();
  std::vector<Vec3> p(n);
  for (int k = 0; k < n; ++k) {
    const double a = span * (k + jitter * rng.uniform(-1, 1)) / n;
    p[k] = R * Vec3(r * std::cos(a), r * std::sin(a), 0.0) +
           Vec3(rng.normal(0, sigma), rng.normal(0, sigma), rng.normal(0, sigma));
  }
  return p;
}

// Wavy closed-ish 3-D contour of about 1 m, as in the benchmark.
std::vector<Vec3> wavy_contour(int n, double span) {
  std::vector<Vec3> p(n);
  for (int k = 0; k < n; ++k) {
    const double a = span * k / n + 0.002 * std::sin(13.0 * k);
    const double r = 0.15 * (1.0 + 0.08 * std::sin(7 * a));
    p[k] = Vec3(r * std::cos(a), 0.8 * r * std::sin(a), 0.01 * std::sin(5 * a));
  }
  return p;
}

double max_residual(const BSplineCurve& c, const std::vector<Vec3>& pts) {
  double e = 0;
  for (std::size_t k = 0; k < pts.size(); ++k)
    e = std::max(e, (bspline_point(c, c.params[k]) - pts[k]).norm());
  return e;
}

// Distinct interior knots (strictly inside (0, 1)) of a curve.
std::vector<double> interior_knots(const BSplineCurve& c) {
  std::vector<double> k;
  const int nc = static_cast<int>(c.control_points.size());
  for (int i = c.degree + 1; i < nc; ++i)
    if (c.knots[i] > 0 && c.knots[i] < 1 && (k.empty() || c.knots[i] > k.back()))
      k.push_back(c.knots[i]);
  return k;
}

// Largest |dᵏC/duᵏ| over the knots, per order: the scale for relative continuity checks.
std::array<double, 6> derivative_scale(const BSplineCurve& c) {
  std::array<double, 6> s{};
  for (double u : c.knots) {
    const CurveDerivs d = bspline_derivatives(c, u, 5);
    for (int k = 0; k < 6; ++k) s[k] = std::max(s[k], d[k].norm());
  }
  return s;
}

// Checks C4 at every interior knot: one-sided limits of orders 0..4 agree; returns the largest
// relative jump of the fifth derivative (which a quintic generally has).
double check_c4(const BSplineCurve& c) {
  const auto scale = derivative_scale(c);
  double jump5 = 0;
  for (double u : interior_knots(c)) {
    const CurveDerivs L = bspline_derivatives(c, u, 5, KnotSide::kLeft);
    const CurveDerivs R = bspline_derivatives(c, u, 5, KnotSide::kRight);
    for (int k = 0; k <= 4; ++k)
      EXPECT_LE((L[k] - R[k]).norm(), 1e-9 * scale[k]) << "order " << k << " at u = " << u;
    jump5 = std::max(jump5, (L[5] - R[5]).norm() / scale[5]);
  }
  return jump5;
}

}  // namespace

TEST(BSpline, PassesThroughRandomPointsForEverySize) {
  for (int n : {2, 3, 4, 5, 6, 7, 12, 60, 1273}) {
    const auto pts = random_points(n, 100 + n);
    const BSplineResult r = interpolate_quintic(pts);
    ASSERT_EQ(r.curve.control_points.size(), static_cast<std::size_t>(n + 4));
    ASSERT_EQ(r.curve.knots.size(), static_cast<std::size_t>(n + 4 + 6));
    EXPECT_EQ(r.curve.params.front(), 0.0);
    EXPECT_EQ(r.curve.params.back(), 1.0);
    EXPECT_LT(max_residual(r.curve, pts), 1e-9) << n << " points";
    // The end points are the first and last control points of the clamped curve.
    EXPECT_LT((r.curve.control_points.front() - pts.front()).norm(), 1e-15);
    EXPECT_LT((r.curve.control_points.back() - pts.back()).norm(), 1e-15);
  }
}

TEST(BSpline, PassesThroughANoisyCircleWithBothParametrizations) {
  const auto pts = noisy_circle(400, 0.3, 1e-3, 1.9 * M_PI, 5);
  for (auto par : {Parametrization::kChordLength, Parametrization::kCentripetal}) {
    BSplineParams p;
    p.parametrization = par;
    const BSplineResult r = interpolate_quintic(pts, p);
    EXPECT_LT(max_residual(r.curve, pts), 1e-9);
  }
}

TEST(BSpline, ChordLengthParametersAreNormalizedCumulativeChords) {
  const std::vector<Vec3> pts = {{0, 0, 0}, {1, 0, 0}, {1, 3, 0}, {1, 3, 4}};
  const auto u = parametrize(pts, Parametrization::kChordLength, false, 0, 2);
  ASSERT_EQ(u.size(), 4u);
  EXPECT_DOUBLE_EQ(u[1], 1.0 / 8);
  EXPECT_DOUBLE_EQ(u[2], 4.0 / 8);
  EXPECT_DOUBLE_EQ(u[3], 1.0);
  const auto c = parametrize(pts, Parametrization::kCentripetal, false, 0, 2);
  const double tot = 1 + std::sqrt(3.0) + 2;
  EXPECT_NEAR(c[1], 1 / tot, 1e-15);
  EXPECT_NEAR(c[2], (1 + std::sqrt(3.0)) / tot, 1e-15);
  // Closed: the closing chord |(1,3,4) − 0| = √26 counts in the total.
  const auto z = parametrize(pts, Parametrization::kChordLength, true, 0, 4);
  EXPECT_NEAR(z[3], 8 / (8 + std::sqrt(26.0)), 1e-15);
}

TEST(BSpline, MeetsGivenEndDerivatives) {
  const auto pts = noisy_circle(50, 0.2, 0.0, 1.5 * M_PI, 9);
  BSplineParams p;
  p.start_velocity = Vec3(0.3, -0.7, 0.2);
  p.start_acceleration = Vec3(-2.0, 0.5, 1.0);
  p.end_velocity = Vec3(0.1, 0.9, -0.4);
  p.end_acceleration = Vec3(3.0, -1.0, 0.25);
  const BSplineResult r = interpolate_quintic(pts, p);
  const CurveDerivs d0 = bspline_derivatives(r.curve, 0.0, 2);
  const CurveDerivs d1 = bspline_derivatives(r.curve, 1.0, 2);
  EXPECT_LE((d0[1] - *p.start_velocity).norm(), 1e-9 * p.start_velocity->norm());
  EXPECT_LE((d0[2] - *p.start_acceleration).norm(), 1e-9 * p.start_acceleration->norm());
  EXPECT_LE((d1[1] - *p.end_velocity).norm(), 1e-9 * p.end_velocity->norm());
  EXPECT_LE((d1[2] - *p.end_acceleration).norm(), 1e-9 * p.end_acceleration->norm());
  EXPECT_EQ(r.start_velocity, *p.start_velocity);
  EXPECT_LT(max_residual(r.curve, pts), 1e-9);
}

namespace {

// Velocity and acceleration at x[0] of the polynomial through (x[i], y[i]): a dense
// Vandermonde solve, independent of the library's divided differences.
void reference_end(const std::vector<double>& x, const std::vector<Vec3>& y, Vec3& v, Vec3& a) {
  const int m = static_cast<int>(x.size());
  Eigen::MatrixXd V(m, m), Y(m, 3);
  for (int i = 0; i < m; ++i) {
    for (int j = 0; j < m; ++j) V(i, j) = std::pow(x[i] - x[0], j);
    Y.row(i) = y[i].transpose();
  }
  const Eigen::MatrixXd c = V.fullPivLu().solve(Y);
  v = c.row(1).transpose();
  a = m > 2 ? Vec3(2 * c.row(2).transpose()) : Vec3::Zero();
}

}  // namespace

TEST(BSpline, DefaultEndDerivativesAreTheEndCubicsOrNatural) {
  for (int n : {2, 3, 4, 30}) {
    const auto pts = noisy_circle(n, 0.2, 1e-4, 1.2 * M_PI, 3);
    const BSplineResult r = interpolate_quintic(pts);
    const auto& u = r.curve.params;
    const int m = std::min(n, 4);
    std::vector<double> xs, xe;
    std::vector<Vec3> ys, ye;
    for (int i = 0; i < m; ++i) {
      xs.push_back(u[i]);
      ys.push_back(pts[i]);
      xe.push_back(u[n - 1 - i]);
      ye.push_back(pts[n - 1 - i]);
    }
    Vec3 v0, a0, v1, a1;
    reference_end(xs, ys, v0, a0);
    reference_end(xe, ye, v1, a1);
    const double sv = v0.norm(), sa = std::max(a0.norm(), 1.0);
    EXPECT_LE((r.start_velocity - v0).norm(), 1e-9 * sv) << n;
    EXPECT_LE((r.start_acceleration - a0).norm(), 1e-9 * sa) << n;
    EXPECT_LE((r.end_velocity - v1).norm(), 1e-9 * sv) << n;
    EXPECT_LE((r.end_acceleration - a1).norm(), 1e-9 * sa) << n;
    const CurveDerivs d0 = bspline_derivatives(r.curve, 0.0, 2);
    const CurveDerivs d1 = bspline_derivatives(r.curve, 1.0, 2);
    EXPECT_LE((d0[1] - v0).norm(), 1e-9 * sv) << n;
    EXPECT_LE((d0[2] - a0).norm(), 1e-9 * sa) << n;
    EXPECT_LE((d1[1] - v1).norm(), 1e-9 * sv) << n;
    EXPECT_LE((d1[2] - a1).norm(), 1e-9 * sa) << n;
    // The end velocity points along the motion (from Q_{N−2} towards Q_{N−1}).
    EXPECT_GT(r.end_velocity.dot(pts.back() - pts[n - 2]), 0) << n;

    BSplineParams nat;
    nat.end_estimate = EndEstimate::kNatural;
    const BSplineResult rn = interpolate_quintic(pts, nat);
    EXPECT_LT(bspline_derivatives(rn.curve, 0.0, 2)[2].norm(), 1e-9) << n;
    EXPECT_LT(bspline_derivatives(rn.curve, 1.0, 2)[2].norm(), 1e-9) << n;
    EXPECT_LE((rn.start_velocity - v0).norm(), 1e-9 * sv) << n;
    EXPECT_LT(max_residual(rn.curve, pts), 1e-9) << n;
  }
}

TEST(BSpline, DefaultEndsAddNoJerkSpike) {
  // On a smooth path the estimated end conditions must be accurate enough that the jerk
  // changes no faster near the ends than inside (a 3-point parabola fails this by ~25x).
  const auto pts = wavy_contour(1273, 1.95 * M_PI);
  SmoothnessParams sp;
  sp.samples = 5000;
  const SmoothnessResult s = evaluate_smoothness(view(interpolate_quintic(pts).curve), sp);
  double ends = 0, inside = 0;
  for (int i = 1; i < sp.samples; ++i) {
    const double jump = (s.jerk[i] - s.jerk[i - 1]).norm();
    const bool near_end = i < sp.samples / 20 || i > sp.samples - sp.samples / 20;
    (near_end ? ends : inside) = std::max(near_end ? ends : inside, jump);
  }
  EXPECT_GT(inside, 0);
  EXPECT_LT(ends, 2 * inside);
}

TEST(BSpline, IsC4AtEveryInteriorKnotAndOnlyC4) {
  for (auto pts : {random_points(40, 21), noisy_circle(120, 0.3, 1e-3, 1.8 * M_PI, 4)}) {
    const BSplineResult r = interpolate_quintic(pts);
    ASSERT_FALSE(interior_knots(r.curve).empty());
    // The check can see a discontinuity: the fifth derivative does jump.
    EXPECT_GT(check_c4(r.curve), 1e-6);
  }
}

TEST(BSpline, DerivativesMatchFiniteDifferences) {
  const BSplineResult r = interpolate_quintic(noisy_circle(15, 0.3, 1e-2, 1.5 * M_PI, 8));
  Rng rng(3);
  const auto scale = derivative_scale(r.curve);
  for (int n = 0; n < 50; ++n) {
    const double u = rng.uniform(0.05, 0.95), h = 1e-6;
    const CurveDerivs d = bspline_derivatives(r.curve, u, 5);
    const CurveDerivs dp = bspline_derivatives(r.curve, u + h, 5);
    const CurveDerivs dm = bspline_derivatives(r.curve, u - h, 5);
    for (int k = 1; k <= 5; ++k) {
      const Vec3 fd = (dp[k - 1] - dm[k - 1]) / (2 * h);
      // A knot between u − h and u + h makes the fifth-order difference meaningless.
      if (k == 5 && (dp[5] - dm[5]).norm() > 1e-12 * scale[5]) continue;
      EXPECT_LE((fd - d[k]).norm(), 1e-5 * scale[k]) << "order " << k << " at u = " << u;
    }
  }
}

TEST(BSpline, ClosedCurvePassesThroughAndClosesWithC4) {
  const auto pts = noisy_circle(200, 0.25, 1e-3, 2 * M_PI, 12);
  BSplineParams p;
  p.closed = true;
  const BSplineResult r = interpolate_quintic(pts, p);
  const BSplineCurve& c = r.curve;
  ASSERT_TRUE(c.periodic);
  ASSERT_EQ(c.control_points.size(), pts.size() + 5);
  EXPECT_LT(max_residual(c, pts), 1e-9);
  // The seam: u = 1 (left piece, not wrapped) against u = 0 (right piece).
  const auto scale = derivative_scale(c);
  const CurveDerivs a = bspline_derivatives(c, 0.0, 5, KnotSide::kRight);
  const CurveDerivs b = bspline_derivatives(c, 1.0, 5, KnotSide::kLeft);
  for (int k = 0; k <= 4; ++k) EXPECT_LE((a[k] - b[k]).norm(), 1e-9 * scale[k]) << "order " << k;
  EXPECT_LE((a[0] - pts[0]).norm(), 1e-9);
  check_c4(c);
  // Parameters outside [0, 1] wrap around.
  EXPECT_LT((bspline_point(c, 1.25) - bspline_point(c, 0.25)).norm(), 1e-12);
  EXPECT_LT((bspline_point(c, -0.1) - bspline_point(c, 0.9)).norm(), 1e-12);
  // The reported seam derivatives are the curve's.
  EXPECT_EQ(r.start_velocity, a[1]);
}

TEST(BSpline, ClosedCurveDropsARepeatedFirstPointAndWorksWithFewPoints) {
  std::vector<Vec3> pts = noisy_circle(6, 0.25, 0.0, 2 * M_PI, 1);
  BSplineParams p;
  p.closed = true;
  const BSplineResult r6 = interpolate_quintic(pts, p);
  EXPECT_LT(max_residual(r6.curve, pts), 1e-9);
  pts.push_back(pts.front());
  const BSplineResult r7 = interpolate_quintic(pts, p);
  ASSERT_EQ(r7.curve.params.size(), 6u);
  for (std::size_t i = 0; i < r6.curve.control_points.size(); ++i)
    EXPECT_LT((r6.curve.control_points[i] - r7.curve.control_points[i]).norm(), 1e-15);
  const CurveDerivs a = bspline_derivatives(r6.curve, 0.0, 4);
  const CurveDerivs b = bspline_derivatives(r6.curve, 1.0, 4, KnotSide::kLeft);
  for (int k = 0; k <= 4; ++k) EXPECT_LE((a[k] - b[k]).norm(), 1e-9 * (1 + a[k].norm()));
}

TEST(BSpline, ClosedCircleHasConstantCurvatureAndKnownLength) {
  const double R = 0.25;
  BSplineParams p;
  p.closed = true;
  SmoothnessParams sp;
  sp.samples = 1000;
  // Evenly spaced points: chord length is proportional to arc length, so the quintic converges
  // at full order; jittered spacing makes the parametrization's speed uneven and costs accuracy.
  for (double jitter : {0.0, 0.3}) {
    const double tol = jitter == 0 ? 1e-7 : 1e-3;  // relative
    const CurveView v =
        view(interpolate_quintic(noisy_circle(256, R, 0.0, 2 * M_PI, 2, jitter), p).curve);
    const ArcLengthTable tab = arc_length_table(v);
    EXPECT_NEAR(tab.length(), 2 * M_PI * R, 2 * M_PI * R * tol * tol);
    const SmoothnessResult s = evaluate_smoothness(v, sp);
    for (int i = 0; i < sp.samples; ++i) {
      ASSERT_NEAR(s.curvature[i], 1 / R, tol / R);
      // On a circle run at unit speed, d³r/ds³ = −κ²·T: magnitude 1/R², along the tangent.
      ASSERT_NEAR(s.jerk[i].norm(), 1 / (R * R), 10 * tol / (R * R));
      const Vec3 T = v.derivatives(s.u[i], 1)[1].normalized();
      ASSERT_NEAR(s.jerk[i].dot(T), -1 / (R * R), 10 * tol / (R * R));
    }
    EXPECT_NEAR(s.s.back(), tab.length(), 1e-12);
  }
}

TEST(BSpline, CurvatureAndJerkDoNotDependOnTheParametrization) {
  // The same geometry through u = φ(w) = w²·(3 − 2w) (speed varying, zero at neither end for
  // w in (0, 1)): the chain rule gives the w-derivatives, and the arc-length quantities must
  // agree with those from the u-derivatives.
  const BSplineResult r = interpolate_quintic(noisy_circle(40, 0.3, 5e-3, 1.5 * M_PI, 13));
  Rng rng(21);
  for (int n = 0; n < 100; ++n) {
    const double w = rng.uniform(0.05, 0.95);
    const double f = w * w * (3 - 2 * w), f1 = 6 * w * (1 - w), f2 = 6 - 12 * w, f3 = -12;
    const CurveDerivs d = bspline_derivatives(r.curve, f, 3);
    CurveDerivs e;
    e.fill(Vec3::Zero());
    e[0] = d[0];
    e[1] = d[1] * f1;
    e[2] = d[2] * f1 * f1 + d[1] * f2;
    e[3] = d[3] * f1 * f1 * f1 + 3 * d[2] * f1 * f2 + d[1] * f3;
    EXPECT_NEAR(curvature(e), curvature(d), 1e-9 * curvature(d));
    const Vec3 jd = third_derivative_by_arc_length(d), je = third_derivative_by_arc_length(e);
    EXPECT_LE((jd - je).norm(), 1e-9 * jd.norm());
    // And against the definition: d/ds of the curvature vector r'' by central differences in s.
    auto rss = [&](double u) {
      const CurveDerivs q = bspline_derivatives(r.curve, u, 2);
      const double v = q[1].norm();
      return Vec3((q[2] - q[2].dot(q[1]) / (v * v) * q[1]) / (v * v));
    };
    const double v = d[1].norm(), hs = 1e-5;
    const Vec3 fd = (rss(f + hs / v) - rss(f - hs / v)) / (2 * hs);
    EXPECT_LE((fd - jd).norm(), 1e-4 * jd.norm());
  }
}

TEST(BSpline, ArcLengthAndItsInverseAgree) {
  const CurveView v = view(interpolate_quintic(noisy_circle(80, 0.3, 2e-3, 1.7 * M_PI, 6)).curve);
  // 5-point Gauss–Legendre converges at O(h¹⁰): halving the pieces changes little.
  const ArcLengthTable tab = arc_length_table(v);
  const ArcLengthTable fine = arc_length_table(v, 16);
  EXPECT_NEAR(tab.length(), fine.length(), 1e-8 * fine.length());
  EXPECT_NEAR(arc_length_table(v, 1).length(), fine.length(), 1e-5 * fine.length());
  Rng rng(4);
  for (int n = 0; n < 100; ++n) {
    const double s = rng.uniform(0, tab.length());
    const double u = param_at_arc_length(v, tab, s);
    EXPECT_NEAR(arc_length_at(v, tab, u), s, 1e-11);
  }
  EXPECT_EQ(param_at_arc_length(v, tab, -1.0), 0.0);
  EXPECT_EQ(param_at_arc_length(v, tab, 1e9), 1.0);
  const auto samples = sample_points(v, 11);
  ASSERT_EQ(samples.size(), 11u);
  EXPECT_LT((samples.back() - v.derivatives(1.0, 0)[0]).norm(), 1e-15);
}

TEST(BSpline, CollinearPointsGiveAStraightCurve) {
  const Vec3 a(0.1, -0.2, 0.3), dir = Vec3(1, -2, 0.5).normalized();
  Rng rng(17);
  std::vector<Vec3> pts;
  double s = 0;
  for (int k = 0; k < 40; ++k) {
    pts.push_back(a + s * dir);
    s += rng.uniform(0.005, 0.05);
  }
  for (auto est : {EndEstimate::kCubic, EndEstimate::kNatural}) {
    BSplineParams p;
    p.end_estimate = est;
    const BSplineResult r = interpolate_quintic(pts, p);
    for (const Vec3& P : r.curve.control_points)
      EXPECT_LT((P - a).cross(dir).norm(), 1e-12);  // every control point on the line
    SmoothnessParams sp;
    sp.samples = 500;
    const SmoothnessResult sm = evaluate_smoothness(view(r.curve), sp);
    EXPECT_LT(sm.max_curvature, 1e-9);
    EXPECT_NEAR(sm.length, (pts.back() - pts.front()).norm(), 1e-9);
  }
}

TEST(BSpline, RejectsBadInput) {
  EXPECT_THROW(interpolate_quintic({}), ArgumentError);
  EXPECT_THROW(interpolate_quintic({Vec3(0, 0, 0)}), ArgumentError);
  auto pts = random_points(10, 1);
  pts[3].y() = std::numeric_limits<double>::quiet_NaN();
  try {
    interpolate_quintic(pts);
    FAIL() << "NaN accepted";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("points[3]"), std::string::npos) << e.what();
  }
  pts = random_points(10, 1);
  pts[5] = pts[4];
  try {
    interpolate_quintic(pts);
    FAIL() << "duplicate accepted";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("points[5]"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("points[4]"), std::string::npos) << e.what();
  }
  EXPECT_THROW(fit_polynomial(pts), ArgumentError);
  EXPECT_THROW(interpolate_natural_cubic(pts), ArgumentError);

  BSplineParams closed;
  closed.closed = true;
  EXPECT_THROW(interpolate_quintic(random_points(5, 2), closed), ArgumentError);
  BSplineParams bad_v;
  bad_v.end_velocity = Vec3(0, std::numeric_limits<double>::infinity(), 0);
  EXPECT_THROW(interpolate_quintic(random_points(5, 2), bad_v), ArgumentError);
  BSplineParams bad_d;
  bad_d.min_point_distance = -1;
  EXPECT_THROW(interpolate_quintic(random_points(5, 2), bad_d), ArgumentError);
  PolynomialFitParams bad_deg;
  bad_deg.degree = 6;
  EXPECT_THROW(fit_polynomial(random_points(10, 2), bad_deg), ArgumentError);
  EXPECT_THROW(evaluate_smoothness(view(interpolate_natural_cubic(random_points(4, 2))), {1}),
               ArgumentError);
}

TEST(BandSolver, MatchesADenseSolveOnRandomBandedSystems) {
  Rng rng(99);
  for (auto [n, kl, ku] : {std::array<int, 3>{50, 3, 2}, {40, 2, 5}, {30, 0, 3}, {7, 4, 4}}) {
    BandMatrix A(n, kl, ku);
    Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(n, n);
    for (int i = 0; i < n; ++i)
      for (int j = std::max(0, i - kl); j <= std::min(n - 1, i + ku); ++j) {
        // Zero diagonals now and then force row exchanges.
        const double v = (i == j && i % 3 == 0 && kl > 0) ? 0.0 : rng.uniform(-1, 1);
        A.at(i, j) = v;
        dense(i, j) = v;
      }
    Eigen::MatrixXd B(n, 2);
    for (int i = 0; i < n; ++i) B(i, 0) = rng.uniform(-1, 1), B(i, 1) = rng.uniform(-1, 1);
    const Eigen::MatrixXd x_dense = dense.partialPivLu().solve(B);
    std::vector<double> rhs(2 * n);
    for (int i = 0; i < n; ++i) rhs[2 * i] = B(i, 0), rhs[2 * i + 1] = B(i, 1);
    ASSERT_TRUE(band_lu(A));
    band_solve(A, rhs.data(), 2);
    for (int i = 0; i < n; ++i)
      for (int c = 0; c < 2; ++c)
        EXPECT_NEAR(rhs[2 * i + c], x_dense(i, c), 1e-9 * (1 + x_dense.cwiseAbs().maxCoeff()))
            << "n=" << n << " kl=" << kl << " ku=" << ku;
  }
  // A zero column is singular.
  BandMatrix S(4, 1, 1);
  S.at(0, 0) = 1;
  S.at(1, 0) = 1;
  S.at(2, 3) = 1;
  S.at(3, 3) = 1;
  EXPECT_FALSE(band_lu(S));
}

TEST(Baselines, CubicInterpolatesAndThePolynomialDoesNotOnAWigglyCurve) {
  std::vector<Vec3> pts;
  for (int k = 0; k < 60; ++k) {
    const double x = k / 59.0;
    pts.emplace_back(x, 0.1 * std::sin(6 * M_PI * x), 0.05 * std::cos(4 * M_PI * x));
  }
  const PolynomialCurve poly = fit_polynomial(pts);
  ASSERT_EQ(poly.coeffs.size(), 6u);
  const CubicSplineCurve cub = interpolate_natural_cubic(pts);
  const CurveView vp = view(poly), vc = view(cub);
  double ep = 0, ec = 0;
  for (int k = 0; k < 60; ++k) {
    ep = std::max(ep, (vp.derivatives(poly.params[k], 0)[0] - pts[k]).norm());
    ec = std::max(ec, (vc.derivatives(cub.params[k], 0)[0] - pts[k]).norm());
  }
  EXPECT_GT(ep, 1e-2);
  EXPECT_LT(ec, 1e-12);
  // Natural ends, C2 at the knots, third derivative jumping.
  EXPECT_LT(vc.derivatives(0.0, 2)[2].norm(), 1e-12);
  EXPECT_LT(vc.derivatives(1.0, 2)[2].norm(), 1e-12);
  const double u = cub.params[20], h = 1e-9;
  const CurveDerivs L = vc.derivatives(u - h, 3), R = vc.derivatives(u + h, 3);
  EXPECT_LT((L[2] - R[2]).norm(), 1e-5);
  EXPECT_GT((L[3] - R[3]).norm(), 1.0);
}

TEST(Baselines, PolynomialIsTheLeastSquaresFitAndInterpolatesFewPoints) {
  // Least squares: the residuals are orthogonal to every monomial xʲ, j ≤ 5 (normal equations).
  const auto pts = noisy_circle(200, 0.3, 1e-3, 1.5 * M_PI, 8);
  const PolynomialCurve poly = fit_polynomial(pts);
  ASSERT_EQ(poly.coeffs.size(), 6u);
  const CurveView v = view(poly);
  Eigen::Matrix<double, 6, 3> normal = Eigen::Matrix<double, 6, 3>::Zero();
  double max_res = 0;
  for (std::size_t k = 0; k < pts.size(); ++k) {
    const Vec3 r = v.derivatives(poly.params[k], 0)[0] - pts[k];
    max_res = std::max(max_res, r.norm());
    const double x = 2 * poly.params[k] - 1;
    for (int j = 0; j < 6; ++j) normal.row(j) += std::pow(x, j) * r.transpose();
  }
  EXPECT_GT(max_res, 1e-3);
  EXPECT_LT(normal.cwiseAbs().maxCoeff(), 1e-12);
  // Evenly spaced points on a line: chord length is linear in position, so the fit is exact.
  std::vector<Vec3> line;
  for (int k = 0; k < 1273; ++k) line.push_back(Vec3(0.1, 0.2, 0.3) + k * 1e-3 * Vec3(1, 2, 2) / 3);
  const PolynomialCurve pl = fit_polynomial(line);
  for (int k = 0; k < 1273; k += 7)
    EXPECT_LT((view(pl).derivatives(pl.params[k], 0)[0] - line[k]).norm(), 1e-12);
  // Derivatives against finite differences.
  const double u = 0.37, h = 1e-5;
  const CurveDerivs d = v.derivatives(u, 5), dp = v.derivatives(u + h, 5),
                    dm = v.derivatives(u - h, 5);
  for (int k = 1; k <= 5; ++k)
    EXPECT_LE(((dp[k - 1] - dm[k - 1]) / (2 * h) - d[k]).norm(), 1e-5 * (1 + d[k].norm()));
  // Four points: degree 3, through all of them.
  const auto few = random_points(4, 8);
  const PolynomialCurve p4 = fit_polynomial(few);
  ASSERT_EQ(p4.coeffs.size(), 4u);
  for (int k = 0; k < 4; ++k)
    EXPECT_LT((view(p4).derivatives(p4.params[k], 0)[0] - few[k]).norm(), 1e-12);
}

TEST(Comparison, QuinticAndCubicPassThroughTheQuinticIsSmoother) {
  const auto pts = wavy_contour(300, 1.9 * M_PI);
  CurveComparisonParams p;
  p.include_closed = true;
  p.smoothness_samples = 3000;
  p.timing_repeats = 1;
  const CurveComparison c = compare_curve_methods(pts, p);
  ASSERT_EQ(c.methods.size(), 4u);
  const auto& q = c.methods[0];
  const auto& qc = c.methods[1];
  const auto& poly = c.methods[2];
  const auto& cub = c.methods[3];
  EXPECT_EQ(q.method, CurveMethod::kQuinticBSpline);
  EXPECT_EQ(qc.method, CurveMethod::kQuinticBSplineClosed);
  EXPECT_EQ(poly.method, CurveMethod::kPolynomial5);
  EXPECT_EQ(cub.method, CurveMethod::kNaturalCubic);
  EXPECT_TRUE(q.passes_through);
  EXPECT_TRUE(qc.passes_through);
  EXPECT_TRUE(cub.passes_through);
  EXPECT_FALSE(poly.passes_through);
  EXPECT_GT(poly.mean_error, 1e-3);
  for (const auto& m : c.methods) {
    EXPECT_LE(m.max_error, m.max_error_at_param + 1e-15) << to_string(m.method);
    EXPECT_LE(m.mean_error, m.max_error) << to_string(m.method);
    EXPECT_GT(m.fit_time, 0.0);
    EXPECT_GT(m.length, 0.7);
  }
  // The cubic's third derivative jumps at every knot; the quintic's is continuous.
  EXPECT_LT(q.max_jerk_jump, 0.5 * cub.max_jerk_jump);
  EXPECT_LT(qc.max_jerk_jump, 0.5 * cub.max_jerk_jump);
  EXPECT_EQ(to_string(CurveMethod::kNaturalCubic), "natural_cubic");
}
