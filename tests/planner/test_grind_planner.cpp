#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <string>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

const Vec3 kUp = Vec3::UnitZ();

Pose translation(const Vec3& t) {
  Pose X = Pose::Identity();
  X.translation() = t;
  return X;
}

// Horizontal fin on the vertical wall x_C = 0 whose outward normal −x_C faces the robot; the root
// runs along y_C from y0 to y1 at z_C = 0.
GrindPath wall_line(double y0, double y1, double step) {
  GrindPath p;
  const int n = static_cast<int>(std::lround((y1 - y0) / step));
  for (int k = 0; k <= n; ++k) {
    p.points_C.push_back(Vec3(0, y0 + k * step, 0));
    p.normals_C.push_back(Vec3(-1, 0, 0));
  }
  p.fin_normal_C = kUp;
  return p;
}

// Flash around a vertical hole of radius R centred on the z_C axis: the wall normal points into
// the hole's free space (toward the axis).
GrindPath hole_circle(double R, int n) {
  GrindPath p;
  p.closed = true;
  for (int k = 0; k < n; ++k) {
    const double a = 2 * M_PI * k / n;
    p.points_C.push_back(Vec3(R * std::cos(a), R * std::sin(a), 0));
    p.normals_C.push_back(-Vec3(std::cos(a), std::sin(a), 0));
  }
  p.fin_normal_C = kUp;
  return p;
}

// Parameters with the burr flush against the wall (no stock allowance) and approach and
// retract straight along the fin normal at the wall offset (no lead-in): exact geometry.
GrindParams flush() {
  GrindParams p;
  p.stock_allowance = 0;
  p.lead_clearance = 0;
  return p;
}

// The timed joint trajectory is continuous and inside the joint limits (position, velocity,
// acceleration), with no NaN, and its velocities integrate to its positions.
void expect_trajectory_sound(const RobotModel& robot, const GrindResult& r) {
  const JointTrajectory& T = r.trajectory;
  ASSERT_GT(T.size(), 2u);
  ASSERT_EQ(r.tcp_B.size(), T.size());
  double max_step = 0, max_integ = 0, vr = 0, ar = 0;
  for (std::size_t n = 0; n < T.size(); ++n) {
    ASSERT_TRUE(T.q[n].allFinite() && T.dq[n].allFinite() && T.ddq[n].allFinite()) << n;
    EXPECT_TRUE(robot.within_limits(T.q[n], 1e-9)) << "step " << n;
    for (int j = 0; j < 6; ++j) {
      vr = std::max(vr, std::abs(T.dq[n][j]) / robot.limits[j].velocity);
      ar = std::max(ar, std::abs(T.ddq[n][j]) / robot.limits[j].acceleration);
    }
    if (n + 1 < T.size()) {
      EXPECT_NEAR(T.t[n + 1] - T.t[n], T.dt, 1e-9);
      const Vector6 dq = T.q[n + 1] - T.q[n];
      for (int j = 0; j < 6; ++j)
        max_step = std::max(max_step, std::abs(dq[j]) / (robot.limits[j].velocity * T.dt));
      const Vector6 integ = dq - 0.5 * T.dt * (T.dq[n] + T.dq[n + 1]);
      // The trapezoid rule is exact under constant acceleration; a step of the acceleration
      // (the timing's profile is acceleration-limited, not jerk-limited) leaves up to
      // |Δa|·dt²/8 ≤ a_max·dt²/4 of it; a velocity step leaves |Δv|·dt/2.
      for (int j = 0; j < 6; ++j)
        max_integ = std::max(max_integ, std::abs(integ[j]) /
                                            (robot.limits[j].acceleration * T.dt * T.dt / 4));
    }
  }
  EXPECT_LE(max_step, 1.0) << "a joint moves faster than its limit between two samples";
  EXPECT_LT(max_integ, 1.0) << "positions and velocities disagree (a jump)";
  EXPECT_LE(vr, 1.0);
  EXPECT_LE(ar, 1.0);
  EXPECT_NEAR(r.max_joint_velocity_ratio, vr, 1e-9);
  EXPECT_NEAR(r.max_joint_accel_ratio, ar, 1e-9);
  // At rest at both ends.
  EXPECT_LT(T.dq.front().norm(), 1e-12);
  EXPECT_LT(T.dq.back().norm(), 1e-9);
}

// Every sample's q is an IK solution of its pose on the reported branch (one branch throughout,
// hence no wrist flip or elbow/shoulder switch), and the samples' joints never jump.
void expect_single_branch(const RobotModel& robot, const GrindResult& r, double max_jump) {
  const int branch = r.branch.index();
  for (std::size_t i = 0; i < r.samples.size(); ++i) {
    const GrindSample& s = r.samples[i];
    const Pose X = fk_tool(robot, s.q);
    ASSERT_LT((X.translation() - s.X_BT.translation()).norm(), 1e-9) << i;
    ASSERT_LT(rotation_distance(X.linear(), s.X_BT.linear()), 1e-9) << i;
    IkParams ip;
    ip.q_ref = s.q;
    const IkResult ik = ik_tool(robot, s.X_BT, ip);
    int found = -1;
    for (const auto& sol : ik.solutions)
      if ((sol.q - s.q).cwiseAbs().maxCoeff() < 1e-6) found = sol.branch.index();
    ASSERT_EQ(found, branch) << "sample " << i << " is not on branch " << r.branch.name();
    if (i > 0) {
      ASSERT_LE((s.q - r.samples[i - 1].q).cwiseAbs().maxCoeff(), max_jump) << i;
    }
  }
}

// Signed clearance between the ball-ended burr (hemisphere at the tip, cylinder above) and the
// wall plane through `root` with normal `n` (0: tangent, < 0: gouge), for a tool pose X_CT.
double wall_clearance(const Pose& X_CT, const Vec3& root, const Vec3& n, double radius,
                      double length) {
  const Vec3 z = X_CT.linear().col(2);
  const Vec3 centre = X_CT.translation() - radius * z;  // the ball end's centre
  const Vec3 top = X_CT.translation() - length * z;
  const double c = z.dot(n);
  const double ball = (centre - root).dot(n) - radius;
  const double side = std::min((centre - root).dot(n), (top - root).dot(n)) -
                      radius * std::sqrt(std::max(0.0, 1 - c * c));
  return std::min(ball, side);
}

// How far from the wall plane (along its normal n, through the root point on the fin plane) a
// ball-ended burr at X_CT begins: the flash it leaves at the root [m] (searched in 1 µm steps).
double root_gap(const Pose& X_CT, const Vec3& root, const Vec3& n, double radius, double length) {
  const Vec3 z = X_CT.linear().col(2), tip = X_CT.translation(), centre = tip - radius * z;
  const auto inside = [&](const Vec3& q) {
    if ((q - centre).norm() <= radius) return true;
    const double u = (tip - q).dot(z);  // axial distance from the tip
    return u >= radius && u <= length && ((q - tip) + u * z).norm() <= radius;
  };
  for (double x = 0; x < 2 * radius; x += 1e-6)
    if (inside(root + x * n)) return x;
  return 2 * radius;
}

}  // namespace

