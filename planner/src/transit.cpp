#include "flashtwin/planner/transit.hpp"

#include <algorithm>
#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

namespace {

// Minimum-jerk blend s(τ) = 10τ³ − 15τ⁴ + 6τ⁵ and its derivatives: rest to rest, its peak
// speed 15/8 and peak acceleration 10/√3 (at τ = ½ ∓ √3/6) per unit of distance and time.
constexpr double kPeakSpeed = 1.875, kPeakAccel = 5.773502691896258;

// Duration of a rest-to-rest minimum-jerk move by dq within `ratio` of the joint limits.
double move_duration(const RobotModel& robot, const Vector6& dq, double ratio) {
  double T = 0;
  for (int i = 0; i < kNumJoints; ++i) {
    const double d = std::abs(dq[i]);
    T = std::max({T, kPeakSpeed * d / (ratio * robot.limits[i].velocity),
                  std::sqrt(kPeakAccel * d / (ratio * robot.limits[i].acceleration))});
  }
  return T;
}

// Appends the move qa → qb sampled every dt (the first sample only when `out` is empty: moves
// share their junction).
void append_move(const RobotModel& robot, const Vector6& qa, const Vector6& qb, double ratio,
                 double dt, JointTrajectory& out) {
  const Vector6 dq = qb - qa;
  const double T = move_duration(robot, dq, ratio);
  const double t0 = out.t.empty() ? 0.0 : out.t.back();
  const int n = std::max(1, static_cast<int>(std::ceil(T / dt - 1e-9)));
  for (int k = out.t.empty() ? 0 : 1; k <= n; ++k) {
    const double tau = static_cast<double>(k) / n;
    const double s = tau * tau * tau * (10 - 15 * tau + 6 * tau * tau);
    const double ds = T > 0 ? 30 * tau * tau * (1 - tau) * (1 - tau) / T : 0.0;
    const double dds = T > 0 ? 60 * tau * (1 - tau) * (1 - 2 * tau) / (T * T) : 0.0;
    out.t.push_back(t0 + tau * T);
    out.q.push_back(qa + s * dq);
    out.dq.push_back(ds * dq);
    out.ddq.push_back(dds * dq);
  }
}

// Walks the joint-space line qa → qb (the geometric path of a minimum-jerk move) checking the
// clearance: a step moves no point of the robot farther than the last clearance less half the
// required one, so between two checks the clearance stays above need / 2. Returns the least
// clearance found (stops at the first below `need`).
Clearance check_line(const RobotModel& robot, const Vector6& qa, const Vector6& qb, double need,
                     const ClearanceFn& clearance, std::size_t& checks) {
  const double reach = motion_bound(robot, qb - qa);
  Clearance worst{1e300, ""};
  double lambda = 0;
  for (;;) {
    const Clearance c = clearance(qa + lambda * (qb - qa));
    ++checks;
    if (c.distance < worst.distance) worst = c;
    if (c.distance < need || lambda >= 1) return worst;
    const double step = std::max(c.distance - 0.5 * need, 2e-4);
    lambda = reach > 0 ? std::min(1.0, lambda + step / reach) : 1.0;
  }
}

// The configuration with the tool raised by `lift` along up_B from q, on q's branch (the IK
// solution nearest q); false when the raised pose is out of reach.
bool lifted(const RobotModel& robot, const Vector6& q, const Vec3& up_B, double lift, Vector6& out) {
  Pose X = fk_tool(robot, q);
  X.translation() += lift * up_B;
  IkParams ip;
  ip.q_ref = q;
  const IkResult r = ik_tool(robot, X, ip);
  if (!r.ok()) return false;
  double best = 1e300;
  for (const IkSolution& s : r.solutions) {
    const double d = (s.q - q).norm();
    if (d < best) best = d, out = s.q;
  }
  return true;
}

std::string mm(double v) { return strf("%.2f mm", v * 1e3); }

// RRT-connect (Kuffner & LaValle 2000) in joint space within the joint limits: two trees grown
// from the ends towards random configurations (one step of at most `step` rad per extension,
// each edge walked by check_line), until they connect. Then shortcut: from each waypoint, the
// farthest later one a clear line reaches. Returns the waypoints (ends included), or none.
std::vector<Vector6> rrt_connect(const RobotModel& robot, const Vector6& qa, const Vector6& qb,
                                 double need, const ClearanceFn& clearance, const TransitParams& P,
                                 std::size_t& checks) {
  struct Tree {
    std::vector<Vector6> q;
    std::vector<int> parent;
  };
  Tree ta{{qa}, {-1}}, tb{{qb}, {-1}};
  Rng rng(P.rrt_seed);
  const auto clear = [&](const Vector6& x, const Vector6& y) {
    return check_line(robot, x, y, need, clearance, checks).distance >= need;
  };
  const auto nearest = [](const Tree& t, const Vector6& q) {
    std::size_t best = 0;
    double d = 1e300;
    for (std::size_t i = 0; i < t.q.size(); ++i)
      if ((t.q[i] - q).squaredNorm() < d) d = (t.q[i] - q).squaredNorm(), best = i;
    return best;
  };
  // One step from the nearest node towards q; the new node's index, or −1 when blocked.
  const auto extend = [&](Tree& t, const Vector6& q) -> int {
    const std::size_t n = nearest(t, q);
    Vector6 dq = q - t.q[n];
    if (dq.norm() > P.rrt_step) dq *= P.rrt_step / dq.norm();
    const Vector6 q_new = t.q[n] + dq;
    if (!clear(t.q[n], q_new)) return -1;
    t.q.push_back(q_new);
    t.parent.push_back(static_cast<int>(n));
    return static_cast<int>(t.q.size() - 1);
  };
  const auto branch = [](const Tree& t, int i) {
    std::vector<Vector6> out;
    for (; i >= 0; i = t.parent[static_cast<std::size_t>(i)]) out.push_back(t.q[static_cast<std::size_t>(i)]);
    return out;  // from node i back to the root
  };
  Tree* grow = &ta;
  Tree* other = &tb;
  for (int it = 0; it < P.rrt_iterations; ++it) {
    Vector6 q_rand;
    // Samples near the ends: within rrt_margin of the box their joints span (and the limits),
    // so a route does not swing the arm round through far configurations.
    for (int j = 0; j < kNumJoints; ++j) {
      const double lo = std::max(robot.limits[j].lower, std::min(qa[j], qb[j]) - P.rrt_margin);
      const double hi = std::min(robot.limits[j].upper, std::max(qa[j], qb[j]) + P.rrt_margin);
      q_rand[j] = rng.uniform(lo, hi);
    }
    const int i_new = extend(*grow, q_rand);
    if (i_new >= 0) {
      // Connect: the other tree steps towards the new node until it reaches it or is blocked.
      const Vector6 target = grow->q[static_cast<std::size_t>(i_new)];
      int i_other = -1;
      for (;;) {
        const int k = extend(*other, target);
        if (k < 0) break;
        i_other = k;
        if ((other->q[static_cast<std::size_t>(k)] - target).norm() < 1e-12) {
          std::vector<Vector6> a = branch(ta, static_cast<int>(grow == &ta ? i_new : i_other));
          std::vector<Vector6> b = branch(tb, static_cast<int>(grow == &ta ? i_other : i_new));
          std::reverse(a.begin(), a.end());
          a.insert(a.end(), b.begin() + 1, b.end());  // the shared node once
          // Shortcut.
          std::vector<Vector6> way{a.front()};
          for (std::size_t i = 0; i + 1 < a.size();) {
            std::size_t j = a.size() - 1;
            while (j > i + 1 && !clear(a[i], a[j])) --j;
            way.push_back(a[j]);
            i = j;
          }
          return way;
        }
      }
    }
    std::swap(grow, other);
  }
  return {};
}

}  // namespace

