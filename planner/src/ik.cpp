#include "flashtwin/planner/ik.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

std::string IkBranch::name() const {
  return std::string(front ? "front" : "back") + "/" + (elbow_up ? "up" : "down") + "/" +
         (flip ? "flip" : "noflip");
}

std::string to_string(IkStatus s) {
  switch (s) {
    case IkStatus::kOk: return "ok";
    case IkStatus::kUnreachable: return "unreachable";
    case IkStatus::kOutsideLimits: return "outside_limits";
    case IkStatus::kUnsupportedGeometry: return "unsupported_geometry";
  }
  return "?";
}

bool ik_supported(const RobotModel& r) {
  const double e = 1e-12;
  auto near = [e](double v, double t) { return std::abs(v - t) < e; };
  const double h = M_PI / 2;
  return near(r.dh[0].alpha, -h) && near(r.dh[1].alpha, 0) && near(r.dh[2].alpha, -h) &&
         near(r.dh[3].alpha, h) && near(r.dh[4].alpha, -h) && near(r.dh[5].alpha, 0) &&
         near(r.dh[3].a, 0) && near(r.dh[4].a, 0) && near(r.dh[5].a, 0) && near(r.dh[4].d, 0) &&
         std::hypot(r.dh[2].a, r.dh[3].d) > 1e-9 && std::abs(r.dh[1].a) > 1e-9;
}

namespace {

double wrap_pi(double a) {
  a = std::remainder(a, 2 * M_PI);  // in [-pi, pi]
  return a;
}

// The 2π-equivalent of `theta` within [lo, hi] nearest to `ref`; false when none fits.
bool fit_limits(double theta, const JointLimits& L, double ref, double& out) {
  const double base = wrap_pi(theta);
  bool found = false;
  double best = 0, best_d = 0;
  for (int k = -2; k <= 2; ++k) {
    const double c = base + 2 * M_PI * k;
    if (!L.contains(c, 1e-12)) continue;
    const double dist = std::abs(c - ref);
    if (!found || dist < best_d) {
      found = true;
      best = c;
      best_d = dist;
    }
  }
  out = found ? best : base;
  return found;
}

}  // namespace

