#include "flashtwin/planner/timing.hpp"

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdarg>
#include <cstddef>
#include <cstdio>
#include <limits>
#include <utility>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"

namespace flashtwin::planner {

namespace {

// Slower than this [m/s] counts as having to stop: the path cannot be followed continuously.
constexpr double kFeedFloor = 1e-6;


std::string num(double v) {
  return strf("%.17g", v);
}

void require(bool ok, const std::string& field, const std::string& expected, double got) {
  if (!ok) throw ArgumentError(field + ": expected " + expected + ", got " + num(got));
}

// Jerk-limited speed-up from rest to speed v (acceleration <= amax, jerk j, zero acceleration
// at both ends), continued at constant speed v. Used forwards for the start ramp and mirrored
// for the end ramp.
struct SCurve {
  double v = 0, j = 0, ap = 0;   // target speed, jerk, peak acceleration
  double t1 = 0, t2 = 0, T = 0;  // jerk phase, constant-acceleration phase, total ramp time
  double s1 = 0, v1 = 0, s2 = 0, v2 = 0, D = 0;  // state after phase 1 and 2; ramp length

  SCurve(double speed, double amax, double jerk) : v(speed), j(jerk) {
    t1 = std::min(amax / jerk, std::sqrt(speed / jerk));
    ap = j * t1;
    v1 = 0.5 * j * t1 * t1;
    s1 = j * t1 * t1 * t1 / 6;
    t2 = std::max(0.0, (v - 2 * v1) / ap);
    v2 = v1 + ap * t2;
    s2 = s1 + v1 * t2 + 0.5 * ap * t2 * t2;
    T = 2 * t1 + t2;
    D = s2 + v2 * t1 + 0.5 * ap * t1 * t1 - j * t1 * t1 * t1 / 6;
  }

  // Position [m], speed [m/s], acceleration [m/s^2] at time t >= 0 after the start.
  void eval(double t, double& s, double& sd, double& sdd) const {
    if (t <= 0) {
      s = sd = sdd = 0;
    } else if (t <= t1) {
      sdd = j * t;
      sd = 0.5 * j * t * t;
      s = j * t * t * t / 6;
    } else if (t <= t1 + t2) {
      const double u = t - t1;
      sdd = ap;
      sd = v1 + ap * u;
      s = s1 + v1 * u + 0.5 * ap * u * u;
    } else if (t <= T) {
      const double u = t - t1 - t2;
      sdd = ap - j * u;
      sd = v2 + ap * u - 0.5 * j * u * u;
      s = s2 + v2 * u + 0.5 * ap * u * u - j * u * u * u / 6;
    } else {
      sdd = 0;
      sd = v;
      s = D + v * (t - T);
    }
  }

  // Time at which the ramp has covered distance s (inverse of eval; bisection in the ramp).
  double time_at(double s) const {
    if (s <= 0) return 0;
    if (s >= D) return T + (s - D) / v;
    double lo = 0, hi = T;
    for (int it = 0; it < 200 && hi - lo > 1e-15 * T; ++it) {
      const double mid = 0.5 * (lo + hi);
      double sm, vm, am;
      eval(mid, sm, vm, am);
      (sm < s ? lo : hi) = mid;
    }
    return 0.5 * (lo + hi);
  }

