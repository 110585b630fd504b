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

bool ik_supported(const RobotModel& r) { return arm_geometry(r) != ArmGeometry::kUnsupported; }

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

// The wrist rotation W = Rz(a)·Ry(−b)·Rz(c) (ZYZ with a negated middle angle, the form both
// arm types share: R_36 of a spherical wrist with (a, b, c) = (θ4, θ5, θ6); R_16 of an offset
// wrist with (θ2+θ3+θ4, θ5, θ6)). Its third column is (−ca·sb, −sa·sb, cb) and its third row
// (sb·cc, −sb·sc, cb), so for sb ≠ 0 the two signs of sb give the two wrist branches. At sb = 0
// only a + c (b = 0) or a − c (b = π) is fixed: `held_first` keeps a at `held` and solves c, or
// else keeps c at `held` and solves a.
struct WristAngles {
  double a, b, c;
  bool flip;
};

std::vector<WristAngles> wrist_angles(const Mat3& W, double tol, bool held_first, double held,
                                      bool& singular) {
  const double sb = std::hypot(W(0, 2), W(1, 2));
  singular = sb < tol;
  if (singular) {
    if (W(2, 2) > 0) {  // b = 0: W = Rz(a + c)
      const double sum = std::atan2(W(1, 0), W(0, 0));
      return {held_first ? WristAngles{held, 0, sum - held, false}
                         : WristAngles{sum - held, 0, held, false}};
    }
    // b = π: W = Rz(a)·Ry(π)·Rz(c) fixes a − c.
    const double diff = std::atan2(-W(1, 0), -W(0, 0));
    return {held_first ? WristAngles{held, M_PI, held - diff, false}
                       : WristAngles{diff + held, M_PI, held, false}};
  }
  std::vector<WristAngles> out;
  for (int w = 0; w < 2; ++w) {
    const double sgn = w == 0 ? 1.0 : -1.0;
    out.push_back({std::atan2(-sgn * W(1, 2), -sgn * W(0, 2)), sgn * std::atan2(sb, W(2, 2)),
                   std::atan2(-sgn * W(2, 1), sgn * W(2, 0)), w == 1});
  }
  return out;
}

// Solutions of a spherical-wrist (PUMA/OPW-type) arm, any branch, limits not yet applied.
// Returns false (with res.message) when the wrist centre is out of reach.
bool solve_spherical_wrist(const RobotModel& robot, const Pose& X_BE, const IkParams& params,
                           IkResult& res, std::vector<IkSolution>& all,
                           std::vector<std::string>& notes) {
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
      return false;
    }
  }
  const double fwd = std::sqrt(fwd2);
  res.shoulder_singular = fwd < tol;
  if (res.shoulder_singular) notes.push_back("shoulder singular (front and back coincide)");

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
      const Pose X_B3 = dh_link(dh[0], th1) * dh_link(dh[1], th2) * dh_link(dh[2], th3);
      const Mat3 W = X_B3.linear().transpose() * R;
      bool singular = false;
      const double th4_ref = params.q_ref ? (*params.q_ref)[3] : 0.0;
      for (const WristAngles& w : wrist_angles(W, params.wrist_tol, true, th4_ref, singular)) {
        Vector6 q;
        q << th1, th2, th3, w.a, w.b, w.c;
        all.push_back({q, IkBranch{front, elbow_up, w.flip}});
      }
      res.wrist_singular = res.wrist_singular || singular;
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
    return false;
  }
  return true;
}