TEST(GrindPlanner, LineOnVerticalWallGivesKnownToolPoses) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindParams P = flush();
  const GrindResult r = plan_grind(robot, X_BC, wall_line(-0.1, 0.1, 0.005), P);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_EQ(r.passes, 1);
  const double rad = robot.tool.radius, dtip = robot.tool.length / 2;

  // Segments: approach in the air, plunge through the fin, one pass, retract, joined at shared
  // samples.
  ASSERT_EQ(r.segments.size(), 4u);
  EXPECT_EQ(r.segments[0].kind, SampleKind::kApproach);
  EXPECT_EQ(r.segments[1].kind, SampleKind::kApproach);
  EXPECT_EQ(r.segments[2].kind, SampleKind::kCut);
  EXPECT_EQ(r.segments[3].kind, SampleKind::kRetract);
  EXPECT_DOUBLE_EQ(r.segments[0].feed, P.approach_feed);
  EXPECT_DOUBLE_EQ(r.segments[1].feed, P.plunge_feed);
  EXPECT_DOUBLE_EQ(r.segments[2].feed, P.feed);
  for (std::size_t k = 1; k < 4; ++k)
    EXPECT_EQ(r.segments[k - 1].last_sample, r.segments[k].first_sample) << k;
  EXPECT_EQ(r.segments[3].last_sample, r.samples.size() - 1);
  {
    // The plunge starts at most tip depth + 2 mm (one sample spacing of slack) above the cut
    // start, i.e. before the tip reaches the fin plane, and the air part stays above it.
    const Vec3 start = r.samples[r.segments[2].first_sample].X_CT.translation();
    const double plunge = (r.samples[r.segments[1].first_sample].X_CT.translation() - start).norm();
    EXPECT_LE(plunge, dtip + 0.002 + 1e-12);
    EXPECT_GT(plunge, dtip);
  }
  const std::size_t c0 = r.segments[2].first_sample, c1 = r.segments[2].last_sample;
  // 200 mm at 0.5 mm, plus the straight run-out of P.overrun (2 mm) past each end.
  ASSERT_DOUBLE_EQ(P.overrun, 0.002);
  EXPECT_EQ(c1 - c0, 408u);

  for (std::size_t i = c0; i <= c1; ++i) {
    const GrindSample& s = r.samples[i];
    // Axis along −fin normal, axis r off the wall, tip d_tip below the fin mid-plane.
    EXPECT_LT((s.X_CT.linear().col(2) - Vec3(0, 0, -1)).norm(), 1e-12) << i;
    EXPECT_NEAR(s.X_CT.translation().x(), -rad, 1e-12) << i;
    EXPECT_NEAR(s.X_CT.translation().z(), -dtip, 1e-12) << i;
    EXPECT_NEAR(s.X_CT.translation().y(), -0.102 + 0.0005 * static_cast<double>(i - c0), 1e-9);
    EXPECT_NEAR(s.axis_offset, rad, 1e-12);
    EXPECT_EQ(s.kind, SampleKind::kCut);
    const Pose X = X_BC * s.X_CT;
    EXPECT_LT((X.matrix() - s.X_BT.matrix()).norm(), 1e-12);
    EXPECT_EQ(s.extra_lead, 0.0);
    EXPECT_EQ(s.extra_tilt, 0.0);
    // The nearest input point (ties halfway between two points go either way).
    EXPECT_LE(std::abs(-0.1 + 0.005 * s.path_index - s.X_CT.translation().y()), 0.0025 + 1e-12);
  }
  // Approach from 30 mm straight above the start along the fin normal; retract likewise.
  const Vec3 start = r.samples[c0].X_CT.translation(), end = r.samples[c1].X_CT.translation();
  EXPECT_LT((r.samples.front().X_CT.translation() - (start + 0.03 * kUp)).norm(), 1e-12);
  EXPECT_LT((r.samples.back().X_CT.translation() - (end + 0.03 * kUp)).norm(), 1e-12);
  for (std::size_t i = 0; i < c0; ++i) {
    const Vec3 d = r.samples[i].X_CT.translation() - start;
    EXPECT_LT(d.head<2>().norm(), 1e-12);
    EXPECT_GT(d.z(), 0);
  }
  EXPECT_NEAR(r.path_length, 0.204 + 2 * 0.03, 1e-9);
  EXPECT_NEAR(r.cut_length, 0.204, 1e-9);

  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
  EXPECT_GE(r.min_manipulability, P.manipulability_threshold);
  EXPECT_TRUE(r.reoriented_ranges.empty());

  // The executed TCP (FK of q(t)) stays on the planned line while cutting.
  double max_dev = 0;
  for (std::size_t n = r.segments[2].first_step; n <= r.segments[2].last_step; ++n) {
    const Vec3 p = r.tcp_B[n].translation();
    max_dev = std::max(max_dev, std::hypot(p.x() - (0.7 - rad), p.z() - (-0.15 - dtip)));
  }
  EXPECT_LT(max_dev, 1e-5);
  // The feed: cutting at `feed`, approaching at `approach_feed` (both reached, never exceeded).
  double cut_max = 0, app_max = 0;
  for (std::size_t n = r.segments[2].first_step; n <= r.segments[2].last_step; ++n)
    cut_max = std::max(cut_max, r.trajectory.sdot[n]);
  for (std::size_t n = r.segments[0].first_step; n <= r.segments[0].last_step; ++n)
    app_max = std::max(app_max, r.trajectory.sdot[n]);
  double plunge_max = 0;
  for (std::size_t n = r.segments[1].first_step; n <= r.segments[1].last_step; ++n)
    plunge_max = std::max(plunge_max, r.trajectory.sdot[n]);
  EXPECT_NEAR(cut_max, P.feed, 1e-3 * P.feed);
  EXPECT_NEAR(app_max, P.approach_feed, 1e-3 * P.approach_feed);
  EXPECT_NEAR(plunge_max, P.plunge_feed, 1e-3 * P.plunge_feed);
  EXPECT_GT(r.total_time, 0.2 / P.feed);
}

TEST(GrindPlanner, ClosedCircleAroundHole) {
  const RobotModel robot = ftest::ft6();
  Pose X_BC = translation(Vec3(0.7, 0.05, -0.15));
  X_BC.linear() = Eigen::AngleAxisd(0.5, Vec3::UnitZ()).toRotationMatrix();
  const double R = 0.03;
  GrindParams P = flush();
  const GrindResult r = plan_grind(robot, X_BC, hole_circle(R, 72), P);
  ASSERT_TRUE(r.ok()) << r.message;
  const double rad = robot.tool.radius, dtip = robot.tool.length / 2;
  ASSERT_EQ(r.segments.size(), 4u);
  const std::size_t c0 = r.segments[2].first_sample, c1 = r.segments[2].last_sample;
  // 2πR at 0.5 mm (the interpolated loop is a hair shorter than the circle).
  EXPECT_NEAR(static_cast<double>(c1 - c0), 2 * M_PI * R / 0.0005, 1.0);
  double max_err = 0;
  for (std::size_t i = c0; i <= c1; ++i) {
    const GrindSample& s = r.samples[i];
    const Vec3 tip = s.X_CT.translation();
    // Axis parallel to the hole axis, r inside the hole wall, tip d_tip below the fin.
    EXPECT_LT((s.X_CT.linear().col(2) - Vec3(0, 0, -1)).norm(), 1e-12);
    max_err = std::max(max_err, std::abs(tip.head<2>().norm() - (R - rad)));
    EXPECT_NEAR(tip.z(), -dtip, 1e-12);
    EXPECT_TRUE((X_BC * s.X_CT).matrix().isApprox(s.X_BT.matrix(), 1e-12));
  }
  EXPECT_LT(max_err, 1e-5);
  // The loop closes: the pass ends where it started, having gone once around.
  EXPECT_LT((r.samples[c0].X_CT.translation() - r.samples[c1].X_CT.translation()).norm(), 1e-9);
  EXPECT_NEAR(r.cut_length, 2 * M_PI * (R - rad), 1e-4);
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
}

namespace {

// A hole of radius R drawn as a CAD mesh draws it: a polygon of `facets` flat facets (corners on
// the circle, `inward` their normals), `per_facet` root points along each with its facet's normal.
GrindPath faceted_hole(double R, int facets, int per_facet, std::vector<Vec3>& corner,
                       std::vector<Vec3>& inward) {
  GrindPath hole;
  hole.closed = true;
  hole.fin_normal_C = kUp;
  corner.assign(static_cast<std::size_t>(facets), Vec3::Zero());
  inward = corner;
  for (int k = 0; k < facets; ++k) {
    const double a = 2 * M_PI * k / facets, mid = 2 * M_PI * (k + 0.5) / facets;
    corner[k] = Vec3(R * std::cos(a), R * std::sin(a), 0);
    inward[k] = -Vec3(std::cos(mid), std::sin(mid), 0);
  }
  for (int k = 0; k < facets; ++k)
    for (int i = 0; i < per_facet; ++i) {
      const double w = (i + 0.5) / per_facet;
      hole.points_C.push_back((1 - w) * corner[k] + w * corner[(k + 1) % facets]);
      hole.normals_C.push_back(inward[k]);
    }
  return hole;
}

}  // namespace

// A hole drawn as the CAD draws it: a polygon of 24 flat facets (vertices on a 30 mm circle),
// root points along the facets with the facets' normals. A burr laid against one facet near a
// corner would cross the next one's plane by up to r·(1 − cos 15°) ≈ 0.2 mm; the plan keeps the
// burr's axis at least r from every facet plane, and within r·(1/cos 7.5° − 1) ≈ 0.05 mm (and
// some) of touching the nearest one.
TEST(GrindPlanner, BurrStaysOutOfAPolygonalHolesFacets) {
  const RobotModel robot = ftest::ft6();
  Pose X_BC = translation(Vec3(0.7, 0.05, -0.15));
  X_BC.linear() = Eigen::AngleAxisd(0.5, Vec3::UnitZ()).toRotationMatrix();
  const int facets = 24;
  std::vector<Vec3> corner, inward;
  const GrindPath hole = faceted_hole(0.03, facets, 8, corner, inward);
  const GrindResult r = plan_grind(robot, X_BC, hole, flush());
  ASSERT_TRUE(r.ok()) << r.message;
  const double rad = robot.tool.radius;
  double worst_in = -1, worst_off = 0;
  std::size_t cut = 0;
  for (const GrindSample& s : r.samples) {
    if (s.kind != SampleKind::kCut || s.pass != r.passes - 1) continue;
    ++cut;
    const Vec3 axis = s.X_CT.translation();
    double nearest = 1e300;
    for (int k = 0; k < facets; ++k) nearest = std::min(nearest, (axis - corner[k]).dot(inward[k]));
    worst_in = std::max(worst_in, rad - nearest);    // > 0: into a facet's plane
    worst_off = std::max(worst_off, nearest - rad);  // stand-off from the nearest facet
  }
  ASSERT_GT(cut, 100u);
  // Unguarded: ~0.2 mm. The samples come off a spline through the shifted points: µm left.
  EXPECT_LT(worst_in, 0.02e-3);
  EXPECT_LT(worst_off, rad * (1 / std::cos(M_PI / facets) - 1) + 0.02e-3);
  std::printf("24-facet hole: burr axis at most %.4f mm into a facet plane, at most %.3f mm off "
              "the nearest\n", worst_in * 1e3, worst_off * 1e3);
}

