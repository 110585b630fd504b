#include "flashtwin/sim/ft_sensor.hpp"

#include <algorithm>
#include <cmath>
#include <string>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {

namespace {

[[noreturn]] void bad(const std::string& field, const std::string& expected, double got) {
  throw ArgumentError("execution.sensor." + field + ": expected " + expected + ", got " +
                      std::to_string(got));
}

void check_non_negative(const std::string& field, double v, const char* unit) {
  if (!(std::isfinite(v) && v >= 0)) bad(field, std::string("a finite value >= 0 [") + unit + "]", v);
}

Vec3 normal3(Rng& rng) {
  // Evaluated in a fixed order (x, y, z): the sequence does not depend on the compiler.
  const double x = rng.normal();
  const double y = rng.normal();
  const double z = rng.normal();
  return Vec3(x, y, z);
}

Vec3 clamp3(const Vec3& v, double range) {
  return v.cwiseMax(Vec3::Constant(-range)).cwiseMin(Vec3::Constant(range));
}

}  // namespace

void check_ft_sensor_params(const FtSensorParams& p) {
  if (!(std::isfinite(p.period) && p.period >= 1e-4 && p.period <= 0.1))
    bad("period", "a sample period in [0.0001, 0.1] s", p.period);
  if (!(std::isfinite(p.cutoff) && p.cutoff > 0)) bad("cutoff", "a finite frequency > 0 [Hz]", p.cutoff);
  check_non_negative("force_noise", p.force_noise, "N");
  check_non_negative("torque_noise", p.torque_noise, "N*m");
  check_non_negative("force_offset", p.force_offset, "N");
  check_non_negative("torque_offset", p.torque_offset, "N*m");
  check_non_negative("force_drift", p.force_drift, "N/sqrt(s)");
  check_non_negative("torque_drift", p.torque_drift, "N*m/sqrt(s)");
  if (!(std::isfinite(p.force_range) && p.force_range > 0))
    bad("force_range", "a finite force > 0 [N]", p.force_range);
  if (!(std::isfinite(p.torque_range) && p.torque_range > 0))
    bad("torque_range", "a finite torque > 0 [N*m]", p.torque_range);
  if (!(std::isfinite(p.tare_time) && p.tare_time >= 0 && p.tare_time <= 1))
    bad("tare_time", "a time in [0, 1] s", p.tare_time);
}

FtSensor::FtSensor(const FtSensorParams& params, std::uint64_t seed) : params_(params), rng_(seed) {
  check_ft_sensor_params(params);
  offset_.force = params.force_offset * normal3(rng_);
  offset_.torque = params.torque_offset * normal3(rng_);
}

Wrench FtSensor::sample(const Wrench& true_E) {
  const FtSensorParams& p = params_;
  const double walk = std::sqrt(p.period);
  offset_.force += p.force_drift * walk * normal3(rng_);
  offset_.torque += p.torque_drift * walk * normal3(rng_);
  const Vec3 f = true_E.force + offset_.force, tau = true_E.torque + offset_.torque;
  if (!started_) {
    // The sensor has been on for a while: its filter has settled on the first value.
    filtered_ = {f, tau};
    started_ = true;
  } else {
    // First-order low-pass, exact for a value held over the sample period.
    const double alpha = 1 - std::exp(-2 * M_PI * p.cutoff * p.period);
    filtered_.force += alpha * (f - filtered_.force);
    filtered_.torque += alpha * (tau - filtered_.torque);
  }
  Wrench out;
  out.force = clamp3(filtered_.force + p.force_noise * normal3(rng_), p.force_range);
  out.torque = clamp3(filtered_.torque + p.torque_noise * normal3(rng_), p.torque_range);
  return out;
}

Wrench payload_reading(const Payload& payload, const Mat3& R_WE, const Vec3& g_W) {
  // At rest the wrist holds the payload up: force −m·g, and the torque that cancels the weight's
  // moment about the flange, −c × (m·g), both in {E}.
  const Vec3 weight_E = R_WE.transpose() * (payload.mass * g_W);
  return {-weight_E, -payload.com_E.cross(weight_E)};
}

Wrench LoadEstimator::update(const Wrench& reading_E, const Mat3& R_WE, double t) {
  const Wrench rest = payload_reading(payload_, R_WE, g_W_);
  const Vec3 f = reading_E.force - rest.force, tau = reading_E.torque - rest.torque;
  untared_W_ = -(R_WE * f);
  if (!tared_) {
    if (f.norm() <= kTareLimit) {
      sum_.force += f;
      sum_.torque += tau;
      ++n_;
    }
    if (t + 1e-12 < tare_start_ + tare_time_) return {};
    if (n_ > 0) tare_ = {sum_.force / n_, sum_.torque / n_};
    tared_ = true;
  }
  // The reading changes by minus the load on the tool.
  return {-(R_WE * (f - tare_.force)), -(R_WE * (tau - tare_.torque))};
}

void LoadEstimator::retare(double t) {
  tare_start_ = t;
  tared_ = false;
  sum_ = {};
  n_ = 0;
}

}  // namespace flashtwin::sim
