#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <functional>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/timing.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::planner;

namespace {

// A path of tool poses (arc length s of the TCP) solved by IK, each solution the one nearest
// to the previous so the joint path stays on one branch without 2π jumps.
struct IkPath {
  std::vector<double> s;
  std::vector<Vector6> q;
};

IkPath ik_path(const RobotModel& robot, const Vector6& seed, int n, double step,
               const std::function<Pose(double)>& pose_at, bool within_limits_only = true) {
  IkPath path;
  Vector6 prev = seed;
  for (int i = 0; i < n; ++i) {
    const double s = i * step;
    IkParams ip;
    ip.q_ref = prev;
    ip.within_limits_only = within_limits_only;
    const IkResult r = ik_tool(robot, pose_at(s), ip);
    EXPECT_FALSE(r.solutions.empty()) << "IK failed at s = " << s << ": " << r.message;
    if (r.solutions.empty()) return path;
    double best = 1e9;
    Vector6 nearest = prev;
    for (const auto& sol : r.solutions) {
      Vector6 c = sol.q;
      // Without the limit filter, unwrap each joint to the 2π-equivalent nearest the previous
      // one, as a careless upstream would: the path may then run out of range.
      if (!within_limits_only)
        for (int j = 0; j < 6; ++j) c[j] += 2 * M_PI * std::round((prev[j] - c[j]) / (2 * M_PI));
      const double d = (c - prev).cwiseAbs().maxCoeff();
      if (d < best) {
        best = d;
        nearest = c;
      }
    }
    prev = nearest;
    path.s.push_back(s);
    path.q.push_back(prev);
  }
  return path;
}

Vector6 seed_config() {
  Vector6 q;
  q << 0.2, -1.0, -1.9, 0.1, -1.0, 0.3;
  return q;
}

// Straight line of the TCP along -y of the base at constant orientation, 1 mm samples.
IkPath line_path(const RobotModel& robot, double length = 0.3) {
  const Pose X0 = fk_tool(robot, seed_config());
  const int n = static_cast<int>(std::lround(length / 0.001)) + 1;
  return ik_path(robot, seed_config(), n, 0.001, [&](double s) {
    Pose X = X0;
    X.translation() += Vec3(0, -s, 0);
    return X;
  });
}

// Line whose tool also spins about its own axis (joint 6) by `total` [rad], the spin rate a
// raised cosine over [a, b] along s.
IkPath twist_path(const RobotModel& robot, double length, double a, double b, double total,
                  bool within_limits_only = true) {
  const Pose X0 = fk_tool(robot, seed_config());
  const int n = static_cast<int>(std::lround(length / 0.001)) + 1;
  const auto angle = [=](double s) {
    if (s <= a) return 0.0;
    if (s >= b) return total;
    const double w = (s - a) / (b - a);
    return total * (w - std::sin(2 * M_PI * w) / (2 * M_PI));
  };
  return ik_path(
      robot, seed_config(), n, 0.001,
      [&](double s) {
        Pose X = X0;
        X.translation() += Vec3(0, -s, 0);
        X.linear() = X0.linear() * Eigen::AngleAxisd(angle(s), Vec3::UnitZ()).toRotationMatrix();
        return X;
      },
      within_limits_only);
}

Vector6 vlimits(const RobotModel& r) {
  Vector6 v;
  for (int j = 0; j < 6; ++j) v[j] = r.limits[j].velocity;
  return v;
}
Vector6 alimits(const RobotModel& r) {
  Vector6 a;
  for (int j = 0; j < 6; ++j) a[j] = r.limits[j].acceleration;
  return a;
}

// The checks every produced trajectory must pass, the limits checked on the samples by finite
// differences as well as on the reported derivatives.
void check_trajectory(const TimingResult& res, const std::vector<double>& s,
                      const std::vector<Vector6>& q, const Vector6& vlim, const Vector6& alim,
                      const TimingParams& P) {
  ASSERT_TRUE(res.ok()) << res.message;
  const JointTrajectory& tr = res.trajectory;
  const std::size_t K = tr.size();
  ASSERT_GE(K, 3u);
  ASSERT_EQ(tr.q.size(), K);
  ASSERT_EQ(tr.dq.size(), K);
  ASSERT_EQ(tr.ddq.size(), K);
  ASSERT_EQ(tr.s.size(), K);
  ASSERT_EQ(tr.sdot.size(), K);
  EXPECT_DOUBLE_EQ(tr.dt, P.dt);
  EXPECT_DOUBLE_EQ(res.total_time, tr.t.back());

  // Monotone time on the fixed period; monotone path parameter covering the whole path.
  for (std::size_t n = 0; n < K; ++n) EXPECT_NEAR(tr.t[n], n * P.dt, 1e-12);
  for (std::size_t n = 1; n < K; ++n) {
    ASSERT_GT(tr.t[n], tr.t[n - 1]);
    ASSERT_GE(tr.s[n], tr.s[n - 1]);
    ASSERT_GE(tr.sdot[n], 0.0);
  }
  EXPECT_DOUBLE_EQ(tr.s.front(), s.front());
  EXPECT_NEAR(tr.s.back(), s.back(), 1e-12);

  // Rest at both ends: zero velocity and zero acceleration; the end configurations exactly.
  EXPECT_EQ(tr.sdot.front(), 0.0);
  EXPECT_EQ(tr.sddot.front(), 0.0);
  EXPECT_NEAR(tr.sdot.back(), 0.0, 1e-12);
  EXPECT_NEAR(tr.sddot.back(), 0.0, 1e-9);
  EXPECT_LT(tr.dq.front().norm(), 1e-12);
  EXPECT_LT(tr.ddq.front().norm(), 1e-12);
  EXPECT_LT(tr.dq.back().norm(), 1e-9);
  EXPECT_LT(tr.ddq.back().norm(), 1e-6);
  EXPECT_LT((tr.q.front() - q.front()).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((tr.q.back() - q.back()).cwiseAbs().maxCoeff(), 1e-12);

  // Positions on the path: q(t) = q(s(t)) on the interpolation of the samples.
  const JointPathSpline spline(s, q);
  double worst_pos = 0;
  for (std::size_t n = 0; n < K; ++n)
    worst_pos = std::max(worst_pos, (tr.q[n] - spline.position(tr.s[n])).cwiseAbs().maxCoeff());
  EXPECT_LT(worst_pos, 1e-12);

  // Limits: reported derivatives and finite differences of the sampled positions.
  Vector6 vr = Vector6::Zero(), ar = Vector6::Zero(), vfd = Vector6::Zero(), afd = Vector6::Zero();
  for (std::size_t n = 0; n < K; ++n) {
    vr = vr.cwiseMax(tr.dq[n].cwiseAbs().cwiseQuotient(vlim));
    ar = ar.cwiseMax(tr.ddq[n].cwiseAbs().cwiseQuotient(alim));
    if (n + 1 < K) {
      const Vector6 v = (tr.q[n + 1] - tr.q[n]) / P.dt;
      vfd = vfd.cwiseMax(v.cwiseAbs().cwiseQuotient(vlim));
    }
    if (n > 0 && n + 1 < K) {
      const Vector6 a = (tr.q[n + 1] - 2 * tr.q[n] + tr.q[n - 1]) / (P.dt * P.dt);
      afd = afd.cwiseMax(a.cwiseAbs().cwiseQuotient(alim));
    }
  }
  EXPECT_LE(vr.maxCoeff(), 1.0);
  EXPECT_LE(ar.maxCoeff(), 1.0);
  EXPECT_LE(vfd.maxCoeff(), 1.0) << "finite-difference velocity over the limit";
  EXPECT_LE(afd.maxCoeff(), 1.0) << "finite-difference acceleration over the limit";
  // The reported ratios are those of the samples.
  EXPECT_LT((res.max_velocity_ratio - vr).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_LT((res.max_accel_ratio - ar).cwiseAbs().maxCoeff(), 1e-12);
  EXPECT_DOUBLE_EQ(res.max_joint_velocity_ratio, vr.maxCoeff());
  EXPECT_DOUBLE_EQ(res.max_joint_accel_ratio, ar.maxCoeff());
  // Reported derivatives agree with the positions (central differences, O(dt²)).
  // Central differences are within max|ddq|·dt/2 of the derivative, also across the jumps of
  // the acceleration.
  for (std::size_t n = 1; n + 1 < K; ++n) {
    const Vector6 v = (tr.q[n + 1] - tr.q[n - 1]) / (2 * P.dt);
    ASSERT_LT((v - tr.dq[n]).cwiseAbs().maxCoeff(), alim.maxCoeff() * P.dt) << "n = " << n;
  }
  // Path speed never above the feed, path acceleration within its bound.
  for (std::size_t n = 0; n < K; ++n) {
    ASSERT_LE(tr.sdot[n], P.feed * (1 + 1e-9));
    ASSERT_LE(std::abs(tr.sddot[n]), P.max_path_accel * (1 + 1e-9));
  }
}

bool bitwise_equal(const JointTrajectory& a, const JointTrajectory& b) {
  if (a.size() != b.size()) return false;
  for (std::size_t n = 0; n < a.size(); ++n)
    if (a.t[n] != b.t[n] || a.s[n] != b.s[n] || a.sdot[n] != b.sdot[n] || a.q[n] != b.q[n] ||
        a.dq[n] != b.dq[n] || a.ddq[n] != b.ddq[n])
      return false;
  return true;
}

}  // namespace

TEST(JointPathSpline, ReproducesQuadraticsAndInterpolatesSamples) {
  // Non-uniform knots; each joint a different parabola in s.
  std::vector<double> s;
  std::vector<Vector6> q;
  double si = 0.1;
  for (int i = 0; i < 40; ++i) {
    s.push_back(si);  // spacing 0.3 to 1.7 mm
    si += 0.001 * (1 + 0.7 * std::sin(1.3 * i));
  }
  const auto f = [](double x, int j) {
    return 0.1 * j - 0.5 + (j - 2.5) * x + 3.0 * (j - 3) * x * x;
  };
  for (double x : s) {
    Vector6 v;
    for (int j = 0; j < 6; ++j) v[j] = f(x, j);
    q.push_back(v);
  }
  const JointPathSpline spline(s, q);
  for (double x = s.front(); x <= s.back(); x += 1.7e-5) {
    Vector6 p, d1, d2;
    spline.evaluate(x, p, d1, d2);
    for (int j = 0; j < 6; ++j) {
      ASSERT_NEAR(p[j], f(x, j), 1e-12);
      ASSERT_NEAR(d1[j], (j - 2.5) + 6.0 * (j - 3) * x, 1e-8);
      ASSERT_NEAR(d2[j], 6.0 * (j - 3), 1e-4);
    }
  }
  // Arbitrary data: passes through every sample, first and second derivatives continuous.
  for (std::size_t i = 0; i < q.size(); ++i)
    for (int j = 0; j < 6; ++j) q[i][j] = std::sin(37.0 * s[i] + j) + 0.01 * std::cos(3.0 * i);
  const JointPathSpline wiggly(s, q);
  for (std::size_t i = 0; i < s.size(); ++i)
    EXPECT_LT((wiggly.position(s[i]) - q[i]).cwiseAbs().maxCoeff(), 1e-13);
  for (std::size_t i = 1; i + 1 < s.size(); ++i) {
    Vector6 pa, da, aa, pb, db, ab;
    wiggly.evaluate(s[i] - 1e-12, pa, da, aa);
    wiggly.evaluate(s[i] + 1e-12, pb, db, ab);
    const double scale = std::max(1.0, aa.cwiseAbs().maxCoeff());
    EXPECT_LT((da - db).cwiseAbs().maxCoeff(), 1e-8 * scale);
    EXPECT_LT((aa - ab).cwiseAbs().maxCoeff(), 1e-6 * scale);
  }
  EXPECT_THROW(JointPathSpline({0.0}, {Vector6::Zero()}), ArgumentError);
  EXPECT_THROW(JointPathSpline({0.0, 0.0}, {Vector6::Zero(), Vector6::Zero()}), ArgumentError);
}

TEST(Timing, StraightLineThroughIkStaysWithinLimits) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = line_path(robot);
  ASSERT_EQ(path.s.size(), 301u);
  for (double feed : {0.02, 0.2}) {
    SCOPED_TRACE("feed " + std::to_string(feed));
    TimingParams P;
    P.feed = feed;
    const TimingResult res = time_parametrize(robot, path.s, path.q, P);
    check_trajectory(res, path.s, path.q, vlimits(robot), alimits(robot), P);
    EXPECT_TRUE(res.reductions.empty());
    // The feed is reached and held: the cruise takes most of the time.
    const auto& tr = res.trajectory;
    std::size_t cruise = 0;
    for (double v : tr.sdot) cruise += v > feed * (1 - 1e-3);
    EXPECT_GT(cruise, tr.size() / 2);
    // Time close to length/feed plus one ramp time (S-curve ramps are symmetric).
    const double ramp_t = feed / P.max_path_accel + P.max_path_accel / P.max_path_jerk;
    EXPECT_NEAR(res.total_time, 0.3 / feed + ramp_t, 0.01 * res.total_time + 2 * P.dt);
    // Jerk-limited: the path acceleration changes at no more than max_path_jerk.
    double jerk = 0;
    for (std::size_t n = 1; n < tr.size(); ++n)
      jerk = std::max(jerk, std::abs(tr.sddot[n] - tr.sddot[n - 1]) / P.dt);
    EXPECT_LE(jerk, P.max_path_jerk * (1 + 1e-6));
    EXPECT_GT(jerk, 0.5 * P.max_path_jerk);  // and it is used
    std::printf("line at %.2f m/s: %.3f s, max ratios v %.3f a %.3f, time scale %.6f\n", feed,
                res.total_time, res.max_joint_velocity_ratio, res.max_joint_accel_ratio,
                res.time_scale);
  }
}

TEST(Timing, VelocityBottleneckSlowsTheFeedLocallyAndIsReported) {
  const RobotModel robot = ftest::ft6();
  // The tool spins 5 rad about its axis between s = 0.08 and 0.13 m: joint 6 would need
  // 0.06 m/s · 200 rad/m = 12 rad/s at the requested feed (limit 8.03 rad/s).
  const IkPath path = twist_path(robot, 0.25, 0.08, 0.13, 5.0);
  ASSERT_EQ(path.s.size(), 251u);
  TimingParams P;
  P.feed = 0.06;
  const TimingResult res = time_parametrize(robot, path.s, path.q, P);
  check_trajectory(res, path.s, path.q, vlimits(robot), alimits(robot), P);
  ASSERT_EQ(res.reductions.size(), 1u);
  const FeedReduction& r = res.reductions[0];
  EXPECT_EQ(r.joint, 5);
  EXPECT_EQ(r.limit, LimitKind::kVelocity);
  EXPECT_GT(r.s_begin, 0.02);
  EXPECT_LT(r.s_end, 0.23);
  EXPECT_LE(r.s_begin, 0.105);  // the peak spin rate is at s = 0.105
  EXPECT_GE(r.s_end, 0.105);
  EXPECT_NEAR(r.s_at_min, 0.105, 0.005);
  EXPECT_LE(r.first_sample, 105u);
  EXPECT_GE(r.last_sample, 105u);
  EXPECT_NEAR(r.nominal_feed, P.feed, 1e-12);
  // Lowest feed: joint 6 at 95 % of its limit at the spin rate of about 200 rad/m.
  EXPECT_LT(r.min_feed, 0.045);
  EXPECT_GT(r.min_feed, 0.030);
  // Joint 6 runs close to its planning limit, never over; the feed is held elsewhere.
  EXPECT_GT(res.max_velocity_ratio[5], 0.9);
  const auto& tr = res.trajectory;
  bool full_before = false, full_after = false;
  for (std::size_t n = 0; n < tr.size(); ++n) {
    if (tr.sdot[n] > P.feed * (1 - 1e-3)) {
      full_before = full_before || tr.s[n] < r.s_begin;
      full_after = full_after || tr.s[n] > r.s_end;
    }
    if (tr.s[n] > r.s_begin && tr.s[n] < r.s_end) {
      ASSERT_LT(tr.sdot[n], P.feed * (1 - 1e-4));
    }
  }
  EXPECT_TRUE(full_before);
  EXPECT_TRUE(full_after);
  std::printf(
      "spin bottleneck: feed %.3f m/s reduced to %.4f m/s over s = %.4f..%.4f m (samples "
      "%zu..%zu), joint %d %s; max ratios v %.3f a %.3f; %.3f s, time scale %.6f\n",
      P.feed, r.min_feed, r.s_begin, r.s_end, r.first_sample, r.last_sample, r.joint + 1,
      to_string(r.limit).c_str(), res.max_joint_velocity_ratio, res.max_joint_accel_ratio,
      res.total_time, res.time_scale);

  // The same path without the slowdown would break the limit: time it with the joint-6
  // velocity limit lifted and look at the true limit.
  TimingParams lifted = P;
  Vector6 v = vlimits(robot);
  v[5] = 1e3;
  lifted.velocity_limits = v;
  const TimingResult fast = time_parametrize(robot, path.s, path.q, lifted);
  ASSERT_TRUE(fast.ok()) << fast.message;
  double peak6 = 0;
  for (const Vector6& dq : fast.trajectory.dq) peak6 = std::max(peak6, std::abs(dq[5]));
  EXPECT_GT(peak6, robot.limits[5].velocity);
  EXPECT_LT(fast.total_time, res.total_time);
}

TEST(Timing, AccelerationBottleneckSlowsTheFeed) {
  const RobotModel robot = ftest::ft6();
  // Synthetic joint path: joint 1 wiggles with q'' up to 0.2·(2π/0.02)² ≈ 2e4 rad/m² in the
  // middle third: at 0.05 m/s that asks 49 rad/s² of a 10 rad/s² joint.
  std::vector<double> s;
  std::vector<Vector6> q;
  for (int i = 0; i <= 300; ++i) {
    const double x = i * 0.001;
    Vector6 c = robot.home;
    c[1] += 0.3 * x;
    if (x > 0.1 && x < 0.2)
      c[0] += 0.2 * std::pow(std::sin(M_PI * (x - 0.1) / 0.1), 2) *
              std::sin(2 * M_PI * (x - 0.1) / 0.02);
    s.push_back(x);
    q.push_back(c);
  }
  TimingParams P;
  P.feed = 0.05;
  const TimingResult res = time_parametrize(robot, s, q, P);
  check_trajectory(res, s, q, vlimits(robot), alimits(robot), P);
  ASSERT_FALSE(res.reductions.empty());
  bool accel = false;
  for (const auto& r : res.reductions) {
    EXPECT_EQ(r.joint, 0);
    EXPECT_GT(r.s_begin, 0.09);
    EXPECT_LT(r.s_end, 0.21);
    EXPECT_LT(r.min_feed, 0.03);
    accel = accel || r.limit == LimitKind::kAcceleration;
  }
  EXPECT_TRUE(accel);
  EXPECT_GT(res.max_accel_ratio[0], 0.85);
  std::printf(
      "wiggle bottleneck: %zu reductions, lowest %.4f m/s; max ratios v %.3f a %.3f; "
      "time scale %.6f\n",
      res.reductions.size(), res.reductions[0].min_feed, res.max_joint_velocity_ratio,
      res.max_joint_accel_ratio, res.time_scale);
}

TEST(Timing, JointOutOfRangeFailsNamingFirstSampleAndJoint) {
  const RobotModel robot = ftest::ft6();
  // The tool spins 6.5 rad along the path: joint 6 (from 0.3 rad) passes its upper limit of
  // 6.109 rad. IK without the limit filter keeps the continuous branch.
  const IkPath path = twist_path(robot, 0.2, 0.0, 0.2, 6.5, false);
  ASSERT_EQ(path.s.size(), 201u);
  int first = -1, joint = -1;
  for (std::size_t i = 0; i < path.q.size() && first < 0; ++i)
    for (int j = 0; j < 6; ++j)
      if (!robot.limits[j].contains(path.q[i][j])) {
        first = static_cast<int>(i);
        joint = j;
        break;
      }
  ASSERT_GT(first, 0);
  ASSERT_EQ(joint, 5);
  const TimingResult res = time_parametrize(robot, path.s, path.q);
  EXPECT_FALSE(res.ok());
  EXPECT_EQ(res.status, TimingStatus::kPositionLimit);
  EXPECT_EQ(res.failed_sample, first);
  EXPECT_EQ(res.failed_joint, 5);
  EXPECT_EQ(res.failed_limit, LimitKind::kPosition);
  EXPECT_DOUBLE_EQ(res.failed_value, path.q[first][5]);
  EXPECT_DOUBLE_EQ(res.failed_bound, robot.limits[5].upper);
  EXPECT_NEAR(res.failed_excess, path.q[first][5] - robot.limits[5].upper, 1e-15);
  EXPECT_NE(res.message.find("sample " + std::to_string(first) + ": joint 6 position"),
            std::string::npos)
      << res.message;
  EXPECT_NE(res.message.find("exceeds upper limit 6.1087 rad"), std::string::npos) << res.message;
  EXPECT_TRUE(res.trajectory.t.empty());

  // Lower limit, joint 2, at sample 0.
  std::vector<Vector6> q2 = {robot.home, robot.home};
  q2[0][1] = robot.limits[1].lower - 0.05;
  const TimingResult low = time_parametrize(robot, {0.0, 0.01}, q2);
  EXPECT_EQ(low.status, TimingStatus::kPositionLimit);
  EXPECT_EQ(low.failed_sample, 0);
  EXPECT_EQ(low.failed_joint, 1);
  EXPECT_NE(low.message.find("sample 0: joint 2 position"), std::string::npos) << low.message;
  EXPECT_NE(low.message.find("below lower limit"), std::string::npos) << low.message;
  EXPECT_NE(low.message.find("by 0.0500 rad"), std::string::npos) << low.message;
}

TEST(Timing, JumpBetweenSamplesIsADiscontinuity) {
  const RobotModel robot = ftest::ft6();
  IkPath path = line_path(robot, 0.1);
  // Joint 4 jumps by 1.2 rad between samples 59 and 60 (as at an IK branch switch); every
  // sample stays within the joint ranges.
  for (std::size_t i = 60; i < path.q.size(); ++i) path.q[i][3] += 1.2;
  const TimingResult res = time_parametrize(robot, path.s, path.q);
  EXPECT_EQ(res.status, TimingStatus::kDiscontinuous);
  EXPECT_EQ(res.failed_sample, 60);
  EXPECT_EQ(res.failed_joint, 3);
  EXPECT_EQ(res.failed_limit, LimitKind::kJointStep);
  EXPECT_NEAR(res.failed_excess, std::abs(path.q[60][3] - path.q[59][3]) - 0.5, 1e-12);
  EXPECT_NE(res.message.find("samples 59-60: joint 4 jumps"), std::string::npos) << res.message;
}

TEST(Timing, KinkBelowMinFeedFails) {
  const RobotModel robot = ftest::ft6();
  // Joint 1 reverses its slope abruptly at s = 0.05 m (a corner of the joint path): following
  // it needs q'' ≈ 4 rad/m / 1 mm, i.e. a feed of at most sqrt(9.5 / 4000) ≈ 0.05 m/s.
  std::vector<double> s;
  std::vector<Vector6> q;
  for (int i = 0; i <= 100; ++i) {
    const double x = i * 0.001;
    Vector6 c = robot.home;
    c[0] += 2.0 * (0.05 - std::abs(x - 0.05));
    s.push_back(x);
    q.push_back(c);
  }
  TimingParams P;
  P.feed = 0.1;
  P.min_feed = 0.07;
  const TimingResult res = time_parametrize(robot, s, q, P);
  EXPECT_EQ(res.status, TimingStatus::kBelowMinFeed);
  EXPECT_EQ(res.failed_joint, 0);
  EXPECT_EQ(res.failed_limit, LimitKind::kAcceleration);
  EXPECT_NEAR(res.failed_sample, 50, 1);
  EXPECT_LT(res.failed_value, 0.07);
  EXPECT_NEAR(res.failed_excess, 0.07 - res.failed_value, 1e-12);
  EXPECT_NE(res.message.find("joint 1 acceleration limit"), std::string::npos) << res.message;
  EXPECT_NE(res.message.find("below min_feed"), std::string::npos) << res.message;

  // Without the floor the corner is passed slowly, within the limits.
  P.min_feed = 0;
  const TimingResult slow = time_parametrize(robot, s, q, P);
  check_trajectory(slow, s, q, vlimits(robot), alimits(robot), P);
  ASSERT_EQ(slow.reductions.size(), 1u);
  EXPECT_NEAR(slow.reductions[0].s_at_min, 0.05, 0.002);
  EXPECT_LT(slow.reductions[0].min_feed, 0.07);
}

TEST(Timing, PositionsFollowThePolynomialPathExactly) {
  const RobotModel robot = ftest::ft6();
  // Joint paths quadratic in s are reproduced exactly by the spline: q(t) = f(s(t)) and
  // dq(t) = f'(s(t))·ṡ(t), ddq = f'·s̈ + f''·ṡ².
  Vector6 c0 = robot.home, c1, c2;
  c1 << 1.0, -0.5, 0.8, 2.0, -1.5, 3.0;
  c2 << -2.0, 1.0, 0.5, -4.0, 3.0, 6.0;
  std::vector<double> s;
  std::vector<Vector6> q;
  double si = 0.05;
  for (int i = 0; i <= 120; ++i) {
    s.push_back(si);
    q.push_back(c0 + c1 * si + c2 * si * si);
    si += 0.0025 * (1 + 0.3 * (i % 3));  // uneven spacing
  }
  TimingParams P;
  P.feed = 0.04;
  const TimingResult res = time_parametrize(robot, s, q, P);
  check_trajectory(res, s, q, vlimits(robot), alimits(robot), P);
  const auto& tr = res.trajectory;
  for (std::size_t n = 0; n < tr.size(); ++n) {
    const double x = tr.s[n];
    ASSERT_LT((tr.q[n] - (c0 + c1 * x + c2 * x * x)).cwiseAbs().maxCoeff(), 1e-12);
    const Vector6 d1 = c1 + 2 * c2 * x;
    ASSERT_LT((tr.dq[n] - d1 * tr.sdot[n]).cwiseAbs().maxCoeff(), 1e-9);
    ASSERT_LT(
        (tr.ddq[n] - (d1 * tr.sddot[n] + 2 * c2 * tr.sdot[n] * tr.sdot[n])).cwiseAbs().maxCoeff(),
        1e-6);
  }
}

TEST(Timing, ShortPathNeverReachesTheFeedButIsNotAReduction) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = line_path(robot, 0.004);  // shorter than the two ramps at 0.1 m/s
  TimingParams P;
  P.feed = 0.1;
  const TimingResult res = time_parametrize(robot, path.s, path.q, P);
  check_trajectory(res, path.s, path.q, vlimits(robot), alimits(robot), P);
  EXPECT_TRUE(res.reductions.empty());
  double peak = 0;
  for (double v : res.trajectory.sdot) peak = std::max(peak, v);
  EXPECT_LT(peak, 0.09);
  EXPECT_GT(peak, 0.02);
  // The lower peak is reached with zero acceleration: jerk-limited throughout.
  const auto& tr = res.trajectory;
  for (std::size_t n = 1; n < tr.size(); ++n)
    ASSERT_LE(std::abs(tr.sddot[n] - tr.sddot[n - 1]) / P.dt, P.max_path_jerk * (1 + 1e-6));
}

