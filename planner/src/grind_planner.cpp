#include "flashtwin/planner/grind_planner.hpp"

#include <algorithm>
#include <cmath>
#include <cstdarg>
#include <cstdio>
#include <limits>
#include <optional>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/planner/bspline.hpp"
#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

std::string to_string(GrindStatus status) {
  switch (status) {
    case GrindStatus::kOk:
      return "ok";
    case GrindStatus::kUnreachable:
      return "unreachable";
    case GrindStatus::kJointLimit:
      return "joint_limit";
    case GrindStatus::kSingular:
      return "singular";
    case GrindStatus::kDiscontinuous:
      return "discontinuous";
    case GrindStatus::kTimingFailed:
      return "timing_failed";
    case GrindStatus::kToolTooLarge:
      return "tool_too_large";
    case GrindStatus::kCollision:
      return "collision";
  }
  return "unknown";
}

std::string to_string(SampleKind kind) {
  switch (kind) {
    case SampleKind::kApproach:
      return "approach";
    case SampleKind::kCut:
      return "cut";
    case SampleKind::kLink:
      return "link";
    case SampleKind::kRetract:
      return "retract";
  }
  return "unknown";
}

std::string to_string(ReorientReason reason) {
  switch (reason) {
    case ReorientReason::kSingular:
      return "singular";
    case ReorientReason::kJointLimit:
      return "joint_limit";
    case ReorientReason::kUnreachable:
      return "unreachable";
    case ReorientReason::kDiscontinuous:
      return "discontinuous";
    case ReorientReason::kCollision:
      return "collision";
  }
  return "unknown";
}

namespace {


std::string vec_text(const Vec3& v) {
  return strf("(%g, %g, %g)", v.x(), v.y(), v.z());
}

// Quintic smoothstep: 0 → 1 with zero first and second derivatives at both ends.
double smoothstep(double x) {
  x = std::clamp(x, 0.0, 1.0);
  return x * x * x * (10 - 15 * x + 6 * x * x);
}

// Nominal geometry of one sample, in {C} (see the header for the symbols).
struct Geo {
  Vec3 p, n, t;
  double slope = 0;  // [rad] the wall's own normal is n turned by this towards f (a sloped wall)
  double extra = 0;  // pass offset e [m]
  double lift = 0;   // approach/retract height along f [m]
  SampleKind kind = SampleKind::kCut;
  int pass = 0;
  int path_index = 0;
  double dir = 1;  // +1 on a pass along the path, −1 on one back along it (t reversed)
  double lead_cap = 0;  // largest extra lead allowed here [rad] (lead_cap_at)
};

// Re-orientation of one sample on top of the nominal lead/tilt and the base spin [rad]. Its
// lead turns the shank toward the path's own direction (points_C order), whichever way the
// pass travels: a re-orientation is a place on the casting where the wrist needs the axis
// turned, so it must stay put when the next pass comes back along the path (as a lead toward
// the travel it would flip at every turn-round; the nominal P.lead does follow the travel).
struct Dev {
  double lead = 0, tilt = 0, spin = 0;
};

// Per-sample IK outcome while following one branch.
enum class NodeStatus { kOk, kLowManip, kUnreachable, kJointLimit, kJump, kBranchLost, kCollision };

struct Node {
  NodeStatus status = NodeStatus::kUnreachable;
  bool has_q = false;  // q is a solution on the followed branch (possibly bad otherwise)
  Vector6 q = Vector6::Zero();
  double manip = 0;
  int joint = -1;    // kJointLimit: the joint; kJump: the joint that jumps
  double value = 0;  // kJointLimit: excess [rad]; kJump: the step [rad]; kCollision: clearance [m]
  std::string info;  // IK message for kUnreachable; what comes near for kCollision
};

// Severity for naming a bad range's cause (the first sample of the most severe kind).
int severity(NodeStatus s) {
  switch (s) {
    case NodeStatus::kUnreachable:
      return 4;
    case NodeStatus::kJointLimit:
    case NodeStatus::kCollision:
      return 3;
    case NodeStatus::kLowManip:
      return 2;  // jumps and lost branches are its usual symptoms
    case NodeStatus::kBranchLost:
      return 1;
    case NodeStatus::kJump:
      return 1;
    case NodeStatus::kOk:
      return 0;
  }
  return 0;
}

ReorientReason reason_of(NodeStatus s) {
  switch (s) {
    case NodeStatus::kLowManip:
      return ReorientReason::kSingular;
    case NodeStatus::kUnreachable:
      return ReorientReason::kUnreachable;
    case NodeStatus::kJointLimit:
      return ReorientReason::kJointLimit;
    case NodeStatus::kCollision:
      return ReorientReason::kCollision;
    default:
      return ReorientReason::kDiscontinuous;
  }
}

GrindStatus status_of(NodeStatus s) {
  switch (s) {
    case NodeStatus::kLowManip:
      return GrindStatus::kSingular;
    case NodeStatus::kUnreachable:
      return GrindStatus::kUnreachable;
    case NodeStatus::kJointLimit:
      return GrindStatus::kJointLimit;
    case NodeStatus::kCollision:
      return GrindStatus::kCollision;
    default:
      return GrindStatus::kDiscontinuous;
  }
}

// The 2π-equivalent of `v` nearest to `ref`.
double unwrap_near(double v, double ref) {
  return v + 2 * M_PI * std::round((ref - v) / (2 * M_PI));
}

// How far `v` lies outside [lower, upper] (0 inside), and on which side (+1 upper, −1 lower).
double limit_excess(const JointLimits& L, double v, int* side = nullptr) {
  if (v > L.upper) {
    if (side) *side = 1;
    return v - L.upper;
  }
  if (v < L.lower) {
    if (side) *side = -1;
    return L.lower - v;
  }
  if (side) *side = 0;
  return 0;
}

// Everything the per-sample solves need; immutable while the seeds are tracked.
struct Context {
  const RobotModel& robot;
  const GrindParams& P;
  Pose X_BC;
  Vec3 f, x_ref;
  double radius = 0, length = 0, tip_depth = 0, lead = 0, tilt = 0;
  std::vector<Geo> geo;
  std::vector<double> s_nom;  // nominal tool path length at each sample [m]

  Pose pose_C(std::size_t i, const Dev& d, double spin0, double* off = nullptr) const {
    const Geo& g = geo[i];
    // On a sloped wall the burr's side lies on the wall: its own normal, and the fin normal
    // turned into the wall's tangent plane (the shank leans with the wall).
    const double cb = std::cos(g.slope), sb = std::sin(g.slope);
    const Vec3 n_wall = cb * g.n + sb * f, f_wall = cb * f - sb * g.n;
    const double l = lead + g.dir * d.lead, tl = tilt + d.tilt, sp = spin0 + d.spin;
    Pose X = grind_tool_pose(g.p, n_wall, g.t, f_wall, x_ref, g.extra, l, tl, sp, radius, length, tip_depth, off);
    // Above the floor: the burr slides up its axis where its lowest point would come nearer the
    // floor than the clearance (a fin low on the casting), not above the depth that keeps the fin
    // on the burr's straight side.
    const double up = P.floor_C || P.riser_C ? -X.linear().col(2).dot(floor_normal()) : 0.0;
    if (up > 0.1) {  // the tip's rise per unit of less tip depth
      const double short_by = floor_shortfall(X);
      if (short_by > 0) {
        const double min_depth = std::min(tip_depth, radius + 1e-3);
        const double depth = std::max(min_depth, tip_depth - short_by / up);
        X = grind_tool_pose(g.p, n_wall, g.t, f_wall, x_ref, g.extra, l, tl, sp, radius, length, depth, off);
      }
    }
    X.translation() += g.lift * f;
    return X;
  }

  // The floors' shared upward normal in {C}: the table's (a riser's top is parallel to it).
  Vec3 floor_normal() const { return P.floor_C ? P.floor_C->second : P.riser_C->X_CR.linear().col(2); }

  // How far the burr at tool pose X (TCP in {C}) comes nearer than floor_clearance to the floor
  // under it: the table's top, or the riser's where the burr's lowest point is over the riser
  // (grown by the burr radius and the clearance); <= 0 when clear. The burr's lowest point is
  // the lower of its two end circles' lowest points (ends at the tip and `length` up its axis).
  double floor_shortfall(const Pose& X) const {
    const Vec3 N = floor_normal(), z = X.linear().col(2), tip = X.translation();
    const Vec3 ball = tip - radius * z, top = tip - length * z;  // the burr's two lowest centres
    const Vec3 lowest = ball.dot(N) < top.dot(N) ? ball : top;
    const auto height = [&](const Vec3& o) { return (lowest - o).dot(N) - radius; };
    double short_by = -std::numeric_limits<double>::infinity();
    if (P.floor_C) short_by = P.floor_clearance - height(P.floor_C->first);
    if (P.riser_C) {
      const Vec3 q = P.riser_C->X_CR.inverse() * lowest;
      const double reach = radius + P.floor_clearance;
      if (std::abs(q.x()) <= P.riser_C->half.x() + reach && std::abs(q.y()) <= P.riser_C->half.y() + reach)
        short_by = std::max(short_by, P.floor_clearance - height(P.riser_C->X_CR.translation()));
    }
    return short_by;
  }

  // IK of sample i on branch `branch`, continuing from `ref` (first: no continuity checks).
  Node solve(std::size_t i, const Dev& d, double spin0, int branch, const Vector6& ref,
             bool first) const {
    Node node;
    const Pose X_BT = X_BC * pose_C(i, d, spin0);
    IkParams ip;
    ip.q_ref = ref;
    const IkResult res = ik_tool(robot, X_BT, ip);
    for (const auto& sol : res.solutions) {
      if (sol.branch.index() != branch) continue;
      node.has_q = true;
      node.q = sol.q;
      break;
    }
    if (node.has_q) {
      node.status = NodeStatus::kOk;
      // A joint the IK moved to another 2π-equivalent to stay within its range: the continuous
      // motion would leave the range there.
      if (!first) {
        for (int j = 0; j < kNumJoints; ++j) {
          const double c = unwrap_near(node.q[j], ref[j]);
          const double ex = limit_excess(robot.limits[j], c);
          if (ex > 0 && (node.status != NodeStatus::kJointLimit || ex > node.value)) {
            node.status = NodeStatus::kJointLimit;
            node.joint = j;
            node.value = ex;
          }
        }
        if (node.status == NodeStatus::kOk) {
          const Vector6 step = (node.q - ref).cwiseAbs();
          int j = 0;
          const double m = step.maxCoeff(&j);
          if (m > P.max_joint_jump) {
            node.status = NodeStatus::kJump;
            node.joint = j;
            node.value = m;
          }
        }
      }
      node.manip = manipulability(robot, node.q);
      if (node.status == NodeStatus::kOk && !(node.manip >= P.manipulability_threshold))
        node.status = NodeStatus::kLowManip;
      if (node.status == NodeStatus::kOk && P.clearance) {
        const Clearance c = P.clearance(node.q);
        if (c.distance < P.min_clearance) {
          node.status = NodeStatus::kCollision;
          node.value = c.distance;
          node.info = c.what;
        }
      }
      return node;
    }
    // No solution on this branch within the limits: find out why.
    ip.within_limits_only = false;
    const IkResult all = ik_tool(robot, X_BT, ip);
    if (all.solutions.empty()) {
      node.status = NodeStatus::kUnreachable;
      node.info = all.message;
      return node;
    }
    for (const auto& sol : all.solutions) {
      if (sol.branch.index() != branch) continue;
      node.status = NodeStatus::kJointLimit;
      node.value = 0;
      for (int j = 0; j < kNumJoints; ++j) {
        // Continuous value next to the reference; at the first sample the best equivalent.
        double ex = 0;
        if (!first) {
          ex = limit_excess(robot.limits[j], unwrap_near(sol.q[j], ref[j]));
        } else {
          ex = std::numeric_limits<double>::infinity();
          for (int k = -2; k <= 2; ++k)
            ex = std::min(ex, limit_excess(robot.limits[j],
                                           std::remainder(sol.q[j], 2 * M_PI) + 2 * M_PI * k));
        }
        if (ex > node.value) {
          node.value = ex;
          node.joint = j;
        }
      }
      node.q = sol.q;
      node.manip = manipulability(robot, sol.q);
      return node;
    }
    node.status = NodeStatus::kBranchLost;
    node.info = all.message;
    return node;
  }