// The same kind of hole, coarser: 16 facets of a 24 mm circle (as a CAD export draws a small
// bore), each turning the wall normal by 22.5°. The burr's axis stands r + e off the wall along the normal, so with the facets'
// normals as they are it would step back by (r + e)·0.39 ≈ 2.5 mm at every facet edge, more than
// the root advances there: the tool would stop and turn on the spot, and the joint-space spline
// through those poses rings. The wall the facets approximate turns smoothly, and so does the
// burr: along the finishing pass its axis goes round the hole's centre steadily (each sample's
// angular step within 0.3–3× the mean, none backwards) and the wrist turns by no more than 3×
// its mean step between samples.
TEST(GrindPlanner, BurrGoesRoundAFacetedHoleSteadily) {
  const RobotModel robot = ftest::ft6();
  Pose X_BC = translation(Vec3(0.7, 0.05, -0.15));
  X_BC.linear() = Eigen::AngleAxisd(0.5, Vec3::UnitZ()).toRotationMatrix();
  std::vector<Vec3> corner, inward;
  const GrindPath hole = faceted_hole(0.024, 16, 10, corner, inward);
  const GrindResult r = plan_grind(robot, X_BC, hole, flush());
  ASSERT_TRUE(r.ok()) << r.message;
  std::vector<double> step, wrist;
  const GrindSample* prev = nullptr;
  for (const GrindSample& s : r.samples) {
    if (s.kind != SampleKind::kCut || s.pass != r.passes - 1) continue;
    if (prev) {
      const Vec3 a = prev->X_CT.translation(), b = s.X_CT.translation();
      step.push_back(std::atan2(a.x() * b.y() - a.y() * b.x(), a.x() * b.x() + a.y() * b.y()));
      wrist.push_back((s.q - prev->q).tail<3>().cwiseAbs().maxCoeff());
    }
    prev = &s;
  }
  ASSERT_GT(step.size(), 100u);
  double mean = 0, wrist_mean = 0;
  for (std::size_t i = 0; i < step.size(); ++i) {
    mean += step[i] / static_cast<double>(step.size());
    wrist_mean += wrist[i] / static_cast<double>(wrist.size());
  }
  const double sign = mean > 0 ? 1 : -1;
  double lo = 1e300, hi = 0, wrist_max = 0;
  for (std::size_t i = 0; i < step.size(); ++i) {
    lo = std::min(lo, sign * step[i] / std::abs(mean));
    hi = std::max(hi, sign * step[i] / std::abs(mean));
    wrist_max = std::max(wrist_max, wrist[i]);
  }
  EXPECT_GT(lo, 0.3);
  EXPECT_LT(hi, 3.0);
  EXPECT_LT(wrist_max, 3 * wrist_mean);
  std::printf("16-facet hole: axis step %.2f-%.2f x its mean, wrist step at most %.2f x its mean\n",
              lo, hi, wrist_max / wrist_mean);
  expect_trajectory_sound(robot, r);
}

// The planner eases a clearance in and out along a path (a hole's facets and its root points'
// scatter ask for one that jumps from sample to sample): the upper envelope with a bounded slope
// is never below the values, changes by at most the slope × the length between neighbours, and
// is the smallest such (each point's value is one carried down the slope from some point, the
// shorter way round a closed path), checked against the definition by brute force.
TEST(GrindPlanner, UpperEnvelopeAlongAPathIsTheSmallestWithBoundedSlope) {
  unsigned state = 12345u;
  const auto uniform = [&] {  // deterministic, uniform in [0, 1)
    state = state * 1664525u + 1013904223u;
    return static_cast<double>(state >> 8) / 16777216.0;
  };
  for (const bool closed : {false, true}) {
    // 90 points round a 20 mm circle at irregular angles, sparse spikes up to 0.3 mm between.
    const std::size_t n = 90;
    std::vector<Vec3> points;
    std::vector<double> v, e, at;  // at: length along the polyline from the first point
    double angle = 0;
    for (std::size_t k = 0; k < n; ++k) {
      angle += 2 * M_PI / n * (0.5 + uniform());
      points.push_back(0.02 * Vec3(std::cos(angle), std::sin(angle), 0));
      at.push_back(k ? at.back() + (points[k] - points[k - 1]).norm() : 0.0);
      v.push_back(uniform() < 0.1 ? 0.3e-3 * uniform() : 0.0);
    }
    const double total = at.back() + (points.front() - points.back()).norm();
    e = v;
    const double slope = 0.1;
    upper_envelope_along(e, points, slope, closed);
    for (std::size_t k = 0; k < n; ++k) {
      double expect = v[k];
      for (std::size_t j = 0; j < n; ++j) {
        double d = std::abs(at[k] - at[j]);
        if (closed) d = std::min(d, total - d);
        expect = std::max(expect, v[j] - slope * d);
      }
      EXPECT_NEAR(e[k], expect, 1e-15) << (closed ? "closed" : "open") << " k=" << k;
      EXPECT_GE(e[k], v[k]);
      if (k) {
        EXPECT_LE(std::abs(e[k] - e[k - 1]), slope * (at[k] - at[k - 1]) + 1e-15);
      }
    }
  }
}

TEST(GrindPlanner, RotationAboutToolAxisCannotLeaveWristSingularityOfThisTool) {
  // Why the planner must lean the axis at a wrist singularity: with X_ET a pure offset along
  // z_E, spinning the tool about z_T leaves the wrist centre and θ5 unchanged.
  const RobotModel robot = ftest::ft6();
  Pose X = translation(Vec3(0.55, 0.15, -0.72));
  X.linear() = Vec3(1, -1, -1).asDiagonal();
  const IkResult a = ik_tool(robot, X);
  ASSERT_TRUE(a.ok());
  for (double spin : {0.3, 1.0, 2.5}) {
    Pose Y = X;
    Y.linear() = X.linear() * Eigen::AngleAxisd(spin, Vec3::UnitZ()).toRotationMatrix();
    const IkResult b = ik_tool(robot, Y);
    ASSERT_EQ(a.solutions.size(), b.solutions.size());
    for (std::size_t k = 0; k < a.solutions.size(); ++k) {
      EXPECT_NEAR(manipulability(robot, a.solutions[k].q), manipulability(robot, b.solutions[k].q),
                  1e-12);
      EXPECT_NEAR(a.solutions[k].q[4], b.solutions[k].q[4], 1e-9);
    }
  }
}

TEST(GrindPlanner, WristSingularityIsAvoidedByLeaningAndReported) {
  const RobotModel robot = ftest::ft6();
  // The tool tip runs along x_B at y_B = 0.15, z_B = −0.72: there the forearm of the only
  // (elbow-up) branches points straight down along the tool axis near x_B = 0.52.
  const Pose X_BC = translation(Vec3(0.5, 0.144, -0.71));
  GrindPath path;
  for (int k = 0; k <= 40; ++k) {
    path.points_C.push_back(Vec3(-0.1 + 0.005 * k, 0, 0));
    path.normals_C.push_back(Vec3(0, 1, 0));
  }
  path.fin_normal_C = kUp;
  GrindParams P = flush();
  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;

  // The nominal poses (no re-orientation) pass the singularity on this branch.
  const double rad = robot.tool.radius, len = robot.tool.length, dtip = len / 2;
  std::vector<int> singular_points;
  double nominal_min = 1;
  for (std::size_t k = 0; k < path.points_C.size(); ++k) {
    const Pose X = X_BC * grind_tool_pose(path.points_C[k], Vec3(0, 1, 0), Vec3(1, 0, 0), kUp,
                                          Vec3(1, 0, 0), 0, 0, 0, r.base_spin, rad, len, dtip);
    const IkResult ik = ik_tool(robot, X);
    for (const auto& sol : ik.solutions)
      if (sol.branch.index() == r.branch.index()) {
        const double m = manipulability(robot, sol.q);
        nominal_min = std::min(nominal_min, m);
        if (m < P.manipulability_threshold) singular_points.push_back(static_cast<int>(k));
      }
  }
  ASSERT_LT(nominal_min, 0.2 * P.manipulability_threshold) << "test path misses the singularity";
  ASSERT_FALSE(singular_points.empty());

  // Reported: every nominally singular point lies in a re-oriented range of reason singular.
  ASSERT_FALSE(r.reoriented_ranges.empty());
  for (int k : singular_points) {
    bool covered = false;
    for (const auto& rr : r.reoriented_ranges)
      covered |= rr.reason == ReorientReason::kSingular && rr.first_path_index <= k &&
                 k <= rr.last_path_index;
    EXPECT_TRUE(covered) << "path index " << k;
  }
  for (const auto& rr : r.reoriented_ranges) {
    const double lean = std::hypot(rr.extra_lead, rr.extra_tilt);
    EXPECT_GT(lean, 0);
    EXPECT_LE(lean, P.max_extra_tilt + 1e-12);
    EXPECT_LT(rr.nominal_min_manipulability, P.manipulability_threshold);
    EXPECT_GE(rr.min_manipulability, P.manipulability_threshold);
    EXPECT_LE(rr.first_sample, rr.last_sample);
  }
  // Fixed everywhere, within the allowed lean, without gouging the wall.
  EXPECT_GE(r.min_manipulability, P.manipulability_threshold);
  for (const GrindSample& s : r.samples) {
    EXPECT_GE(s.manipulability, P.manipulability_threshold);
    const double lean = std::acos(std::clamp(-s.X_CT.linear().col(2).dot(kUp), -1.0, 1.0));
    EXPECT_LE(lean, P.max_extra_tilt + 1e-9);
    if (s.kind == SampleKind::kCut) {
      EXPECT_NEAR(wall_clearance(s.X_CT, Vec3(0, 0, 0), Vec3(0, 1, 0), rad, len), 0.0, 1e-12);
    }
  }
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
  // No wrist flip: θ5 keeps its sign and stays away from zero over the whole trajectory.
  double min_abs_q5 = 10;
  for (const Vector6& q : r.trajectory.q) {
    EXPECT_EQ(std::signbit(q[4]), std::signbit(r.trajectory.q.front()[4]));
    min_abs_q5 = std::min(min_abs_q5, std::abs(q[4]));
  }
  EXPECT_GT(min_abs_q5, 0.05);
}

