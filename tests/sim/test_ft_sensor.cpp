// The flange F/T sensor model (noise, zero offset and its drift, low-pass, saturation) and the
// controller's load estimate from its readings (payload weight and tare removed).
#include <gtest/gtest.h>

#include <cmath>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/sim/ft_sensor.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

// A sensor without offset, drift or noise unless a test sets them.
FtSensorParams quiet() {
  FtSensorParams p;
  p.force_noise = p.torque_noise = 0;
  p.force_offset = p.torque_offset = 0;
  p.force_drift = p.torque_drift = 0;
  return p;
}

Mat3 random_rotation(Rng& rng) {
  const Vec3 axis = Vec3(rng.normal(), rng.normal(), rng.normal()).normalized();
  return Eigen::AngleAxisd(rng.uniform(0, M_PI), axis).toRotationMatrix();
}

}  // namespace

TEST(FtSensor, NoiseHasTheStatedRmsAboutTheTrueWrenchPlusOffset) {
  FtSensorParams p = quiet();
  p.force_noise = 0.5;
  p.torque_noise = 0.05;
  p.force_offset = 5;
  FtSensor s(p, 7);
  const Wrench w{Vec3(10, -20, 30), Vec3(1, 2, -3)};
  // The first sample settles the filter; the offset is constant (no drift).
  const Wrench first = s.sample(w);
  const int n = 20000;
  Vec3 sum = Vec3::Zero(), sq = Vec3::Zero(), tsq = Vec3::Zero();
  for (int k = 0; k < n; ++k) {
    const Wrench r = s.sample(w);
    sum += r.force;
    sq += (r.force - first.force).cwiseAbs2();
    tsq += (r.torque - w.torque).cwiseAbs2();
  }
  const Vec3 mean = sum / n;
  // Mean: the true force plus one fixed offset of the order of force_offset.
  const Vec3 offset = mean - w.force;
  EXPECT_GT(offset.norm(), 0.5);
  EXPECT_LT(offset.norm(), 5 * 5.0);
  for (int i = 0; i < 3; ++i) {
    // RMS about the mean: the stated noise (the first sample's own noise adds at most 1 σ²).
    const double rms = std::sqrt(sq[i] / n - std::pow(first.force[i] - mean[i], 2));
    EXPECT_NEAR(rms, 0.5, 0.05) << "axis " << i;
    EXPECT_NEAR(std::sqrt(tsq[i] / n), 0.05, 0.005) << "torque axis " << i;
  }
}

TEST(FtSensor, LowPassReachesSixtyThreePercentAfterOneTimeConstant) {
  FtSensorParams p = quiet();
  p.period = 1e-4;
  p.cutoff = 50;
  FtSensor s(p, 1);
  s.sample({});  // settled at zero
  const double tau = 1 / (2 * M_PI * p.cutoff);
  const int steps = static_cast<int>(std::lround(tau / p.period));
  Wrench r;
  for (int k = 0; k < steps; ++k) r = s.sample({Vec3(100, 0, 0), Vec3::Zero()});
  EXPECT_NEAR(r.force.x(), 100 * (1 - std::exp(-1.0)), 1.0);
  for (int k = 0; k < 20 * steps; ++k) r = s.sample({Vec3(100, 0, 0), Vec3::Zero()});
  EXPECT_NEAR(r.force.x(), 100, 1e-3);
}

TEST(FtSensor, ZeroOffsetDriftsAsARandomWalk) {
  // Over many sensors, the offset's change after T seconds has variance drift²·T per axis.
  FtSensorParams p = quiet();
  p.force_drift = 0.2;
  p.period = 0.01;
  const int sensors = 400, samples = 1000;  // T = 10 s
  double var = 0;
  for (int k = 0; k < sensors; ++k) {
    FtSensor s(p, 1000 + k);
    const double start = s.sample({}).force.x();
    double last = start;
    for (int i = 0; i < samples; ++i) last = s.sample({}).force.x();
    var += (last - start) * (last - start);
  }
  var /= sensors;
  const double expected = 0.2 * 0.2 * samples * p.period;  // 0.4 N²
  EXPECT_NEAR(var, expected, 0.2 * expected);
}