  // Follows `branch` over samples a..b into out[0..b−a]; sample a continues from `ref` (or starts
  // fresh when a == 0). With early_exit, stops at the first bad sample and returns its index.
  // Returns −1 when every sample is ok.
  long track(const std::vector<Dev>& dev, double spin0, int branch, Vector6 ref, std::size_t a,
             std::size_t b, std::vector<Node>& out, bool early_exit) const {
    out.resize(b - a + 1);
    long first_bad = -1;
    for (std::size_t i = a; i <= b; ++i) {
      Node node = solve(i, dev[i], spin0, branch, ref, i == 0);
      if (node.has_q && (node.status == NodeStatus::kOk || node.status == NodeStatus::kLowManip ||
                         node.status == NodeStatus::kJump || node.status == NodeStatus::kCollision))
        ref = node.q;
      const bool bad = node.status != NodeStatus::kOk;
      out[i - a] = std::move(node);
      if (bad && first_bad < 0) {
        first_bad = static_cast<long>(i);
        if (early_exit) break;
      }
    }
    return first_bad;
  }
};

// One seed: an IK solution of the first pose (its branch) under one base spin.
struct Seed {
  int branch = 0;
  double spin0 = 0;
  Vector6 q0 = Vector6::Zero();
  Dev base;  // lean of the whole path (when the nominal first pose has no allowed solution)
};

// What tracking one seed produced.
struct SeedOutcome {
  bool complete = false;
  std::vector<Node> nodes;
  std::vector<Dev> dev;
  std::vector<ReorientedRange> ranges;
  // Failure (complete == false).
  std::size_t fail_sample = 0;
  Node fail_node;
  std::size_t range_first = 0;  // the unfixable range's first bad sample
  // Score (complete == true).
  double min_manip = 0, margin = 0;
};

// Re-orientation candidates in the order tried: rotations about the tool axis (free for an
// axisymmetric burr), then growing leans of the axis in eight directions of (lead, tilt).
struct Candidate {
  Dev d;
  int level = 0;  // 0: spin; k ≥ 1: lean magnitude step k
};

std::vector<Candidate> candidates(const GrindParams& P) {
  std::vector<Candidate> c;
  for (int k = 1; k <= 6; ++k) {
    c.push_back({{0, 0, k * M_PI / 6}, 0});
    if (k < 6) c.push_back({{0, 0, -k * M_PI / 6}, 0});
  }
  if (P.max_extra_tilt > 0) {
    for (int k = 1; k <= P.reorient_steps; ++k) {
      const double m = P.max_extra_tilt * k / P.reorient_steps;
      // (lead, tilt) directions: pure lead first (keeps the cutter parallel to the wall), then
      // pure tilt, then the diagonals.
      const double h = std::sqrt(0.5);
      const double dirs[8][2] = {{1, 0}, {-1, 0}, {0, 1},   {0, -1},
                                 {h, h}, {-h, h}, {-h, -h}, {h, -h}};
      for (const auto& d : dirs) c.push_back({{m * d[0], m * d[1], 0}, k});
    }
    // Leads alone beyond that, in the same steps, up to max_extra_lead.
    const double step = P.max_extra_tilt / P.reorient_steps;
    for (int k = P.reorient_steps + 1; k * step <= P.max_extra_lead + 1e-12; ++k) {
      c.push_back({{k * step, 0, 0}, k});
      c.push_back({{-k * step, 0, 0}, k});
    }
  }
  return c;
}

// Whether a sample's total re-orientation stays within the allowances: its lead within the
// sample's cap (Geo::lead_cap), its tilt within max_extra_tilt. (Fixes of neighbouring ranges
// add up where their fades overlap.)
bool lean_allowed(const GrindParams& P, const Geo& g, const Dev& d) {
  return std::abs(d.lead) <= g.lead_cap + 1e-12 && std::abs(d.tilt) <= P.max_extra_tilt + 1e-12;
}

// A re-orientation tried on one bad range: the candidate faded in over `blend` before the range
// and out after it (weights w over the window wa..wb).
struct Fix {
  bool ok = false;
  Dev d;
  int level = 0;
  double blend = 0, min_manip = 0;
  std::size_t wa = 0, wb = 0;
  std::vector<double> w;
  std::vector<Node> nodes;  // the window's IK nodes under the fix
};

// Tries `cand` on the bad range a..b of `out`, with the fade lengthened (×2, ×4) when the wrist
// cannot follow it within max_joint_jump per sample (a jump inside the fade).
Fix try_fix(const Context& C, const Seed& seed, const SeedOutcome& out, std::size_t a,
            std::size_t b, const Candidate& cand) {
  const std::size_t N = C.geo.size();
  Fix fix;
  fix.d = cand.d;
  fix.level = cand.level;
  std::vector<Dev> trial = out.dev;
  for (double mult : {1.0, 2.0, 4.0}) {
    const double bl = C.P.blend_length * mult;
    std::size_t wa = a, wb = b;
    while (wa > 0 && C.s_nom[wa - 1] > C.s_nom[a] - bl) --wa;
    while (wb + 1 < N && C.s_nom[wb + 1] < C.s_nom[b] + bl) ++wb;
    fix.w.assign(wb - wa + 1, 1.0);
    for (std::size_t i = wa; i <= wb; ++i) {
      double& wi = fix.w[i - wa];
      if (i < a) wi = smoothstep((C.s_nom[i] - (C.s_nom[a] - bl)) / bl);
      if (i > b) wi = smoothstep(((C.s_nom[b] + bl) - C.s_nom[i]) / bl);
      trial[i].lead = out.dev[i].lead + wi * cand.d.lead;
      trial[i].tilt = out.dev[i].tilt + wi * cand.d.tilt;
      trial[i].spin = out.dev[i].spin + wi * cand.d.spin;
      // Overlapping fixes add up: keep the total lean within the allowance.
      if (!lean_allowed(C.P, C.geo[i], trial[i])) return fix;
    }
    const Vector6 ref = wa == 0 ? seed.q0 : out.nodes[wa - 1].q;
    const long bad = C.track(trial, seed.spin0, seed.branch, ref, wa, wb, fix.nodes, true);
    if (bad < 0) {
      fix.ok = true;
      fix.blend = bl;
      fix.wa = wa;
      fix.wb = wb;
      fix.min_manip = std::numeric_limits<double>::infinity();
      for (const Node& nd : fix.nodes) fix.min_manip = std::min(fix.min_manip, nd.manip);
      return fix;
    }
    const auto ib = static_cast<std::size_t>(bad);
    const bool jump_in_fade = fix.nodes[ib - wa].status == NodeStatus::kJump && (ib < a || ib > b);
    if (!jump_in_fade) break;
    for (std::size_t i = wa; i <= wb; ++i) trial[i] = out.dev[i];  // undo before widening
  }
  fix.ok = false;
  return fix;
}

// The re-orientation of the bad range a..b: the first spin about the tool axis that works;
// else a lead (the axis turned within the wall's plane keeps the burr's side flush with the
// wall), the smallest that works; else a lean with tilt, the smallest (shank away from the wall:
// the ball end cuts at the root, grind_tool_pose; toward it: the upper end's rim stands off
// the fin by up to 1 mm × sin tilt). Within a level, the best manipulability.
Fix best_fix(const Context& C, const Seed& seed, const SeedOutcome& out, std::size_t a,
             std::size_t b, const std::vector<Candidate>& cands) {
  Fix best;
  for (const bool with_tilt : {false, true}) {
    for (const Candidate& cand : cands) {
      if ((cand.d.tilt != 0) != with_tilt) continue;
      if (best.ok && cand.level != best.level) break;  // smallest working level only
      Fix fix = try_fix(C, seed, out, a, b, cand);
      if (fix.ok && (!best.ok || fix.min_manip > best.min_manip)) best = std::move(fix);
      if (best.ok && cand.level == 0) break;
    }
    if (best.ok) break;
  }
  return best;
}

// Tracks one seed over all samples, re-orienting bad ranges.
SeedOutcome track_seed(const Context& C, const Seed& seed, const std::vector<Candidate>& cands) {
  const std::size_t N = C.geo.size();
  const GrindParams& P = C.P;
  SeedOutcome out;
  out.dev.assign(N, seed.base);
  C.track(out.dev, seed.spin0, seed.branch, seed.q0, 0, N - 1, out.nodes, false);

  for (int round = 0; round < 3; ++round) {
    // Bad ranges, merged when their blend windows would overlap.
    std::vector<std::pair<std::size_t, std::size_t>> ranges;
    for (std::size_t i = 0; i < N; ++i) {
      if (out.nodes[i].status == NodeStatus::kOk) continue;
      if (!ranges.empty() && C.s_nom[i] - C.s_nom[ranges.back().second] < 2 * P.blend_length)
        ranges.back().second = i;
      else
        ranges.push_back({i, i});
    }
    if (ranges.empty()) {
      out.complete = true;
      break;
    }
    if (round == 2) ranges.resize(1);  // last round: only report
    for (const auto& [a, b] : ranges) {
      // The worst bad sample of the range (first of the most severe kind) for reports.
      std::size_t worst = a;
      double nominal_min = std::numeric_limits<double>::infinity();
      for (std::size_t i = a; i <= b; ++i) {
        const Node& nd = out.nodes[i];
        if (severity(nd.status) > severity(out.nodes[worst].status)) worst = i;
        nominal_min = std::min(nominal_min, nd.has_q ? nd.manip : 0.0);
      }
      const NodeStatus worst_status = out.nodes[worst].status;
      bool fixed = false;
      if (round < 2) {
        const Fix best = best_fix(C, seed, out, a, b, cands);
        if (best.ok) {
          for (std::size_t i = best.wa; i <= best.wb; ++i) {
            const double wi = best.w[i - best.wa];
            out.dev[i].lead += wi * best.d.lead;
            out.dev[i].tilt += wi * best.d.tilt;
            out.dev[i].spin += wi * best.d.spin;
            out.nodes[i] = best.nodes[i - best.wa];
          }
          ReorientedRange rr;
          rr.reason = reason_of(worst_status);
          rr.first_sample = a;
          rr.last_sample = b;
          rr.first_path_index = C.geo[a].path_index;
          rr.last_path_index = C.geo[b].path_index;
          rr.pass = C.geo[a].pass;
          rr.nominal_min_manipulability = nominal_min;
          rr.min_manipulability = best.min_manip;
          rr.extra_lead = best.d.lead;
          rr.extra_tilt = best.d.tilt;
          rr.extra_spin = best.d.spin;
          rr.blend_length = best.blend;
          out.ranges.push_back(rr);
          fixed = true;
        }
      }
      if (!fixed) {
        out.fail_sample = worst;
        out.fail_node = out.nodes[worst];
        out.range_first = a;
        return out;
      }
    }
    // Re-track everything with the re-orientations (the windows' ends must still join).
    C.track(out.dev, seed.spin0, seed.branch, seed.q0, 0, N - 1, out.nodes, false);
  }
  FT_ASSERT(out.complete);  // round 2 either finds nothing or returns a failure
  out.min_manip = std::numeric_limits<double>::infinity();
  out.margin = std::numeric_limits<double>::infinity();
  for (const Node& nd : out.nodes) {
    out.min_manip = std::min(out.min_manip, nd.manip);
    for (int j = 0; j < kNumJoints; ++j)
      out.margin = std::min(
          {out.margin, nd.q[j] - C.robot.limits[j].lower, C.robot.limits[j].upper - nd.q[j]});
  }
  return out;
}

void check_finite(const Vec3& v, const std::string& what) {
  if (!v.allFinite())
    throw ArgumentError(
        strf("%s: expected finite coordinates, got %s", what.c_str(), vec_text(v).c_str()));
}

void check_param(bool ok, const char* field, const char* expected, double got) {
  if (!ok) throw ArgumentError(strf("GrindParams.%s: expected %s, got %g", field, expected, got));
}

// One sample of the root curve in {C}: point, wall normal, tangent along the travel, the nearest
// input point, and the spline segment it lies on (between kept points seg and seg + 1).
struct PathSample {
  Vec3 p, n, t;
  int path_index = 0;
  std::size_t seg = 0;
};

// A sharp convex edge of the wall between two root points: where the root lines along the two
// faces meet, and the angle the wall normal turns there.
struct Corner {
  Vec3 edge;
  double turn = 0;  // [rad]
};

// Root points a, b (wall normals na, nb ⊥ f) on either side of a sharp convex edge. The root
// line on each face runs along n × f; both lie in the fin plane, so the edge E solves
//   na·E = na·a,  nb·E = nb·b,  f·E = f·a.
// Convex: each point lies behind the other's face (the material is inside the chord a–b, and
// an interpolating spline between them cuts into it). The edge must lie ahead of a and
// behind b, each within `reach`; the normals must turn 25–150° (a rounded edge turns in
// smaller steps, which the spline follows).
std::optional<Corner> convex_corner(const Vec3& a, const Vec3& na, const Vec3& b, const Vec3& nb,
                                    const Vec3& f, double reach) {
  const double turn = std::acos(std::clamp(na.dot(nb), -1.0, 1.0));
  if (turn < 25 * M_PI / 180 || turn > 150 * M_PI / 180) return std::nullopt;
  if (na.dot(b - a) >= 0 || nb.dot(a - b) >= 0) return std::nullopt;  // concave or flat
  Mat3 A;
  A.row(0) = na.transpose();
  A.row(1) = nb.transpose();
  A.row(2) = f.transpose();
  const Vec3 E = A.fullPivLu().solve(Vec3(na.dot(a), nb.dot(b), f.dot(a)));
  Vec3 ta = na.cross(f), tb = nb.cross(f);
  if (ta.dot(b - a) < 0) ta = -ta;
  if (tb.dot(b - a) < 0) tb = -tb;
  const double sa = ta.dot(E - a), sb = tb.dot(b - E);
  constexpr double kSlack = 1e-5;
  if (!E.allFinite() || sa < -kSlack || sb < -kSlack || sa > reach || sb > reach) return std::nullopt;
  return Corner{E, turn};
}

// Sharp convex edges: the quintic spline through root points on two faces cuts the edge on a
// chord (0.3–0.5 mm inside the steel at a 90° edge with 1 mm point spacing) and rings for a few
// millimetres beside it, and the flush burr would follow it into the wall. Near each edge the
// samples are replaced by the root lines themselves: straight along face a up to the edge,
// then a roll round it (the root point stays on the edge while the wall normal turns from na
// to nb about f, so the burr's axis runs on an arc of radius r + e round the edge and grinds
// the flash standing off it), then straight along face b. Within `kStraight` of the edge,
// as long as the samples keep their face's normal. (Closed paths: not across their seam.)
void roll_round_convex_corners(std::vector<PathSample>& ps, const std::vector<Vec3>& pts,
                               const std::vector<Vec3>& kept_wall, const Vec3& f, double spacing,
                               double radius) {
  constexpr double kReach = 0.003, kStraight = 0.006;
  const double same_face = std::cos(10 * M_PI / 180);
  std::vector<PathSample> out;
  std::size_t next = 0;  // first sample of ps not yet copied to out
  for (std::size_t j = 0; j + 1 < pts.size(); ++j) {
    const Vec3 &na = kept_wall[j], &nb = kept_wall[j + 1];
    const auto c = convex_corner(pts[j], na, pts[j + 1], nb, f, kReach);
    if (!c) continue;
    // The samples on segment j, widened along each face.
    std::size_t k0 = ps.size(), k1 = 0;
    for (std::size_t k = next; k < ps.size(); ++k)
      if (ps[k].seg == j) {
        k0 = std::min(k0, k);
        k1 = std::max(k1, k);
      }
    if (k0 >= ps.size() || k0 < std::max<std::size_t>(next, 1) || k1 + 2 > ps.size()) continue;
    while (k0 > std::max<std::size_t>(next, 1) && (ps[k0 - 1].p - c->edge).norm() <= kStraight &&
           ps[k0 - 1].n.dot(na) >= same_face)
      --k0;
    while (k1 + 2 < ps.size() && (ps[k1 + 1].p - c->edge).norm() <= kStraight &&
           ps[k1 + 1].n.dot(nb) >= same_face)
      ++k1;
    Vec3 ta = na.cross(f), tb = nb.cross(f);
    if (ta.dot(pts[j + 1] - pts[j]) < 0) ta = -ta;
    if (tb.dot(pts[j + 1] - pts[j]) < 0) tb = -tb;
    // Nearest input point of a new sample: that of the nearest replaced sample.
    const auto index_near = [&](const Vec3& q) {
      std::size_t best = k0;
      for (std::size_t k = k0; k <= k1; ++k)
        if ((ps[k].p - q).norm() < (ps[best].p - q).norm()) best = k;
      return ps[best].path_index;
    };
    out.insert(out.end(), ps.begin() + static_cast<std::ptrdiff_t>(next),
               ps.begin() + static_cast<std::ptrdiff_t>(k0));
    const Vec3& E = c->edge;
    const double La = std::max(0.0, ta.dot(E - ps[k0].p)), Lb = std::max(0.0, tb.dot(ps[k1].p - E));
    const auto ma = static_cast<std::size_t>(std::ceil(La / spacing - 1e-9));
    for (std::size_t i = 0; i < ma; ++i) {
      const Vec3 q = E - ta * La * (1 - static_cast<double>(i) / static_cast<double>(ma));
      out.push_back({q, na, ta, index_near(q), j});
    }
    // The roll: the burr's axis moves r·turn along its arc; steps of about `spacing`.
    const Vec3 axis = na.cross(nb).normalized();
    const auto mr = static_cast<std::size_t>(std::max(2.0, std::ceil(radius * c->turn / spacing)));
    const int at_edge = index_near(E);
    for (std::size_t i = 0; i <= mr; ++i) {
      const double th = c->turn * static_cast<double>(i) / static_cast<double>(mr);
      const Vec3 n = Eigen::AngleAxisd(th, axis) * na;
      Vec3 t = n.cross(f).normalized();
      if (t.dot(ta + tb) < 0) t = -t;
      out.push_back({E, n, t, at_edge, j});
    }
    const auto mb = static_cast<std::size_t>(std::ceil(Lb / spacing - 1e-9));
    for (std::size_t i = 1; i <= mb; ++i) {
      const Vec3 q = E + tb * Lb * static_cast<double>(i) / static_cast<double>(mb);
      out.push_back({q, nb, tb, index_near(q), j + 1});
    }
    next = k1 + 1;
  }
  if (next == 0) return;  // no sharp convex edge
  out.insert(out.end(), ps.begin() + static_cast<std::ptrdiff_t>(next), ps.end());
  ps = std::move(out);
}

// A curved wall in a CAD mesh is flat facets, so the root points along it carry piecewise-
// constant normals that turn by the facet angle at each facet edge (round_flange's bore: about
// 0.1 rad every 2 mm). The burr's axis stands r + e (6–7 mm) off the wall along that normal:
// where the normal turns by θ between two samples 0.5 mm apart on a concave wall, the axis steps
// back by (r + e)·θ ≈ 0.6 mm and cancels the root's advance. Two tool poses then stand at almost
// one point with the wrist turned by 0.01 rad between them, and the joint-space timing spline
// through them rings by centimetres (round_flange 504: 46 mm off the samples' chord, a path
// refused; housing 7330 in a bolt hole). The wall the facets approximate turns smoothly, and so
// does this normal: each run of points on one facet (one normal) keeps it at the run's middle,
// and across each concave facet edge the normal turns linearly with arc length from one run's
// middle to the next (at most kBlend either side of the edge). An edge turning by more than
// 45° is a real inside corner and stays sharp; so do convex edges (roll_round_convex_corners
// rolls round those from 25°), where the axis steps forward, never back. The burr leaning into its own facet
// by the turn is kept out by clear_concave_facets.
std::vector<Vec3> smooth_facet_normals(const std::vector<Vec3>& points,
                                       const std::vector<Vec3>& wall, const Vec3& f, bool closed) {
  constexpr double kBlend = 3e-3;                        // [m]
  const double same = std::cos(0.5 * M_PI / 180);         // one facet: normals within 0.5°
  const double max_turn = std::cos(45 * M_PI / 180);      // a real inside corner beyond
  const std::size_t n = points.size();
  std::vector<Vec3> out = wall;
  if (n < 3) return out;
  // Walk from a facet edge (closed: so that no run wraps round the seam).
  std::size_t start = 0;
  if (closed) {
    start = n;
    for (std::size_t i = 0; i < n && start == n; ++i)
      if (wall[i].dot(wall[(i + n - 1) % n]) < same) start = i;
    if (start == n) return out;  // one facet all round
  }
  const std::size_t m = closed ? n + 1 : n;  // closed: the start point again, one lap on
  std::vector<std::size_t> idx(m);
  std::vector<double> s(m, 0.0);
  for (std::size_t k = 0; k < m; ++k) {
    idx[k] = (start + k) % n;
    if (k > 0) s[k] = s[k - 1] + (points[idx[k]] - points[idx[k - 1]]).norm();
  }
  struct Run { std::size_t k0, k1; };  // [k0, k1] along the walk
  std::vector<Run> runs;
  for (std::size_t k = 0; k < n; ++k)
    if (runs.empty() || wall[idx[k]].dot(wall[idx[runs.back().k0]]) < same)
      runs.push_back({k, k});
    else
      runs.back().k1 = k;
  if (closed) runs.push_back({n, n});  // the first run again, a lap on (its start only)
  const auto mid = [&](const Run& r) { return 0.5 * (s[r.k0] + s[r.k1]); };
  for (std::size_t r = 0; r + 1 < runs.size(); ++r) {
    const Run &A = runs[r], &B = runs[r + 1];
    const Vec3 &na = wall[idx[A.k0]], &nb = wall[idx[B.k0]];
    // Only concave edges: on a convex one the axis steps forward, never back.
    if (na.dot(nb) < max_turn || na.dot(points[idx[B.k0]] - points[idx[A.k1]]) <= 0) continue;
    const double edge = 0.5 * (s[A.k1] + s[B.k0]);
    // Closed: the last boundary's far side is the first run, whose middle lies a lap on.
    const double mid_b = closed && r + 2 == runs.size() ? mid(runs.front()) + s[n] : mid(B);
    const double a = std::min(edge - mid(A), kBlend), b = std::min(mid_b - edge, kBlend);
    if (!(a + b > 1e-9)) continue;
    const auto blend = [&](std::size_t k, double sk) {
      const double w = std::clamp((sk - (edge - a)) / (a + b), 0.0, 1.0);
      Vec3 v = (1 - w) * na + w * nb;
      v -= v.dot(f) * f;
      if (v.norm() > 1e-9) out[idx[k]] = v.normalized();
    };
    for (std::size_t k = A.k0; k <= A.k1; ++k)
      if (s[k] > edge - a) blend(k, s[k]);
    if (closed && r + 2 == runs.size()) {
      for (std::size_t k = runs.front().k0; k <= runs.front().k1; ++k)
        if (s[k] + s[n] < edge + b) blend(k, s[k] + s[n]);
    } else {
      for (std::size_t k = B.k0; k <= B.k1; ++k)
        if (s[k] < edge + b) blend(k, s[k]);
    }
  }
  return out;
}

// Where the wall is concave round the burr (a hole, an inside corner) and made of flat pieces
// (the CAD's facets: a hole is a polygon), a burr of radius r laid against one piece at the
// root point crosses the next piece's plane: at a corner turning by θ, by r·(1 − cos θ) ≈ r·θ²/2
// with that piece's normal, r·θ²/8 with the normals blended (a 6 mm burr in an 8 mm hole drawn
// to 0.05 mm chords: θ ≈ 0.22 rad, 0.04–0.15 mm into the wall: the hole-ring gouges). Each
// sample moves off the wall along its normal until the burr's axis stands at least r from the
// plane of every root point on the concave side of it (p_k above that plane) within 2r, in the
// section across the fin; the corner's point then stays uncut by about r·θ²/8 (flash, not steel).
// The shift changes from sample to sample: with every facet (a hole's facets are ~1 mm long) and
// with the detected root points' scatter (seed 5002: up to 0.33 mm in a hole whose mean is
// 0.06 mm). A path that waves by 0.1 mm once per millimetre is one the servos lag behind (housing
// 7111: tracking error 0.16 mm where the deepest gouge was cut, 0.106 mm). The small steps are
// eased: the shift's part up to kEased gets its upper envelope with a slope of at most kSlope
// along the path, and a sample's shift is the larger of that and its own. So no sample gets less
// clearance than it asks for, and none more than kEased beyond it (flash left by the easing is
// bounded by that). Larger shifts are geometry (an inside corner of 60° asks for up to r, along a
// ramp the burr can follow) and stay as they are: eased whole, such a corner held the burr off
// the wall for 10 mm per millimetre of shift (user_mesh 8509: 4.35 mm of flash left standing).
// Measured with the slope 0.02 / 0.1 and kEased unbounded, then 0.1 / 0.1 mm: housing 7111
// gouge 0.062 / 0.070, then 0.078 mm; default 5002 residual 0.20 / 0.12, then 0.05 mm.
void clear_concave_facets(std::vector<PathSample>& ps, const std::vector<Vec3>& points,
                          const std::vector<Vec3>& wall, const Vec3& f, double r, bool closed) {
  const auto across = [&](const Vec3& v) { return Vec3(v - v.dot(f) * f); };
  constexpr double kOnPlane = 2e-5;  // [m]
  std::vector<double> shift(ps.size(), 0.0);
  for (std::size_t k = 0; k < ps.size(); ++k) {
    const PathSample& q = ps[k];
    const Vec3 c = across(q.p + r * q.n);
    for (std::size_t j = 0; j < points.size(); ++j) {
      const Vec3 pj = across(points[j]);
      if ((pj - c).norm() > 2 * r) continue;
      const Vec3& nj = wall[j];
      const double cos_kj = q.n.dot(nj);
      // (Within kOnPlane of the plane: on it; the spline through the points strays by µm.)
      const double above = across(q.p - points[j]).dot(nj);
      if (cos_kj < 0.3 || above < -kOnPlane) continue;  // convex to q
      // A point on q's own facet counts where the burr dips below that facet's plane on the
      // point's side: q's normal turned across a concave facet edge (smooth_facet_normals) by
      // δ leans the burr into its own facet by r·(1 − cos δ), behind q. (Not a roll round a
      // convex edge: there the burr dips past the edge, where the facet has ended.)
      if (above <= kOnPlane && across(q.n - nj).dot(pj - across(q.p)) <= 0) continue;
      const double deficit = r - (c - pj).dot(nj);
      if (deficit > 0) shift[k] = std::max(shift[k], deficit / cos_kj);
    }
  }
  constexpr double kSlope = 0.1;   // [m/m] of path
  constexpr double kEased = 1e-4;  // [m] shifts up to this are eased; larger ones are geometry
  std::vector<Vec3> along(ps.size());
  std::vector<double> eased(shift.size());
  for (std::size_t k = 0; k < ps.size(); ++k) {
    along[k] = ps[k].p;
    eased[k] = std::min(shift[k], kEased);
  }
  upper_envelope_along(eased, along, kSlope, closed);
  for (std::size_t k = 0; k < ps.size(); ++k)
    ps[k].p += std::max(eased[k], shift[k]) * ps[k].n;
}

// Extra axis offsets e of the passes for a fin `height` high [m]: roughing passes of equal
// radial depths (each ≤ max_depth_of_cut) down to finish_depth above the wall, then the
// finishing pass at the stock allowance. Unknown height (0): the finishing pass alone.
// @throws ArgumentError when that takes more than 100 passes.
std::vector<double> pass_offsets(const GrindParams& P, double height) {
  std::vector<double> e;
  const double rough = height - P.finish_depth;
  if (rough > 1e-9) {
    const double passes = std::ceil(rough / P.max_depth_of_cut - 1e-9);
    if (passes + 1 > 100)
      throw ArgumentError(strf("GrindPath.fin_height: expected at most 100 passes of "
                               "max_depth_of_cut %g m, got a fin %g m high (over 100 passes)",
                               P.max_depth_of_cut, height));
    const auto n = static_cast<int>(passes);
    for (int j = 0; j < n; ++j)
      e.push_back(P.stock_allowance + P.finish_depth + rough * (n - 1 - j) / n);
  }
  e.push_back(P.stock_allowance);
  return e;
}

// The robot with every joint's position range shrunk by `margin` at both ends [rad].
RobotModel with_limit_margin(const RobotModel& robot, double margin) {
  RobotModel r = robot;
  for (auto& L : r.limits) {
    L.lower += margin;
    L.upper -= margin;
  }
  return r;
}

// The largest extra lead at path sample k [rad]. A lead swings the burr's ends along the path
// by a·sin(lead) (a: the farther end's axial distance from the root); where the wall is concave
// along the path (curving toward its normal, as in a hole) it comes closer there by
// (a sin lead)² κ / 2, held to 10 µm. Never below max_extra_tilt (the lean every path had before
// leads alone were allowed further).
double lead_cap_at(const GrindParams& P, const std::vector<PathSample>& ps, std::size_t k, double a,
                   bool closed) {
  const std::size_t n = ps.size();
  double cap = std::max(P.max_extra_lead, P.max_extra_tilt);
  if (n < 3 || a <= 0) return cap;
  const std::size_t i0 = k > 0 ? k - 1 : (closed ? n - 1 : 0);
  const std::size_t i1 = k + 1 < n ? k + 1 : (closed ? 0 : n - 1);
  const double ds = (ps[i1].p - ps[i0].p).norm();
  if (i0 == i1 || ds < 1e-9) return cap;
  const double kappa_n = (ps[i1].t - ps[i0].t).dot(ps[k].n) / ds;  // > 0: concave
  constexpr double kTol = 10e-6;
  if (kappa_n > 1e-9) cap = std::min(cap, std::asin(std::min(1.0, std::sqrt(2 * kTol / kappa_n) / a)));
  return std::max(cap, P.max_extra_tilt);
}

// The largest share of its torque budget (factor × limit, less what gravity takes) a timed
// motion's dynamic torque asks of any joint: k² for the uniform slow-down by k that brings every
// joint within budget. Slowing down by k scales q̇ by 1/k and q̈ by 1/k²; with gravity g(q)
// unchanged the torque becomes g + (τ − g)/k² (the velocity-product and damping terms fall at
// least as fast), so a joint with |τ| over its budget L needs k² ≥ |τ − g| / (L − |g|). Steps
// at low speed and acceleration (the cut at the feed) are not evaluated: their torque is
// gravity's. Returns 1 when every joint is within budget.
double torque_slowdown_sq(const RobotModel& robot, const JointTrajectory& T, const TorqueFn& torque,
                          double factor) {
  double k2 = 1;
  const Vector6 zero = Vector6::Zero();
  for (std::size_t n = 0; n < T.q.size(); ++n) {
    bool moving = false;
    for (int j = 0; j < kNumJoints && !moving; ++j) {
      const JointLimits& L = robot.limits[static_cast<std::size_t>(j)];
      moving = std::abs(T.ddq[n][j]) > 0.05 * L.acceleration || std::abs(T.dq[n][j]) > 0.1 * L.velocity;
    }
    if (!moving) continue;
    const Vector6 tau = torque(T.q[n], T.dq[n], T.ddq[n]);
    std::optional<Vector6> g;  // gravity's share, evaluated once a joint is over budget
    for (int j = 0; j < kNumJoints; ++j) {
      const double budget = factor * robot.limits[static_cast<std::size_t>(j)].torque;
      if (!(budget > 0) || std::abs(tau[j]) <= budget) continue;
      if (!g) g = torque(T.q[n], zero, zero);
      // Gravity alone near the budget: slow down as if a tenth of it were left.
      const double room = std::max(budget - std::abs((*g)[j]), 0.1 * budget);
      k2 = std::max(k2, std::abs(tau[j] - (*g)[j]) / room);
    }
  }
  return k2;
}

// time_parametrize, slowed down (velocity limits / k, acceleration limits / k²) until the motion
// asks no joint more than P.torque_factor of its torque limit; a few rounds, as the path's own
// bounds (feed, path acceleration) make the slow-down less than uniform.
TimingResult time_within_torque(const RobotModel& robot, const std::vector<double>& s,
                                const std::vector<Vector6>& q, TimingParams tp, const GrindParams& P) {
  TimingResult tr = time_parametrize(robot, s, q, tp);
  if (!P.torque || !tr.ok()) return tr;
  Vector6 v, a;
  for (int j = 0; j < kNumJoints; ++j) {
    v[j] = tp.velocity_limits ? (*tp.velocity_limits)[j] : robot.limits[static_cast<std::size_t>(j)].velocity;
    a[j] = tp.acceleration_limits ? (*tp.acceleration_limits)[j]
                                  : robot.limits[static_cast<std::size_t>(j)].acceleration;
  }
  for (int round = 0; round < 4; ++round) {
    const double k2 = torque_slowdown_sq(robot, tr.trajectory, P.torque, P.torque_factor);
    if (k2 <= 1) break;
    const double k2_step = 1.05 * k2;  // a little beyond: the slow-down is not quite uniform
    v /= std::sqrt(k2_step);
    a /= k2_step;
    tp.velocity_limits = v;
    tp.acceleration_limits = a;
    TimingResult slower = time_parametrize(robot, s, q, tp);
    if (!slower.ok()) break;
    tr = std::move(slower);
    // The ratios against the robot's own limits, not the lowered ones timed with.
    for (int j = 0; j < kNumJoints; ++j) {
      const JointLimits& L = robot.limits[static_cast<std::size_t>(j)];
      tr.max_velocity_ratio[j] *= v[j] / L.velocity;
      tr.max_accel_ratio[j] *= a[j] / L.acceleration;
    }
    tr.max_joint_velocity_ratio = tr.max_velocity_ratio.maxCoeff();
    tr.max_joint_accel_ratio = tr.max_accel_ratio.maxCoeff();
  }
  return tr;
}

}  // namespace