double motion_bound(const RobotModel& robot, const Vector6& dq, double radius) {
  double bound = 0, reach = robot.tool.X_ET.translation().norm() + radius;
  for (int i = kNumJoints - 1; i >= 0; --i) {
    reach += std::abs(robot.dh[i].a) + std::abs(robot.dh[i].d);
    bound += std::abs(dq[i]) * reach;
  }
  return bound;
}

TransitResult plan_transit(const RobotModel& robot, const Vector6& q_from, const Vector6& q_to,
                           const ClearanceFn& clearance, const TransitParams& P) {
  const auto bad = [](const char* field, const char* expected, double got) {
    throw ArgumentError(strf("transit.%s: expected %s, got %g", field, expected, got));
  };
  if (!(P.clearance > 0 && std::isfinite(P.clearance))) bad("clearance", "a distance > 0 [m]", P.clearance);
  if (!(P.min_end_clearance >= 0 && P.min_end_clearance <= P.clearance))
    bad("min_end_clearance", "a distance in [0, clearance] [m]", P.min_end_clearance);
  if (!(P.speed_ratio > 0 && P.speed_ratio <= 1)) bad("speed_ratio", "a fraction in (0, 1]", P.speed_ratio);
  if (!(P.dt > 0 && std::isfinite(P.dt))) bad("dt", "a period > 0 [s]", P.dt);
  if (!q_from.allFinite() || !q_to.allFinite()) bad("q", "finite joint angles", NAN);
  if (!(P.rrt_step > 0)) bad("rrt_step", "a joint step > 0 [rad]", P.rrt_step);

  TransitResult res;
  // Where the move's own ends stand nearer than twice the clearance asked, it keeps half the
  // nearer end's (leaving a part it stood close to, the move may pass a little nearer to it
  // than its start; half is a margin a tracking error of the transit never uses up).
  const Clearance c_from = clearance(q_from), c_to = clearance(q_to);
  res.checks = 2;
  for (const Clearance* c : {&c_from, &c_to})
    if (c->distance < P.min_end_clearance) {
      res.message = "an end of the transit is not clear: " + mm(c->distance) + " (" + c->what + ")";
      res.min_clearance = c->distance;
      return res;
    }
  const double need = std::min(P.clearance, 0.5 * std::min(c_from.distance, c_to.distance));

  // The direct move, then lifts in turn: the waypoints' joint lines must all keep `need`.
  std::vector<std::vector<Vector6>> routes{{q_from, q_to}};
  std::vector<double> route_lift{0.0};
  if (ik_supported(robot))
    for (const double lift : P.lifts) {
      Vector6 up_from, up_to;
      if (!lifted(robot, q_from, P.up_B, lift, up_from) || !lifted(robot, q_to, P.up_B, lift, up_to)) continue;
      routes.push_back({q_from, up_from, up_to, q_to});
      route_lift.push_back(lift);
    }
  // Through the parking configurations given (home: clear by the cell's design), straight from
  // the ends and over each lift.
  const std::size_t n_plain = routes.size();
  for (const Vector6& via : P.via) {
    routes.push_back({q_from, via, q_to});
    route_lift.push_back(0.0);
    for (std::size_t r = 1; r < n_plain; ++r) {
      const Vector6 up_from = routes[r][1], up_to = routes[r][2];  // copies: push_back reallocates
      routes.push_back({q_from, up_from, via, up_to, q_to});
      route_lift.push_back(route_lift[r]);
    }
  }
  Clearance best_fail{-1e300, ""};
  for (std::size_t r = 0; r < routes.size(); ++r) {
    const auto& way = routes[r];
    Clearance worst{1e300, ""};
    for (std::size_t k = 0; k + 1 < way.size() && worst.distance >= need; ++k) {
      const Clearance c = check_line(robot, way[k], way[k + 1], need, clearance, res.checks);
      if (c.distance < worst.distance) worst = c;
    }
    if (worst.distance < need) {
      if (worst.distance > best_fail.distance) best_fail = worst;
      continue;
    }
    for (std::size_t k = 0; k + 1 < way.size(); ++k)
      append_move(robot, way[k], way[k + 1], P.speed_ratio, P.dt, res.trajectory);
    res.trajectory.dt = P.dt;
    for (const Vector6& q : res.trajectory.q) res.tcp_B.push_back(fk_tool(robot, q));
    res.ok = true;
    res.lifted = r > 0;
    res.min_clearance = std::min({worst.distance, c_from.distance, c_to.distance});
    res.message = r == 0 ? "direct" : r < n_plain ? strf("over a lift of %.2f m", route_lift[r])
                : route_lift[r] > 0 ? strf("through a parking pose over a lift of %.2f m", route_lift[r])
                                    : "through a parking pose";
    return res;
  }
  // Last: a sampled route.
  if (P.rrt_iterations > 0) {
    const std::vector<Vector6> way = rrt_connect(robot, q_from, q_to, need, clearance, P, res.checks);
    if (!way.empty()) {
      Clearance worst{1e300, ""};
      for (std::size_t k = 0; k + 1 < way.size(); ++k) {
        const Clearance c = check_line(robot, way[k], way[k + 1], need, clearance, res.checks);
        if (c.distance < worst.distance) worst = c;
        append_move(robot, way[k], way[k + 1], P.speed_ratio, P.dt, res.trajectory);
      }
      res.trajectory.dt = P.dt;
      for (const Vector6& q : res.trajectory.q) res.tcp_B.push_back(fk_tool(robot, q));
      res.ok = true;
      res.lifted = true;
      res.min_clearance = std::min({worst.distance, c_from.distance, c_to.distance});
      res.message = strf("a sampled route through %zu waypoints", way.size() - 2);
      return res;
    }
  }
  res.min_clearance = best_fail.distance;
  res.message = "no clear transit (direct" + std::string(n_plain > 1 ? ", over a lift" : "") +
                std::string(P.via.empty() ? "" : ", through a parking pose") +
                std::string(P.rrt_iterations > 0 ? ", sampled" : "") +
                "): it comes within " + mm(best_fail.distance) + " of " + best_fail.what +
                " (needs " + mm(need) + ")";
  return res;
}

}  // namespace flashtwin::planner