TEST(FtSensor, SaturatesAtItsRangeAndIsDeterministic) {
  FtSensorParams p = quiet();
  p.force_range = 100;
  FtSensor s(p, 3);
  EXPECT_DOUBLE_EQ(s.sample({Vec3(250, -300, 50), Vec3::Zero()}).force.x(), 100);
  FtSensorParams noisy;  // the defaults
  FtSensor a(noisy, 42), b(noisy, 42), c(noisy, 43);
  const Wrench w{Vec3(1, 2, 3), Vec3(0.1, 0.2, 0.3)};
  bool differs = false;
  for (int k = 0; k < 100; ++k) {
    const Wrench ra = a.sample(w), rb = b.sample(w), rc = c.sample(w);
    EXPECT_EQ(ra.force, rb.force);
    EXPECT_EQ(ra.torque, rb.torque);
    differs = differs || ra.force != rc.force;
  }
  EXPECT_TRUE(differs);
}

TEST(FtSensor, BadParametersAreRefusedNamingTheField) {
  FtSensorParams p;
  p.cutoff = 0;
  try {
    FtSensor s(p, 1);
    FAIL() << "accepted cutoff 0";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("execution.sensor.cutoff"), std::string::npos) << e.what();
  }
  p = FtSensorParams{};
  p.force_noise = -1;
  EXPECT_THROW(check_ft_sensor_params(p), ArgumentError);
  p = FtSensorParams{};
  p.period = std::nan("");
  EXPECT_THROW(check_ft_sensor_params(p), ArgumentError);
}

TEST(LoadEstimator, RemovesThePayloadAtAnyOrientationAndTheTare) {
  // A 4 kg spindle, its centre of mass 0.12 m out along the flange's z and 0.01 m aside; the
  // sensor reads the payload (plus an offset the tare removes); the estimate is the external
  // load, in {W}, at every orientation of the flange.
  const Payload payload{4.0, Vec3(0.01, 0, 0.12)};
  const Vec3 g(0, 0, -9.81);
  Rng rng(5);
  const Wrench offset{Vec3(3, -2, 1), Vec3(0.1, 0.05, -0.2)};
  LoadEstimator est(payload, g, 0.02);
  Mat3 R = random_rotation(rng);
  // Taring at rest in free air over 20 ms (1 ms samples).
  for (int k = 0; k < 20; ++k) {
    const Wrench rest = payload_reading(payload, R, g);
    const Wrench got = est.update({rest.force + offset.force, rest.torque + offset.torque}, R, 1e-3 * k);
    EXPECT_EQ(got.force, Vec3::Zero());
  }
  const Wrench rest = payload_reading(payload, R, g);
  est.update({rest.force + offset.force, rest.torque + offset.torque}, R, 0.02);
  ASSERT_TRUE(est.tared());
  for (int trial = 0; trial < 50; ++trial) {
    R = random_rotation(rng);
    // An external load on the tool (force at the flange, torque about it), {W}.
    const Vec3 F_W(rng.uniform(-200, 200), rng.uniform(-200, 200), rng.uniform(-200, 200));
    const Vec3 T_W(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-5, 5));
    const Wrench at_rest = payload_reading(payload, R, g);
    // The reading changes by minus the load (the wrist holds the tool against it).
    const Wrench reading{at_rest.force + offset.force - R.transpose() * F_W,
                         at_rest.torque + offset.torque - R.transpose() * T_W};
    const Wrench got = est.update(reading, R, 1.0 + trial);
    EXPECT_LT((got.force - F_W).norm(), 1e-9) << "trial " << trial;
    EXPECT_LT((got.torque - T_W).norm(), 1e-9) << "trial " << trial;
  }
  // The payload's static reading: its weight held up, and the weight's moment about the flange
  // (c × W = (0.01, 0, 0.12) × (0, 0, −39.24) = (0, 0.392, 0) N·m) cancelled.
  const Wrench up = payload_reading(payload, Mat3::Identity(), g);
  EXPECT_LT((up.force - Vec3(0, 0, 4 * 9.81)).norm(), 1e-12);
  EXPECT_LT((up.torque - Vec3(0, -0.01 * 4 * 9.81, 0)).norm(), 1e-12);
}