namespace {

// How far the commanded tool path (tcp_B, every period) comes from the straight line between
// the two samples it lies between (by path position s), at its farthest: where and when.
struct Swing {
  double distance = 0;  // [m]
  std::size_t sample = 0;
  double t = 0;  // [s]
};
Swing largest_swing(const GrindResult& r) {
  Swing w;
  if (r.samples.size() < 2) return w;
  std::size_t i = 0;
  for (std::size_t k = 0; k < r.tcp_B.size(); ++k) {
    const double sk = r.trajectory.s[k];
    while (i + 2 < r.samples.size() && r.samples[i + 1].s <= sk) ++i;
    const GrindSample& a = r.samples[i];
    const GrindSample& b = r.samples[i + 1];
    const double u = b.s > a.s ? std::clamp((sk - a.s) / (b.s - a.s), 0.0, 1.0) : 0.0;
    const Vec3 line = (1 - u) * a.X_BT.translation() + u * b.X_BT.translation();
    const double d = (r.tcp_B[k].translation() - line).norm();
    if (d > w.distance) w = {d, i, r.trajectory.t[k]};
  }
  return w;
}

}  // namespace

Pose grind_tool_pose(const Vec3& p, const Vec3& n, const Vec3& t, const Vec3& f, const Vec3& x_ref,
                     double extra_offset, double lead, double tilt, double spin, double radius,
                     double length, double tip_depth, double* axis_offset) {
  // Shank direction (tip → flange) and the tool axis z_T.
  const Vec3 w = std::cos(tilt) * (std::cos(lead) * f + std::sin(lead) * t) + std::sin(tilt) * n;
  const Vec3 z = -w.normalized();
  // Smallest axis offset keeping the whole burr out of the wall plane. The burr is ball-ended
  // (every cell burr is: ToolEnd::kBall): a cylinder from one radius up its axis, a hemisphere
  // of its radius below.
  const double c = z.dot(n);
  constexpr double kEndMargin = 1e-3, kStandoff = 0.05e-3;
  double off = radius;
  if (c > 1e-12) {
    // Shank toward the wall: the burr touches the wall plane only at its upper end's rim and
    // stands off it at the fin by that end's axial distance from the fin × c: with the fin
    // halfway along a 20 mm burr, 0.46 mm at 0.046 rad and 1.3 mm at 0.13 rad (cover 9148,
    // 9103: that much flash left along the stretch). The burr slides down its axis until its
    // upper end comes within kEndMargin of the fin (the fin's half thickness and some), the
    // stand-off then kEndMargin·c; on the way there no more than kStandoff (continuous in c).
    tip_depth = std::max(tip_depth, std::min(length - kEndMargin, length - kStandoff / c));
    off = radius * std::sqrt(std::max(0.0, 1 - c * c)) + (length - tip_depth) * c;
  } else if (c < -1e-12) {
    // Shank away from the wall: the ball touches the wall plane (its centre one radius off it)
    // and the straight side above the ball stands off it by r(1 - cos) + s·|c| at axial height s
    // over the ball's centre. The burr slides up its axis until the fin is within kStandoff/|c|
    // of the ball's centre (continuous in c), at the most until the ball's centre is on the fin
    // plane: there the ball touches the wall at the root and, whatever the lean, the flash left
    // is what a sphere leaves on a fin of thickness t, t²/(8r) (0.05 mm for a 1.5 mm fin on a
    // 12 mm burr). (It was the flat end's rim that was put on the wall: on a ball-ended burr
    // that stood the ball 3-4 mm off the root at 0.26 rad: user_mesh 701-710, the leans beside
    // the bracket's upright leg.)
    if (tip_depth > radius) tip_depth = std::max(radius, std::min(tip_depth, radius + kStandoff / -c));
    off = radius + std::max(0.0, tip_depth - radius) * -c;
  }
  off += extra_offset;
  if (axis_offset) *axis_offset = off;
  Vec3 x = x_ref - x_ref.dot(z) * z;
  if (x.norm() < 1e-9) x = z.unitOrthogonal();
  x.normalize();
  x = std::cos(spin) * x + std::sin(spin) * z.cross(x);
  Pose X = Pose::Identity();
  X.linear().col(0) = x;
  X.linear().col(1) = z.cross(x);
  X.linear().col(2) = z;
  X.translation() = p + off * n + tip_depth * z;
  return X;
}