// The parting-line fin round a dome (cover seed 9005's, as detection found it): the wall slopes
// 52° off the vertical, and the shank, lying on the wall up its slope, points away from the
// arm on the side facing it, so the wrist bends toward a joint limit there. Leans within
// max_extra_tilt do not free it; a lead alone (the shank turned along the wall, the burr still
// flush) does, and it stays put on the casting when the next pass comes back along the path.
TEST(GrindPlanner, WristAtItsLimitRoundADomeIsFreedByALeadThatStaysOnTheCasting) {
  const RobotModel robot = ftest::ft6();
  Pose X_BC = translation(Vec3(0.71, 0, -0.17));
  X_BC.linear() = Eigen::AngleAxisd(0.3, Vec3::UnitZ()).toRotationMatrix();
  GrindPath path;
  const double R = 0.0357, a0 = -129.8 * M_PI / 180, a1 = 24.4 * M_PI / 180;
  const int n = 250;
  for (int k = 0; k <= n; ++k) {
    const double a = a0 + (a1 - a0) * k / n;
    path.points_C.push_back(Vec3(0.0191 + R * std::cos(a), R * std::sin(a), 0.0447));
    path.normals_C.push_back(Vec3(0.787 * std::cos(a), 0.787 * std::sin(a), 0.617).normalized());
  }
  path.fin_normal_C = kUp;
  path.fin_height = 0.0043;

  // A lean allowance below what this path needs (0.2 rad of lead at its end) and leads alone
  // allowed past it.
  GrindParams P;
  P.max_extra_tilt = 0.13;
  GrindParams tilt_sized = P;
  tilt_sized.max_extra_lead = P.max_extra_tilt;
  {
    const GrindResult t = plan_grind(robot, X_BC, path, tilt_sized);
    bool flush = t.ok();
    for (const auto& rr : t.reoriented_ranges) flush = flush && rr.extra_tilt == 0;
    EXPECT_FALSE(flush) << "the test path no longer needs more than a tilt-sized lean";
  }

  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_GE(r.passes, 2);
  double most_lead = 0;
  for (const auto& rr : r.reoriented_ranges) {
    EXPECT_EQ(rr.extra_tilt, 0.0) << "a tilt leaves a wedge of flash";
    most_lead = std::max(most_lead, std::abs(rr.extra_lead));
  }
  EXPECT_GT(most_lead, P.max_extra_tilt);
  EXPECT_LE(most_lead, P.max_extra_lead + 1e-12);
  // Where a pass turns round at the path's end the burr keeps its axis: the lead is a place on
  // the casting, not a direction of travel (as one toward the travel it flipped there, by
  // twice the lead). The burr stays on the wall (a lead keeps its side flush).
  const double rad = robot.tool.radius, len = robot.tool.length;
  for (std::size_t i = 1; i < r.samples.size(); ++i) {
    const GrindSample& a = r.samples[i - 1];
    const GrindSample& b = r.samples[i];
    const double turn = std::acos(std::clamp(
        a.X_CT.linear().col(2).dot(b.X_CT.linear().col(2)), -1.0, 1.0));
    EXPECT_LT(turn, 0.1) << "sample " << i;  // a fade turns it by at most ~0.05
    if (b.kind == SampleKind::kCut) {
      EXPECT_EQ(b.extra_tilt, 0.0);
      const auto k = static_cast<std::size_t>(b.path_index);
      EXPECT_GT(wall_clearance(b.X_CT, path.points_C[k], path.normals_C[k], rad, len), -0.1e-3)
          << "sample " << i;
    }
  }
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
}

TEST(GrindPlanner, JointLimitIsAvoidedByRotationAboutToolAxis) {
  RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  const GrindPath path = wall_line(-0.15, 0.15, 0.005);
  GrindParams P = flush();
  P.spin_candidates = 1;
  const GrindResult free_run = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(free_run.ok()) << free_run.message;
  // Joint 6 counter-rotates joint 1 along the line; narrow its range so the last 40 % of the
  // line would need it beyond the upper (or lower) limit.
  const double a = free_run.samples.front().q[5], b = free_run.samples.back().q[5];
  const double delta = b - a;
  ASSERT_GT(std::abs(delta), 0.3);
  JointLimits& L6 = robot.limits[5];
  // Room for the smallest spin step (30°) on the other side.
  L6.lower = delta > 0 ? a - 0.4 : a + 0.6 * delta;
  L6.upper = delta > 0 ? a + 0.6 * delta : a + 0.4;
  P.branch_mask = 1u << free_run.branch.index();
  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.reoriented_ranges.size(), 1u);
  const ReorientedRange& rr = r.reoriented_ranges[0];
  EXPECT_EQ(rr.reason, ReorientReason::kJointLimit);
  EXPECT_NE(rr.extra_spin, 0.0);  // the free rotation, no lean
  EXPECT_EQ(rr.extra_lead, 0.0);
  EXPECT_EQ(rr.extra_tilt, 0.0);
  EXPECT_EQ(rr.last_sample, r.samples.size() - 1);  // to the end of the retract
  // Tool axis untouched: still along −fin normal, still flush with the wall.
  for (const GrindSample& s : r.samples) {
    EXPECT_LT((s.X_CT.linear().col(2) - Vec3(0, 0, -1)).norm(), 1e-12);
    EXPECT_NEAR(s.axis_offset, robot.tool.radius, 1e-12);
  }
  EXPECT_NEAR(r.samples.back().q[5], b + rr.extra_spin, 1e-6);
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
}

TEST(GrindPlanner, PathPartlyOutOfReachFailsAtFirstBadIndex) {
  const RobotModel robot = ftest::ft6();
  // The root runs along x_B from 0.7 to 1.3 m from the base, beyond the ~1.0 m reach.
  const Pose X_BC = translation(Vec3(0, 0.1, -0.15));
  GrindPath path;
  for (int k = 0; k <= 60; ++k) {
    path.points_C.push_back(Vec3(0.7 + 0.01 * k, 0, 0));
    path.normals_C.push_back(Vec3(0, -1, 0));
  }
  path.fin_normal_C = kUp;
  const GrindResult r = plan_grind(robot, X_BC, path);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status, GrindStatus::kUnreachable);
  ASSERT_GE(r.failed_sample, 0);
  ASSERT_LT(r.failed_sample, static_cast<int>(r.samples.size()));
  const GrindSample& bad = r.samples[static_cast<std::size_t>(r.failed_sample)];
  EXPECT_EQ(bad.kind, SampleKind::kCut);
  EXPECT_EQ(r.failed_pass, 0);
  // Independently: the first sample whose pose has no IK solution at all.
  int first_unreachable = -1;
  for (std::size_t i = 0; i < r.samples.size() && first_unreachable < 0; ++i) {
    IkParams ip;
    ip.within_limits_only = false;
    if (ik_tool(robot, r.samples[i].X_BT, ip).solutions.empty())
      first_unreachable = static_cast<int>(i);
  }
  EXPECT_EQ(r.failed_sample, first_unreachable);
  // Its path index is the input point nearest to it (points every 10 mm along x).
  const double x = bad.X_CT.translation().x();
  EXPECT_EQ(r.failed_path_index, static_cast<int>(std::lround((x - 0.7) / 0.01)));
  EXPECT_GT(r.failed_path_index, 20);
  EXPECT_LT(r.failed_path_index, 40);
  // The wrist centre there is at the edge of the reach (a2 + √(a3² + d4²) ≈ 1.0004 m).
  const Vec3 wc = (bad.X_BT * robot.tool.X_ET.inverse()).translation();
  EXPECT_NEAR(std::hypot(std::hypot(wc.x(), wc.y()), wc.z()), 1.0, 0.02);
  EXPECT_NE(r.message.find("path index " + std::to_string(r.failed_path_index)), std::string::npos)
      << r.message;
  EXPECT_NE(r.message.find("unreachable"), std::string::npos) << r.message;
  EXPECT_TRUE(r.trajectory.t.empty());
}

TEST(GrindPlanner, StockAllowanceKeepsTheBurrOffTheWall) {
  // By default the last pass runs flush against the wall; a stock allowance of 30 µm puts the
  // burr axis r + 0.03 mm off it.
  const RobotModel robot = ftest::ft6();
  EXPECT_EQ(GrindParams{}.stock_allowance, 0.0);
  GrindParams P;
  P.stock_allowance = 0.03e-3;
  const GrindResult r =
      plan_grind(robot, translation(Vec3(0.7, 0, -0.15)), wall_line(-0.02, 0.02, 0.005), P);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.pass_offsets.size(), 1u);
  EXPECT_DOUBLE_EQ(r.pass_offsets[0], 0.03e-3);
  for (const auto& s : r.samples)
    if (s.kind == SampleKind::kCut) {
      EXPECT_NEAR(s.X_CT.translation().x(), -(robot.tool.radius + 0.03e-3), 1e-12);
    }
}