TEST(LoadEstimator, ATareTakenInContactLeavesTheLoadedReadingsOutAndTheStopSeesThem) {
  // A path that starts with the tool already pressed against the part (a misplaced plan): the
  // readings while taring are 300 N off the payload's. They stay out of the tare (which is then
  // zero), so the load estimate and the untared force a protective stop compares both show the
  // 300 N instead of a tare hiding it.
  const Payload payload{3.0, Vec3(0, 0, 0.1)};
  const Vec3 g(0, 0, -9.81);
  const Mat3 R = Eigen::AngleAxisd(0.7, Vec3(1, 2, 0).normalized()).toRotationMatrix();
  const Vec3 F_W(0, 300, 0);  // the part pushing on the tool, {W}
  const Wrench rest = payload_reading(payload, R, g);
  const Wrench pressed{rest.force - R.transpose() * F_W, rest.torque};
  LoadEstimator est(payload, g, 0.02);
  for (int k = 0; k <= 20; ++k) est.update(pressed, R, 1e-3 * k);
  ASSERT_TRUE(est.tared());
  const Wrench got = est.update(pressed, R, 0.021);
  EXPECT_LT((got.force - F_W).norm(), 1e-9);
  EXPECT_LT((est.untared_force_W() - F_W).norm(), 1e-9);

  // A small zero offset (within the limit) is tared away as before; the untared force keeps it.
  const Vec3 offset_E(4, -3, 2);
  LoadEstimator free_air(payload, g, 0.02);
  for (int k = 0; k <= 20; ++k) free_air.update({rest.force + offset_E, rest.torque}, R, 1e-3 * k);
  const Wrench loaded{rest.force + offset_E - R.transpose() * F_W, rest.torque};
  EXPECT_LT((free_air.update(loaded, R, 0.03).force - F_W).norm(), 1e-9);
  EXPECT_LT((free_air.untared_force_W() - (F_W - R * offset_E)).norm(), 1e-9);
}

TEST(LoadEstimator, AReTareInFreeAirRemovesTheDriftSinceTheFirstAndKeepsTheTareWhenLoaded) {
  // The zero drifts by 3 N between the tare at the start and a stop in free air before the
  // finishing pass: until the re-tare the estimate carries the drift as a load; while the
  // re-tare is taken the estimate is zero; after it the drift is gone. A re-tare whose readings
  // are all loaded (the tool touching the part) keeps the previous tare.
  const Payload payload{3.0, Vec3(0, 0, 0.1)};
  const Vec3 g(0, 0, -9.81);
  const Mat3 R = Eigen::AngleAxisd(0.4, Vec3(0, 1, 1).normalized()).toRotationMatrix();
  const Wrench rest = payload_reading(payload, R, g);
  const auto reading = [&](const Vec3& zero_E, const Vec3& load_W) {
    return Wrench{rest.force + zero_E - R.transpose() * load_W, rest.torque};
  };
  LoadEstimator est(payload, g, 0.02);
  const Vec3 zero0(2, -1, 0.5);
  for (int k = 0; k <= 20; ++k) est.update(reading(zero0, Vec3::Zero()), R, 1e-3 * k);
  ASSERT_TRUE(est.tared());
  const Vec3 drift_E(0, 3, 0);
  const Vec3 F_W(10, 0, -20);
  // Before the re-tare: the drift reads as load (minus it, in {W}).
  EXPECT_LT(
      (est.update(reading(zero0 + drift_E, F_W), R, 100.0).force - (F_W - R * drift_E)).norm(),
      1e-9);
  est.retare(150.0);
  EXPECT_FALSE(est.tared());
  for (int k = 0; k < 20; ++k)
    EXPECT_EQ(est.update(reading(zero0 + drift_E, Vec3::Zero()), R, 150.0 + 1e-3 * k).force,
              Vec3::Zero());
  est.update(reading(zero0 + drift_E, Vec3::Zero()), R, 150.02);
  ASSERT_TRUE(est.tared());
  EXPECT_LT((est.update(reading(zero0 + drift_E, F_W), R, 200.0).force - F_W).norm(), 1e-9);
  // A re-tare in contact (300 N): every reading is left out, the last tare stays.
  est.retare(250.0);
  for (int k = 0; k <= 20; ++k)
    est.update(reading(zero0 + drift_E, Vec3(0, 300, 0)), R, 250.0 + 1e-3 * k);
  ASSERT_TRUE(est.tared());
  EXPECT_LT((est.update(reading(zero0 + drift_E, F_W), R, 260.0).force - F_W).norm(), 1e-9);
}
