#pragma once
// The flange force/torque sensor as the robot controller reads it, and the controller's estimate
// of the process load from that reading (MuJoCo-free: the executor feeds it the wrench MuJoCo's
// flange sensors compute).
//
// Frames: the sensor frame {E} is the flange (site `flange`, on the tool body); readings are in
// {E}, torques about its origin. The reading is the wrench the wrist exerts on the tool (MuJoCo's
// convention for a force/torque sensor on the child body), so at rest it carries the tool's
// weight upwards and under a process load it changes by minus that load.
//
// Sensor model, per sample (period T_s):
//   zero offset  b_k = b_{k-1} + σ_drift·√T_s·ξ        (random walk; b_0 ~ N(0, σ_offset²))
//   filter       y_k = y_{k-1} + α·(w_k + b_k − y_{k-1}), α = 1 − exp(−2π·f_c·T_s)
//   output       r_k = clamp(y_k + σ_noise·ξ, ±range)
// with w_k the true wrench, ξ independent standard normals per axis.
//
// Controller (LoadEstimator): the load on the tool from the reading, as a robot with a flange
// sensor computes it: minus (reading − the payload's static wrench at the flange's orientation
// (load data: mass and centre of mass, gravity in {W}) − the tare). The tare is the mean of
// (reading − payload) over the first `tare_time` of a motion, which starts at rest in free air
// (the sensor zeroed before each path, as cells do), and again wherever the plan stops the arm
// in free air (retare). The payload's inertial forces are not
// removed (at grinding feeds they are below the sensor's noise).
//
// Defaults: a 6-axis strain-gauge sensor sized for robotic grinding (process forces up to the
// 2 kN protective stop). They are of the order such sensors publish, not one datasheet's
// figures: a ±2500 N / ±400 N·m range (the class of ATI's Omega160; its datasheet was not at
// hand here), output noise 0.5 N / 0.05 N·m RMS per axis, samples every 2 ms (ATI's Ethernet
// Axia streams at 0.5–8 kHz, ATI manual 9620-05-C-Ethernet Axia, table 5.5; a KUKA RSI cycle is
// 4 ms), a 152 Hz low-pass, a zero offset of 5 N / 0.25 N·m at switch-on and a drift of
// 0.2 N/√s (the spindle warming the flange; an assumption). For scale: UR's CB-series arms,
// whose force is estimated from motor currents, are quoted at ±10 N / ±5 N·m (UR forum,
// "internal force sensor properties").
#include <cstdint>

#include "flashtwin/core/random.hpp"
#include "flashtwin/core/transform.hpp"

namespace flashtwin::sim {

/// The sensor's parameters (fields named `execution.sensor.<field>` in error messages).
struct FtSensorParams {
  double period = 0.002;        ///< [s] sample period of the readings the controller gets
  double cutoff = 152;          ///< [Hz] first-order low-pass of the sensor's output
  double force_noise = 0.5;     ///< [N] RMS noise of each force axis of the output
  double torque_noise = 0.05;   ///< [N·m] RMS noise of each torque axis
  double force_offset = 5.0;    ///< [N] σ of each force axis's zero offset at the start
  double torque_offset = 0.25;  ///< [N·m] σ of each torque axis's zero offset
  double force_drift = 0.2;     ///< [N/√s] random walk of the force zero offset
  double torque_drift = 0.01;   ///< [N·m/√s] random walk of the torque zero offset
  double force_range = 2500;    ///< [N] the reading saturates here (each axis)
  double torque_range = 400;    ///< [N·m]
  /// [s] the controller tares the sensor over this long at the start of each motion.
  double tare_time = 0.02;
};

/// @throws ArgumentError naming the field (`execution.sensor.cutoff`, ...).
void check_ft_sensor_params(const FtSensorParams& params);

/// A wrench: force [N] and torque [N·m] (about a stated point, in a stated frame).
struct Wrench {
  Vec3 force = Vec3::Zero();
  Vec3 torque = Vec3::Zero();
};

/// The sensor's state: one per motion (seeded), advanced once per sample.
class FtSensor {
 public:
  FtSensor(const FtSensorParams& params, std::uint64_t seed);
  /// One sample of the true wrench w_E at the flange ({E}, about its origin) → the reading.
  Wrench sample(const Wrench& true_E);
  /// A step in the zero offset from the next sample on (a fault: a cable pulled, a thermal
  /// shock); filtered like any change of the input.
  void shift_zero(const Wrench& step_E) {
    offset_.force += step_E.force;
    offset_.torque += step_E.torque;
  }
  const FtSensorParams& params() const { return params_; }

 private:
  FtSensorParams params_;
  Rng rng_;
  Wrench offset_, filtered_;
  bool started_ = false;
};

/// What the controller is told of the tool (KUKA LOAD_DATA, a UR payload): mass [kg] and centre
/// of mass in {E} [m].
struct Payload {
  double mass = 0;
  Vec3 com_E = Vec3::Zero();
};

/// The reading the payload alone gives at rest with the flange at orientation R_WE (gravity g_W
/// [m/s²] in {W}): the wrench holding it up, in {E}, about the flange.
Wrench payload_reading(const Payload& payload, const Mat3& R_WE, const Vec3& g_W);

/// The controller's estimate of the load on the tool from the sensor's readings.
class LoadEstimator {
 public:
  LoadEstimator(const Payload& payload, const Vec3& g_W, double tare_time)
      : payload_(payload), g_W_(g_W), tare_time_(tare_time) {}
  /// Feeds a reading taken at motion time t [s] with the flange at R_WE; returns the load on the
  /// tool (force, torque about the flange) in {W}. Zero while taring (t < the tare's start +
  /// tare_time; the first starts at 0). A reading
  /// more than kTareLimit off the payload's is a loaded sensor (the tool touching something) and
  /// is left out of the tare; with no reading left the tare is zero.
  Wrench update(const Wrench& reading_E, const Mat3& R_WE, double t);
  /// Zero the sensor again over tare_time from motion time t [s] (the arm stopped in free air):
  /// the readings then replace the tare; until it is taken update() returns zero. With no
  /// reading within kTareLimit the previous tare stays.
  void retare(double t);
  bool tared() const { return tared_; }
  /// The latest reading less the payload, untared, {W}: what a protective stop compares with
  /// its limit (a tare taken in contact cannot hide a collision).
  const Vec3& untared_force_W() const { return untared_W_; }
  static constexpr double kTareLimit = 25;  ///< [N] (5 σ of the default zero offset)

 private:
  Payload payload_;
  Vec3 g_W_;
  double tare_time_;
  double tare_start_ = 0;  ///< [s] motion time the current tare window opened
  Wrench sum_, tare_;
  Vec3 untared_W_ = Vec3::Zero();
  int n_ = 0;
  bool tared_ = false;
};

}  // namespace flashtwin::sim