TEST(GrindPlanner, BurrLeansWithASlopedWall) {
  // The wall line of the first test on a wall sloping 30° off the vertical (its normal turned
  // up by 30°, as a dome's below its apex): on the finishing pass the burr's side lies on the
  // wall (axis square to the wall normal, r off the wall plane, no part of the cutting length
  // inside it). Upright, as for a vertical wall, its tip would stand 0.5 d_tip·sin 30° inside.
  const RobotModel robot = ftest::ft6();
  GrindPath path = wall_line(-0.02, 0.02, 0.005);
  const double beta = M_PI / 6;
  const Vec3 n_wall(-std::cos(beta), 0, std::sin(beta));
  for (auto& n : path.normals_C) n = n_wall;
  const GrindParams P = flush();
  const GrindResult r = plan_grind(robot, translation(Vec3(0.7, 0, -0.15)), path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  const double rad = robot.tool.radius, len = robot.tool.length;
  std::size_t cuts = 0;
  for (const auto& s : r.samples) {
    if (s.kind != SampleKind::kCut) continue;
    ++cuts;
    EXPECT_NEAR(s.X_CT.linear().col(2).dot(n_wall), 0.0, 1e-9);
    EXPECT_NEAR(wall_clearance(s.X_CT, Vec3::Zero(), n_wall, rad, len), 0.0, 1e-9);
  }
  EXPECT_GT(cuts, 80u);
}

TEST(GrindPlanner, HoleNarrowerThanTheBurrIsRefused) {
  // The burr (radius r) cannot follow a hole of radius r + 0.1 mm, whether its loop is whole
  // or only a 120° arc of it was seen; a hole of radius r + 1 mm is planned.
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  const double r = robot.tool.radius;
  const GrindResult closed = plan_grind(robot, X_BC, hole_circle(r + 1e-4, 60));
  EXPECT_EQ(closed.status, GrindStatus::kToolTooLarge) << closed.message;
  GrindPath arc = hole_circle(r + 1e-4, 60);
  arc.closed = false;
  arc.points_C.resize(21);
  arc.normals_C.resize(21);
  const GrindResult open = plan_grind(robot, X_BC, arc);
  EXPECT_EQ(open.status, GrindStatus::kToolTooLarge) << open.message;
  EXPECT_NE(open.message.find("circle through the arc"), std::string::npos) << open.message;
  GrindPath wide = hole_circle(r + 1e-3, 60);
  wide.closed = false;
  wide.points_C.resize(21);
  wide.normals_C.resize(21);
  const GrindResult w = plan_grind(robot, X_BC, wide);
  EXPECT_TRUE(w.ok()) << w.message;
  // The hole's radius is reported (the caller's rack choice reads it); a straight wall: none.
  EXPECT_NEAR(closed.hole_radius, r + 1e-4, 1e-5);
  EXPECT_NEAR(w.hole_radius, r + 1e-3, 1e-5);
  EXPECT_EQ(plan_grind(robot, X_BC, wall_line(-0.05, 0.05, 0.005), flush()).hole_radius, 0.0);
}

TEST(GrindPlanner, LeadInAndOutKeepTheBurrOffTheWallWhileItPlungesAndLifts) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindParams P = flush();
  P.lead_clearance = 0.5e-3;
  const GrindResult r = plan_grind(robot, X_BC, wall_line(-0.05, 0.05, 0.005), P);
  ASSERT_TRUE(r.ok()) << r.message;
  const double rad = robot.tool.radius;
  // approach (air), plunge, lead-in, pass, lead-out, lift: joined at shared samples.
  ASSERT_EQ(r.segments.size(), 6u);
  const SampleKind kinds[6] = {SampleKind::kApproach, SampleKind::kApproach, SampleKind::kApproach,
                               SampleKind::kCut,      SampleKind::kRetract,  SampleKind::kRetract};
  for (std::size_t k = 0; k < 6; ++k) {
    EXPECT_EQ(r.segments[k].kind, kinds[k]) << k;
    if (k > 0) {
      EXPECT_EQ(r.segments[k - 1].last_sample, r.segments[k].first_sample) << k;
    }
  }
  EXPECT_EQ(r.segments[2].feed, P.feed);
  EXPECT_EQ(r.segments[4].feed, P.feed);
  // Descent and lift 0.5 mm off the wall offset (the wall is x = 0, the tool on x < 0).
  for (std::size_t i = 0; i <= r.segments[1].last_sample; ++i)
    EXPECT_NEAR(-r.samples[i].X_CT.translation().x(), rad + 0.5e-3, 1e-12) << i;
  for (std::size_t i = r.segments[5].first_sample; i < r.samples.size(); ++i)
    EXPECT_NEAR(-r.samples[i].X_CT.translation().x(), rad + 0.5e-3, 1e-12) << i;
  // The lead-in and lead-out are radial: along the wall normal at the pass's ends.
  const Vec3 in = r.samples[r.segments[2].last_sample].X_CT.translation() -
                  r.samples[r.segments[2].first_sample].X_CT.translation();
  EXPECT_LT((in - Vec3(0.5e-3, 0, 0)).norm(), 1e-12);
  const Vec3 out = r.samples[r.segments[4].last_sample].X_CT.translation() -
                   r.samples[r.segments[4].first_sample].X_CT.translation();
  EXPECT_LT((out + Vec3(0.5e-3, 0, 0)).norm(), 1e-12);
  for (std::size_t i = r.segments[3].first_sample; i <= r.segments[3].last_sample; ++i)
    EXPECT_NEAR(-r.samples[i].X_CT.translation().x(), rad, 1e-12) << i;
  expect_trajectory_sound(robot, r);
  // A hole 0.3 mm wider than the burr leaves no room to step in: the burr would ream the fin
  // ring in one plunge along the wall, so a smaller burr is asked for.
  const GrindResult h = plan_grind(robot, X_BC, hole_circle(rad + 0.3e-3, 72), P);
  EXPECT_EQ(h.status, GrindStatus::kToolTooLarge) << h.message;
  // A 4 mm ring fin in a hole 0.6 mm wider than the burr: the roughing pass takes all the room
  // (the burr's axis on the hole's centre, no lead-in); the finishing pass runs flush, and the
  // lead-out steps off the whole lead clearance before the retract lifts.
  GrindPath ring = hole_circle(rad + 0.6e-3, 72);
  ring.fin_height = 0.004;
  const GrindResult f = plan_grind(robot, X_BC, ring, P);
  ASSERT_TRUE(f.ok()) << f.message;
  ASSERT_EQ(f.passes, 2);
  EXPECT_NEAR(f.samples.front().axis_offset, rad + 0.6e-3, 1e-12);
  EXPECT_EQ(f.segments.back().kind, SampleKind::kRetract);
  for (std::size_t i = f.segments.back().first_sample; i < f.samples.size(); ++i)
    EXPECT_NEAR(f.samples[i].axis_offset, rad + P.lead_clearance, 1e-12) << i;
}

// Timing bounds joint velocities and accelerations only; with the arm's dynamics given, a
// motion that would ask a joint more than torque_factor of its torque limit is timed again more
// slowly (tilted 8032: a lift swung the shoulder at its acceleration limit, asked 400 N·m of
// 400, the servo saturated and the burr fell 10 mm into the table). Here a synthetic arm whose
// most accelerated joint needs τ = g + c·q̈, c set so the plan timed without it asks twice the
// dynamic budget.
TEST(GrindPlanner, TimedMotionKeepsWithinTheJointTorques) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindParams P = flush();
  P.lead_clearance = 0.5e-3;
  P.approach_distance = 0.05;  // long, fast moves in the air, quick ramps
  P.approach_feed = 1.0;
  P.timing.max_path_accel = 5.0;
  P.timing.max_path_jerk = 200.0;
  const GrindPath path = wall_line(-0.05, 0.05, 0.005);
  const GrindResult fast = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(fast.ok()) << fast.message;
  int j = 0;
  double peak = 0;  // the largest |q̈_j| / limit of any joint
  for (const Vector6& a : fast.trajectory.ddq)
    for (int i = 0; i < 6; ++i)
      if (std::abs(a[i]) / robot.limits[i].acceleration > peak) peak = std::abs(a[i]) / robot.limits[i].acceleration, j = i;
  ASSERT_GT(peak, 0.3) << "the test needs a motion that accelerates a joint";
  const double budget = P.torque_factor * robot.limits[j].torque, g = 0.3 * budget;
  const double c = 2 * (budget - g) / (peak * robot.limits[j].acceleration);
  int calls = 0;
  P.torque = [&](const Vector6&, const Vector6&, const Vector6& ddq) {
    ++calls;
    Vector6 tau = Vector6::Zero();
    tau[j] = g + c * ddq[j];
    return tau;
  };
  const GrindResult slow = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(slow.ok()) << slow.message;
  EXPECT_GT(calls, 0);
  double asked = 0;
  for (const Vector6& a : slow.trajectory.ddq) asked = std::max(asked, std::abs(g + c * a[j]));
  EXPECT_LE(asked, budget * (1 + 1e-6)) << "joint " << j + 1;
  EXPECT_GT(asked, 0.8 * budget) << "slowed more than needed";
  EXPECT_GT(slow.total_time, fast.total_time);
  // The same path, only slower: the same samples, a sound trajectory.
  ASSERT_EQ(slow.samples.size(), fast.samples.size());
  for (std::size_t i = 0; i < slow.samples.size(); ++i)
    ASSERT_LT((slow.samples[i].q - fast.samples[i].q).norm(), 1e-12) << i;
  expect_trajectory_sound(robot, slow);
}

TEST(GrindPlanner, PassesInAHoleStopAtItsCentre) {
  // A ring fin 8 mm high in a hole of radius r + 3.5 mm: past an axis offset of 3.5 mm the
  // burr's axis would cross the hole's centre, so the passes take 3.5 mm: two roughing passes
  // of 1.6 mm down to the finishing depth, then the finishing pass.
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  const double r = robot.tool.radius;
  GrindParams P;
  GrindPath ring = hole_circle(r + 3.5e-3, 72);
  ring.fin_height = 0.008;
  const GrindResult g = plan_grind(robot, X_BC, ring, P);
  ASSERT_TRUE(g.ok()) << g.message;
  ASSERT_EQ(g.passes, 3);
  EXPECT_NEAR(g.pass_offsets[0], P.stock_allowance + P.finish_depth + 1.6e-3, 1e-12);
  EXPECT_NEAR(g.pass_offsets[1], P.stock_allowance + P.finish_depth, 1e-12);
  EXPECT_EQ(g.pass_offsets[2], P.stock_allowance);
  // The feed is the contact's on the wall: the tool centre, on a circle of radius R − r − e,
  // moves slower by (R − r − e)/(R − e), and the timed TCP speed along the pass follows it.
  const double R = r + 3.5e-3;
  for (const GrindSegment& sg : g.segments) {
    if (sg.kind != SampleKind::kCut) continue;
    const double e = g.pass_offsets[static_cast<std::size_t>(sg.pass)];
    const double base = sg.pass + 1 < g.passes ? P.roughing_feed : P.feed;
    EXPECT_NEAR(sg.feed, base * (R - r - e) / (R - e), 1e-12) << sg.pass;
    double vmax = 0;
    for (std::size_t k = sg.first_step; k <= sg.last_step; ++k)
      vmax = std::max(vmax, g.trajectory.sdot[k]);
    EXPECT_NEAR(vmax, sg.feed, 0.02 * sg.feed) << sg.pass;
  }
  // The same fin on a straight wall gets the full height in passes of ≤ 2 mm.
  GrindPath line = wall_line(-0.05, 0.05, 0.005);
  line.fin_height = 0.008;
  EXPECT_EQ(plan_grind(robot, X_BC, line, P).passes, 5);
}