void upper_envelope_along(std::vector<double>& v, const std::vector<Vec3>& points, double slope,
                          bool closed) {
  FT_ASSERT(points.size() == v.size());
  const std::size_t n = v.size();
  if (n < 2) return;
  const auto gap = [&](std::size_t a, std::size_t b) { return (points[a] - points[b]).norm(); };
  // A sweep each way carries every value on down its slope; round a closed path twice, so a
  // value reaches every point both ways round.
  const std::size_t rounds = closed ? 2 : 1;
  for (std::size_t i = 1; i < rounds * n; ++i) {  // forward
    const std::size_t k = i % n, prev = (i - 1) % n;
    v[k] = std::max(v[k], v[prev] - slope * gap(k, prev));
  }
  for (std::size_t i = rounds * n - 1; i-- > 0;) {  // backward
    const std::size_t k = i % n, next = (i + 1) % n;
    v[k] = std::max(v[k], v[next] - slope * gap(k, next));
  }
}

GrindResult plan_grind(const RobotModel& robot_in, const Pose& X_BC, const GrindPath& path,
                       const GrindParams& P) {
  check_param(P.limit_margin >= 0 && P.limit_margin <= 0.2, "limit_margin", "0..0.2 [rad]", P.limit_margin);
  // Plans stay `limit_margin` inside every position range: a servo tracking a reference at the
  // very limit overshoots it, and the executor clamps its reference inside the range.
  const RobotModel robot = with_limit_margin(robot_in, P.limit_margin);
  // ---- Input checks (bad input throws).
  check_param(P.spacing > 0 && std::isfinite(P.spacing), "spacing", "> 0 [m]", P.spacing);
  check_param(P.feed > 0 && std::isfinite(P.feed), "feed", "> 0 [m/s]", P.feed);
  check_param(P.approach_feed > 0 && std::isfinite(P.approach_feed), "approach_feed", "> 0 [m/s]",
              P.approach_feed);
  check_param(P.plunge_feed > 0 && std::isfinite(P.plunge_feed), "plunge_feed", "> 0 [m/s]",
              P.plunge_feed);
  check_param(P.approach_distance >= 0 && std::isfinite(P.approach_distance), "approach_distance",
              ">= 0 [m]", P.approach_distance);
  check_param(std::abs(P.lead) < M_PI / 2, "lead", "|lead| < pi/2 [rad]", P.lead);
  check_param(std::abs(P.tilt) < M_PI / 2, "tilt", "|tilt| < pi/2 [rad]", P.tilt);
  check_param(P.max_depth_of_cut > 0 && std::isfinite(P.max_depth_of_cut), "max_depth_of_cut",
              "> 0 [m]", P.max_depth_of_cut);
  check_param(P.retare_length >= 0 && std::isfinite(P.retare_length), "retare_length", ">= 0 [m]",
              P.retare_length);
  check_param(P.retare_ramp_time >= 0 && P.retare_ramp_time <= 10, "retare_ramp_time", "0..10 [s]",
              P.retare_ramp_time);
  check_param(P.finish_depth >= 0 && P.finish_depth <= 0.01, "finish_depth", "0..0.01 [m]",
              P.finish_depth);
  check_param(P.roughing_feed > 0 && std::isfinite(P.roughing_feed), "roughing_feed", "> 0 [m/s]",
              P.roughing_feed);
  check_param(P.lead_clearance >= 0 && P.lead_clearance <= 0.01, "lead_clearance", "0..0.01 [m]",
              P.lead_clearance);
  check_param(P.overrun >= 0 && P.overrun <= 0.05, "overrun", "0..0.05 [m]", P.overrun);
  check_param(P.stock_allowance >= 0 && P.stock_allowance <= 0.005, "stock_allowance",
              "0..0.005 [m]", P.stock_allowance);
  check_param(P.manipulability_threshold >= 0, "manipulability_threshold", ">= 0",
              P.manipulability_threshold);
  check_param(P.max_extra_tilt >= 0 && P.max_extra_tilt <= M_PI / 4, "max_extra_tilt",
              "0..pi/4 [rad]", P.max_extra_tilt);
  check_param(P.max_extra_lead >= 0 && P.max_extra_lead <= M_PI / 2, "max_extra_lead",
              "0..pi/2 [rad]", P.max_extra_lead);
  check_param(P.reorient_steps >= 1, "reorient_steps", ">= 1", P.reorient_steps);
  check_param(P.blend_length > 0, "blend_length", "> 0 [m]", P.blend_length);
  check_param(P.spin_candidates >= 1 && P.spin_candidates <= 64, "spin_candidates", "1..64",
              P.spin_candidates);
  check_param(P.max_joint_jump > 0, "max_joint_jump", "> 0 [rad]", P.max_joint_jump);
  check_param((P.branch_mask & 0xFFu) != 0, "branch_mask", "at least one of bits 0..7",
              P.branch_mask);
  if (!ik_supported(robot))
    throw ArgumentError("robot '" + robot.name +
                        "': expected a D-H table of a type the analytic IK handles (spherical wrist or UR-type offset wrist)");
  const double radius = robot.tool.radius, length = robot.tool.length;
  if (!(radius > 0) || !(length > 0))
    throw ArgumentError(
        strf("robot tool: expected radius > 0 and length > 0 [m], got %g and %g", radius, length));
  const double tip_depth = P.tip_depth.value_or(length / 2);
  check_param(tip_depth >= 0 && tip_depth <= length, "tip_depth", "0..tool length [m]", tip_depth);
  const std::size_t N0 = path.points_C.size();
  if (path.normals_C.size() != N0)
    throw ArgumentError(strf("GrindPath.normals_C: expected %zu normals (one per point), got %zu",
                             N0, path.normals_C.size()));
  check_finite(path.fin_normal_C, "GrindPath.fin_normal_C");
  if (!(path.fin_normal_C.norm() > 1e-12))
    throw ArgumentError("GrindPath.fin_normal_C: expected a non-zero vector, got (0, 0, 0)");
  if (!(path.fin_height >= 0) || !std::isfinite(path.fin_height))
    throw ArgumentError(strf("GrindPath.fin_height: expected >= 0 [m], got %g", path.fin_height));
  const Vec3 f = path.fin_normal_C.normalized();
  std::vector<Vec3> wall(N0);
  std::vector<double> slope(N0, 0.0);  // [rad] each root point's wall slope (Geo::slope)
  for (std::size_t i = 0; i < N0; ++i) {
    check_finite(path.points_C[i], strf("GrindPath.points_C[%zu]", i));
    check_finite(path.normals_C[i], strf("GrindPath.normals_C[%zu]", i));
    const Vec3& n = path.normals_C[i];
    const Vec3 np = n - n.dot(f) * f;
    if (!(n.norm() > 1e-12) || np.norm() < 0.1 * n.norm())
      throw ArgumentError(
          strf("GrindPath.normals_C[%zu]: expected a wall normal at least 5.7 deg "
               "away from the fin normal, got %s",
               i, vec_text(n).c_str()));
    wall[i] = np.normalized();
    // A wall sloping more than 1° off square to the fin (a dome, a drafted wall): the burr
    // leans with it (Context::pose_C). Within 1° the lean would move the burr by under 0.02 %
    // of its radius: square.
    const double b = std::asin(std::clamp(n.normalized().dot(f), -1.0, 1.0));
    slope[i] = std::abs(b) > M_PI / 180 ? b : 0.0;
  }

  // ---- The burr must fit: a path on a wall that curves round its centre (closed, or an open
  // arc of at least 45°: part of a hole seen) is in a hole, and the burr (radius r) needs room
  // to step in to the wall from nearer the centre. A burr that leaves less than the lead
  // clearance would ream: its end face plunges through the whole fin ring at once (housing
  // 7002: a 12 mm burr in a 12.5 mm hole, 200-700 N, the arm pushed 0.4 mm off the plan and
  // the wall gouged 0.11 mm along the plunge); a smaller burr from the rack orbits instead.
  double hole_r = 1e300;  // [m] radius of the hole the path runs round (1e300: not a hole)
  if (N0 >= 3) {
    const double kClearance = std::max(2e-4, P.lead_clearance);
    if (path.closed) {
      // Centroid weighted by arc length (points may be denser on one side of the loop).
      Vec3 c = Vec3::Zero();
      double wsum = 0;
      for (std::size_t i = 0; i < N0; ++i) {
        const double wi = 0.5 * ((path.points_C[(i + 1) % N0] - path.points_C[i]).norm() +
                                 (path.points_C[i] - path.points_C[(i + N0 - 1) % N0]).norm());
        c += wi * path.points_C[i];
        wsum += wi;
      }
      c /= std::max(wsum, 1e-300);
      double inward = 0, r_min = 1e300;
      for (std::size_t i = 0; i < N0; ++i) {
        Vec3 v = c - path.points_C[i];
        v -= v.dot(f) * f;
        const double dist = v.norm();
        r_min = std::min(r_min, dist);
        if (dist > 1e-12) inward += wall[i].dot(v / dist);
      }
      if (inward / static_cast<double>(N0) > 0.5) hole_r = r_min;
    } else {
      const ArcFit arc = fit_arc(path.points_C, f, wall);
      if (arc.ok && arc.facing > 0.8 && std::abs(arc.swept) >= M_PI / 4 &&
          arc.rms < 0.1 * arc.radius)
        hole_r = arc.radius;
    }
    if (hole_r < radius + kClearance) {
      GrindResult res;
      res.hole_radius = hole_r;
      res.status = GrindStatus::kToolTooLarge;
      res.message = strf("hole of radius %.2f mm (%s) is too narrow for the burr of radius "
                         "%.2f mm (+%.1f mm room to step in): needs a smaller burr",
                         hole_r * 1e3,
                         path.closed ? "nearest root point to its centre" : "circle through the arc",
                         radius * 1e3, kClearance * 1e3);
      return res;
    }
  }

  // The tool poses follow the smooth wall the facets approximate; the clearance from the steel
  // (clear_concave_facets) is kept from the facets themselves.
  const std::vector<Vec3> facet_wall = wall;
  wall = smooth_facet_normals(path.points_C, facet_wall, f, path.closed);

  // ---- Thin the points to at least `spacing` apart (the spline rejects duplicates).
  std::vector<std::size_t> kept;
  for (std::size_t i = 0; i < N0; ++i) {
    if (kept.empty() || (path.points_C[i] - path.points_C[kept.back()]).norm() >= P.spacing)
      kept.push_back(i);
    else if (!path.closed && i + 1 == N0 && kept.size() > 1)
      kept.back() = i;  // keep the true end of an open path
  }
  if (path.closed)
    while (kept.size() > 1 &&
           (path.points_C[kept.back()] - path.points_C[kept.front()]).norm() < P.spacing)
      kept.pop_back();
  const std::size_t min_points = path.closed ? 6 : 2;
  if (kept.size() < min_points)
    throw ArgumentError(
        strf("GrindPath.points_C: expected at least %zu points %g m apart for a "
             "%s path, got %zu of %zu",
             min_points, P.spacing, path.closed ? "closed" : "open", kept.size(), N0));
  std::vector<Vec3> pts;
  for (std::size_t k : kept) pts.push_back(path.points_C[k]);

  // ---- Quintic B-spline and arc-length samples.
  BSplineParams bp;
  bp.closed = path.closed;
  const BSplineResult spline = interpolate_quintic(pts, bp);
  const CurveView cv = view(spline.curve);
  const ArcLengthTable table = arc_length_table(cv);
  const double total = table.length();
  const auto n_samples =
      static_cast<std::size_t>(std::max(1.0, std::ceil(total / P.spacing - 1e-9)));
  const std::vector<double>& up = spline.curve.params;
  const std::size_t K = pts.size();
  std::vector<PathSample> ps(n_samples + 1);
  for (std::size_t k = 0; k <= n_samples; ++k) {
    const double s = total * static_cast<double>(k) / static_cast<double>(n_samples);
    const double u = param_at_arc_length(cv, table, s);
    const CurveDerivs d = cv.derivatives(u, 1);
    // Bracketing input points and the weight of the second.
    std::size_t j =
        static_cast<std::size_t>(std::upper_bound(up.begin(), up.end(), u) - up.begin());
    j = j == 0 ? 0 : j - 1;
    if (!path.closed && j + 1 >= K) j = K - 2;
    const std::size_t j1 = (j + 1) % K;
    const double u0 = up[j], u1 = j + 1 < K ? up[j + 1] : 1.0;
    const double wgt = u1 > u0 ? std::clamp((u - u0) / (u1 - u0), 0.0, 1.0) : 0.0;
    Vec3 n = (1 - wgt) * wall[kept[j]] + wgt * wall[kept[j1]];
    n -= n.dot(f) * f;
    if (n.norm() < 1e-6) n = wgt < 0.5 ? wall[kept[j]] : wall[kept[j1]];
    n.normalize();
    Vec3 t = n.cross(f);
    if (t.dot(d[1]) < 0) t = -t;
    // Nearest input point among those between the bracketing kept points.
    const std::size_t i0 = kept[j], i1 = kept[j1];
    std::size_t best = i0;
    double best_d = (path.points_C[i0] - d[0]).norm();
    for (std::size_t i = i0;; i = (i + 1) % N0) {
      const double di = (path.points_C[i] - d[0]).norm();
      if (di < best_d) {
        best_d = di;
        best = i;
      }
      if (i == i1) break;
    }
    ps[k] = {d[0], n, t, static_cast<int>(best), j};
  }
  {
    std::vector<Vec3> kept_wall;
    for (std::size_t k : kept) kept_wall.push_back(wall[k]);
    roll_round_convex_corners(ps, pts, kept_wall, f, P.spacing, radius);
  }
  clear_concave_facets(ps, path.points_C, facet_wall, f, radius + P.stock_allowance, path.closed);
  // ---- Run-out past the ends of an open path, straight along the end tangents.
  if (!path.closed && P.overrun > 0 && ps.size() >= 3) {
    auto run_out = [&](const PathSample& end, const PathSample& inner, double sign) {
      // Bend near the end: tangent turn over the last (up to) 3 mm. Where the wall curves
      // round the tool (concave, a hole) the burr axis runs on a circle smaller by r + e, and
      // a straight run-out of length s cuts s² κ / (2 (1 − κ (r + e))) into the wall; where it
      // curves away (convex) the run-out leaves the wall.
      const double arc = std::max((end.p - inner.p).norm(), 1e-9);
      const double turn = std::acos(std::clamp(end.t.dot(inner.t), -1.0, 1.0));
      const double kappa = turn / arc;
      const bool concave = (sign * (end.t - inner.t)).dot(end.n) > 0;
      double len = P.overrun;
      if (concave && kappa > 1e-9) {
        const double room = 1 - kappa * (radius + P.stock_allowance);
        len = room > 0.05 ? std::min(len, std::sqrt(2 * 20e-6 * room / kappa)) : 0.0;
      }
      std::vector<PathSample> out;
      const auto m = static_cast<std::size_t>(std::floor(len / P.spacing + 1e-9));
      for (std::size_t i = 1; i <= m; ++i)
        out.push_back({end.p + sign * static_cast<double>(i) * P.spacing * end.t, end.n, end.t,
                       end.path_index, end.seg});
      return out;
    };
    const std::size_t back3 = std::min<std::size_t>(
        ps.size() - 1, static_cast<std::size_t>(std::ceil(0.003 / P.spacing)));
    auto head = run_out(ps.front(), ps[back3], -1.0);
    auto tail = run_out(ps.back(), ps[ps.size() - 1 - back3], 1.0);
    std::reverse(head.begin(), head.end());
    ps.insert(ps.begin(), head.begin(), head.end());
    ps.insert(ps.end(), tail.begin(), tail.end());
  }

  // ---- Passes: roughing passes of equal radial depths, then the finishing pass against the
  // wall. In a hole the burr's axis need not go past the hole's centre (offset hole_r − r).
  GrindResult res;
  res.hole_radius = hole_r < 1e299 ? hole_r : 0.0;
  res.tool_radius = radius;
  res.pass_offsets = pass_offsets(P, std::min(path.fin_height, std::max(0.0, hole_r - radius)));
  res.passes = static_cast<int>(res.pass_offsets.size());

  // In a hole the burr's axis runs on a circle of radius ρ = hole_r − r − e while its contact
  // with the wall runs on one of radius hole_r − e, faster by their ratio (a 5 mm hole with a
  // 4 mm burr: 5×). The feed is the contact's, as CAM systems set it on inner arcs: the tool
  // centre moves at feed · ρ / (hole_r − e) (at least 5 % of it).
  const auto contact_feed = [&](double feed, double e) {
    if (hole_r >= 1e299) return feed;
    return feed * std::clamp((hole_r - radius - e) / (hole_r - e), 0.05, 1.0);
  };

  // ---- The whole motion as one sample sequence: approach, passes joined by links, retract.
  Context C{robot, P, X_BC, f, ps[0].t, radius, length, tip_depth, P.lead, P.tilt, {}, {}};
  struct SegDraft {
    SampleKind kind;
    int pass;
    std::size_t first, last;
    double feed = 0;  ///< [m/s]; 0: the kind's feed (cutting or approach)
    double ramp_time = 0;  ///< [s] GrindSegment::ramp_time
  };
  std::vector<SegDraft> segs;
  // Each path sample's lead cap (the same on every pass), and the least of them.
  std::vector<double> lead_cap(ps.size());
  for (std::size_t k = 0; k < ps.size(); ++k)
    lead_cap[k] = lead_cap_at(P, ps, k, std::max(tip_depth, length - tip_depth), path.closed);
  const double min_lead_cap = ps.empty() ? 0.0 : *std::min_element(lead_cap.begin(), lead_cap.end());
  auto cut_geo = [&](int pass, std::size_t k) {
    // Open paths alternate direction from pass to pass (no traverse back through the air).
    const bool reverse = !path.closed && (pass % 2 == 1);
    const PathSample& q = ps[reverse ? ps.size() - 1 - k : k];
    Geo g;
    g.p = q.p;
    g.n = q.n;
    g.t = reverse ? Vec3(-q.t) : q.t;
    g.dir = reverse ? -1 : 1;
    g.lead_cap = lead_cap[reverse ? ps.size() - 1 - k : k];
    g.slope = slope[static_cast<std::size_t>(q.path_index)];
    g.extra = res.pass_offsets[static_cast<std::size_t>(pass)];
    g.kind = SampleKind::kCut;
    g.pass = pass;
    g.path_index = q.path_index;
    return g;
  };
  // Samples of a straight move `height` long along the fin normal (at least one).
  const auto lift_steps = [&](double height) {
    return static_cast<std::size_t>(std::max(1.0, std::ceil(height / P.spacing - 1e-9)));
  };
  // Lead-in and lead-out: the approach comes down `clear` off the first pass's wall offset and
  // steps in to it; the last pass steps off by `clear_out` before the retract lifts, so the
  // burr neither plunges nor lifts along the finished wall (in a hole: each at most to its
  // centre; a first pass that already takes all of a small hole's room needs no lead-in).
  const auto clearance = [&](double e) {
    return std::clamp(std::min(P.lead_clearance, hole_r - radius - e), 0.0, P.lead_clearance);
  };
  // Radial move at path sample k of `pass` from offset e0 (the last sample so far) to e1. The
  // lead-in ends on the pass's first sample, pushed next (`onto_next`); the lead-out pushes
  // its end.
  const auto radial = [&](int pass, std::size_t k, SampleKind kind, double e0, double e1,
                          bool onto_next) {
    const std::size_t first = C.geo.size() - 1;
    const auto m =
        static_cast<std::size_t>(std::max(1.0, std::ceil(std::abs(e1 - e0) / P.spacing - 1e-9)));
    for (std::size_t i = 1; i + (onto_next ? 1 : 0) <= m; ++i) {
      Geo g = cut_geo(pass, k);
      g.kind = kind;
      g.extra = e0 + (e1 - e0) * static_cast<double>(i) / static_cast<double>(m);
      C.geo.push_back(g);
    }
    segs.push_back({kind, pass, first, C.geo.size() - (onto_next ? 0 : 1),
                    contact_feed(P.feed, std::min(e0, e1))});
  };
  // The last stretch of a descent plunges the cutter through the fin (its tip crosses the fin
  // plane at lift = tip depth): that part runs at the plunge feed, the rest in the air at the
  // approach feed.
  const double plunge_height = std::min(P.approach_distance, tip_depth + 0.002);
  // Approach of `pass` at its path sample k: down along the fin normal from `height` above
  // it, the lead clearance (clearance(e)) off its wall offset e, then the lead-in. `from_last`: the
  // top is the last sample so far (pushed by the move before), else it is pushed here as the
  // motion's first sample. `plunge_feed`: the feed of the last stretch, through the fin (the air
  // above it at the approach feed).
  const auto come_down = [&](int pass, std::size_t k, double height, bool from_last,
                             double plunge_feed) {
    const double e = res.pass_offsets[static_cast<std::size_t>(pass)];
    const double cl = clearance(e);
    const std::size_t steps = lift_steps(height);
    const std::size_t first = from_last ? C.geo.size() - 1 : C.geo.size();
    // The first sample at or below the plunge height (none: npos).
    constexpr std::size_t npos = static_cast<std::size_t>(-1);
    std::size_t split = from_last && height <= plunge_height ? first : npos;
    for (std::size_t i = from_last ? 1 : 0; i < steps; ++i) {
      Geo g = cut_geo(pass, k);
      g.kind = SampleKind::kApproach;
      g.lift = height * (1 - static_cast<double>(i) / static_cast<double>(steps));
      g.extra += cl;
      if (split == npos && g.lift <= plunge_height) split = C.geo.size();
      C.geo.push_back(g);
    }
    if (cl > 0) {
      Geo g = cut_geo(pass, k);
      g.kind = SampleKind::kApproach;
      g.extra += cl;
      C.geo.push_back(g);  // down at the fin plane, `cl` off the wall offset
    }
    // The descent ends on the first cut sample (pushed next) or, with a lead-in, down here.
    const std::size_t down = cl > 0 ? C.geo.size() - 1 : C.geo.size();
    if (split == npos || split == first || split + 1 >= first + steps) {
      segs.push_back({SampleKind::kApproach, pass, first, down, plunge_feed});
    } else {
      segs.push_back({SampleKind::kApproach, pass, first, split});
      segs.push_back({SampleKind::kApproach, pass, split, down, plunge_feed});
    }
    if (cl > 0) radial(pass, k, SampleKind::kApproach, e + cl, e, true);
  };
  // Retract from the last sample so far, path sample k of its pass: the lead-out, then
  // straight up `height` along the fin normal.
  const auto lift_off = [&](std::size_t k, double height) {
    const Geo last = C.geo.back();
    const double cl = clearance(last.extra);
    if (cl > 0) radial(last.pass, k, SampleKind::kRetract, last.extra, last.extra + cl, false);
    const std::size_t first = C.geo.size() - 1;
    const Geo end = C.geo.back();
    const std::size_t steps = lift_steps(height);
    for (std::size_t i = 1; i <= steps; ++i) {
      Geo g = end;
      g.kind = SampleKind::kRetract;
      g.lift = height * static_cast<double>(i) / static_cast<double>(steps);
      C.geo.push_back(g);
    }
    segs.push_back({SampleKind::kRetract, last.pass, first, C.geo.size() - 1});
  };
  // Stops in free air for a controller that reads a flange F/T sensor (retare_before_finish):
  // up out of the part from the last sample so far (path sample `from_k` of its pass) to the
  // plunge height, where the burr's tip is 2 mm above the fin plane and the arm rests (the
  // controller zeroes its sensor there), a step across in the air to above path sample `k` of
  // `pass`, the lead clearance off its offset, and down again with the lead-in. Where the pass
  // before cut the fin to within that clearance (finish_depth < lead_clearance) the descent is
  // in the air, at the approach feed; else it plunges at the plunge feed.
  const auto stop_in_air = [&](std::size_t from_k, int pass, std::size_t k) {
    lift_off(from_k, plunge_height);
    const Geo top = C.geo.back();
    const double e = res.pass_offsets[static_cast<std::size_t>(pass)];
    const double e1 = e + clearance(e);
    const std::size_t first = C.geo.size() - 1;
    const auto m = static_cast<std::size_t>(
        std::max(0.0, std::ceil(std::abs(top.extra - e1) / P.spacing - 1e-9)));
    for (std::size_t i = 1; i <= m; ++i) {
      Geo g = cut_geo(pass, k);
      g.kind = SampleKind::kApproach;
      g.lift = plunge_height;
      g.extra = top.extra + (e1 - top.extra) * static_cast<double>(i) / static_cast<double>(m);
      C.geo.push_back(g);
    }
    if (m > 0) segs.push_back({SampleKind::kApproach, pass, first, C.geo.size() - 1});
    const bool in_air = pass > 0 && res.pass_offsets[static_cast<std::size_t>(pass - 1)] < e1;
    come_down(pass, k, plunge_height, true, in_air ? P.approach_feed : P.plunge_feed);
  };
  const bool retare = P.retare_before_finish && P.approach_distance > 0 && res.passes > 1;
  if (P.approach_distance > 0) come_down(0, 0, P.approach_distance, false, P.plunge_feed);
  // Neighbouring segments share their junction sample: the approach ends on the first cut
  // sample, a link starts on a pass's last sample and ends on the next pass's first.
  for (int pass = 0; pass < res.passes; ++pass) {
    const bool finishing = pass + 1 == res.passes;
    if (pass > 0 && retare && finishing) {
      stop_in_air(ps.size() - 1, pass, 0);
    } else if (pass > 0) {
      // Radial step-in from the previous pass's end to the next pass's start (same point).
      radial(pass, 0, SampleKind::kLink, C.geo.back().extra,
             res.pass_offsets[static_cast<std::size_t>(pass)], true);
    }
    const double feed = contact_feed(finishing ? P.feed : P.roughing_feed,
                                     res.pass_offsets[static_cast<std::size_t>(pass)]);
    // A long finishing pass stops in free air again every retare_length of path (and goes on
    // from the same path sample), so the sensor's drift since its last zero stays small.
    // No stop within a quarter of that of the pass's end.
    const bool split = retare && finishing && P.retare_length > 0;
    const std::size_t first_piece = segs.size();
    double left = 0;  // path length still to cut [m]
    for (std::size_t k = 1; k < ps.size(); ++k) left += (ps[k].p - ps[k - 1].p).norm();
    std::size_t first = C.geo.size();
    double run = 0;  // path length since the pass (re)started [m]
    for (std::size_t k = 0; k < ps.size(); ++k) {
      const Geo g = cut_geo(pass, k);
      if (k > 0) {
        const double step = (g.p - C.geo.back().p).norm();
        run += step;
        left -= step;
      }
      C.geo.push_back(g);
      if (split && run >= P.retare_length && left > P.retare_length / 4) {
        segs.push_back({SampleKind::kCut, pass, first, C.geo.size() - 1, feed});
        stop_in_air(k, pass, k);
        first = C.geo.size();
        C.geo.push_back(cut_geo(pass, k));  // on from where it stopped
        run = 0;
      }
    }
    segs.push_back({SampleKind::kCut, pass, first, C.geo.size() - 1, feed});
    // Pieces that stop on the wall ramp their feed (and with it the process force) gently.
    if (segs.size() > first_piece + 1)
      for (std::size_t i = first_piece; i < segs.size(); ++i)
        if (segs[i].kind == SampleKind::kCut) segs[i].ramp_time = P.retare_ramp_time;
  }
  if (P.approach_distance > 0) lift_off(ps.size() - 1, P.approach_distance);
  const std::size_t N = C.geo.size();
  // Nominal tool path length (the blend windows are measured in it).
  C.s_nom.assign(N, 0.0);
  {
    Vec3 prev = C.pose_C(0, Dev{}, 0).translation();
    for (std::size_t i = 1; i < N; ++i) {
      const Vec3 cur = C.pose_C(i, Dev{}, 0).translation();
      C.s_nom[i] = C.s_nom[i - 1] + std::max((cur - prev).norm(), 1e-9);
      prev = cur;
    }
  }

  // ---- Seeds: every allowed IK solution of the first pose under every base spin.
  std::vector<Seed> seeds;
  Node first_fail;  // why the first pose has no seed at all
  const std::vector<Candidate> cands = candidates(P);
  const auto seeds_leaning = [&](const Dev& base) {
    for (int k = 0; k < P.spin_candidates; ++k) {
      const double spin0 = 2 * M_PI * k / P.spin_candidates;
      const Pose X_BT = X_BC * C.pose_C(0, base, spin0);
      const IkResult r = ik_tool(robot, X_BT);
      for (const auto& sol : r.solutions)
        if (P.branch_mask & (1u << sol.branch.index())) seeds.push_back({sol.branch.index(), spin0, sol.q, base});
    }
  };
  seeds_leaning(Dev{});
  // No allowed solution at the nominal first pose under any spin (a wrist bent past its range
  // to hold the burr upright close to the base): the whole path leans, the smallest lead alone
  // that gives seeds, else the smallest lean with tilt (a tilt of the whole path would leave a
  // wedge of flash along all of it: cover seed 9020, 0.18 rad, 1.3 mm).
  Geo everywhere;  // the tightest allowance along the path
  everywhere.lead_cap = min_lead_cap;
  for (const bool with_tilt : {false, true})
    for (std::size_t c = 0; c < cands.size() && seeds.empty(); ++c)
      if (cands[c].level > 0 && (cands[c].d.tilt != 0) == with_tilt &&
          lean_allowed(P, everywhere, cands[c].d))
        seeds_leaning(cands[c].d);  // the samples' extra lead and tilt show the lean
  std::vector<SeedOutcome> outcomes;
  for (const Seed& sd : seeds) outcomes.push_back(track_seed(C, sd, cands));
  res.seeds_tried = static_cast<int>(seeds.size());

  // ---- Choose: complete seeds that keep the burr flush with the wall (no tilt anywhere: a
  // tilted burr cuts the root with its ball, which leaves flash where the fin stands off the
  // ball's centre plane, or with its upper rim, which leaves a wedge) if there are any, among them those within
  // 10 % of the best minimum manipulability, then the fewest re-orientations, then the largest
  // joint-limit margin, then the first.
  const auto flush = [](const SeedOutcome& o) {
    return std::all_of(o.dev.begin(), o.dev.end(), [](const Dev& d) { return d.tilt == 0; });
  };
  bool any_flush = false;
  for (const auto& o : outcomes)
    if (o.complete) {
      ++res.seeds_completed;
      any_flush = any_flush || flush(o);
    }
  double best_manip = -1;
  for (const auto& o : outcomes)
    if (o.complete && (!any_flush || flush(o))) best_manip = std::max(best_manip, o.min_manip);
  int chosen = -1;
  for (std::size_t k = 0; k < outcomes.size(); ++k) {
    const auto& o = outcomes[k];
    if (!o.complete || (any_flush && !flush(o)) || o.min_manip < 0.9 * best_manip) continue;
    if (chosen < 0) {
      chosen = static_cast<int>(k);
      continue;
    }
    const auto& c = outcomes[static_cast<std::size_t>(chosen)];
    if (o.ranges.size() < c.ranges.size() ||
        (o.ranges.size() == c.ranges.size() && o.margin > c.margin + 1e-9))
      chosen = static_cast<int>(k);
  }

  // ---- Samples (final poses when a seed completed, nominal ones otherwise).
  const SeedOutcome* best = chosen >= 0 ? &outcomes[static_cast<std::size_t>(chosen)] : nullptr;
  int report = -1;  // failing seed to report: the one that got farthest
  if (!best)
    for (std::size_t k = 0; k < outcomes.size(); ++k)
      if (report < 0 ||
          outcomes[k].fail_sample > outcomes[static_cast<std::size_t>(report)].fail_sample)
        report = static_cast<int>(k);
  const SeedOutcome* shown =
      best ? best : (report >= 0 ? &outcomes[static_cast<std::size_t>(report)] : nullptr);
  const double spin0 = best ? seeds[static_cast<std::size_t>(chosen)].spin0
                            : (report >= 0 ? seeds[static_cast<std::size_t>(report)].spin0 : 0.0);
  res.samples.resize(N);
  for (std::size_t i = 0; i < N; ++i) {
    GrindSample& gs = res.samples[i];
    const Dev d = best ? best->dev[i] : Dev{};
    gs.kind = C.geo[i].kind;
    gs.pass = C.geo[i].pass;
    gs.path_index = C.geo[i].path_index;
    gs.X_CT = C.pose_C(i, d, spin0, &gs.axis_offset);
    gs.X_BT = X_BC * gs.X_CT;
    gs.extra_lead = C.geo[i].dir * d.lead;  // toward this sample's travel
    gs.extra_tilt = d.tilt;
    gs.extra_spin = d.spin;
    if (shown && shown->nodes[i].has_q) {
      gs.q = shown->nodes[i].q;
      gs.manipulability = shown->nodes[i].manip;
    }
    if (i > 0)
      gs.s = res.samples[i - 1].s +
             std::max((gs.X_BT.translation() - res.samples[i - 1].X_BT.translation()).norm(), 1e-9);
  }
  res.base_spin = spin0;
  for (const auto& sg : segs) {
    GrindSegment g;
    g.kind = sg.kind;
    g.pass = sg.pass;
    g.first_sample = sg.first;
    g.last_sample = sg.last;
    g.feed = sg.feed > 0 ? sg.feed
                         : (sg.kind == SampleKind::kCut || sg.kind == SampleKind::kLink ? P.feed
                                                                                         : P.approach_feed);
    g.ramp_time = sg.ramp_time;
    res.segments.push_back(g);
  }
  res.path_length = res.samples.back().s;
  for (const auto& g : res.segments)
    if (g.kind == SampleKind::kCut || g.kind == SampleKind::kLink)
      res.cut_length += res.samples[g.last_sample].s - res.samples[g.first_sample].s;

  const auto where = [&](std::size_t i) {
    const GrindSample& gs = res.samples[i];
    return strf("path index %d (sample %zu, pass %d, %s)", gs.path_index, i, gs.pass,
                to_string(gs.kind).c_str());
  };
  if (!best) {
    // ---- Failure: no seed, or every seed stuck; report the one that got farthest.
    std::size_t i = 0;
    Node nd;
    if (report < 0) {
      // No allowed IK solution at the first pose: say why.
      IkParams ip;
      ip.within_limits_only = false;
      const IkResult all = ik_tool(robot, res.samples[0].X_BT, ip);
      if (all.solutions.empty()) {
        nd.status = NodeStatus::kUnreachable;
        nd.info = all.message;
      } else {
        nd.status = NodeStatus::kJointLimit;
        nd.value = std::numeric_limits<double>::infinity();
        for (const auto& sol : all.solutions) {
          if (!(P.branch_mask & (1u << sol.branch.index()))) continue;
          double worst = 0;
          int wj = -1;
          for (int j = 0; j < kNumJoints; ++j) {
            double ex = std::numeric_limits<double>::infinity();
            for (int k = -2; k <= 2; ++k)
              ex = std::min(ex, limit_excess(robot.limits[j],
                                             std::remainder(sol.q[j], 2 * M_PI) + 2 * M_PI * k));
            if (ex > worst) {
              worst = ex;
              wj = j;
            }
          }
          if (worst < nd.value) {
            nd.value = worst;
            nd.joint = wj;
          }
        }
        if (nd.joint < 0) {
          nd.status = NodeStatus::kBranchLost;
          nd.info = "no IK solution on an allowed branch (branch_mask)";
        }
      }
    } else {
      i = shown->fail_sample;
      nd = shown->fail_node;
    }
    res.status = status_of(nd.status);
    res.failed_sample = static_cast<int>(i);
    res.failed_path_index = res.samples[i].path_index;
    res.failed_pass = res.samples[i].pass;
    std::string why;
    switch (nd.status) {
      case NodeStatus::kUnreachable:
        why = "unreachable: " + nd.info;
        break;
      case NodeStatus::kJointLimit: {
        res.failed_joint = nd.joint;
        res.failed_excess = nd.value;
        int side = 0;
        if (nd.has_q) limit_excess(robot.limits[nd.joint], nd.q[nd.joint], &side);
        why = strf("joint %d beyond its %slimit by %.4f rad", nd.joint + 1,
                   side > 0 ? "upper " : (side < 0 ? "lower " : ""), nd.value);
        break;
      }
      case NodeStatus::kLowManip:
        res.failed_excess = nd.manip;
        why =
            strf("singular: manipulability %.3g below %.3g", nd.manip, P.manipulability_threshold);
        break;
      case NodeStatus::kJump:
        res.failed_joint = nd.joint;
        res.failed_excess = nd.value;
        why = strf("joint %d jumps by %.3f rad (more than %.3f) between samples", nd.joint + 1,
                   nd.value, P.max_joint_jump);
        break;
      case NodeStatus::kCollision:
        res.failed_excess = nd.value;
        why = strf("%s within %.2f mm (needs %.2f mm)", nd.info.c_str(), nd.value * 1e3,
                   P.min_clearance * 1e3);
        break;
      default:
        why = "configuration branch lost: " + nd.info;
        break;
    }
    res.message = where(i) + ": " + why;
    if (report >= 0) {
      res.message += strf(
          " for every IK branch (%d tried) and re-orientation (spin about the "
          "tool axis, lean up to %.3f rad, lead alone up to %.3f rad)",
          res.seeds_tried, P.max_extra_tilt, std::max(P.max_extra_tilt, P.max_extra_lead));
      if (shown->range_first < i)
        res.message += strf("; the problems start at sample %zu (path index %d)",
                            shown->range_first, res.samples[shown->range_first].path_index);
    } else {
      res.message += " at the first pose";
    }
    return res;
  }

  // ---- Success so far: branch, re-orientations, manipulability.
  {
    const int b = seeds[static_cast<std::size_t>(chosen)].branch;
    res.branch.front = b < 4;
    res.branch.elbow_up = (b & 2) == 0;
    res.branch.flip = (b & 1) != 0;
  }
  res.reoriented_ranges = best->ranges;
  res.min_manipulability = best->min_manip;

  // ---- Time parametrization, one segment at a time (each starts and ends at rest). The
  // samples keep limit_margin inside each range; the interpolation between them may use half
  // of that (a quintic B-spline through samples at the margin swings a little past them), and
  // still stays inside the executor's reference clamp (0.01 rad for the default 0.02).
  const RobotModel robot_timing = with_limit_margin(robot_in, P.limit_margin / 2);
  for (auto& g : res.segments) {
    std::vector<double> s;
    std::vector<Vector6> q;
    for (std::size_t i = g.first_sample; i <= g.last_sample; ++i) {
      s.push_back(res.samples[i].s);
      q.push_back(res.samples[i].q);
    }
    TimingParams tp = P.timing;
    tp.feed = g.feed;
    if (g.ramp_time > 0) {
      // A triangular acceleration ramp to the feed v with jerk J takes T = 2·√(v/J) and peaks
      // at J·T/2: J = 4v/T², peak 2v/T.
      tp.max_path_jerk = std::min(tp.max_path_jerk, 4 * g.feed / (g.ramp_time * g.ramp_time));
      tp.max_path_accel = std::min(tp.max_path_accel, 2 * g.feed / g.ramp_time);
    }
    const TimingResult tr = time_within_torque(robot_timing, s, q, tp, P);
    if (!tr.ok()) {
      const std::size_t i =
          g.first_sample + static_cast<std::size_t>(std::max(0, tr.failed_sample));
      res.status = GrindStatus::kTimingFailed;
      res.failed_sample = static_cast<int>(i);
      res.failed_path_index = res.samples[i].path_index;
      res.failed_pass = res.samples[i].pass;
      res.failed_joint = tr.failed_joint;
      res.failed_excess = tr.failed_excess;
      res.message =
          where(i) + ": time parametrization failed (" + to_string(tr.status) + "): " + tr.message;
      res.trajectory = JointTrajectory{};
      return res;
    }
    JointTrajectory& T = res.trajectory;
    const std::size_t n0 = T.t.empty() ? 0 : T.t.size() - 1;
    const std::size_t skip = T.t.empty() ? 0 : 1;  // the shared rest sample
    T.dt = tr.trajectory.dt;
    for (std::size_t k = skip; k < tr.trajectory.size(); ++k) {
      T.t.push_back(static_cast<double>(n0 + k) * T.dt);
      T.q.push_back(tr.trajectory.q[k]);
      T.dq.push_back(tr.trajectory.dq[k]);
      T.ddq.push_back(tr.trajectory.ddq[k]);
      T.s.push_back(tr.trajectory.s[k]);
      T.sdot.push_back(tr.trajectory.sdot[k]);
      T.sddot.push_back(tr.trajectory.sddot[k]);
    }
    g.first_step = n0;
    g.last_step = T.t.size() - 1;
    res.max_joint_velocity_ratio =
        std::max(res.max_joint_velocity_ratio, tr.max_joint_velocity_ratio);
    res.max_joint_accel_ratio = std::max(res.max_joint_accel_ratio, tr.max_joint_accel_ratio);
    for (FeedReduction fr : tr.reductions) {
      fr.first_sample += g.first_sample;
      fr.last_sample += g.first_sample;
      res.feed_reductions.push_back(fr);
    }
  }
  // The commanded motion itself, every period, against the ranges less half the margin (as
  // timed): what the robot is sent must be what was checked (tilted 8011: 0.034 rad past joint
  // 5's limit at 1 ms samples of a hole path whose samples and timing grid were inside; the
  // executor clamped the joint, the burr left its path and gouged 0.85 mm).
  for (std::size_t k = 0; k < res.trajectory.q.size(); ++k) {
    const Vector6& q = res.trajectory.q[k];
    for (int j = 0; j < kNumJoints; ++j) {
      const JointLimits& L = robot_timing.limits[static_cast<std::size_t>(j)];
      const double excess = std::max(q[j] - L.upper, L.lower - q[j]);
      if (excess <= 1e-9) continue;
      // The path sample nearest the period's path position.
      std::size_t i = 0;
      while (i + 1 < res.samples.size() && res.samples[i + 1].s <= res.trajectory.s[k]) ++i;
      res.status = GrindStatus::kJointLimit;
      res.failed_sample = static_cast<int>(i);
      res.failed_path_index = res.samples[i].path_index;
      res.failed_pass = res.samples[i].pass;
      res.failed_joint = j;
      res.failed_excess = excess;
      res.message = where(i) + strf(": the timed motion at %.3f s takes joint %d %.4f rad past its "
                                    "range less half the margin", res.trajectory.t[k], j + 1, excess);
      res.trajectory = JointTrajectory{};
      return res;
    }
  }
  res.total_time = res.trajectory.duration();
  res.tcp_B.reserve(res.trajectory.size());
  for (const auto& q : res.trajectory.q) res.tcp_B.push_back(fk_tool(robot, q));
  // The commanded tool path, every period, within kMaxSwing of the straight line between the
  // samples it passes: the joint spline through samples whose joints turn far over a short tool
  // travel rings (round_flange 504's bore, the wrist turning a leaning burr round it: the tool
  // swung 46 mm off its samples and into the part, 44,000 steps of collet in the casting; noisy
  // 202: 12.8 mm). Any joint-space motion between samples bows off their chord: up to ~1 mm for
  // the wrist turning max_joint_jump (0.2 rad) with the tip 0.22 m out (r·θ²/8), ~2 mm on the
  // noisy family's rough paths; those run as planned and the twin measures what they do.
  constexpr double kMaxSwing = 5e-3;
  if (const Swing w = largest_swing(res); w.distance > kMaxSwing) {
    res.status = GrindStatus::kDiscontinuous;
    res.failed_sample = static_cast<int>(w.sample);
    res.failed_path_index = res.samples[w.sample].path_index;
    res.failed_pass = res.samples[w.sample].pass;
    res.message = where(w.sample) + strf(": the timed motion at %.3f s swings the tool %.1f mm off "
                                         "the line between its samples (more than %.0f mm)",
                                         w.t, w.distance * 1e3, kMaxSwing * 1e3);
    res.trajectory = JointTrajectory{};
    res.tcp_B.clear();
  }
  return res;
}

