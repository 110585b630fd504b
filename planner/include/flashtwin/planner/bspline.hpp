#pragma once
// Quintic (fifth-degree) non-uniform B-spline interpolation of 3-D points (thesis §4.3/§4.4):
// open curves with first/second-derivative end conditions, closed (periodic, C4 at the seam)
// curves, evaluation up to the fifth derivative, arc length, curvature/jerk smoothness, and the
// two baselines the thesis compares against (quintic polynomial least squares, natural cubic
// spline) behind one evaluation interface.
//
// Every curve here is parametrized over u ∈ [0, 1]; derivatives are with respect to u, so a
// first derivative is in [m] (per unit of u), a k-th derivative in [m] as well.
#include <array>
#include <functional>
#include <optional>
#include <string>
#include <vector>

#include "flashtwin/core/transform.hpp"

namespace flashtwin::planner {

// ---------------------------------------------------------------------------------------------
// Parametrization

/// How the interpolation parameters ū_k of the data points are spaced.
enum class Parametrization {
  kChordLength,  ///< ū_k − ū_{k−1} ∝ |Q_k − Q_{k−1}|
  kCentripetal,  ///< ū_k − ū_{k−1} ∝ |Q_k − Q_{k−1}|^½ (Lee 1989)
};

/// Parameters ū_0 = 0 < ū_1 < … of `points`, normalized to end at 1. Open: N values, the last 1.
/// Closed: N values ū_0..ū_{N−1} < 1, the closing segment Q_{N−1}→Q_0 ending at u = 1.
/// @throws ArgumentError when a point is not finite or lies within `min_point_distance` [m] of its
/// predecessor (the message names the index), or when fewer than `min_points` are given.
std::vector<double> parametrize(const std::vector<Vec3>& points, Parametrization parametrization,
                                bool closed, double min_point_distance, int min_points);

// ---------------------------------------------------------------------------------------------
// Banded linear systems (the interpolation solver, exposed for tests)

/// Square band matrix with `kl` sub- and `ku` super-diagonals, room for the LU fill (kl more
/// super-diagonals) and the row pivots of band_lu.
struct BandMatrix {
  int n = 0, kl = 0, ku = 0;
  std::vector<double> data;  ///< n rows × width(): entry (i, j) at i·width() + (j − i + kl)
  std::vector<int> pivots;   ///< after band_lu: row swapped with row k at step k
  BandMatrix() = default;
  BandMatrix(int n_, int kl_, int ku_);
  int width() const { return 2 * kl + ku + 1; }
  /// Entry (i, j). @pre i − kl ≤ j ≤ i + ku + kl.
  double& at(int i, int j) { return data[static_cast<std::size_t>(i) * width() + (j - i + kl)]; }
  double at(int i, int j) const {
    return data[static_cast<std::size_t>(i) * width() + (j - i + kl)];
  }
};

/// In-place LU factorization with partial pivoting inside the band, O(n·kl·(kl+ku)).
/// @return false when a pivot is exactly zero (singular matrix).
bool band_lu(BandMatrix& A);

/// Solves A·X = B in place with the factors of band_lu; `rhs` is n × nrhs, row-major.
void band_solve(const BandMatrix& lu, double* rhs, int nrhs);

// ---------------------------------------------------------------------------------------------
// Quintic B-spline interpolation

/// Which default an end derivative takes when the caller does not give it.
enum class EndEstimate {
  /// Velocity and acceleration of the cubic through the four end points at their parameters
  /// (three points: the parabola; two: the chord as velocity and zero acceleration).
  kCubic,
  /// Velocity from the cubic as above, acceleration zero ("natural" end, C'' = 0).
  kNatural,
};

/// Options of the quintic interpolation.
struct BSplineParams {
  Parametrization parametrization = Parametrization::kChordLength;
  /// Closed contour: periodic curve through Q_0..Q_{N−1} and back to Q_0, C4 at the seam; the
  /// end conditions below are then ignored. A last point repeating the first (within
  /// `min_point_distance`) is dropped.
  bool closed = false;
  /// End derivatives dC/du, d²C/du² at u = 0 and u = 1 [m] (u ∈ [0, 1], so a curve of length
  /// L run at constant speed has |dC/du| = L). Unset ones come from `end_estimate`.
  std::optional<Vec3> start_velocity, start_acceleration, end_velocity, end_acceleration;
  EndEstimate end_estimate = EndEstimate::kCubic;
  /// Consecutive points closer than this are rejected as duplicates [m].
  double min_point_distance = 1e-9;
};

/// A B-spline curve on u ∈ [0, 1]: C(u) = Σ_i P_i·B_{i,p}(u).
struct BSplineCurve {
  int degree = 5;
  /// Periodic (closed) curve: u outside [0, 1] wraps around. Open curves clamp u to [0, 1].
  bool periodic = false;
  /// Non-decreasing knots, size control_points.size() + degree + 1; the domain is
  /// [knots[degree], knots[control_points.size()]] = [0, 1]. Open: clamped (6 zeros, 6 ones).
  /// Periodic: the unclamped periodic extension of the data parameters.
  std::vector<double> knots;
  /// Control points [m]. Open: N + 4. Periodic: N distinct ones followed by the first `degree`
  /// repeated (N + 5 in all).
  std::vector<Vec3> control_points;
  /// Parameters ū_k of the interpolated points (size N).
  std::vector<double> params;
};

/// The interpolating curve and the end conditions it was built with.
struct BSplineResult {
  BSplineCurve curve;
  /// dC/du and d²C/du² at u = 0 and 1 [m] (given or estimated; for closed curves the values of
  /// the periodic curve at the seam).
  Vec3 start_velocity = Vec3::Zero(), start_acceleration = Vec3::Zero();
  Vec3 end_velocity = Vec3::Zero(), end_acceleration = Vec3::Zero();
};

/// Quintic B-spline through every point, O(N). Open: N + 4 control points from the N point
/// equations plus C'(0), C''(0), C'(1), C''(1); knots by de Boor's averaging over the sites
/// (0, 0, 0, ū_1, …, ū_{N−2}, 1, 1, 1); banded solve. Closed: knots at the data parameters,
/// cyclic banded (bordered) solve.
/// @pre points [m], N ≥ 2 (open) or N ≥ 6 distinct points (closed).
/// @throws ArgumentError on too few points, non-finite points or end vectors, duplicate
/// consecutive points, or a negative min_point_distance.
BSplineResult interpolate_quintic(const std::vector<Vec3>& points,
                                  const BSplineParams& params = {});

// ---------------------------------------------------------------------------------------------
// Evaluation

/// Derivatives dᵏC/duᵏ for k = 0..5 (orders not asked for are zero).
using CurveDerivs = std::array<Vec3, 6>;

/// Which one-sided limit to take at a knot.
enum class KnotSide {
  kRight,  ///< the polynomial piece starting at u (the default)
  kLeft,   ///< the piece ending at u
};

/// Derivatives 0..order of the B-spline at u (de Boor differencing on the knot span).
/// @pre 0 ≤ order ≤ 5.
CurveDerivs bspline_derivatives(const BSplineCurve& curve, double u, int order,
                                KnotSide side = KnotSide::kRight);

/// Point C(u) [m].
Vec3 bspline_point(const BSplineCurve& curve, double u);

/// Fifth-degree (or lower, when N ≤ 5) least-squares polynomial per coordinate over the
/// chord-length parameter: C(u) = Σ_j c_j·xʲ with x = 2u − 1. Does not pass through the points.
struct PolynomialCurve {
  std::vector<Vec3> coeffs;    ///< c_0..c_degree [m]
  std::vector<double> params;  ///< ū_k of the fitted points
};

/// Options of the polynomial baseline.
struct PolynomialFitParams {
  int degree = 5;  ///< polynomial degree (lowered to N − 1 for few points)
  Parametrization parametrization = Parametrization::kChordLength;
  double min_point_distance = 1e-9;  ///< [m], as in BSplineParams
};

/// Least-squares polynomial (normal equations in the Legendre basis of x, O(N)).
/// @throws ArgumentError as parametrize(), or when degree is outside 1..5.
PolynomialCurve fit_polynomial(const std::vector<Vec3>& points,
                               const PolynomialFitParams& params = {});

/// Natural cubic spline through the points (C'' = 0 at both ends), per coordinate.
struct CubicSplineCurve {
  std::vector<double> params;  ///< knots ū_k
  std::vector<Vec3> points;    ///< Q_k [m]
  std::vector<Vec3> second;    ///< d²C/du² at each knot [m]
};

/// Options of the cubic baseline.
struct CubicSplineParams {
  Parametrization parametrization = Parametrization::kChordLength;
  double min_point_distance = 1e-9;  ///< [m], as in BSplineParams
};

/// Natural cubic interpolation (tridiagonal Thomas solve), O(N).
/// @throws ArgumentError as parametrize() (N ≥ 2).
CubicSplineCurve interpolate_natural_cubic(const std::vector<Vec3>& points,
                                           const CubicSplineParams& params = {});

/// Any of the curves above behind one interface, for the sampling helpers below.
struct CurveView {
  /// Derivatives 0..order at u ∈ [0, 1]. @pre 0 ≤ order ≤ 5.
  std::function<CurveDerivs(double u, int order)> derivatives;
  /// Increasing parameters from 0 to 1 at which the curve's polynomial pieces meet
  /// (quadrature intervals of the arc length).
  std::vector<double> breaks;
};

CurveView view(const BSplineCurve& curve);
CurveView view(const PolynomialCurve& curve);
CurveView view(const CubicSplineCurve& curve);

/// `count` points at u uniformly spaced over [0, 1] (both ends included). @pre count ≥ 2.
std::vector<Vec3> sample_points(const CurveView& curve, int count);

/// Cumulative arc length s(u) at the break points (each break interval split in
/// `pieces_per_break` equal parts), by 5-point Gauss–Legendre quadrature per part.
struct ArcLengthTable {
  std::vector<double> u;  ///< increasing, from 0 to 1
  std::vector<double> s;  ///< [m] arc length from u = 0, same size
  double length() const { return s.empty() ? 0.0 : s.back(); }
};

ArcLengthTable arc_length_table(const CurveView& curve, int pieces_per_break = 2);

/// Arc length from 0 to u [m] (table plus quadrature over the partial interval).
double arc_length_at(const CurveView& curve, const ArcLengthTable& table, double u);

/// Parameter u at arc length s [m] (clamped to [0, length]), by safeguarded Newton iteration.
double param_at_arc_length(const CurveView& curve, const ArcLengthTable& table, double s);

/// Curvature |C'×C''| / |C'|³ [1/m] from derivatives w.r.t. any parameter (0 where C' = 0).
double curvature(const CurveDerivs& d);

/// Third derivative with respect to arc length, d³C/ds³ [1/m²] (the geometric jerk of the path
/// run at unit speed), from derivatives 0..3 w.r.t. any parameter (zero where C' = 0).
Vec3 third_derivative_by_arc_length(const CurveDerivs& d);

/// Options of the smoothness sampling.
struct SmoothnessParams {
  int samples = 5000;  ///< samples uniformly spaced in arc length (≥ 2)
};

/// Curvature and jerk along the curve and their largest jumps between consecutive samples.
struct SmoothnessResult {
  std::vector<double> u, s;       ///< sample parameters and arc lengths [m]
  std::vector<double> curvature;  ///< [1/m]
  std::vector<Vec3> jerk;         ///< d³C/ds³ [1/m²]
  double length = 0;              ///< [m]
  double max_curvature = 0;       ///< [1/m]
  double max_curvature_jump = 0;  ///< max |κ_{i+1} − κ_i| [1/m]
  double max_jerk = 0;            ///< max |d³C/ds³| [1/m²]
  double max_jerk_jump = 0;       ///< max |j_{i+1} − j_i| [1/m²]
};

/// Samples curvature and jerk uniformly in arc length. @throws ArgumentError when samples < 2.
SmoothnessResult evaluate_smoothness(const CurveView& curve, const SmoothnessParams& params = {});

// ---------------------------------------------------------------------------------------------
// Comparison of the methods (the thesis table)

enum class CurveMethod {
  kQuinticBSpline,        ///< interpolate_quintic, open
  kQuinticBSplineClosed,  ///< interpolate_quintic, closed
  kPolynomial5,           ///< fit_polynomial, degree 5
  kNaturalCubic,          ///< interpolate_natural_cubic
};

/// "quintic_bspline", "quintic_bspline_closed", "polynomial5", "natural_cubic".
std::string to_string(CurveMethod method);

/// Options of compare_curve_methods.
struct CurveComparisonParams {
  Parametrization parametrization = Parametrization::kChordLength;
  bool include_closed = false;    ///< also fit the closed quintic (points as a closed contour)
  int smoothness_samples = 5000;  ///< see SmoothnessParams
  double pass_tolerance = 1e-9;   ///< max point-to-curve distance of a curve that passes [m]
  int timing_repeats = 5;         ///< fits per method; the fastest is reported
};

/// One row of the comparison.
struct CurveMethodReport {
  CurveMethod method = CurveMethod::kQuinticBSpline;
  double fit_time = 0;             ///< [s] fastest of the timing repeats
  double mean_error_at_param = 0;  ///< mean |C(ū_k) − Q_k| [m]
  double max_error_at_param = 0;   ///< max |C(ū_k) − Q_k| [m]
  double mean_error = 0;           ///< mean point-to-curve distance (nearest point near ū_k) [m]
  double max_error = 0;            ///< max point-to-curve distance [m]
  bool passes_through = false;     ///< max_error < pass_tolerance
  double length = 0;               ///< [m]
  double max_curvature = 0;        ///< [1/m]
  double max_curvature_jump = 0;   ///< [1/m]
  double max_jerk = 0;             ///< [1/m²]
  double max_jerk_jump = 0;        ///< [1/m²]
};

struct CurveComparison {
  std::vector<CurveMethodReport> methods;  ///< quintic, (closed quintic), polynomial, cubic
};

/// Fits every method to `points` and measures time, distance to the points and smoothness.
/// @throws ArgumentError as the fitting functions.
CurveComparison compare_curve_methods(const std::vector<Vec3>& points,
                                      const CurveComparisonParams& params = {});

}  // namespace flashtwin::planner