// The casting stands on a riser (the cell's support block): a fin low in a hole over the riser
// keeps the burr floor_clearance above the riser's top (the burr slides up its axis), while a
// fin on an outer wall, whose burr hangs beside the riser, keeps its full tip depth.
TEST(GrindPlanner, BurrKeepsOffTheRiserUnderTheCastingButHangsBesideIt) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  const double r = robot.tool.radius, dtip = robot.tool.length / 2;
  ASSERT_GT(dtip, r + 2e-3);  // room to slide up by 1 mm and stay at the straight-side depth
  GrindParams P = flush();
  GrindParams::Riser riser;
  riser.X_CR = translation(Vec3(0, 0, -(dtip - 1e-3)));  // top 1 mm above the burr's tip
  riser.half = Eigen::Vector2d(0.02, 0.02);
  const auto lowest_tip = [](const GrindResult& g) {
    double z = 1e9;
    for (const GrindSample& s : g.samples)
      if (s.kind == SampleKind::kCut) z = std::min(z, s.X_CT.translation().z());
    return z;
  };
  const GrindPath ring = hole_circle(r + 3.5e-3, 72);
  const GrindResult free_ring = plan_grind(robot, X_BC, ring, P);
  ASSERT_TRUE(free_ring.ok()) << free_ring.message;
  EXPECT_NEAR(lowest_tip(free_ring), -dtip, 1e-9);  // 1 mm into the riser without it
  P.riser_C = riser;
  const GrindResult ring_on_riser = plan_grind(robot, X_BC, ring, P);
  ASSERT_TRUE(ring_on_riser.ok()) << ring_on_riser.message;
  EXPECT_NEAR(lowest_tip(ring_on_riser), -(dtip - 2e-3), 1e-9);  // floor_clearance over the top
  // The outer wall x_C = 0 with the riser 15 mm inside it (its edge at x = 15 mm, the burr at
  // x = -r): nothing under the burr, the full tip depth.
  P.riser_C->X_CR = translation(Vec3(0.035, 0, -(dtip - 1e-3)));
  const GrindResult wall = plan_grind(robot, X_BC, wall_line(-0.02, 0.02, 0.005), P);
  ASSERT_TRUE(wall.ok()) << wall.message;
  EXPECT_NEAR(lowest_tip(wall), -dtip, 1e-9);
}

TEST(GrindPlanner, RunOutIsShortenedWhereTheWallCurves) {
  // Half a 30 mm hole as an open path: a straight 2 mm run-out would leave the curved wall by
  // 2²/(2·30) = 0.067 mm, so it is cut to where it stays within 20 µm (about 1.1 mm).
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindPath arc = hole_circle(0.03, 120);
  arc.closed = false;
  arc.points_C.resize(61);
  arc.normals_C.resize(61);
  GrindParams none = flush();
  none.overrun = 0;
  const GrindResult r0 = plan_grind(robot, X_BC, arc, none);
  const GrindResult r1 = plan_grind(robot, X_BC, arc, flush());
  ASSERT_TRUE(r0.ok() && r1.ok()) << r0.message << r1.message;
  auto cut = [](const GrindResult& r) {
    for (const auto& g : r.segments)
      if (g.kind == SampleKind::kCut) return g;
    return r.segments.front();
  };
  const auto g0 = cut(r0), g1 = cut(r1);
  const std::size_t extra = (g1.last_sample - g1.first_sample) - (g0.last_sample - g0.first_sample);
  EXPECT_GE(extra, 2u);   // some run-out at each end
  EXPECT_LE(extra, 6u);   // but not the full 2 × 4 samples of 0.5 mm
  const double rad = robot.tool.radius;
  for (std::size_t i = g1.first_sample; i <= g1.last_sample; ++i) {
    // The burr axis stays r inside the wall: the contact point within 20 µm of the circle.
    const Vec3 p = r1.samples[i].X_CT.translation();
    EXPECT_NEAR(std::hypot(p.x(), p.y()) + rad, 0.03, 25e-6) << i;
  }
}

TEST(GrindPlanner, BurrRollsRoundAConvexEdgeWithoutCuttingIt) {
  // A fin round the sharp 90° edge of a block (steel where x_C ≥ 0 and y_C ≤ 0): root points
  // 1 mm apart along the face x_C = 0 (normal −x_C) up to 0.4 mm before the edge, then from
  // 0.6 mm past it along the face y_C = 0 (normal +y_C). The flush burr must not cut into the
  // block anywhere (a spline through the points cuts the edge on a chord), and must stay on
  // the edge as it goes round it (touching the steel at every finishing sample).
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindPath path;
  for (double y = -0.0204; y < 0; y += 0.001) {
    path.points_C.push_back(Vec3(0, y, 0));
    path.normals_C.push_back(Vec3(-1, 0, 0));
  }
  for (double x = 0.0006; x < 0.021; x += 0.001) {
    path.points_C.push_back(Vec3(x, 0, 0));
    path.normals_C.push_back(Vec3(0, 1, 0));
  }
  path.fin_normal_C = kUp;
  GrindParams P = flush();
  P.lead = 0;
  P.tilt = 0;
  P.overrun = 0;
  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  const double rad = robot.tool.radius;
  // Distance in the fin plane from the burr's axis to the block.
  const auto to_block = [](const Vec3& q) {
    if (q.x() < 0 && q.y() > 0) return std::hypot(q.x(), q.y());
    if (q.x() < 0) return -q.x();
    if (q.y() > 0) return q.y();
    return -std::min(q.x(), -q.y());
  };
  double worst = 1e9, farthest = 0;
  std::size_t rolled = 0;
  for (const auto& g : r.segments) {
    if (g.kind != SampleKind::kCut) continue;
    for (std::size_t i = g.first_sample; i <= g.last_sample; ++i) {
      const Pose& X = r.samples[i].X_CT;
      const Vec3 z = X.linear().col(2);
      ASSERT_GT(std::abs(z.z()), 0.9);
      const Vec3 axis = X.translation() - z * (X.translation().z() / z.z());  // at z_C = 0
      const double gap = to_block(axis) - rad;
      worst = std::min(worst, gap);
      farthest = std::max(farthest, gap);
      if (axis.x() < 0 && axis.y() > 0) ++rolled;
    }
  }
  EXPECT_GT(worst, -5e-6) << "the burr cuts the edge by " << -worst * 1e3 << " mm";
  EXPECT_LT(farthest, 5e-6) << "the burr leaves the wall by " << farthest * 1e3 << " mm";
  EXPECT_GE(rolled, 5u) << "the burr should roll round the edge in steps";
  expect_trajectory_sound(robot, r);
}

TEST(GrindPlanner, FinHigherThanDepthOfCutGivesRoughingPassesThenAFinishingPass) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindParams P = flush();
  P.max_depth_of_cut = 0.002;
  P.finish_depth = 0.0003;
  P.overrun = 0;  // pass lengths exactly the line's
  // A link before the finishing pass too (the stop in free air instead: the next test).
  P.retare_before_finish = false;
  GrindPath path = wall_line(-0.05, 0.05, 0.005);
  path.fin_height = 3 * P.max_depth_of_cut + P.finish_depth;
  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  // Three roughing passes of 2 mm down to 0.3 mm off the wall, then the finishing pass.
  ASSERT_EQ(r.passes, 4);
  ASSERT_EQ(r.pass_offsets.size(), 4u);
  EXPECT_NEAR(r.pass_offsets[0], 0.0043, 1e-15);
  EXPECT_NEAR(r.pass_offsets[1], 0.0023, 1e-15);
  EXPECT_NEAR(r.pass_offsets[2], 0.0003, 1e-15);
  EXPECT_EQ(r.pass_offsets[3], 0.0);
  const double rad = robot.tool.radius;
  // approach, plunge, cut 0, link, cut 1, link, cut 2, link, cut 3, retract
  ASSERT_EQ(r.segments.size(), 10u);
  const SampleKind kinds[10] = {SampleKind::kApproach, SampleKind::kApproach, SampleKind::kCut,
                                SampleKind::kLink,     SampleKind::kCut,      SampleKind::kLink,
                                SampleKind::kCut,      SampleKind::kLink,     SampleKind::kCut,
                                SampleKind::kRetract};
  double prev_offset = 1;
  for (int k = 0; k < 10; ++k) {
    const GrindSegment& g = r.segments[static_cast<std::size_t>(k)];
    EXPECT_EQ(g.kind, kinds[k]);
    if (k > 0) {
      EXPECT_EQ(g.first_sample, r.segments[static_cast<std::size_t>(k - 1)].last_sample);
    }
    if (g.kind != SampleKind::kCut) continue;
    // Roughing passes at the roughing feed, the finishing pass at the cutting feed.
    EXPECT_EQ(g.feed, g.pass < 3 ? P.roughing_feed : P.feed) << g.pass;
    // Axis offset from the wall decreasing pass by pass, the last at r (flush).
    const double expect = rad + r.pass_offsets[static_cast<std::size_t>(g.pass)];
    EXPECT_LT(expect, prev_offset);
    prev_offset = expect;
    for (std::size_t i = g.first_sample; i <= g.last_sample; ++i) {
      EXPECT_EQ(r.samples[i].pass, g.pass);
      EXPECT_NEAR(-r.samples[i].X_CT.translation().x(), expect, 1e-12);
      EXPECT_NEAR(r.samples[i].axis_offset, expect, 1e-12);
    }
    // Open paths alternate direction: odd passes run back.
    const double y0 = r.samples[g.first_sample].X_CT.translation().y();
    const double y1 = r.samples[g.last_sample].X_CT.translation().y();
    EXPECT_NEAR(g.pass % 2 == 1 ? y0 - y1 : y1 - y0, 0.1, 1e-9);
  }
  EXPECT_NEAR(-r.samples[r.segments[8].last_sample].X_CT.translation().x(), rad, 1e-12);
  // Links: radial step-in at the path end, cutting feed; the last one by the finishing depth.
  for (int k : {3, 5, 7}) {
    const GrindSegment& g = r.segments[static_cast<std::size_t>(k)];
    EXPECT_EQ(g.feed, P.feed);
    const Vec3 d =
        r.samples[g.last_sample].X_CT.translation() - r.samples[g.first_sample].X_CT.translation();
    const double step = k == 7 ? P.finish_depth : P.max_depth_of_cut;
    EXPECT_LT((d - Vec3(step, 0, 0)).norm(), 1e-12) << k;
  }
  EXPECT_NEAR(r.cut_length, 4 * 0.1 + 2 * 0.002 + 0.0003, 1e-9);
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);

  // A fin height that would need more than 100 passes is bad input (no overflow for absurd
  // heights either).
  for (double h : {1.0, 1e12}) {
    path.fin_height = h;
    EXPECT_THROW(plan_grind(robot, X_BC, path, P), ArgumentError) << h;
  }
  // Unknown fin height: one pass.
  path.fin_height = 0;
  EXPECT_EQ(plan_grind(robot, X_BC, path, P).passes, 1);
  // A fin no higher than the finishing depth: the finishing pass alone.
  path.fin_height = 0.0002;
  EXPECT_EQ(plan_grind(robot, X_BC, path, P).passes, 1);
  // Not a whole multiple: equal roughing depths no deeper than the limit.
  path.fin_height = 0.0048;
  const GrindResult r3 = plan_grind(robot, X_BC, path, P);
  ASSERT_EQ(r3.passes, 4);
  EXPECT_NEAR(r3.pass_offsets[0], 0.0033, 1e-15);
  EXPECT_NEAR(r3.pass_offsets[1], 0.0018, 1e-15);
}