// ---------------------------------------------------------------------------------------------
// Outputs

std::string trajectory_csv(const GrindResult& result) {
  std::string out = "t";
  for (const char* p : {"q", "dq", "ddq"})
    for (int j = 1; j <= kNumJoints; ++j) out += strf(",%s%d", p, j);
  out += ",x,y,z,qw,qx,qy,qz\n";
  const JointTrajectory& T = result.trajectory;
  // One row per 1 ms sample: blocks of rows formatted in parallel, joined in order.
  const auto rows = static_cast<long>(T.size());
  constexpr long kBlock = 4096;
  std::vector<std::string> blocks(static_cast<std::size_t>((rows + kBlock - 1) / kBlock));
#pragma omp parallel for schedule(dynamic, 1) if (blocks.size() > 1)
  for (long b = 0; b < static_cast<long>(blocks.size()); ++b) {
    std::string& s = blocks[static_cast<std::size_t>(b)];
    s.reserve(kBlock * 320);
    for (long r = b * kBlock; r < std::min(rows, (b + 1) * kBlock); ++r) {
      const auto k = static_cast<std::size_t>(r);
      // As "%.6f" and ",%.9g" (snprintf was half the planning time).
      append_fixed(s, T.t[k], 6);
      for (const Vector6* v : {&T.q[k], &T.dq[k], &T.ddq[k]})
        for (int j = 0; j < kNumJoints; ++j) {
          s += ',';
          append_general(s, (*v)[j], 9);
        }
      if (k < result.tcp_B.size()) {
        const Pose& X = result.tcp_B[k];
        Eigen::Quaterniond q(X.linear());
        if (q.w() < 0) q.coeffs() = -q.coeffs();
        for (double x : {X.translation().x(), X.translation().y(), X.translation().z(), q.w(),
                         q.x(), q.y(), q.z()}) {
          s += ',';
          append_general(s, x, 9);
        }
      } else {
        s += ",,,,,,,";
      }
      s += '\n';
    }
  }
  std::size_t total = out.size();
  for (const auto& s : blocks) total += s.size();
  out.reserve(total);
  for (const auto& s : blocks) out += s;
  return out;
}