IkResult ik_flange(const RobotModel& robot, const Pose& X_BE, const IkParams& params) {
  IkResult res;
  if (!ik_supported(robot)) {
    res.status = IkStatus::kUnsupportedGeometry;
    res.message = "the D-H table is not of the PUMA type (spherical wrist) the analytic solver "
                  "handles";
    return res;
  }
  if (!X_BE.matrix().allFinite()) {
    res.status = IkStatus::kUnreachable;
    res.message = "pose holds NaN or inf";
    return res;
  }
  const auto& dh = robot.dh;
  const double d1 = dh[0].d, a1 = dh[0].a, zoff = dh[1].d + dh[2].d;
  const double a2 = dh[1].a, a3 = dh[2].a, d4 = dh[3].d, d6 = dh[5].d;
  const double L = std::hypot(a3, d4), phi = std::atan2(d4, a3);
  const Mat3 R = X_BE.linear();
  // Wrist centre: the flange origin moved back by d6 along the flange z axis.
  const Vec3 pw = X_BE.translation() - d6 * R.col(2);

  // Joint 1: the wrist centre seen from the shoulder axis at radius r has a fixed lateral
  // offset zoff, so its forward coordinate is ±sqrt(r² − zoff²).
  const double r2 = pw.x() * pw.x() + pw.y() * pw.y();
  double fwd2 = r2 - zoff * zoff;
  const double tol = params.length_tol;
  if (fwd2 < 0) {
    if (fwd2 > -2 * std::abs(zoff) * tol - tol * tol) {
      fwd2 = 0;
    } else {
      char b[200];
      std::snprintf(b, sizeof b,
                    "wrist centre %.4f m from the axis of joint 1, closer than the shoulder "
                    "offset %.4f m",
                    std::sqrt(r2), std::abs(zoff));
      res.message = b;
      return res;
    }
  }
  const double fwd = std::sqrt(fwd2);
  res.shoulder_singular = fwd < tol;
  std::vector<std::string> notes;
  if (res.shoulder_singular) notes.push_back("shoulder singular (front and back coincide)");

  std::vector<IkSolution> all;
  bool any_reach = false;
  for (int s = 0; s < (res.shoulder_singular ? 1 : 2); ++s) {
    const bool front = s == 0;
    const double X = front ? fwd : -fwd;
    const double th1 = std::atan2(pw.y(), pw.x()) - std::atan2(zoff, X);
    // Wrist centre in the plane of the upper arm (frame {1} coordinates).
    const double x = X - a1, y = d1 - pw.z();
    double c_psi = (x * x + y * y - a2 * a2 - L * L) / (2 * a2 * L);
    if (std::abs(c_psi) > 1) {
      // Slack for poses exactly at the edge of the reach (stretched/folded elbow).
      const double excess = std::abs(std::hypot(x, y) - (c_psi > 0 ? a2 + L : std::abs(a2 - L)));
      if (excess > tol) continue;
      c_psi = std::clamp(c_psi, -1.0, 1.0);
    }
    any_reach = true;
    const double psi0 = std::acos(c_psi);
    const bool elbow_singular = std::sin(psi0) < params.elbow_tol;
    res.elbow_singular = res.elbow_singular || elbow_singular;
    for (int e = 0; e < (elbow_singular ? 1 : 2); ++e) {
      const double psi = e == 0 ? psi0 : -psi0;
      const double th2 = std::atan2(y, x) - std::atan2(L * std::sin(psi), a2 + L * std::cos(psi));
      const double th3 = psi - phi;
      const bool elbow_up = (psi >= 0) == front;
      // Wrist: R_36 = Rz(θ4)·Ry(−θ5)·Rz(θ6).
      Vector6 q = Vector6::Zero();
      q[0] = th1;
      q[1] = th2;
      q[2] = th3;
      const Pose X_B3 = dh_link(dh[0], th1) * dh_link(dh[1], th2) * dh_link(dh[2], th3);
      const Mat3 W = X_B3.linear().transpose() * R;
      const double s5 = std::hypot(W(0, 2), W(1, 2));
      const bool wrist_singular = s5 < params.wrist_tol;
      if (wrist_singular) {
        res.wrist_singular = true;
        const double th4 = params.q_ref ? (*params.q_ref)[3] : 0.0;
        q[3] = th4;
        if (W(2, 2) > 0) {
          // θ5 = 0: R_36 = Rz(θ4 + θ6).
          q[4] = 0;
          q[5] = std::atan2(W(1, 0), W(0, 0)) - th4;
        } else {
          // θ5 = π: R_36 = Rz(θ4)·Ry(π)·Rz(θ6), only θ4 − θ6 is fixed.
          q[4] = M_PI;
          q[5] = th4 - std::atan2(-W(1, 0), -W(0, 0));
        }
        all.push_back({q, IkBranch{front, elbow_up, false}});
        continue;
      }
      for (int w = 0; w < 2; ++w) {
        const double sgn = w == 0 ? 1.0 : -1.0;
        q[3] = std::atan2(-sgn * W(1, 2), -sgn * W(0, 2));
        q[4] = sgn * std::atan2(s5, W(2, 2));
        q[5] = std::atan2(-sgn * W(2, 1), sgn * W(2, 0));
        all.push_back({q, IkBranch{front, elbow_up, w == 1}});
      }
    }
  }
  if (res.elbow_singular) notes.push_back("elbow singular (arm stretched or folded)");
  if (res.wrist_singular)
    notes.push_back("wrist singular (theta5 = 0: theta4 held at its reference, theta6 solved)");

  if (!any_reach) {
    const double dist = std::hypot(fwd - a1, d1 - pw.z());
    char b[240];
    std::snprintf(b, sizeof b,
                  "wrist centre out of reach: %.4f m from the shoulder, reachable between "
                  "%.4f and %.4f m",
                  dist, std::abs(a2 - L), a2 + L);
    res.message = b;
    return res;
  }

  // Choose 2π-equivalents within the limits, nearest the reference (or zero).
  for (auto& sol : all) {
    bool inside = true;
    for (int i = 0; i < kNumJoints; ++i) {
      const double ref = params.q_ref ? (*params.q_ref)[i] : 0.0;
      inside = fit_limits(sol.q[i], robot.limits[i], ref, sol.q[i]) && inside;
    }
    if (inside || !params.within_limits_only) res.solutions.push_back(sol);
    if (!inside) ++res.discarded_by_limits;
  }
  std::sort(res.solutions.begin(), res.solutions.end(),
            [](const IkSolution& a, const IkSolution& b) {
              return a.branch.index() < b.branch.index();
            });
  const bool any_inside = static_cast<int>(all.size()) > res.discarded_by_limits;
  res.status = any_inside ? IkStatus::kOk : IkStatus::kOutsideLimits;
  if (!any_inside)
    notes.insert(notes.begin(), std::to_string(all.size()) +
                                    " solution(s) exist but none within the joint limits");
  for (const auto& n : notes) res.message += (res.message.empty() ? "" : "; ") + n;
  if (res.message.empty()) res.message = "ok";
  return res;
}

IkResult ik_tool(const RobotModel& robot, const Pose& X_BT, const IkParams& params) {
  return ik_flange(robot, X_BT * robot.tool.X_ET.inverse(), params);
}

}  // namespace flashtwin::planner