TEST(Timing, LimitOverridesAndFactorAreApplied) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = line_path(robot, 0.2);
  TimingParams P;
  P.feed = 0.3;
  P.limit_factor = 0.8;
  Vector6 v = vlimits(robot) * 0.1, a = alimits(robot) * 0.2;
  P.velocity_limits = v;
  P.acceleration_limits = a;
  const TimingResult res = time_parametrize(robot, path.s, path.q, P);
  check_trajectory(res, path.s, path.q, v, a, P);
  EXPECT_FALSE(res.reductions.empty());
  EXPECT_LE(res.max_joint_velocity_ratio, 0.9);
  EXPECT_LE(res.max_joint_accel_ratio, 0.9);
  EXPECT_GT(res.max_joint_velocity_ratio, 0.7);
}

TEST(Timing, RandomSmoothPathsStayWithinLimits) {
  const RobotModel robot = ftest::ft6();
  Rng rng(7);
  int reduced = 0;
  double worst_v = 0, worst_a = 0;
  for (int trial = 0; trial < 40; ++trial) {
    SCOPED_TRACE("trial " + std::to_string(trial));
    // Each joint: a sum of three sinusoids in s around the home configuration; uneven samples.
    std::array<std::array<double, 9>, 6> c;
    for (auto& cj : c)
      for (int m = 0; m < 3; ++m) {
        cj[3 * m] = rng.uniform(0.0, 0.15);          // amplitude [rad]; the sum stays in range
        cj[3 * m + 1] = rng.uniform(1.0, 80.0);      // wavenumber [rad/m]
        cj[3 * m + 2] = rng.uniform(0.0, 2 * M_PI);  // phase
      }
    const double length = rng.uniform(0.01, 0.4);
    std::vector<double> s;
    std::vector<Vector6> q;
    for (double x = 0; x < length; x += rng.uniform(0.0003, 0.003)) {
      Vector6 v = robot.home;
      for (int j = 0; j < 6; ++j)
        for (int m = 0; m < 3; ++m)
          v[j] += c[j][3 * m] * std::sin(c[j][3 * m + 1] * x + c[j][3 * m + 2]);
      s.push_back(x);
      q.push_back(v);
    }
    TimingParams P;
    P.feed = rng.uniform(0.005, 0.5);
    P.max_path_accel = rng.uniform(0.1, 3.0);
    P.max_path_jerk = rng.uniform(1.0, 50.0);
    P.limit_factor = rng.uniform(0.8, 1.0);
    P.dt = trial % 2 ? 0.001 : 0.002;
    const TimingResult res = time_parametrize(robot, s, q, P);
    check_trajectory(res, s, q, vlimits(robot), alimits(robot), P);
    if (HasFatalFailure()) return;
    reduced += !res.reductions.empty();
    worst_v = std::max(worst_v, res.max_joint_velocity_ratio / P.limit_factor);
    worst_a = std::max(worst_a, res.max_joint_accel_ratio / P.limit_factor);
  }
  EXPECT_GT(reduced, 10);  // the set exercises the limits
  std::printf(
      "40 random paths: %d slowed by the limits; worst ratio to the planning limit: "
      "velocity %.4f, acceleration %.4f\n",
      reduced, worst_v, worst_a);
}