namespace {

std::string json_string(const std::string& s) {
  std::string o = "\"";
  for (char c : s) {
    switch (c) {
      case '"':
        o += "\\\"";
        break;
      case '\\':
        o += "\\\\";
        break;
      case '\n':
        o += "\\n";
        break;
      case '\t':
        o += "\\t";
        break;
      default:
        if (static_cast<unsigned char>(c) < 0x20)
          o += strf("\\u%04x", c);
        else
          o += c;
    }
  }
  return o + "\"";
}

std::string json_number(double v) {
  return std::isfinite(v) ? exact_number(v) : "null";
}

}  // namespace

std::string grind_summary_json(const GrindResult& r) {
  std::string o = "{\n";
  const auto kv = [&](const std::string& k, const std::string& v, bool last = false) {
    o += "  " + json_string(k) + ": " + v + (last ? "\n" : ",\n");
  };
  kv("status", json_string(to_string(r.status)));
  kv("message", json_string(r.message));
  if (!r.ok()) {
    kv("failed_sample", std::to_string(r.failed_sample));
    kv("failed_path_index", std::to_string(r.failed_path_index));
    kv("failed_pass", std::to_string(r.failed_pass));
    kv("failed_joint", std::to_string(r.failed_joint));
    kv("failed_excess", json_number(r.failed_excess));
  }
  kv("branch", json_string(r.ok() ? r.branch.name() : ""));
  kv("base_spin_rad", json_number(r.base_spin));
  kv("trajectory.max_joint_velocity_ratio", json_number(r.max_joint_velocity_ratio));
  kv("trajectory.max_joint_accel_ratio", json_number(r.max_joint_accel_ratio));
  kv("trajectory.min_manipulability", json_number(r.min_manipulability));
  kv("trajectory.total_time_s", json_number(r.total_time));
  kv("trajectory.path_length_m", json_number(r.path_length));
  kv("trajectory.cut_length_m", json_number(r.cut_length));
  kv("trajectory.passes", std::to_string(r.passes));
  kv("trajectory.samples", std::to_string(r.samples.size()));
  kv("trajectory.steps", std::to_string(r.trajectory.size()));
  std::string arr = "[";
  for (std::size_t k = 0; k < r.reoriented_ranges.size(); ++k) {
    const auto& x = r.reoriented_ranges[k];
    arr += strf(
        "%s\n    {\"reason\": %s, \"first_sample\": %zu, \"last_sample\": %zu, "
        "\"first_path_index\": %d, \"last_path_index\": %d, \"pass\": %d, "
        "\"nominal_min_manipulability\": %s, \"min_manipulability\": %s, "
        "\"extra_lead_rad\": %s, \"extra_tilt_rad\": %s, \"extra_spin_rad\": %s}",
        k ? "," : "", json_string(to_string(x.reason)).c_str(), x.first_sample, x.last_sample,
        x.first_path_index, x.last_path_index, x.pass,
        json_number(x.nominal_min_manipulability).c_str(),
        json_number(x.min_manipulability).c_str(), json_number(x.extra_lead).c_str(),
        json_number(x.extra_tilt).c_str(), json_number(x.extra_spin).c_str());
  }
  arr += r.reoriented_ranges.empty() ? "]" : "\n  ]";
  kv("trajectory.reoriented_ranges", arr);
  arr = "[";
  for (std::size_t k = 0; k < r.feed_reductions.size(); ++k) {
    const auto& x = r.feed_reductions[k];
    arr += strf(
        "%s\n    {\"first_sample\": %zu, \"last_sample\": %zu, \"s_begin_m\": %s, "
        "\"s_end_m\": %s, \"min_feed_m_s\": %s, \"nominal_feed_m_s\": %s, "
        "\"joint\": %d, \"limit\": %s}",
        k ? "," : "", x.first_sample, x.last_sample, json_number(x.s_begin).c_str(),
        json_number(x.s_end).c_str(), json_number(x.min_feed).c_str(),
        json_number(x.nominal_feed).c_str(), x.joint + 1, json_string(to_string(x.limit)).c_str());
  }
  arr += r.feed_reductions.empty() ? "]" : "\n  ]";
  kv("trajectory.feed_reductions", arr, true);
  return o + "}\n";
}