// Before the finishing pass the burr leaves the part and stops in free air, so a controller
// that reads a flange F/T sensor can zero it again (the finishing pass sets the wall; a
// sensor's drift over the roughing passes would move it by ≈0.1 mm): the lead-out, a lift at
// the approach feed until the tip is 2 mm above the fin plane, a step across in the air to
// above the finishing pass's start, the descent (in the air: at the approach feed) and the
// lead-in.
TEST(GrindPlanner, FinishingPassStartsFromAStopInFreeAir) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindParams P = flush();
  P.lead_clearance = 0.5e-3;
  P.overrun = 0;
  P.retare_before_finish = true;  // (off by default: a scenario turns it on for the sensor)
  GrindPath path = wall_line(-0.05, 0.05, 0.005);
  path.fin_height = P.max_depth_of_cut + P.finish_depth;  // one roughing pass, the finishing pass
  const GrindResult r = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(r.ok()) << r.message;
  ASSERT_EQ(r.passes, 2);
  const double rad = robot.tool.radius;
  const double tip = P.tip_depth.value_or(robot.tool.length / 2);
  const double up = std::min(P.approach_distance, tip + 0.002);
  // approach (air), plunge, lead-in, cut 0, lead-out, lift, across, plunge, lead-in, cut 1,
  // lead-out, lift
  const SampleKind A = SampleKind::kApproach, K = SampleKind::kCut, R = SampleKind::kRetract;
  const std::vector<SampleKind> kinds = {A, A, A, K, R, R, A, A, A, K, R, R};
  ASSERT_EQ(r.segments.size(), kinds.size());
  for (std::size_t k = 0; k < kinds.size(); ++k) {
    EXPECT_EQ(r.segments[k].kind, kinds[k]) << k;
    if (k > 0) {
      EXPECT_EQ(r.segments[k - 1].last_sample, r.segments[k].first_sample) << k;
    }
  }
  const auto p = [&](std::size_t i) { return r.samples[i].X_CT.translation(); };
  // The fin plane is z = 0 (wall_line); the stop: lifted by `up` off the roughing pass's end,
  // the lead clearance off its offset.
  const std::size_t stop = r.segments[5].last_sample;
  EXPECT_NEAR(p(stop).z() - p(r.segments[4].last_sample).z(), up, 1e-12);
  EXPECT_NEAR(-p(stop).x(), rad + r.pass_offsets[0] + 0.5e-3, 1e-12);
  EXPECT_EQ(r.segments[5].feed, P.approach_feed);
  // Across in the air, to the lead clearance off the finishing offset, at the approach feed.
  const std::size_t above = r.segments[6].last_sample;
  EXPECT_NEAR(p(above).z(), p(stop).z(), 1e-12);
  EXPECT_NEAR(-p(above).x(), rad + 0.5e-3, 1e-12);
  EXPECT_NEAR(p(above).y(), p(stop).y(), 1e-12);
  EXPECT_EQ(r.segments[6].feed, P.approach_feed);
  // Down to where the finishing pass starts, then the radial lead-in. The roughing pass left
  // 0.3 mm of fin, within the 0.5 mm lead clearance, so the descent is in the air: at the
  // approach feed, not the plunge feed.
  EXPECT_EQ(r.segments[7].feed, P.approach_feed);
  EXPECT_EQ(r.segments[1].feed, P.plunge_feed);
  EXPECT_NEAR(p(r.segments[7].last_sample).z(), p(r.segments[3].last_sample).z(), 1e-12);
  EXPECT_NEAR(-p(r.segments[8].last_sample).x(), rad, 1e-12);
  // The finishing pass runs back over the line from where the roughing pass ended.
  EXPECT_NEAR((p(r.segments[9].first_sample) - p(r.segments[3].last_sample)).y(), 0, 1e-12);
  EXPECT_EQ(r.segments[9].feed, P.feed);
  expect_single_branch(robot, r, P.max_joint_jump);
  expect_trajectory_sound(robot, r);
  // The stop is a rest: the timed motion's speed is zero at the end of the lift.
  const Vector6& dq = r.trajectory.dq[r.segments[5].last_step];
  EXPECT_LT(dq.norm(), 1e-9);
  // One pass alone needs no stop; switched off, a link steps in at the end as before.
  path.fin_height = 0;
  EXPECT_EQ(plan_grind(robot, X_BC, path, P).segments.size(), 6u);
  path.fin_height = P.max_depth_of_cut + P.finish_depth;
  P.retare_before_finish = false;
  const GrindResult l = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(l.ok()) << l.message;
  EXPECT_EQ(l.segments.size(), 8u);
  EXPECT_EQ(l.segments[4].kind, SampleKind::kLink);
  EXPECT_LT(l.total_time, r.total_time);
  // A finishing pass longer than retare_length stops again on the way (here at 40 and 80 mm of
  // the 100 mm line; not again within 10 mm of its end) and goes on from the same point.
  P.retare_before_finish = true;
  P.retare_length = 0.04;
  const GrindResult c = plan_grind(robot, X_BC, path, P);
  ASSERT_TRUE(c.ok()) << c.message;
  std::vector<const GrindSegment*> finish;
  for (const GrindSegment& g : c.segments)
    if (g.kind == SampleKind::kCut && g.pass == 1) finish.push_back(&g);
  ASSERT_EQ(finish.size(), 3u);
  double length = 0;
  for (std::size_t j = 0; j < finish.size(); ++j) {
    const Vec3 a = c.samples[finish[j]->first_sample].X_CT.translation();
    const Vec3 b = c.samples[finish[j]->last_sample].X_CT.translation();
    EXPECT_NEAR(-a.x(), rad, 1e-12);
    length += (b - a).norm();
    if (j > 0) {
      const Vec3 stopped = c.samples[finish[j - 1]->last_sample].X_CT.translation();
      EXPECT_LT((a - stopped).norm(), 1e-12) << j;
      EXPECT_NEAR((b - a).norm(), j == 1 ? 0.04 : 0.02, 0.001) << j;
      // In between: up in the air by the plunge height.
      double top = -1;
      for (std::size_t i = finish[j - 1]->last_sample; i <= finish[j]->first_sample; ++i)
        top = std::max(top, c.samples[i].X_CT.translation().z() - stopped.z());
      EXPECT_NEAR(top, up, 1e-12) << j;
    }
  }
  EXPECT_NEAR(length, 0.1, 1e-9);
  // The pieces come to rest on the wall and start from it with the feed ramped over at least
  // retare_ramp_time (the process force follows the feed; the sensor reads it late).
  for (const GrindSegment* g : finish) {
    EXPECT_EQ(g->ramp_time, P.retare_ramp_time);
    std::size_t up = g->first_step, down = g->last_step;
    while (up < g->last_step && c.trajectory.sdot[up] < 0.99 * g->feed) ++up;
    while (down > g->first_step && c.trajectory.sdot[down] < 0.99 * g->feed) --down;
    ASSERT_LT(up, down);  // the piece reaches its feed
    const double ramp = 0.9 * P.retare_ramp_time;
    EXPECT_GE(c.trajectory.t[up] - c.trajectory.t[g->first_step], ramp);
    EXPECT_GE(c.trajectory.t[g->last_step] - c.trajectory.t[down], ramp);
  }
  // Without the stops on the way, the finishing pass ramps as fast as the timing allows.
  EXPECT_EQ(r.segments[9].ramp_time, 0.0);
  expect_trajectory_sound(robot, c);
}