TEST(Timing, DeterministicAndPeriodRespected) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = twist_path(robot, 0.25, 0.08, 0.13, 5.0);
  TimingParams P;
  P.feed = 0.06;
  P.dt = 0.004;
  const TimingResult a = time_parametrize(robot, path.s, path.q, P);
  const TimingResult b = time_parametrize(robot, path.s, path.q, P);
  ASSERT_TRUE(a.ok());
  EXPECT_TRUE(bitwise_equal(a.trajectory, b.trajectory));
  EXPECT_EQ(a.total_time, b.total_time);
  EXPECT_EQ(a.reductions.size(), b.reductions.size());
  check_trajectory(a, path.s, path.q, vlimits(robot), alimits(robot), P);
  EXPECT_GE(a.time_scale, 1.0);
  EXPECT_LT(a.time_scale, 1.01);
}

TEST(Timing, BadInputThrows) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = line_path(robot, 0.01);
  const auto throws_with = [&](const std::vector<double>& s, const std::vector<Vector6>& q,
                               const TimingParams& P, const std::string& needle) {
    try {
      time_parametrize(robot, s, q, P);
      ADD_FAILURE() << "no exception for " << needle;
    } catch (const ArgumentError& e) {
      EXPECT_NE(std::string(e.what()).find(needle), std::string::npos) << e.what();
      EXPECT_NE(std::string(e.what()).find("expected"), std::string::npos) << e.what();
    }
  };
  TimingParams P;
  throws_with({0.0}, {robot.home}, P, "at least 2");
  throws_with(path.s, std::vector<Vector6>(path.q.begin(), path.q.end() - 1), P, "q:");
  std::vector<double> bad_s = path.s;
  bad_s[3] = bad_s[2];
  throws_with(bad_s, path.q, P, "s[3]");
  std::vector<Vector6> bad_q = path.q;
  bad_q[4][2] = std::nan("");
  throws_with(path.s, bad_q, P, "q[4]");
  TimingParams p1;
  p1.feed = 0;
  throws_with(path.s, path.q, p1, "feed");
  TimingParams p2;
  p2.limit_factor = 1.5;
  throws_with(path.s, path.q, p2, "limit_factor");
  TimingParams p3;
  p3.dt = -1;
  throws_with(path.s, path.q, p3, "dt");
  TimingParams p4;
  p4.min_feed = 1.0;
  throws_with(path.s, path.q, p4, "min_feed");
  TimingParams p5;
  Vector6 v = vlimits(robot);
  v[2] = 0;
  p5.velocity_limits = v;
  throws_with(path.s, path.q, p5, "velocity_limits[2]");
}

TEST(Timing, TooLongIsRefused) {
  const RobotModel robot = ftest::ft6();
  const IkPath path = line_path(robot, 0.05);
  TimingParams P;
  P.feed = 0.001;
  P.max_duration = 10;
  const TimingResult res = time_parametrize(robot, path.s, path.q, P);
  EXPECT_EQ(res.status, TimingStatus::kTooLong);
  EXPECT_NE(res.message.find("max_duration"), std::string::npos);
}