// Solutions of an offset-wrist arm (the Universal Robots type: joints 2, 3, 4 parallel, wrist
// axes not meeting in a point), after the closed form of Hawkins, "Analytic inverse kinematics
// for the Universal Robots UR-5/UR-10 arms" (2013), derived here in this project's frames:
//  1. The origin of frame {5}, p5 = p6 − d6·z6, lies at the lateral offset dl = d2 + d3 + d4
//     along z1 = (sin θ1, −cos θ1, 0): r·sin(θ1 − ψ) = dl, two roots (front/back).
//  2. R_16 = Rz(θ2+θ3+θ4)·Ry(−θ5)·Rz(θ6) (joints 2–4 turn about z1): the shared wrist
//     decomposition gives θ5 (two signs: flip), θ6 and θ234.
//  3. Frame {4}'s origin p4 = p5 − d5·z4 lies in the plane of joints 2 and 3, a planar
//     two-link problem in a2, a3 (elbow up/down); θ4 = θ234 − θ2 − θ3.
bool solve_offset_wrist(const RobotModel& robot, const Pose& X_BE, const IkParams& params,
                        IkResult& res, std::vector<IkSolution>& all,
                        std::vector<std::string>& notes) {
  const auto& dh = robot.dh;
  const double dl = dh[1].d + dh[2].d + dh[3].d, a2 = dh[1].a, a3 = dh[2].a;
  const double d5 = dh[4].d, d6 = dh[5].d;
  const Mat3 R = X_BE.linear();
  const Vec3 p5 = X_BE.translation() - d6 * R.col(2);
  const double r = std::hypot(p5.x(), p5.y()), tol = params.length_tol;
  if (r < std::abs(dl) - tol) {
    char b[200];
    std::snprintf(b, sizeof b,
                  "wrist point %.4f m from the axis of joint 1, closer than the lateral offset "
                  "%.4f m",
                  r, std::abs(dl));
    res.message = b;
    return false;
  }
  const double psi = std::atan2(p5.y(), p5.x());
  const double beta = std::asin(std::clamp(dl / std::max(r, 1e-300), -1.0, 1.0));
  res.shoulder_singular = std::sqrt(std::max(0.0, r * r - dl * dl)) < tol;
  if (res.shoulder_singular) notes.push_back("shoulder singular (front and back coincide)");
  const double th6_ref = params.q_ref ? (*params.q_ref)[5] : 0.0;
  bool any_reach = false;
  double worst_reach = 0;
  for (int s = 0; s < (res.shoulder_singular ? 1 : 2); ++s) {
    // Front: the root the zero configuration is on (the arm reaching along its own −x1 when
    // a2 < 0, the UR convention); back: the arm turned over the shoulder.
    const bool front = s == 0;
    const double th1 = front ? psi + M_PI - beta : psi + beta;
    const Pose X_B1 = dh_link(dh[0], th1);
    const Mat3 R16 = X_B1.linear().transpose() * R;
    const Vec3 p15 = X_B1.inverse() * p5;
    bool singular = false;
    for (const WristAngles& w : wrist_angles(R16, params.wrist_tol, false, th6_ref, singular)) {
      const double th234 = w.a;
      // p4 in frame {1}: z4 = Rz(θ234)·(0, −1, 0) there.
      const Vec3 z14(std::sin(th234), -std::cos(th234), 0);
      const Vec3 p14 = p15 - d5 * z14;
      const double x = p14.x(), y = p14.y();
      double c3 = (x * x + y * y - a2 * a2 - a3 * a3) / (2 * a2 * a3);
      if (std::abs(c3) > 1) {
        const double reach = std::hypot(x, y);
        const double excess = c3 > 0 ? reach - std::abs(a2 + a3) : std::abs(a2 - a3) - reach;
        worst_reach = std::max(worst_reach, reach);
        if (excess > tol) continue;
        c3 = std::clamp(c3, -1.0, 1.0);
      }
      any_reach = true;
      const double t3 = std::acos(c3);
      const bool elbow_singular = std::sin(t3) < params.elbow_tol;
      res.elbow_singular = res.elbow_singular || elbow_singular;
      for (int e = 0; e < (elbow_singular ? 1 : 2); ++e) {
        const double th3 = e == 0 ? t3 : -t3;
        const double th2 =
            std::atan2(y, x) - std::atan2(a3 * std::sin(th3), a2 + a3 * std::cos(th3));
        Vector6 q;
        q << th1, th2, th3, th234 - th2 - th3, w.b, w.c;
        // With a2, a3 < 0 (UR), θ3 > 0 on the front branch puts the elbow above the line from
        // the shoulder to the wrist (y1 is up); the back branch mirrors it.
        const bool elbow_up = (th3 * a2 * a3 > 0) == front;
        all.push_back({q, IkBranch{front, elbow_up, w.flip}});
      }
    }
    res.wrist_singular = res.wrist_singular || singular;
  }
  if (res.elbow_singular) notes.push_back("elbow singular (arm stretched or folded)");
  if (res.wrist_singular)
    notes.push_back("wrist singular (theta5 = 0: theta6 held at its reference, theta4 solved)");
  if (!any_reach) {
    char b[240];
    std::snprintf(b, sizeof b,
                  "wrist out of reach: joint 4 would be %.4f m from joint 2, reachable between "
                  "%.4f and %.4f m",
                  worst_reach, std::abs(std::abs(a2) - std::abs(a3)), std::abs(a2) + std::abs(a3));
    res.message = b;
    return false;
  }
  return true;
}

}  // namespace

IkResult ik_flange(const RobotModel& robot, const Pose& X_BE, const IkParams& params) {
  IkResult res;
  const ArmGeometry geometry = arm_geometry(robot);
  if (geometry == ArmGeometry::kUnsupported) {
    res.status = IkStatus::kUnsupportedGeometry;
    res.message = "the D-H table is neither of the spherical-wrist (PUMA/OPW) type nor of the "
                  "offset-wrist (UR) type the analytic solvers handle";
    return res;
  }
  if (!X_BE.matrix().allFinite()) {
    res.status = IkStatus::kUnreachable;
    res.message = "pose holds NaN or inf";
    return res;
  }
  std::vector<IkSolution> all;
  std::vector<std::string> notes;
  const bool reached = geometry == ArmGeometry::kSphericalWrist
                           ? solve_spherical_wrist(robot, X_BE, params, res, all, notes)
                           : solve_offset_wrist(robot, X_BE, params, res, all, notes);
  if (!reached) return res;

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
