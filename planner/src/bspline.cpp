#include "flashtwin/planner/bspline.hpp"

#include <Eigen/Dense>
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <memory>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::planner {

namespace {

constexpr int kQuintic = 5;
constexpr int kMaxDegree = 5;
constexpr int kMaxOrder = 5;

std::string fmt(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.6g", v);
  return buf;
}

std::string fmt(const Vec3& p) {
  return "(" + fmt(p.x()) + ", " + fmt(p.y()) + ", " + fmt(p.z()) + ")";
}

void check_finite(const std::optional<Vec3>& v, const char* name) {
  if (v && !v->allFinite())
    throw ArgumentError(std::string(name) + ": expected finite values, got " + fmt(*v));
}

// Index of the knot span [t_s, t_{s+1}) holding u, restricted to the domain spans p..nc−1.
// kRight picks the span starting at u when u is a knot, kLeft the one ending there.
int find_span(const std::vector<double>& t, int p, int nc, double u, KnotSide side) {
  const auto first = t.begin() + p, last = t.begin() + nc + 1;
  const auto it = side == KnotSide::kRight ? std::upper_bound(first, last, u)
                                           : std::lower_bound(first, last, u);
  const int s = static_cast<int>(it - t.begin()) - 1;
  return std::clamp(s, p, nc - 1);
}

// Cox–de Boor triangle: tri[d][j] = B_{s−d+j, d}(u) for d = 0..p, j = 0..d (the basis functions
// of every degree up to p that are nonzero on span s). Each lower-degree function feeds its two
// neighbours above with one shared denominator, so a level costs d divisions.
// @pre t_s < t_{s+1}.
void basis_triangle(const double* t, int s, double u, int p, double tri[6][6]) {
  tri[0][0] = 1.0;
  for (int d = 1; d <= p; ++d) {
    double saved = 0.0;
    for (int r = 0; r < d; ++r) {
      const int i = s - d + 1 + r;  // B_{i, d−1} = tri[d−1][r]
      const double temp = tri[d - 1][r] / (t[i + d] - t[i]);
      tri[d][r] = saved + (t[i + d] - u) * temp;
      saved = (u - t[i]) * temp;
    }
    tri[d][d] = saved;
  }
}

// Derivatives 0..order on span s of Σ_j c[j]·B_{s−p+j, p}: the coefficients are differenced
// in place (the k-th derivative of a degree-p spline is a degree-(p−k) spline whose
// coefficients are scaled differences) and combined with the lower-degree rows of the triangle.
// T is Vec3 for curve points or a 6-vector for basis-function rows.
template <class T>
void span_derivatives(const double* t, int s, int p, const double tri[6][6], T* c, int order,
                      T* out) {
  out[0] = T::Zero();
  for (int j = 0; j <= p; ++j) out[0] += tri[p][j] * c[j];
  for (int k = 1; k <= order; ++k) {
    out[k] = T::Zero();
    if (k > p) continue;
    const int d = p - k + 1;  // degree before this differentiation
    for (int j = p; j >= k; --j) {
      const int i = s - p + j;
      c[j] = (d / (t[i + d] - t[i])) * (c[j] - c[j - 1]);
    }
    for (int j = k; j <= p; ++j) out[k] += tri[p - k][j - k] * c[j];
  }
}

using Vec6 = Eigen::Matrix<double, 6, 1>;

// Derivatives 0..order of the basis functions B_{s−p..s} at u: rows[k][j] = B^{(k)}_{s−p+j}(u).
void basis_derivative_rows(const std::vector<double>& t, int s, int p, double u, int order,
                           Vec6* rows) {
  double tri[6][6];
  basis_triangle(t.data(), s, u, p, tri);
  Vec6 c[6];
  for (int j = 0; j <= p; ++j) c[j] = Vec6::Unit(j);
  span_derivatives(t.data(), s, p, tri, c, order, rows);
}

// Gauss–Legendre, 5 points on [−1, 1].
constexpr double kGlX[5] = {-0.9061798459386640, -0.5384693101056831, 0.0, 0.5384693101056831,
                            0.9061798459386640};
constexpr double kGlW[5] = {0.2369268850561891, 0.4786286704993665, 0.5688888888888889,
                            0.4786286704993665, 0.2369268850561891};

double speed_integral(const CurveView& c, double a, double b) {
  const double h = 0.5 * (b - a), m = 0.5 * (a + b);
  double sum = 0.0;
  for (int q = 0; q < 5; ++q) sum += kGlW[q] * c.derivatives(m + h * kGlX[q], 1)[1].norm();
  return sum * h;
}

}  // namespace

// ---------------------------------------------------------------------------------------------

namespace {

// parametrize() over the first n of `points` (the closed fit leaves out a repeated first point).
std::vector<double> parametrize_first(const std::vector<Vec3>& points, int n,
                                      Parametrization parametrization, bool closed,
                                      double min_point_distance, int min_points) {
  if (!(min_point_distance >= 0))
    throw ArgumentError("min_point_distance: expected a value >= 0 m, got " +
                        fmt(min_point_distance));
  if (n < min_points)
    throw ArgumentError("points: expected at least " + std::to_string(min_points) +
                        (closed ? " distinct points for a closed curve" : " points") + ", got " +
                        std::to_string(n));
  for (int k = 0; k < n; ++k)
    if (!points[k].allFinite())
      throw ArgumentError("points[" + std::to_string(k) + "]: expected finite coordinates, got " +
                          fmt(points[k]));
  std::vector<double> u(n, 0.0);
  auto step = [&](int a, int b) {
    const double d = (points[b] - points[a]).norm();
    if (!(d > min_point_distance))
      throw ArgumentError("points[" + std::to_string(b) + "]: expected a point more than " +
                          fmt(min_point_distance) + " m from points[" + std::to_string(a) +
                          "], got a distance of " + fmt(d) + " m (duplicate point)");
    return parametrization == Parametrization::kCentripetal ? std::sqrt(d) : d;
  };
  double total = 0.0;
  for (int k = 1; k < n; ++k) {
    total += step(k - 1, k);
    u[k] = total;
  }
  if (closed) total += step(n - 1, 0);
  for (int k = 1; k < n; ++k) u[k] /= total;
  if (!closed) u[n - 1] = 1.0;
  return u;
}

}  // namespace

std::vector<double> parametrize(const std::vector<Vec3>& points, Parametrization parametrization,
                                bool closed, double min_point_distance, int min_points) {
  return parametrize_first(points, static_cast<int>(points.size()), parametrization, closed,
                           min_point_distance, min_points);
}

// ---------------------------------------------------------------------------------------------

BandMatrix::BandMatrix(int n_, int kl_, int ku_)
    : n(n_),
      kl(kl_),
      ku(ku_),
      data(static_cast<std::size_t>(n_) * (2 * kl_ + ku_ + 1), 0.0),
      pivots(n_, 0) {}

bool band_lu(BandMatrix& A) {
  const int n = A.n, kl = A.kl, ku = A.ku, w = A.width();
  // Row i as an array indexed by column: entry (i, j) at row(i)[j].
  auto row = [&](int i) { return A.data.data() + static_cast<std::ptrdiff_t>(i) * w + kl - i; };
  A.pivots.assign(n, 0);
  for (int k = 0; k < n; ++k) {
    const int last_row = std::min(n - 1, k + kl);
    const int last_col = std::min(n - 1, k + ku + kl);
    int piv = k;
    double best = std::abs(row(k)[k]);
    for (int i = k + 1; i <= last_row; ++i)
      if (std::abs(row(i)[k]) > best) {
        best = std::abs(row(i)[k]);
        piv = i;
      }
    A.pivots[k] = piv;
    if (best == 0.0) return false;
    double* rk = row(k);
    // Swap only columns k..: the multipliers left of k stay with their step (LAPACK's order).
    if (piv != k) std::swap_ranges(rk + k, rk + last_col + 1, row(piv) + k);
    const double inv = 1.0 / rk[k];
    for (int i = k + 1; i <= last_row; ++i) {
      double* ri = row(i);
      if (ri[k] == 0.0) continue;
      const double l = ri[k] *= inv;
      for (int j = k + 1; j <= last_col; ++j) ri[j] -= l * rk[j];
    }
  }
  return true;
}

namespace {

// Forward (row swaps + unit L) and back substitution; NR > 0 fixes the number of right-hand
// sides at compile time (the common 3 and 7) so each row update is an unrolled fixed-size
// vector operation held in registers, NR = 0 reads the count from nrhs.
template <int NR>
void band_solve_impl(const BandMatrix& lu, double* rhs, int nrhs) {
  const int n = lu.n, kl = lu.kl, ku = lu.ku, w = lu.width();
  const int nr = NR > 0 ? NR : nrhs;
  using Row = Eigen::Matrix<double, 1, (NR > 0 ? NR : Eigen::Dynamic)>;
  auto a = [&](int i) { return lu.data.data() + static_cast<std::ptrdiff_t>(i) * w + kl - i; };
  auto b = [&](int i) { return Eigen::Map<Row>(rhs + static_cast<std::size_t>(i) * nr, nr); };
  for (int k = 0; k < n; ++k) {
    const int piv = lu.pivots[k];
    if (piv != k) b(k).swap(b(piv));
    const Row bk = b(k);
    for (int i = k + 1; i <= std::min(n - 1, k + kl); ++i) b(i) -= a(i)[k] * bk;
  }
  // Back substitution, farthest column first: x_{i+1}, the value just computed, enters last,
  // which keeps the dependency chain from row to row short.
  for (int i = n - 1; i >= 0; --i) {
    const double* ai = a(i);
    const double inv = 1.0 / ai[i];
    Row acc = b(i);
    for (int j = std::min(n - 1, i + ku + kl); j > i; --j) acc -= ai[j] * b(j);
    b(i) = acc * inv;
  }
}

}  // namespace

void band_solve(const BandMatrix& lu, double* rhs, int nrhs) {
  switch (nrhs) {
    case 3:
      band_solve_impl<3>(lu, rhs, 3);
      break;
    case 7:
      band_solve_impl<7>(lu, rhs, 7);
      break;
    default:
      band_solve_impl<0>(lu, rhs, nrhs);
      break;
  }
}

// ---------------------------------------------------------------------------------------------

namespace {

// First and second derivative at x[0] of the polynomial through (x[i], y[i]), i < m (m ≤ 4),
// from its Newton divided-difference form.
void end_derivatives(const double* x, const Vec3* y, int m, Vec3& d1, Vec3& d2) {
  Vec3 c[4];
  for (int i = 0; i < m; ++i) c[i] = y[i];
  for (int j = 1; j < m; ++j)
    for (int i = m - 1; i >= j; --i) c[i] = (c[i] - c[i - 1]) / (x[i] - x[i - j]);
  // Horner on P(x) = c0 + (x − x0)(c1 + (x − x1)(c2 + …)) together with P' and P''.
  Vec3 P = c[m - 1], dP = Vec3::Zero(), ddP = Vec3::Zero();
  for (int i = m - 2; i >= 0; --i) {
    const double h = x[0] - x[i];
    ddP = ddP * h + 2.0 * dP;
    dP = dP * h + P;
    P = P * h + c[i];
  }
  d1 = dP;
  d2 = ddP;
}

BSplineResult interpolate_open(const std::vector<Vec3>& Q, const BSplineParams& params) {
  const int p = kQuintic;
  const std::vector<double> ub =
      parametrize(Q, params.parametrization, false, params.min_point_distance, 2);
  const int N = static_cast<int>(Q.size());
  const int nc = N + 4;  // control points

  // End conditions: given, or from the cubic through the four end points (fewer when N < 4).
  // A 3-point parabola is too crude for a sixth-order interpolant: its acceleration error shows
  // up as a jerk spike at the ends.
  BSplineResult res;
  Vec3 v0, a0, v1, a1;
  {
    const int m = std::min(N, 4);
    double xs[4], xe[4];
    Vec3 ys[4], ye[4];
    for (int i = 0; i < m; ++i) {
      xs[i] = ub[i];
      ys[i] = Q[i];
      xe[i] = ub[N - 1 - i];
      ye[i] = Q[N - 1 - i];
    }
    end_derivatives(xs, ys, m, v0, a0);
    end_derivatives(xe, ye, m, v1, a1);
  }
  if (params.end_estimate == EndEstimate::kNatural) a0 = a1 = Vec3::Zero();
  res.start_velocity = params.start_velocity.value_or(v0);
  res.start_acceleration = params.start_acceleration.value_or(a0);
  res.end_velocity = params.end_velocity.value_or(v1);
  res.end_acceleration = params.end_acceleration.value_or(a1);

  // Knots: de Boor's averaging over the N + 4 sites, where the two derivative conditions at
  // each end repeat the end parameter (sites 0,0,0, ū_1..ū_{N−2}, 1,1,1): every interior knot
  // is the mean of p consecutive sites, which keeps each site inside its basis function's
  // support (Schoenberg–Whitney) so the system is nonsingular.
  BSplineCurve& curve = res.curve;
  curve.degree = p;
  curve.periodic = false;
  curve.params = ub;
  std::vector<double>& t = curve.knots;
  t.assign(nc + p + 1, 0.0);
  auto site = [&](int i) { return i < 3 ? 0.0 : (i > N ? 1.0 : ub[i - 2]); };
  for (int j = 1; j <= N - 2; ++j) {
    double sum = 0.0;
    for (int i = j; i < j + p; ++i) sum += site(i);
    t[p + j] = sum / p;
  }
  for (int i = nc; i <= nc + p; ++i) t[i] = 1.0;

  // Rows in site order: C(0), C'(0), C''(0), C(ū_1)…C(ū_{N−2}), C''(1), C'(1), C(1). With
  // clamped knots the k-th derivative at an end involves only the first/last k + 1 control
  // points, so the end rows are triangular and the matrix is banded. Interior parameters
  // increase, so their spans are found by walking forward.
  std::vector<int> span(N, p);
  int kl = 2, ku = 2;
  for (int k = 1, s = p; k <= N - 2; ++k) {
    while (s < nc - 1 && t[s + 1] <= ub[k]) ++s;
    span[k] = s;
    kl = std::max(kl, k + 2 - (s - p));  // row k + 2 holds columns s − p .. s
    ku = std::max(ku, s - (k + 2));
  }
  BandMatrix A(nc, kl, ku);
  std::vector<double> rhs(static_cast<std::size_t>(nc) * 3);
  auto set_rhs = [&](int r, const Vec3& b) {
    for (int c = 0; c < 3; ++c) rhs[3 * r + c] = b[c];
  };
  {
    Vec6 d[3];
    basis_derivative_rows(t, p, p, 0.0, 2, d);
    for (int k = 0; k < 3; ++k)
      for (int j = 0; j <= k; ++j) A.at(k, j) = d[k][j];
    basis_derivative_rows(t, nc - 1, p, 1.0, 2, d);
    for (int k = 0; k < 3; ++k)
      for (int j = p - k; j <= p; ++j) A.at(nc - 1 - k, nc - 1 - p + j) = d[k][j];
  }
  set_rhs(0, Q[0]);
  set_rhs(1, res.start_velocity);
  set_rhs(2, res.start_acceleration);
  set_rhs(nc - 3, res.end_acceleration);
  set_rhs(nc - 2, res.end_velocity);
  set_rhs(nc - 1, Q[N - 1]);
  double tri[6][6];
  for (int k = 1; k <= N - 2; ++k) {
    const int s = span[k];
    basis_triangle(t.data(), s, ub[k], p, tri);
    for (int j = 0; j <= p; ++j) A.at(k + 2, s - p + j) = tri[p][j];
    set_rhs(k + 2, Q[k]);
  }
  const bool ok = band_lu(A);
  FT_ASSERT(ok);  // Schoenberg–Whitney holds by construction of the knots
  band_solve(A, rhs.data(), 3);
  curve.control_points.resize(nc);
  for (int i = 0; i < nc; ++i)
    curve.control_points[i] = Vec3(rhs[3 * i], rhs[3 * i + 1], rhs[3 * i + 2]);
  return res;
}

BSplineResult interpolate_closed(const std::vector<Vec3>& Q, const BSplineParams& params) {
  const int p = kQuintic;
  // A last point repeating the first closes the contour explicitly: leave it out.
  int N = static_cast<int>(Q.size());
  if (N >= 2 && Q.back().allFinite() && Q.front().allFinite() &&
      (Q.back() - Q.front()).norm() <= params.min_point_distance)
    --N;
  const std::vector<double> ub =
      parametrize_first(Q, N, params.parametrization, true, params.min_point_distance, p + 1);

  // Periodic knots at the data parameters: t_{p+i} = ū_{i mod N} + ⌊i / N⌋. For odd degree the
  // data sit on the knots, each row of the cyclic system has the p nonzeros
  // B_k..B_{k+p−1}(ū_k), and the matrix is cyclic with two sub- and two super-diagonals.
  BSplineResult res;
  BSplineCurve& curve = res.curve;
  curve.degree = p;
  curve.periodic = true;
  curve.params = ub;
  const int nc = N + p;
  std::vector<double>& t = curve.knots;
  t.resize(nc + p + 1);
  for (int j = 0; j < static_cast<int>(t.size()); ++j) {
    const int i = j - p;
    const int q = (i >= 0 ? i / N : -((-i + N - 1) / N));  // ⌊i / N⌋
    t[j] = ub[i - q * N] + q;
  }

  // Unknown X_c is control point P_{c+2} (mod N), which puts B_{k+2} — the largest value at
  // ū_k — on the diagonal: row k has columns (k−2..k+2) mod N.
  auto wrap = [N](int c) { return ((c % N) + N) % N; };

  // Bordered solve: the leading m = N − 4 unknowns form a banded block B (kl = ku = 2); the
  // cyclic corners go to the border columns C, rows D and corner E. With Z = B⁻¹C and
  // Y = B⁻¹b_top, the 4×4 Schur complement S = E − D·Z gives the border unknowns, then
  // x_top = Y − Z·x_border. O(N) work, one banded factorization.
  const int m = N - 4, nr = 3 + 4;
  BandMatrix B(m, 2, 2);
  std::vector<double> rhs(static_cast<std::size_t>(m) * nr, 0.0);
  Eigen::Matrix4d E = Eigen::Matrix4d::Zero();
  Eigen::Matrix<double, 4, 3> g;
  struct Triplet {
    int r, c;
    double v;
  };
  std::vector<Triplet> D;
  double tri[6][6];
  for (int k = 0; k < N; ++k) {
    basis_triangle(t.data(), p + k, ub[k], p, tri);
    for (int j = 0; j < 5; ++j) {  // B_{k+j}(ū_k); B_{k+5}(ū_k) = 0
      const int c = wrap(k + j - 2);
      const double v = tri[p][j];
      if (k < m) {
        if (c < m)
          B.at(k, c) += v;
        else
          rhs[static_cast<std::size_t>(k) * nr + 3 + (c - m)] += v;
      } else {
        if (c < m)
          D.push_back({k - m, c, v});
        else
          E(k - m, c - m) += v;
      }
    }
    if (k < m)
      for (int c = 0; c < 3; ++c) rhs[static_cast<std::size_t>(k) * nr + c] = Q[k][c];
    else
      g.row(k - m) = Q[k].transpose();
  }
  const bool ok = band_lu(B);
  FT_ASSERT(ok);  // consecutive B-splines at sites inside their supports: nonsingular
  band_solve(B, rhs.data(), nr);
  Eigen::Matrix4d S = E;
  for (const Triplet& d : D)
    for (int c = 0; c < 4; ++c) {
      S(d.r, c) -= d.v * rhs[static_cast<std::size_t>(d.c) * nr + 3 + c];
      if (c < 3) g(d.r, c) -= d.v * rhs[static_cast<std::size_t>(d.c) * nr + c];
    }
  const Eigen::Matrix<double, 4, 3> xb = S.partialPivLu().solve(g);
  // X_c goes to P_{c+2}; then the wrapped copies P_0, P_1 = X_{N−2}, X_{N−1} and
  // P_{N+2..N+4} = X_0..X_2.
  std::vector<Vec3>& P = curve.control_points;
  P.resize(nc);
  for (int k = 0; k < m; ++k) {
    const double* r = &rhs[static_cast<std::size_t>(k) * nr];
    Vec3 x(r[0], r[1], r[2]);
    for (int c = 0; c < 4; ++c) x -= r[3 + c] * xb.row(c).transpose();
    P[k + 2] = x;
  }
  for (int c = 0; c < 4; ++c) P[m + c + 2] = xb.row(c).transpose();
  for (int i = 0; i < nc; ++i)
    if (i < 2 || i >= N + 2) P[i] = P[wrap(i - 2) + 2];
  const CurveDerivs d0 = bspline_derivatives(curve, 0.0, 2);
  res.start_velocity = res.end_velocity = d0[1];
  res.start_acceleration = res.end_acceleration = d0[2];
  return res;
}

}  // namespace

BSplineResult interpolate_quintic(const std::vector<Vec3>& points, const BSplineParams& params) {
  check_finite(params.start_velocity, "start_velocity");
  check_finite(params.start_acceleration, "start_acceleration");
  check_finite(params.end_velocity, "end_velocity");
  check_finite(params.end_acceleration, "end_acceleration");
  return params.closed ? interpolate_closed(points, params) : interpolate_open(points, params);
}

// ---------------------------------------------------------------------------------------------

CurveDerivs bspline_derivatives(const BSplineCurve& curve, double u, int order, KnotSide side) {
  FT_ASSERT(order >= 0 && order <= kMaxOrder);
  const int p = curve.degree;
  FT_ASSERT(p >= 1 && p <= kMaxDegree);
  const int nc = static_cast<int>(curve.control_points.size());
  if (curve.periodic) {
    if (u < 0.0 || u > 1.0) u -= std::floor(u);
  } else {
    u = std::clamp(u, 0.0, 1.0);
  }
  const int s = find_span(curve.knots, p, nc, u, side);
  double tri[6][6];
  basis_triangle(curve.knots.data(), s, u, p, tri);
  Vec3 c[6];
  for (int j = 0; j <= p; ++j) c[j] = curve.control_points[s - p + j];
  CurveDerivs out;
  out.fill(Vec3::Zero());
  span_derivatives(curve.knots.data(), s, p, tri, c, order, out.data());
  return out;
}

Vec3 bspline_point(const BSplineCurve& curve, double u) {
  return bspline_derivatives(curve, u, 0)[0];
}

// ---------------------------------------------------------------------------------------------

PolynomialCurve fit_polynomial(const std::vector<Vec3>& points, const PolynomialFitParams& params) {
  if (params.degree < 1 || params.degree > kMaxDegree)
    throw ArgumentError("degree: expected 1..5, got " + std::to_string(params.degree));
  PolynomialCurve curve;
  curve.params = parametrize(points, params.parametrization, false, params.min_point_distance, 2);
  const int N = static_cast<int>(points.size());
  const int deg = std::min(params.degree, N - 1);
  // Normal equations in the Legendre basis of x = 2u − 1 ∈ [−1, 1], whose Gram matrix is
  // nearly diagonal for spread-out parameters (condition ~ 2·deg + 1), then conversion to
  // monomials of x. Unused degrees are padded with identity rows to keep fixed 6×6 sizes.
  using Mat6 = Eigen::Matrix<double, 6, 6>;
  // leg.row(n) = monomial coefficients of P_n: (n+1)P_{n+1} = (2n+1)x·P_n − n·P_{n−1}.
  Mat6 leg = Mat6::Zero();
  leg(0, 0) = 1.0;
  leg(1, 1) = 1.0;
  for (int n = 1; n < 5; ++n)
    for (int j = 0; j < 6; ++j)
      leg(n + 1, j) = ((j > 0 ? (2 * n + 1) * leg(n, j - 1) : 0.0) - n * leg(n - 1, j)) / (n + 1);
  Mat6 G = Mat6::Zero();
  Eigen::Matrix<double, 6, 3> b = Eigen::Matrix<double, 6, 3>::Zero();
  for (int k = 0; k < N; ++k) {
    const double x = 2.0 * curve.params[k] - 1.0;
    Vec6 P = Vec6::Zero();
    P[0] = 1.0;
    if (deg >= 1) P[1] = x;
    for (int n = 1; n < deg; ++n) P[n + 1] = ((2 * n + 1) * x * P[n] - n * P[n - 1]) / (n + 1);
    G.noalias() += P * P.transpose();
    b.noalias() += P * points[k].transpose();
  }
  for (int j = deg + 1; j < 6; ++j) G(j, j) = 1.0;
  const Eigen::Matrix<double, 6, 3> a = G.ldlt().solve(b);
  const Eigen::Matrix<double, 6, 3> mono = leg.transpose() * a;  // monomial coefficients
  curve.coeffs.resize(deg + 1);
  for (int j = 0; j <= deg; ++j) curve.coeffs[j] = mono.row(j).transpose();
  return curve;
}

CubicSplineCurve interpolate_natural_cubic(const std::vector<Vec3>& points,
                                           const CubicSplineParams& params) {
  CubicSplineCurve curve;
  curve.params = parametrize(points, params.parametrization, false, params.min_point_distance, 2);
  curve.points = points;
  const int N = static_cast<int>(points.size());
  const std::vector<double>& u = curve.params;
  curve.second.assign(N, Vec3::Zero());
  if (N < 3) return curve;
  // Thomas algorithm on h_{i−1}M_{i−1} + 2(h_{i−1}+h_i)M_i + h_i M_{i+1} = 6(d_i − d_{i−1}),
  // M_0 = M_{N−1} = 0; diagonally dominant, so no pivoting.
  const int n = N - 2;
  std::vector<double> cp(n);
  std::vector<Vec3> rp(n);
  for (int r = 0; r < n; ++r) {
    const int i = r + 1;
    const double h0 = u[i] - u[i - 1], h1 = u[i + 1] - u[i];
    const Vec3 rhs = 6.0 * ((points[i + 1] - points[i]) / h1 - (points[i] - points[i - 1]) / h0);
    const double diag = 2.0 * (h0 + h1) - (r > 0 ? h0 * cp[r - 1] : 0.0);
    cp[r] = h1 / diag;
    rp[r] = (rhs - (r > 0 ? Vec3(h0 * rp[r - 1]) : Vec3::Zero())) / diag;
  }
  for (int r = n - 1; r >= 0; --r)
    curve.second[r + 1] = rp[r] - (r + 1 < n ? Vec3(cp[r] * curve.second[r + 2]) : Vec3::Zero());
  return curve;
}

// ---------------------------------------------------------------------------------------------

CurveView view(const BSplineCurve& curve) {
  auto c = std::make_shared<const BSplineCurve>(curve);
  CurveView v;
  v.derivatives = [c](double u, int order) { return bspline_derivatives(*c, u, order); };
  const int nc = static_cast<int>(curve.control_points.size());
  for (int i = curve.degree; i <= nc; ++i)
    if (v.breaks.empty() || curve.knots[i] > v.breaks.back()) v.breaks.push_back(curve.knots[i]);
  return v;
}

CurveView view(const PolynomialCurve& curve) {
  auto c = std::make_shared<const PolynomialCurve>(curve);
  CurveView v;
  v.derivatives = [c](double u, int order) {
    FT_ASSERT(order >= 0 && order <= kMaxOrder);
    CurveDerivs d;
    d.fill(Vec3::Zero());
    const double x = 2.0 * std::clamp(u, 0.0, 1.0) - 1.0;
    const int deg = static_cast<int>(c->coeffs.size()) - 1;
    // dᵏ/duᵏ = 2ᵏ dᵏ/dxᵏ; Horner per derivative order.
    for (int k = 0; k <= std::min(order, deg); ++k) {
      Vec3 acc = Vec3::Zero();
      for (int j = deg; j >= k; --j) {
        double f = 1.0;
        for (int q = 0; q < k; ++q) f *= j - q;
        acc = acc * x + f * c->coeffs[j];
      }
      d[k] = std::ldexp(1.0, k) * acc;
    }
    return d;
  };
  const int pieces = 32;
  for (int i = 0; i <= pieces; ++i) v.breaks.push_back(static_cast<double>(i) / pieces);
  return v;
}

CurveView view(const CubicSplineCurve& curve) {
  auto c = std::make_shared<const CubicSplineCurve>(curve);
  CurveView v;
  v.derivatives = [c](double u, int order) {
    FT_ASSERT(order >= 0 && order <= kMaxOrder);
    const std::vector<double>& t = c->params;
    const int N = static_cast<int>(t.size());
    u = std::clamp(u, 0.0, 1.0);
    const int i = std::clamp(
        static_cast<int>(std::upper_bound(t.begin(), t.end(), u) - t.begin()) - 1, 0, N - 2);
    const double h = t[i + 1] - t[i];
    const double A = (t[i + 1] - u) / h, B = (u - t[i]) / h;
    const Vec3 &q0 = c->points[i], &q1 = c->points[i + 1];
    const Vec3 &m0 = c->second[i], &m1 = c->second[i + 1];
    CurveDerivs d;
    d.fill(Vec3::Zero());
    d[0] = A * q0 + B * q1 + ((A * A * A - A) * m0 + (B * B * B - B) * m1) * (h * h / 6.0);
    if (order >= 1)
      d[1] = (q1 - q0) / h + ((3 * B * B - 1) * m1 - (3 * A * A - 1) * m0) * (h / 6.0);
    if (order >= 2) d[2] = A * m0 + B * m1;
    if (order >= 3) d[3] = (m1 - m0) / h;
    return d;
  };
  v.breaks = curve.params;
  return v;
}

std::vector<Vec3> sample_points(const CurveView& curve, int count) {
  if (count < 2)
    throw ArgumentError("count: expected at least 2 samples, got " + std::to_string(count));
  std::vector<Vec3> out(count);
  for (int i = 0; i < count; ++i)
    out[i] = curve.derivatives(static_cast<double>(i) / (count - 1), 0)[0];
  return out;
}

ArcLengthTable arc_length_table(const CurveView& curve, int pieces_per_break) {
  if (pieces_per_break < 1)
    throw ArgumentError("pieces_per_break: expected at least 1, got " +
                        std::to_string(pieces_per_break));
  ArcLengthTable tab;
  const std::vector<double>& b = curve.breaks;
  FT_ASSERT(b.size() >= 2);
  tab.u.push_back(b.front());
  tab.s.push_back(0.0);
  for (std::size_t i = 0; i + 1 < b.size(); ++i)
    for (int q = 1; q <= pieces_per_break; ++q) {
      const double a = tab.u.back();
      const double e = q == pieces_per_break
                           ? b[i + 1]
                           : b[i] + (b[i + 1] - b[i]) * q / static_cast<double>(pieces_per_break);
      tab.s.push_back(tab.s.back() + speed_integral(curve, a, e));
      tab.u.push_back(e);
    }
  return tab;
}

double arc_length_at(const CurveView& curve, const ArcLengthTable& table, double u) {
  const int n = static_cast<int>(table.u.size());
  u = std::clamp(u, table.u.front(), table.u.back());
  const int j = std::clamp(
      static_cast<int>(std::upper_bound(table.u.begin(), table.u.end(), u) - table.u.begin()) - 1,
      0, n - 2);
  return table.s[j] + speed_integral(curve, table.u[j], u);
}

double param_at_arc_length(const CurveView& curve, const ArcLengthTable& table, double s) {
  const int n = static_cast<int>(table.u.size());
  s = std::clamp(s, 0.0, table.length());
  const int j = std::clamp(
      static_cast<int>(std::upper_bound(table.s.begin(), table.s.end(), s) - table.s.begin()) - 1,
      0, n - 2);
  double lo = table.u[j], hi = table.u[j + 1];
  const double s0 = table.s[j], ds = table.s[j + 1] - s0;
  if (ds <= 0.0) return lo;
  double u = lo + (hi - lo) * (s - s0) / ds;
  const double tol = 1e-13 * std::max(1.0, table.length());
  // Newton on s(u) − s with bisection whenever a step leaves the bracket.
  for (int it = 0; it < 50; ++it) {
    const double f = s0 + speed_integral(curve, table.u[j], u) - s;
    if (std::abs(f) <= tol) break;
    if (f > 0)
      hi = u;
    else
      lo = u;
    const double speed = curve.derivatives(u, 1)[1].norm();
    double next = speed > 0 ? u - f / speed : 0.5 * (lo + hi);
    if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
    if (hi - lo <= 1e-16) break;
    u = next;
  }
  return u;
}

double curvature(const CurveDerivs& d) {
  const double v = d[1].norm();
  if (v <= 0.0) return 0.0;
  return d[1].cross(d[2]).norm() / (v * v * v);
}

Vec3 third_derivative_by_arc_length(const CurveDerivs& d) {
  // r(s) = C(u(s)): r''' = C'''·u_s³ + 3C''·u_s·u_ss + C'·u_sss with u_s = 1/v, v = |C'|.
  const double v = d[1].norm();
  if (v <= 0.0) return Vec3::Zero();
  const double vu = d[1].dot(d[2]) / v;
  const double vuu = (d[2].squaredNorm() + d[1].dot(d[3]) - vu * vu) / v;
  const double us = 1.0 / v;
  const double uss = -vu / (v * v * v);
  const double usss = (-vuu / (v * v * v) + 3.0 * vu * vu / (v * v * v * v)) / v;
  return d[3] * (us * us * us) + d[2] * (3.0 * us * uss) + d[1] * usss;
}

SmoothnessResult evaluate_smoothness(const CurveView& curve, const SmoothnessParams& params) {
  if (params.samples < 2)
    throw ArgumentError("samples: expected at least 2, got " + std::to_string(params.samples));
  SmoothnessResult r;
  const ArcLengthTable tab = arc_length_table(curve);
  r.length = tab.length();
  const int M = params.samples;
  r.u.resize(M);
  r.s.resize(M);
  r.curvature.resize(M);
  r.jerk.resize(M);
  for (int i = 0; i < M; ++i) {
    const double s = r.length * i / (M - 1);
    const double u =
        i == 0 ? tab.u.front() : (i == M - 1 ? tab.u.back() : param_at_arc_length(curve, tab, s));
    const CurveDerivs d = curve.derivatives(u, 3);
    r.u[i] = u;
    r.s[i] = s;
    r.curvature[i] = curvature(d);
    r.jerk[i] = third_derivative_by_arc_length(d);
    r.max_curvature = std::max(r.max_curvature, r.curvature[i]);
    r.max_jerk = std::max(r.max_jerk, r.jerk[i].norm());
    if (i > 0) {
      r.max_curvature_jump =
          std::max(r.max_curvature_jump, std::abs(r.curvature[i] - r.curvature[i - 1]));
      r.max_jerk_jump = std::max(r.max_jerk_jump, (r.jerk[i] - r.jerk[i - 1]).norm());
    }
  }
  return r;
}

// ---------------------------------------------------------------------------------------------

std::string to_string(CurveMethod method) {
  switch (method) {
    case CurveMethod::kQuinticBSpline:
      return "quintic_bspline";
    case CurveMethod::kQuinticBSplineClosed:
      return "quintic_bspline_closed";
    case CurveMethod::kPolynomial5:
      return "polynomial5";
    case CurveMethod::kNaturalCubic:
      return "natural_cubic";
  }
  return "?";
}

namespace {

// Distance from q to the curve near its own parameter: a coarse scan of [lo, hi], then Newton
// on (C(u) − q)·C'(u) = 0 kept inside the window.
double nearest_distance(const CurveView& c, const Vec3& q, double u0, double lo, double hi) {
  double best_u = u0, best = (c.derivatives(u0, 0)[0] - q).norm();
  const int scan = 16;
  for (int i = 0; i <= scan; ++i) {
    const double u = lo + (hi - lo) * i / scan;
    const double d = (c.derivatives(u, 0)[0] - q).norm();
    if (d < best) {
      best = d;
      best_u = u;
    }
  }
  double u = best_u;
  for (int it = 0; it < 20; ++it) {
    const CurveDerivs d = c.derivatives(u, 2);
    const Vec3 e = d[0] - q;
    const double f = e.dot(d[1]), fp = d[1].squaredNorm() + e.dot(d[2]);
    if (fp <= 0.0) break;
    const double next = std::clamp(u - f / fp, lo, hi);
    const double dist = (c.derivatives(next, 0)[0] - q).norm();
    if (dist < best) {
      best = dist;
      best_u = next;
    }
    if (std::abs(next - u) < 1e-15) break;
    u = next;
  }
  return best;
}

template <class Fit>
double best_time(int repeats, Fit&& fit) {
  double best = 1e300;
  for (int r = 0; r < std::max(1, repeats); ++r) {
    const auto t0 = std::chrono::steady_clock::now();
    fit();
    const auto t1 = std::chrono::steady_clock::now();
    best = std::min(best, std::chrono::duration<double>(t1 - t0).count());
  }
  return best;
}

CurveMethodReport measure(CurveMethod method, double fit_time, const CurveView& c,
                          const std::vector<Vec3>& points, const std::vector<double>& ub,
                          bool closed, const CurveComparisonParams& params) {
  CurveMethodReport r;
  r.method = method;
  r.fit_time = fit_time;
  const int N = static_cast<int>(ub.size());
  for (int k = 0; k < N; ++k) {
    const double e0 = (c.derivatives(ub[k], 0)[0] - points[k]).norm();
    double lo, hi;
    if (closed) {
      lo = k > 0 ? ub[k - 1] : ub[N - 1] - 1.0;
      hi = k + 1 < N ? ub[k + 1] : 1.0;
    } else {
      lo = ub[std::max(k - 1, 0)];
      hi = ub[std::min(k + 1, N - 1)];
    }
    const double e = std::min(e0, nearest_distance(c, points[k], ub[k], lo, hi));
    r.mean_error_at_param += e0;
    r.max_error_at_param = std::max(r.max_error_at_param, e0);
    r.mean_error += e;
    r.max_error = std::max(r.max_error, e);
  }
  r.mean_error_at_param /= N;
  r.mean_error /= N;
  r.passes_through = r.max_error < params.pass_tolerance;
  SmoothnessParams sp;
  sp.samples = params.smoothness_samples;
  const SmoothnessResult sm = evaluate_smoothness(c, sp);
  r.length = sm.length;
  r.max_curvature = sm.max_curvature;
  r.max_curvature_jump = sm.max_curvature_jump;
  r.max_jerk = sm.max_jerk;
  r.max_jerk_jump = sm.max_jerk_jump;
  return r;
}

}  // namespace

CurveComparison compare_curve_methods(const std::vector<Vec3>& points,
                                      const CurveComparisonParams& params) {
  CurveComparison out;
  {
    BSplineParams bp;
    bp.parametrization = params.parametrization;
    BSplineResult res;
    const double t =
        best_time(params.timing_repeats, [&] { res = interpolate_quintic(points, bp); });
    out.methods.push_back(measure(CurveMethod::kQuinticBSpline, t, view(res.curve), points,
                                  res.curve.params, false, params));
  }
  if (params.include_closed) {
    BSplineParams bp;
    bp.parametrization = params.parametrization;
    bp.closed = true;
    BSplineResult res;
    const double t =
        best_time(params.timing_repeats, [&] { res = interpolate_quintic(points, bp); });
    out.methods.push_back(measure(CurveMethod::kQuinticBSplineClosed, t, view(res.curve), points,
                                  res.curve.params, true, params));
  }
  {
    PolynomialFitParams pp;
    pp.parametrization = params.parametrization;
    PolynomialCurve poly;
    const double t = best_time(params.timing_repeats, [&] { poly = fit_polynomial(points, pp); });
    out.methods.push_back(
        measure(CurveMethod::kPolynomial5, t, view(poly), points, poly.params, false, params));
  }
  {
    CubicSplineParams cp;
    cp.parametrization = params.parametrization;
    CubicSplineCurve cub;
    const double t =
        best_time(params.timing_repeats, [&] { cub = interpolate_natural_cubic(points, cp); });
    out.methods.push_back(
        measure(CurveMethod::kNaturalCubic, t, view(cub), points, cub.params, false, params));
  }
  return out;
}

}  // namespace flashtwin::planner