Image plot_joint_trajectory(const JointTrajectory& T, JointQuantity quantity, int width,
                            int height) {
  static const Rgb kColors[6] = {{31, 119, 180}, {255, 127, 14},  {44, 160, 44},
                                 {214, 39, 40},  {148, 103, 189}, {140, 86, 75}};
  PlotSpec spec;
  const char* sym = "q";
  switch (quantity) {
    case JointQuantity::kPosition:
      spec.title = "Joint angles";
      spec.ylabel = "q [rad]";
      break;
    case JointQuantity::kVelocity:
      spec.title = "Joint velocities";
      spec.ylabel = "dq/dt [rad/s]";
      sym = "dq";
      break;
    case JointQuantity::kAcceleration:
      spec.title = "Joint accelerations";
      spec.ylabel = "d2q/dt2 [rad/s^2]";
      sym = "ddq";
      break;
  }
  spec.xlabel = "t [s]";
  // At most ~4000 points per line: plenty for the pixel width.
  const std::size_t stride = std::max<std::size_t>(1, T.size() / 4000);
  for (int j = 0; j < kNumJoints; ++j) {
    Series s;
    s.color = kColors[j];
    s.label = strf("%s%d", sym, j + 1);
    s.size = 2;
    for (std::size_t k = 0; k < T.size(); k += stride) {
      const Vector6& v = quantity == JointQuantity::kPosition
                             ? T.q[k]
                             : (quantity == JointQuantity::kVelocity ? T.dq[k] : T.ddq[k]);
      s.x.push_back(T.t[k]);
      s.y.push_back(v[j]);
    }
    spec.series.push_back(std::move(s));
  }
  return render_plot(spec, width, height);
}

void write_grind_outputs(const GrindResult& result, const std::string& dir, bool plots,
                         const std::string& csv) {
  ensure_directory(dir);
  write_text_file(dir + "/trajectory.csv", csv.empty() ? trajectory_csv(result) : csv);
  write_text_file(dir + "/grind_summary.json", grind_summary_json(result));
  if (!plots || !result.ok() || result.trajectory.size() == 0) return;
  write_png(dir + "/joint_positions.png",
            plot_joint_trajectory(result.trajectory, JointQuantity::kPosition));
  write_png(dir + "/joint_velocities.png",
            plot_joint_trajectory(result.trajectory, JointQuantity::kVelocity));
  write_png(dir + "/joint_accelerations.png",
            plot_joint_trajectory(result.trajectory, JointQuantity::kAcceleration));
}

}  // namespace flashtwin::planner