TEST(GrindPlanner, LeadAndTiltGeometry) {
  const Vec3 p(0.1, 0.2, 0.3), n(-1, 0, 0), t(0, 1, 0), f = kUp;
  const double r = 0.006, L = 0.02, d = 0.01;
  // Lead: shank toward the travel direction, axis still parallel to the wall, offset r.
  double off = 0;
  const Pose A = grind_tool_pose(p, n, t, f, t, 0, 0.2, 0, 0, r, L, d, &off);
  const Vec3 za = A.linear().col(2);
  EXPECT_NEAR(-za.dot(t), std::sin(0.2), 1e-15);
  EXPECT_NEAR(za.dot(n), 0, 1e-15);
  EXPECT_NEAR(off, r, 1e-15);
  EXPECT_NEAR(wall_clearance(A, p, n, r, L), 0, 1e-15);
  // The axis crosses the fin plane at p + r·n; the tip is d further along z_T.
  EXPECT_LT((A.translation() - (p + r * n + d * za)).norm(), 1e-15);
  // Tilt, shank toward the wall: the upper end's rim touches the wall, nothing enters it.
  {
    const Pose B = grind_tool_pose(p, n, t, f, t, 0, 0, -0.15, 0, r, L, d, &off);
    EXPECT_NEAR(-B.linear().col(2).dot(n), std::sin(-0.15), 1e-15);
    EXPECT_NEAR(wall_clearance(B, p, n, r, L), 0, 1e-15);
    EXPECT_GT(off, r);
  }
  // Tilt, shank away from the wall: the ball end touches the wall plane (its centre one radius
  // off it), nothing enters it, and the burr comes within 0.05 mm of the root on the fin plane
  // at any lean (the ball's centre slides toward the fin plane as the lean grows).
  for (double tilt : {0.001, 0.05, 0.15, 0.4}) {
    const Pose B = grind_tool_pose(p, n, t, f, t, 0, 0, tilt, 0, r, L, d, &off);
    const Vec3 zb = B.linear().col(2), centre = B.translation() - r * zb;
    EXPECT_NEAR(-zb.dot(n), std::sin(tilt), 1e-15);
    EXPECT_NEAR((centre - p).dot(n), r, 1e-15);
    EXPECT_GE(wall_clearance(B, p, n, r, L), -1e-15) << "tilt " << tilt;
    EXPECT_LE(root_gap(B, p, n, r, L), 0.05e-3 + 1e-6) << "tilt " << tilt;
  }
  // Rotations are proper and the spin turns x_T about z_T.
  const Pose S0 = grind_tool_pose(p, n, t, f, t, 0, 0, 0, 0, r, L, d);
  const Pose S1 = grind_tool_pose(p, n, t, f, t, 0, 0, 0, 0.7, r, L, d);
  EXPECT_NEAR(S0.linear().determinant(), 1, 1e-12);
  EXPECT_NEAR(S0.linear().col(0).dot(S1.linear().col(0)), std::cos(0.7), 1e-12);
  EXPECT_LT((S0.translation() - S1.translation()).norm(), 1e-15);
  // Through the planner: a lead keeps the cutter flush.
  const RobotModel robot = ftest::ft6();
  GrindParams P = flush();
  P.lead = 0.1;
  const GrindResult res =
      plan_grind(robot, translation(Vec3(0.7, 0, -0.15)), wall_line(-0.05, 0.05, 0.005), P);
  ASSERT_TRUE(res.ok()) << res.message;
  for (const GrindSample& s : res.samples) {
    if (s.kind != SampleKind::kCut) continue;
    const Vec3 z = s.X_CT.linear().col(2);
    EXPECT_NEAR(-z.dot(Vec3(0, 1, 0)), std::sin(0.1), 1e-12);
    EXPECT_NEAR(
        wall_clearance(s.X_CT, Vec3(0, 0, 0), Vec3(-1, 0, 0), robot.tool.radius, robot.tool.length),
        0, 1e-12);
  }
}

TEST(GrindPlanner, Deterministic) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.5, 0.144, -0.71));
  GrindPath path;
  for (int k = 0; k <= 40; ++k) {
    path.points_C.push_back(Vec3(-0.1 + 0.005 * k, 0, 0));
    path.normals_C.push_back(Vec3(0, 1, 0));
  }
  const GrindResult a = plan_grind(robot, X_BC, path);
  const GrindResult b = plan_grind(robot, X_BC, path);
  ASSERT_TRUE(a.ok()) << a.message;
  ASSERT_EQ(a.samples.size(), b.samples.size());
  for (std::size_t i = 0; i < a.samples.size(); ++i) {
    ASSERT_EQ(a.samples[i].q, b.samples[i].q);
    ASSERT_EQ(a.samples[i].X_BT.matrix(), b.samples[i].X_BT.matrix());
  }
  ASSERT_EQ(a.trajectory.size(), b.trajectory.size());
  for (std::size_t n = 0; n < a.trajectory.size(); ++n)
    ASSERT_EQ(a.trajectory.q[n], b.trajectory.q[n]);
  EXPECT_EQ(grind_summary_json(a), grind_summary_json(b));
}

TEST(GrindPlanner, BadInputThrowsAndDuplicatesAreThinned) {
  const RobotModel robot = ftest::ft6();
  const Pose X_BC = translation(Vec3(0.7, 0, -0.15));
  GrindPath path = wall_line(-0.02, 0.02, 0.005);
  GrindPath mismatch = path;
  mismatch.normals_C.pop_back();
  EXPECT_THROW(plan_grind(robot, X_BC, mismatch), ArgumentError);
  GrindPath parallel = path;
  parallel.normals_C[3] = Vec3(0, 0, 2);
  EXPECT_THROW(plan_grind(robot, X_BC, parallel), ArgumentError);
  GrindPath nan = path;
  nan.points_C[2].x() = std::nan("");
  EXPECT_THROW(plan_grind(robot, X_BC, nan), ArgumentError);
  GrindPath few = hole_circle(0.03, 4);
  EXPECT_THROW(plan_grind(robot, X_BC, few), ArgumentError);
  GrindParams bad;
  bad.spacing = 0;
  EXPECT_THROW(plan_grind(robot, X_BC, path, bad), ArgumentError);
  // Repeated and nearly repeated points (the spline would reject them) are thinned away.
  GrindPath dup;
  for (const Vec3& p : path.points_C)
    for (int k = 0; k < 3; ++k) {
      dup.points_C.push_back(p + Vec3(0, 1e-5 * k, 0));
      dup.normals_C.push_back(Vec3(-1, 0, 0));
    }
  GrindParams no_runout = flush();
  no_runout.overrun = 0;  // the cut exactly the thinned line
  const GrindResult r = plan_grind(robot, X_BC, dup, no_runout);
  ASSERT_TRUE(r.ok()) << r.message;
  EXPECT_NEAR(r.cut_length, 0.04 + 2e-5, 1e-9);
  GrindParams too_long;
  too_long.overrun = 0.2;
  EXPECT_THROW(plan_grind(robot, X_BC, path, too_long), ArgumentError);
}

TEST(GrindPlanner, WritesCsvJsonAndPlots) {
  const RobotModel robot = ftest::ft6();
  GrindParams P = flush();
  P.overrun = 0;  // the last row exactly above the line's end
  const GrindResult r =
      plan_grind(robot, translation(Vec3(0.7, 0, -0.15)), wall_line(-0.02, 0.02, 0.005), P);
  ASSERT_TRUE(r.ok()) << r.message;
  const std::string dir = ftest::temp_dir("grind_planner");
  write_grind_outputs(r, dir);
  const std::string csv = read_text_file(dir + "/trajectory.csv");
  EXPECT_EQ(static_cast<std::size_t>(std::count(csv.begin(), csv.end(), '\n')),
            r.trajectory.size() + 1);
  const std::string header = csv.substr(0, csv.find('\n'));
  EXPECT_EQ(std::count(header.begin(), header.end(), ','), 25);
  EXPECT_EQ(header.rfind("t,q1,", 0), 0u);
  EXPECT_NE(header.find(",ddq6,x,y,z,qw,qx,qy,qz"), std::string::npos);
  // The last row: the final pose, 30 mm above the end of the line.
  const std::string last = csv.substr(csv.rfind('\n', csv.size() - 2) + 1);
  double vals[26];
  std::size_t pos = 0;
  for (double& v : vals) {
    const std::size_t next = last.find_first_of(",\n", pos);
    v = std::stod(last.substr(pos, next - pos));
    pos = next + 1;
  }
  EXPECT_NEAR(vals[0], r.total_time, 1e-6);
  EXPECT_NEAR(vals[19], 0.7 - robot.tool.radius, 1e-6);
  EXPECT_NEAR(vals[20], 0.02, 1e-6);
  EXPECT_NEAR(vals[21], -0.15 - 0.01 + 0.03, 1e-6);
  EXPECT_NEAR(std::abs(vals[22]), 0, 1e-6);  // z_T down: a half turn about a horizontal axis

  const std::string json = read_text_file(dir + "/grind_summary.json");
  for (const char* key :
       {"\"status\": \"ok\"", "\"trajectory.max_joint_velocity_ratio\"",
        "\"trajectory.max_joint_accel_ratio\"", "\"trajectory.min_manipulability\"",
        "\"trajectory.total_time_s\"", "\"trajectory.reoriented_ranges\": []"})
    EXPECT_NE(json.find(key), std::string::npos) << key;
  for (const char* png :
       {"joint_positions.png", "joint_velocities.png", "joint_accelerations.png"}) {
    std::ifstream in(dir + "/" + png, std::ios::binary);
    ASSERT_TRUE(in.good()) << png;
    char sig[8] = {};
    in.read(sig, 8);
    EXPECT_EQ(std::string(sig + 1, 3), "PNG") << png;
  }
  std::filesystem::remove_all(dir);
}