  double speed_at(double s) const {
    if (s >= D) return v;
    double sm, vm, am;
    eval(time_at(s), sm, vm, am);
    return vm;
  }
};

// One linear constraint c_u·u + c_x·x <= d on the plane of x = ṡ² and u = s̈.
struct Lin {
  double cu, cx, d;
};

// Constraints of one reachability step, at most 4 per joint plus 4.
struct Constraints {
  std::array<Lin, 4 * kNumJoints + 4> c;
  int n = 0;
  void add(double cu, double cx, double d) { c[n++] = Lin{cu, cx, d}; }
};

constexpr double kTinyCu = 1e-14;

// Largest x <= x_cap for which some u satisfies every constraint: Fourier–Motzkin elimination
// of u (pair each lower bound on u with each upper bound). (x, u) = (0, 0) must be feasible.
double max_x(const Constraints& cs, double x_cap) {
  std::array<double, 4 * kNumJoints + 4> pu, qu, pl, ql;
  int nu = 0, nl = 0;
  double best = x_cap;
  for (int i = 0; i < cs.n; ++i) {
    const Lin& l = cs.c[i];
    if (std::abs(l.cu) <= kTinyCu) {
      if (l.cx > 0) best = std::min(best, l.d / l.cx);
    } else if (l.cu > 0) {
      pu[nu] = l.d / l.cu;
      qu[nu++] = -l.cx / l.cu;
    } else {
      pl[nl] = l.d / l.cu;
      ql[nl++] = -l.cx / l.cu;
    }
  }
  for (int a = 0; a < nl; ++a)
    for (int b = 0; b < nu; ++b) {
      const double k = ql[a] - qu[b];
      if (k > 0) best = std::min(best, (pu[b] - pl[a]) / k);
    }
  return std::max(best, 0.0);
}

// Feasible interval [umin, umax] of u at a given x.
std::pair<double, double> u_range(const Constraints& cs, double x) {
  double umin = -std::numeric_limits<double>::infinity();
  double umax = std::numeric_limits<double>::infinity();
  for (int i = 0; i < cs.n; ++i) {
    const Lin& l = cs.c[i];
    if (std::abs(l.cu) <= kTinyCu) continue;
    const double bound = (l.d - l.cx * x) / l.cu;
    if (l.cu > 0)
      umax = std::min(umax, bound);
    else
      umin = std::max(umin, bound);
  }
  return {umin, umax};
}

// The most loaded joint limit at path state (x = ṡ², any of the accelerations us).
struct Load {
  int joint = -1;
  LimitKind kind = LimitKind::kNone;
  double ratio = -1;
};

Load most_loaded(const Vector6& a, const Vector6& b, double x, std::initializer_list<double> us,
                 const Vector6& vlim, const Vector6& alim) {
  Load best;
  const double sd = std::sqrt(std::max(x, 0.0));
  for (int j = 0; j < kNumJoints; ++j) {
    const double rv = std::abs(a[j]) * sd / vlim[j];
    if (rv > best.ratio) best = {j, LimitKind::kVelocity, rv};
    for (double u : us) {
      const double ra = std::abs(a[j] * u + b[j] * x) / alim[j];
      if (ra > best.ratio) best = {j, LimitKind::kAcceleration, ra};
    }
  }
  return best;
}

bool within_range(const JointLimits& L, double q, double tol) {
  return q <= L.upper + tol && q >= L.lower - tol;
}

enum class SegKind { kStartRamp, kEndRamp, kCubicStart, kCubicEnd, kConstAccel };

}  // namespace

// ---------------------------------------------------------------------------------------------
// JointPathSpline

JointPathSpline::JointPathSpline(std::vector<double> s, std::vector<Vector6> q)
    : s_(std::move(s)), q_(std::move(q)) {
  const std::size_t n = s_.size();
  if (n < 2) throw ArgumentError("s: expected at least 2 path samples, got " + std::to_string(n));
  if (q_.size() != n)
    throw ArgumentError("q: expected " + std::to_string(n) + " configurations (one per s), got " +
                        std::to_string(q_.size()));
  for (std::size_t i = 0; i < n; ++i) {
    if (!std::isfinite(s_[i]))
      throw ArgumentError("s[" + std::to_string(i) + "]: expected a finite number, got " +
                          num(s_[i]));
    if (!q_[i].allFinite())
      throw ArgumentError("q[" + std::to_string(i) +
                          "]: expected finite joint values, got a NaN/inf");
    if (i > 0 && !(s_[i] > s_[i - 1]))
      throw ArgumentError("s[" + std::to_string(i) +
                          "]: expected strictly increasing values, got " + num(s_[i]) + " after " +
                          num(s_[i - 1]));
  }
  std::vector<double> h(n - 1);
  for (std::size_t i = 0; i + 1 < n; ++i) h[i] = s_[i + 1] - s_[i];

  // End slopes from the parabola through the first (last) three samples.
  Vector6 d0, dn;
  if (n == 2) {
    d0 = dn = (q_[1] - q_[0]) / h[0];
  } else {
    const double a = h[0], b = h[1];
    d0 = -(2 * a + b) / (a * (a + b)) * q_[0] + (a + b) / (a * b) * q_[1] -
         a / (b * (a + b)) * q_[2];
    const double c = h[n - 3], e = h[n - 2];
    dn = e / (c * (c + e)) * q_[n - 3] - (c + e) / (c * e) * q_[n - 2] +
         (2 * e + c) / (e * (c + e)) * q_[n - 1];
  }

  // Clamped spline: tridiagonal system in the knot second derivatives, solved by Thomas'
  // algorithm (diagonally dominant, no pivoting needed).
  std::vector<double> lo(n, 0), di(n, 0), up(n, 0);
  std::vector<Vector6> r(n);
  di[0] = h[0] / 3;
  up[0] = h[0] / 6;
  r[0] = (q_[1] - q_[0]) / h[0] - d0;
  for (std::size_t i = 1; i + 1 < n; ++i) {
    lo[i] = h[i - 1] / 6;
    di[i] = (h[i - 1] + h[i]) / 3;
    up[i] = h[i] / 6;
    r[i] = (q_[i + 1] - q_[i]) / h[i] - (q_[i] - q_[i - 1]) / h[i - 1];
  }
  lo[n - 1] = h[n - 2] / 6;
  di[n - 1] = h[n - 2] / 3;
  r[n - 1] = dn - (q_[n - 1] - q_[n - 2]) / h[n - 2];
  for (std::size_t i = 1; i < n; ++i) {
    const double w = lo[i] / di[i - 1];
    di[i] -= w * up[i - 1];
    r[i] -= w * r[i - 1];
  }
  m_.assign(n, Vector6::Zero());
  m_[n - 1] = r[n - 1] / di[n - 1];
  for (std::size_t i = n - 1; i-- > 0;) m_[i] = (r[i] - up[i] * m_[i + 1]) / di[i];
}

std::size_t JointPathSpline::interval(double s, std::size_t* hint) const {
  const std::size_t last = s_.size() - 2;
  if (hint) {
    std::size_t i = std::min(*hint, last);
    // Monotone sweeps move by at most a few intervals: walk; otherwise fall through to search.
    for (int step = 0; step < 4; ++step) {
      if (i < last && s >= s_[i + 1]) {
        ++i;
      } else if (i > 0 && s < s_[i]) {
        --i;
      } else {
        *hint = i;
        return i;
      }
    }
  }
  const auto it = std::upper_bound(s_.begin(), s_.end(), s);
  std::size_t i = it == s_.begin() ? 0 : static_cast<std::size_t>(it - s_.begin()) - 1;
  i = std::min(i, last);
  if (hint) *hint = i;
  return i;
}

void JointPathSpline::evaluate(double s, Vector6& q, Vector6& dq_ds, Vector6& d2q_ds2,
                               std::size_t* hint) const {
  FT_ASSERT(s_.size() >= 2);
  s = std::clamp(s, s_.front(), s_.back());
  const std::size_t i = interval(s, hint);
  const double h = s_[i + 1] - s_[i];
  const double a = (s_[i + 1] - s) / h, b = (s - s_[i]) / h;
  q = a * q_[i] + b * q_[i + 1] +
      ((a * a * a - a) * m_[i] + (b * b * b - b) * m_[i + 1]) * (h * h / 6);
  dq_ds =
      (q_[i + 1] - q_[i]) / h + (-(3 * a * a - 1) * m_[i] + (3 * b * b - 1) * m_[i + 1]) * (h / 6);
  d2q_ds2 = a * m_[i] + b * m_[i + 1];
}

Vector6 JointPathSpline::position(double s, std::size_t* hint) const {
  Vector6 q, d1, d2;
  evaluate(s, q, d1, d2, hint);
  return q;
}

// ---------------------------------------------------------------------------------------------

std::string to_string(TimingStatus status) {
  switch (status) {
    case TimingStatus::kOk:
      return "ok";
    case TimingStatus::kPositionLimit:
      return "position_limit";
    case TimingStatus::kDiscontinuous:
      return "discontinuous";
    case TimingStatus::kBelowMinFeed:
      return "below_min_feed";
    case TimingStatus::kTooLong:
      return "too_long";
  }
  return "?";
}

std::string to_string(LimitKind kind) {
  switch (kind) {
    case LimitKind::kNone:
      return "none";
    case LimitKind::kPosition:
      return "position";
    case LimitKind::kVelocity:
      return "velocity";
    case LimitKind::kAcceleration:
      return "acceleration";
    case LimitKind::kJointStep:
      return "joint_step";
  }
  return "?";
}

TimingResult time_parametrize(const RobotModel& robot, const std::vector<double>& s,
                              const std::vector<Vector6>& q, const TimingParams& P) {
  // ---- Input checks (bad input throws; outcomes go into the Result).
  const auto finite_pos = [](double v) { return std::isfinite(v) && v > 0; };
  require(finite_pos(P.feed), "feed", "a positive speed [m/s]", P.feed);
  require(finite_pos(P.max_path_accel), "max_path_accel", "a positive acceleration [m/s^2]",
          P.max_path_accel);
  require(finite_pos(P.max_path_jerk), "max_path_jerk", "a positive jerk [m/s^3]", P.max_path_jerk);
  require(finite_pos(P.limit_factor) && P.limit_factor <= 1, "limit_factor", "a value in (0, 1]",
          P.limit_factor);
  require(finite_pos(P.dt), "dt", "a positive period [s]", P.dt);
  require(finite_pos(P.grid_step), "grid_step", "a positive step [m]", P.grid_step);
  require(std::isfinite(P.position_tol) && P.position_tol >= 0, "position_tol",
          "a non-negative slack [rad]", P.position_tol);
  require(std::isfinite(P.max_joint_step) && P.max_joint_step >= 0, "max_joint_step",
          "a non-negative step [rad]", P.max_joint_step);
  require(std::isfinite(P.min_feed) && P.min_feed >= 0 && P.min_feed < P.feed, "min_feed",
          "a speed in [0, feed) [m/s]", P.min_feed);
  require(std::isfinite(P.reduction_tol) && P.reduction_tol >= 0 && P.reduction_tol < 1,
          "reduction_tol", "a fraction in [0, 1)", P.reduction_tol);
  require(finite_pos(P.max_duration), "max_duration", "a positive duration [s]", P.max_duration);

  Vector6 vlim, alim;  // full limits
  for (int j = 0; j < kNumJoints; ++j) {
    const std::string jn = std::to_string(j);
    vlim[j] = P.velocity_limits ? (*P.velocity_limits)[j] : robot.limits[j].velocity;
    alim[j] = P.acceleration_limits ? (*P.acceleration_limits)[j] : robot.limits[j].acceleration;
    require(finite_pos(vlim[j]),
            P.velocity_limits ? "velocity_limits[" + jn + "]" : "robot.limits[" + jn + "].velocity",
            "a positive velocity [rad/s]", vlim[j]);
    require(finite_pos(alim[j]),
            P.acceleration_limits ? "acceleration_limits[" + jn + "]"
                                  : "robot.limits[" + jn + "].acceleration",
            "a positive acceleration [rad/s^2]", alim[j]);
  }
  const Vector6 vplan = P.limit_factor * vlim, aplan = P.limit_factor * alim;
  const JointPathSpline spline(s, q);  // validates sizes, finiteness and monotone s
  const std::size_t N = s.size();

  TimingResult res;
  const auto fail = [&res](TimingStatus st, int sample, int joint, LimitKind kind, double value,
                           double bound, double excess, std::string msg) {
    res.status = st;
    res.trajectory = JointTrajectory{};
    res.reductions.clear();
    res.failed_sample = sample;
    res.failed_joint = joint;
    res.failed_limit = kind;
    res.failed_value = value;
    res.failed_bound = bound;
    res.failed_excess = excess;
    res.message = std::move(msg);
    return res;
  };
  // Position of one configuration against the ranges; true when it failed (res filled in).
  // `where` names the place in the message, built only on failure.
  const auto position_fails = [&](const Vector6& qq, int sample, const auto& where_fn) {
    for (int j = 0; j < kNumJoints; ++j) {
      if (within_range(robot.limits[j], qq[j], P.position_tol)) continue;
      const std::string where = where_fn();
      const JointLimits& L = robot.limits[j];
      if (qq[j] > L.upper + P.position_tol) {
        fail(TimingStatus::kPositionLimit, sample, j, LimitKind::kPosition, qq[j], L.upper,
             qq[j] - L.upper,
             strf("%s: joint %d position %.4f rad exceeds upper limit %.4f rad by %.4f rad",
                  where.c_str(), j + 1, qq[j], L.upper, qq[j] - L.upper));
        return true;
      }
      if (qq[j] < L.lower - P.position_tol) {
        fail(TimingStatus::kPositionLimit, sample, j, LimitKind::kPosition, qq[j], L.lower,
             L.lower - qq[j],
             strf("%s: joint %d position %.4f rad is below lower limit %.4f rad by %.4f rad",
                  where.c_str(), j + 1, qq[j], L.lower, L.lower - qq[j]));
        return true;
      }
    }
    return false;
  };

  // ---- The samples themselves, in path order: jumps into a sample, then its position.
  for (std::size_t i = 0; i < N; ++i) {
    const int si = static_cast<int>(i);
    if (i > 0 && P.max_joint_step > 0) {
      for (int j = 0; j < kNumJoints; ++j) {
        const double step = std::abs(q[i][j] - q[i - 1][j]);
        if (step > P.max_joint_step)
          return fail(TimingStatus::kDiscontinuous, si, j, LimitKind::kJointStep, step,
                      P.max_joint_step, step - P.max_joint_step,
                      strf("samples %d-%d: joint %d jumps %.4f rad, more than max_joint_step "
                           "%.4f rad by %.4f rad (IK branch switch or angle wrap?)",
                           si - 1, si, j + 1, step, P.max_joint_step, step - P.max_joint_step));
      }
    }
    if (position_fails(q[i], si, [si] { return strf("sample %d", si); })) return res;
  }

  // ---- Nominal speed: the feed with the jerk-limited ramps at both ends. A path too short for
  // both ramps gets a lower peak speed at which the two ramps meet at its middle.
  const double s0 = s.front(), L = s.back() - s0;
  SCurve ramp(P.feed, P.max_path_accel, P.max_path_jerk);
  const bool short_path = 2 * ramp.D > L;
  if (short_path) {
    double lo = 0, hi_v = P.feed;
    for (int it = 0; it < 100; ++it) {
      const double mid = 0.5 * (lo + hi_v);
      (2 * SCurve(mid, P.max_path_accel, P.max_path_jerk).D < L ? lo : hi_v) = mid;
    }
    ramp = SCurve(lo, P.max_path_accel, P.max_path_jerk);
  }

  // ---- Reachability grid: every sample, plus even subdivisions of each interval (and the
  // middle of a short path, where its two ramps meet).
  std::size_t total = 0;
  for (std::size_t i = 0; i + 1 < N; ++i)
    total +=
        static_cast<std::size_t>(std::max(1.0, std::ceil((s[i + 1] - s[i]) / P.grid_step - 1e-9)));
  const std::size_t mult = total >= 4 ? 1 : (4 + total - 1) / total;  // at least 4 steps
  std::vector<double> gs;         // σ = s - s0 of each grid point [m]
  std::vector<std::size_t> gint;  // sample interval holding it
  std::vector<char> at_sample;    // grid point coincides with a sample
  gs.reserve(total * mult + 1);
  for (std::size_t i = 0; i + 1 < N; ++i) {
    const double h = s[i + 1] - s[i];
    const std::size_t n =
        mult * static_cast<std::size_t>(std::max(1.0, std::ceil(h / P.grid_step - 1e-9)));
    for (std::size_t m = 0; m < n; ++m) {
      gs.push_back((s[i] - s0) + h * static_cast<double>(m) / static_cast<double>(n));
      gint.push_back(i);
      at_sample.push_back(m == 0);
    }
  }
  gs.push_back(L);
  gint.push_back(N - 2);
  at_sample.push_back(1);
  if (short_path) {
    const std::size_t pos =
        static_cast<std::size_t>(std::lower_bound(gs.begin(), gs.end(), 0.5 * L) - gs.begin());
    if (pos > 0 && pos < gs.size() && gs[pos] - 0.5 * L > 1e-9 * L &&
        0.5 * L - gs[pos - 1] > 1e-9 * L) {
      gs.insert(gs.begin() + static_cast<std::ptrdiff_t>(pos), 0.5 * L);
      gint.insert(gint.begin() + static_cast<std::ptrdiff_t>(pos), gint[pos - 1]);
      at_sample.insert(at_sample.begin() + static_cast<std::ptrdiff_t>(pos), 0);
    }
  }
  const std::size_t M = gs.size() - 1;  // number of grid steps
  std::vector<double> ds(M);
  for (std::size_t k = 0; k < M; ++k) ds[k] = gs[k + 1] - gs[k];
  // Nearest path sample to a grid point, for messages.
  const auto nearest_sample = [&](std::size_t k) {
    const std::size_t i = gint[k];
    if (at_sample[k]) return k == M ? N - 1 : i;
    return (gs[k] - (s[i] - s0)) <= (s[i + 1] - s0 - gs[k]) ? i : i + 1;
  };

  std::vector<Vector6> d1(M + 1), d2(M + 1);
  {
    std::size_t hint = 0;
    Vector6 qk;
    for (std::size_t k = 0; k <= M; ++k) {
      spline.evaluate(s0 + gs[k], qk, d1[k], d2[k], &hint);
      // The spline between samples may overshoot a limit the samples respect.
      if (!at_sample[k] && position_fails(qk, static_cast<int>(gint[k]), [&] {
            return strf("between samples %zu and %zu (s = %.4f m)", gint[k], gint[k] + 1,
                        s0 + gs[k]);
          }))
        return res;
    }
  }

  std::vector<double> rs(M + 1), re(M + 1), nominal(M + 1);
  for (std::size_t k = 0; k <= M; ++k) {
    rs[k] = ramp.speed_at(gs[k]);
    re[k] = ramp.speed_at(L - gs[k]);
    nominal[k] = std::min(rs[k], re[k]);
  }
  rs[0] = re[M] = nominal[0] = nominal[M] = 0;

  // Constraints of the point k alone (acceleration limits and the path acceleration bound).
  const auto point_constraints = [&](std::size_t k, Constraints& cs) {
    cs.n = 0;
    for (int j = 0; j < kNumJoints; ++j) {
      cs.add(d1[k][j], d2[k][j], aplan[j]);
      cs.add(-d1[k][j], -d2[k][j], aplan[j]);
    }
    cs.add(1, 0, P.max_path_accel);
    cs.add(-1, 0, P.max_path_accel);
  };
  // Constraints of step k (constant u over [σ_k, σ_k+1], starting at x): limits at both ends
  // of the step, and arriving inside [0, x_next_max].
  const auto step_constraints = [&](std::size_t k, double x_next_max, Constraints& cs) {
    point_constraints(k, cs);
    const double two_ds = 2 * ds[k];
    for (int j = 0; j < kNumJoints; ++j) {
      const double a = d1[k + 1][j] + two_ds * d2[k + 1][j], b = d2[k + 1][j];
      cs.add(a, b, aplan[j]);
      cs.add(-a, -b, aplan[j]);
    }
    cs.add(two_ds, 1, x_next_max);
    cs.add(-two_ds, -1, 0);
  };

  // ---- Maximum velocity curve (velocity and acceleration limits, x = ṡ²) and the feed floor.
  const double feed_floor = std::max(P.min_feed, kFeedFloor);
  std::vector<double> xmax(M + 1);
  Constraints cs;
  for (std::size_t k = 0; k <= M; ++k) {
    double xv = std::numeric_limits<double>::infinity();
    for (int j = 0; j < kNumJoints; ++j) {
      const double a = std::abs(d1[k][j]);
      if (a > 0) xv = std::min(xv, (vplan[j] / a) * (vplan[j] / a));
    }
    point_constraints(k, cs);
    const double mvc = max_x(cs, xv);
    if (k > 0 && k < M && mvc < feed_floor * feed_floor &&
        (nominal[k] > feed_floor || mvc < kFeedFloor * kFeedFloor)) {
      const auto [umin, umax] = u_range(cs, mvc);
      const double u = std::isfinite(umin) && std::isfinite(umax) ? 0.5 * (umin + umax) : 0.0;
      const Load ld = most_loaded(d1[k], d2[k], mvc, {u}, vplan, aplan);
      const double v = std::sqrt(mvc);
      const bool is_v = ld.kind == LimitKind::kVelocity;
      const double lim = is_v ? vlim[ld.joint] : alim[ld.joint];
      return fail(
          TimingStatus::kBelowMinFeed, static_cast<int>(nearest_sample(k)), ld.joint, ld.kind, v,
          feed_floor, feed_floor - v,
          strf("sample %zu (s = %.4f m): joint %d %s limit %.4g %s (planned at %.0f%%) "
               "caps the feed at %.3g m/s, below %s %.3g m/s by %.3g m/s",
               nearest_sample(k), s0 + gs[k], ld.joint + 1, is_v ? "velocity" : "acceleration", lim,
               is_v ? "rad/s" : "rad/s^2", 100 * P.limit_factor, v,
               P.min_feed > 0 ? "min_feed" : "the stop threshold", feed_floor, feed_floor - v));
    }
    xmax[k] = std::min(nominal[k] * nominal[k], mvc);
  }
  xmax[0] = xmax[M] = 0;

  // The first and last steps are constant-jerk moves from/to rest (zero speed and zero
  // acceleration at the path ends). Their acceleration at the inner end is ±2x/(3Δs).
  const auto cubic_bound = [&](std::size_t k, double dsk, double sign) {
    double xb = 1.5 * dsk * P.max_path_accel;
    for (int j = 0; j < kNumJoints; ++j) {
      const double c = std::abs(sign * 2 * d1[k][j] / (3 * dsk) + d2[k][j]);
      if (c > 0) xb = std::min(xb, aplan[j] / c);
    }
    return xb;
  };

  // ---- Backward pass: hi[k] = largest x at k from which the end is still reachable.
  std::vector<double> hi(M + 1, 0.0);
  hi[M - 1] = std::min(xmax[M - 1], cubic_bound(M - 1, ds[M - 1], -1));
  for (std::size_t k = M - 1; k-- > 1;) {
    step_constraints(k, hi[k + 1], cs);
    hi[k] = max_x(cs, xmax[k]);
  }

  // ---- Forward pass: the greatest admissible acceleration that stays controllable.
  std::vector<double> x(M + 1, 0.0), u(M, 0.0);
  x[1] = std::min(hi[1], cubic_bound(1, ds[0], +1));
  for (std::size_t k = 1; k + 1 < M; ++k) {
    step_constraints(k, hi[k + 1], cs);
    const auto [umin, umax] = u_range(cs, x[k]);
    const double uk = umax >= umin ? umax : umin;  // round-off: stay reachable
    x[k + 1] = std::clamp(x[k] + 2 * ds[k] * uk, 0.0, hi[k + 1]);
    u[k] = (x[k + 1] - x[k]) / (2 * ds[k]);
  }
  std::vector<double> v(M + 1);
  for (std::size_t k = 0; k <= M; ++k) v[k] = std::sqrt(x[k]);
  u[0] = 2 * x[1] / (3 * ds[0]);               // acceleration at the end of the first step
  u[M - 1] = -2 * x[M - 1] / (3 * ds[M - 1]);  // and at the start of the last

  // ---- Feed reductions: runs of grid points below the nominal speed.
  for (std::size_t k = 1; k < M;) {
    if (v[k] >= nominal[k] * (1 - P.reduction_tol)) {
      ++k;
      continue;
    }
    std::size_t e = k, kmin = k;
    while (e + 1 < M && v[e + 1] < nominal[e + 1] * (1 - P.reduction_tol)) {
      ++e;
      if (v[e] < v[kmin]) kmin = e;
    }
    FeedReduction r;
    r.first_sample = gint[k];
    r.last_sample = at_sample[e] ? gint[e] : gint[e] + 1;
    r.s_begin = s0 + gs[k];
    r.s_end = s0 + gs[e];
    r.min_feed = v[kmin];
    r.s_at_min = s0 + gs[kmin];
    r.nominal_feed = nominal[kmin];
    const Load ld = most_loaded(d1[kmin], d2[kmin], x[kmin], {u[kmin - 1], u[kmin]}, vplan, aplan);
    r.joint = ld.joint;
    r.limit = ld.kind;
    res.reductions.push_back(r);
    k = e + 1;
  }

  // ---- Timeline. Where the speed follows a ramp exactly from the path's start (end), that
  // stretch is played as the analytic S-curve (jerk-limited); elsewhere each step has constant
  // s̈; the first/last steps otherwise are constant-jerk moves from/to rest.
  const auto on_cap = [](double xk, double r) { return xk >= r * r * (1 - 1e-9); };
  std::size_t p = 0;  // grid points 0..p follow the start ramp
  while (p + 1 <= M && rs[p + 1] <= re[p + 1] && on_cap(x[p + 1], rs[p + 1])) ++p;
  // Grid points qe..M follow the end ramp; in a cruise at the full feed both ramps hold, and
  // the two stretches may share their meeting point.
  std::size_t qe = M;
  while (qe > p && re[qe - 1] <= rs[qe - 1] && on_cap(x[qe - 1], re[qe - 1])) --qe;

  std::vector<SegKind> kind(M);
  std::vector<double> t(M + 1, 0.0), tend(M + 1, 0.0);
  for (std::size_t k = qe; k <= M; ++k) tend[k] = ramp.time_at(L - gs[k]);
  double jerk_first = 0, jerk_last = 0;
  for (std::size_t k = 0; k < M; ++k) {
    double dur;
    if (k + 1 <= p) {
      kind[k] = SegKind::kStartRamp;
      dur = ramp.time_at(gs[k + 1]) - t[k];
    } else if (k >= qe) {
      kind[k] = SegKind::kEndRamp;
      dur = tend[k] - tend[k + 1];
    } else if (k == 0 || k == M - 1) {
      const double vk = k == 0 ? v[1] : v[M - 1];
      if (!(vk > 0)) {
        return fail(TimingStatus::kBelowMinFeed, static_cast<int>(k == 0 ? 0 : N - 1), -1,
                    LimitKind::kNone, 0, feed_floor, feed_floor,
                    "the joint limits allow no motion at the path end");
      }
      kind[k] = k == 0 ? SegKind::kCubicStart : SegKind::kCubicEnd;
      dur = 3 * ds[k] / vk;
      (k == 0 ? jerk_first : jerk_last) = 2 * vk / (dur * dur);
    } else {
      kind[k] = SegKind::kConstAccel;
      const double vs = v[k] + v[k + 1];
      if (!(vs > 0)) {
        return fail(TimingStatus::kBelowMinFeed, static_cast<int>(nearest_sample(k)), -1,
                    LimitKind::kNone, 0, feed_floor, feed_floor,
                    strf("sample %zu (s = %.4f m): the joint limits force a stop",
                         nearest_sample(k), s0 + gs[k]));
      }
      dur = 2 * ds[k] / vs;
    }
    t[k + 1] = t[k] + dur;
  }
  const double T = t[M];
  if (!(T <= P.max_duration))
    return fail(TimingStatus::kTooLong, -1, -1, LimitKind::kNone, T, P.max_duration,
                T - P.max_duration,
                strf("the trajectory would last %.1f s, more than max_duration %.1f s by %.1f s", T,
                     P.max_duration, T - P.max_duration));

  // Path state (σ, ṡ, s̈) at profile time tau in step k.
  const auto path_state = [&](std::size_t k, double tau, double& sg, double& sd, double& sdd) {
    switch (kind[k]) {
      case SegKind::kStartRamp:
        ramp.eval(tau, sg, sd, sdd);
        break;
      case SegKind::kEndRamp: {
        ramp.eval(T - tau, sg, sd, sdd);
        sg = L - sg;
        sdd = -sdd;
        break;
      }
      case SegKind::kCubicStart: {
        const double w = std::max(tau, 0.0);
        sdd = jerk_first * w;
        sd = 0.5 * jerk_first * w * w;
        sg = jerk_first * w * w * w / 6;
        break;
      }
      case SegKind::kCubicEnd: {
        const double w = std::max(T - tau, 0.0);
        sdd = -jerk_last * w;
        sd = 0.5 * jerk_last * w * w;
        sg = L - jerk_last * w * w * w / 6;
        break;
      }
      case SegKind::kConstAccel: {
        const double w = tau - t[k];
        sdd = u[k];
        sd = std::max(v[k] + u[k] * w, 0.0);
        sg = gs[k] + v[k] * w + 0.5 * u[k] * w * w;
        break;
      }
    }
    sg = std::clamp(sg, gs[k], gs[k + 1]);
  };

  // ---- Sampling at the period dt, uniformly slowed by `scale` >= 1 so that the duration is
  // a whole number of periods (and further if the samples would exceed the margin).
  const auto sample = [&](double scale_wanted, JointTrajectory& tr, double& scale) {
    const double periods = std::max(1.0, std::ceil(T * scale_wanted / P.dt - 1e-9));
    const std::size_t K = static_cast<std::size_t>(periods);
    scale = periods * P.dt / T;
    tr = JointTrajectory{};
    tr.dt = P.dt;
    tr.t.resize(K + 1);
    tr.q.resize(K + 1);
    tr.dq.resize(K + 1);
    tr.ddq.resize(K + 1);
    tr.s.resize(K + 1);
    tr.sdot.resize(K + 1);
    tr.sddot.resize(K + 1);
    std::size_t k = 0, hint = 0;
    Vector6 qq, q1, q2;
    for (std::size_t n = 0; n <= K; ++n) {
      const double tn = static_cast<double>(n) * P.dt;
      const double tau = n == K ? T : std::min(tn / scale, T);
      while (k + 1 < M && tau > t[k + 1]) ++k;
      double sg = 0, sd = 0, sdd = 0;
      path_state(k, tau, sg, sd, sdd);
      sd /= scale;
      sdd /= scale * scale;
      spline.evaluate(s0 + sg, qq, q1, q2, &hint);
      tr.t[n] = tn;
      tr.s[n] = s0 + sg;
      tr.sdot[n] = sd;
      tr.sddot[n] = sdd;
      tr.q[n] = qq;
      tr.dq[n] = q1 * sd;
      tr.ddq[n] = q1 * sdd + q2 * (sd * sd);
    }
  };
  const auto ratios = [&](const JointTrajectory& tr) {
    res.max_velocity_ratio.setZero();
    res.max_accel_ratio.setZero();
    for (std::size_t n = 0; n < tr.size(); ++n) {
      res.max_velocity_ratio =
          res.max_velocity_ratio.cwiseMax(tr.dq[n].cwiseAbs().cwiseQuotient(vlim));
      res.max_accel_ratio = res.max_accel_ratio.cwiseMax(tr.ddq[n].cwiseAbs().cwiseQuotient(alim));
    }
    res.max_joint_velocity_ratio = res.max_velocity_ratio.maxCoeff();
    res.max_joint_accel_ratio = res.max_accel_ratio.maxCoeff();
  };

  // The grid checks the limits at its points only; should the samples in between exceed half
  // the margin, slow the whole trajectory uniformly (velocity ∝ 1/scale, acceleration ∝ 1/scale²).
  const double margin = 0.5 * (1 + P.limit_factor);
  double want = 1, scale = 1;
  for (int attempt = 0; attempt < 5; ++attempt) {
    sample(want, res.trajectory, scale);
    ratios(res.trajectory);
    const double over = std::max(res.max_joint_velocity_ratio / margin,
                                 std::sqrt(res.max_joint_accel_ratio / margin));
    if (over <= 1) break;
    want = scale * over * (1 + 1e-9);
  }
  res.time_scale = scale;
  res.total_time = res.trajectory.duration();
  res.grid_points = M + 1;
  if (!(res.total_time <= P.max_duration))
    return fail(TimingStatus::kTooLong, -1, -1, LimitKind::kNone, res.total_time, P.max_duration,
                res.total_time - P.max_duration,
                strf("the trajectory would last %.1f s, more than max_duration %.1f s",
                     res.total_time, P.max_duration));
  return res;
}

}  // namespace flashtwin::planner
