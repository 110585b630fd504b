#pragma once
// Virtual laser scanner: rays cast with Embree over the cell's triangles posed in the world.
// Models an industrial laser line profiler swept over the part and a fixed area
// (structured-light) sensor; points come out in the scanner frame {M}.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::sim {

/// Ground-truth class of a scan point (for scoring only; perception never sees it).
enum TruthLabel : std::uint8_t {
  kTruthBody = 0,        ///< nominal casting surface
  kTruthFlash = 1,       ///< a flash (fin, hole flash, spur)
  kTruthBackground = 2,  ///< table, fixture, robot, floor
  kTruthOutlier = 3,     ///< sparse outlier made by the noise model
  kTruthMixed = 4,       ///< mixed point at a depth discontinuity
};

/// One piece of scene geometry, already posed in the world frame {W}.
struct SceneMesh {
  TriangleMesh mesh_W;
  TruthLabel label = kTruthBackground;  ///< what a hit on it is
  std::string name;
};

/// Measurement physics shared by both sensor kinds.
///
/// A laser ray gives a return when it hits a surface at a distance within the sensor's
/// [range_min, range_max], the laser's incidence angle θ (between the ray and the surface
/// normal) is at most max_incidence, the camera sees the lit side of the surface (camera
/// incidence below 90°; max_incidence is not applied to the camera) and nothing lies between
/// the lit point and the camera. Surfaces closer than range_min still block the laser.
/// Both sides of every triangle reflect (open sheets and back faces are visible).
/// Range noise is Gaussian along the ray; a mixed point lies at a uniformly drawn fraction
/// between the two ranges, on the bisector of the two rays, with normal −(bisector).
/// Random draws come from a counter-based hash of (seed, view, profile/row, ray), so the output
/// does not depend on the thread count.
struct NoiseParams {
  double sigma = 30e-6;            ///< [m] range noise std at normal incidence, along the ray
  double incidence_gain = 1.0;     ///< sigma(θ) = sigma · (1 + gain · tan²θ), θ = laser incidence
  double max_incidence = 1.309;    ///< [rad] (75°) no return beyond this laser incidence angle,
                                   ///< in (0, π/2)
  double mixed_jump = 0.002;       ///< [m] range jump between neighbouring rays (both hitting
                                   ///< within the measuring range) that counts as a discontinuity
  double mixed_probability = 0.5;  ///< chance that a discontinuity yields a mixed point: an
                                   ///< extra point between the two depths (kTruthMixed)
  double outlier_rate = 1e-4;      ///< fraction of returns replaced by sparse outliers
  double outlier_range = 0.02;     ///< [m] outliers spread uniformly ± this along the ray
};

/// A laser line profiler (laser fan in the sensor's y-z plane, looking along +z) swept along
/// the sensor's +x axis; the camera sits `baseline` along −x of the laser, aimed at the
/// stand-off point. Profile k is taken with the laser at x = k · profile_spacing in {S},
/// k = 0 .. floor(sweep_length / profile_spacing); ray j of a profile leaves at the angle
/// −fov/2 + fov · j / (points_per_profile − 1) from +z towards +y (0 for a single ray).
struct LineProfilerParams {
  int points_per_profile = 1280;   ///< rays per laser line
  double fov = 0.6;                ///< [rad] laser fan angle, in (0, π)
  double standoff = 0.30;          ///< [m] distance to the middle of the measuring range (must
                                   ///< lie within [range_min, range_max])
  double range_min = 0.15;         ///< [m] nearest measurable distance along a ray
  double range_max = 0.50;         ///< [m] farthest
  double profile_spacing = 0.0005; ///< [m] sweep distance between profiles
  double sweep_length = 0.40;      ///< [m]
  double baseline = 0.12;          ///< [m] laser–camera triangulation baseline
};

/// A fixed area sensor (structured light): projector at the origin looking along +z, camera
/// `baseline` along +x, aimed at the stand-off point. Pixel (u, v) casts the ray through
/// (tan(fov_x/2)·(2(u+½)/width − 1), tan(fov_y/2)·(2(v+½)/height − 1), 1); rows v play the
/// part of profiles (mixed points come from neighbours u, u+1 in a row).
struct AreaSensorParams {
  int width = 1024, height = 768;    ///< rays (pixels)
  double fov_x = 0.7, fov_y = 0.55;  ///< [rad] full angles, in (0, π)
  double standoff = 0.6;             ///< [m] within [range_min, range_max]
  double range_min = 0.3, range_max = 1.0;  ///< [m] along a ray
  double baseline = 0.2;             ///< [m] projector–camera baseline
};

enum class SensorKind { kLineProfiler, kAreaSensor };

/// One view: which sensor, where. X_MS is the sensor pose {S} at the start of the view in the
/// scanner frame {M}; the true pose in the world is X_WM_true · X_MS.
struct ScanView {
  SensorKind kind = SensorKind::kLineProfiler;
  Pose X_MS = Pose::Identity();
  LineProfilerParams line;
  AreaSensorParams area;
};

struct ScanParams {
  std::vector<ScanView> views;
  NoiseParams noise;
  std::uint64_t seed = 1;  ///< (any value)
  int threads = 1;  ///< worker threads, >= 1 (output is byte-identical for any count)
};

/// Points are ordered by view, then profile (row), then ray; a mixed point follows the first
/// ray of its pair.
struct ScanResult {
  PointCloud cloud_M;                    ///< points (and sensor-facing normals) in {M}; its
                                         ///< labels stay empty (truth is kept apart)
  std::vector<std::uint8_t> truth;       ///< TruthLabel per point (scoring only)
  std::uint64_t rays = 0;                ///< primary rays cast
  double time_s = 0;                     ///< wall time of the scan
  double rays_per_s() const { return time_s > 0 ? rays / time_s : 0; }
};

/// Embree's device configuration used when none is given: "max_isa=avx2", so that every
/// machine of this kind traces with the same kernels (Embree otherwise picks AVX-512 where the
/// CPU has it and AVX2 elsewhere, and the scans then differ in the last bits). The environment
/// variable FLASHTWIN_EMBREE_CONFIG replaces it (e.g. "max_isa=sse4.2" to try another path).
std::string default_embree_config();

/// Embree scene over a set of posed meshes; built once, scanned many times (scan() may be
/// called from several threads at once).
class ScanScene {
 public:
  /// Copies the meshes into Embree (float vertices) and builds the BVH. `embree_config` is
  /// Embree's device configuration string (`man rtcNewDevice`); empty means
  /// default_embree_config().
  /// @throws ArgumentError when there is no triangle at all, or a mesh has a non-finite
  /// vertex or an out-of-range index (naming the mesh), or Embree refuses the configuration.
  explicit ScanScene(const std::vector<SceneMesh>& meshes, const std::string& embree_config = {});
  ~ScanScene();
  /// Triangles in the scene.
  std::size_t num_triangles() const;
  ScanScene(const ScanScene&) = delete;
  ScanScene& operator=(const ScanScene&) = delete;
  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  std::unique_ptr<Impl> impl_;
};

/// Scans the scene. X_WM_true is where the scanner frame really is (it may differ from the
/// calibrated pose the caller reports beside the cloud). Deterministic for a given seed.
/// @throws ArgumentError for impossible parameters (non-positive counts, range_min >= range_max,
/// no views, ...), naming the field ("scan.views[0].line.points_per_profile: expected > 0,
/// got 0"), or when X_WM_true or a view's X_MS is not rigid.
ScanResult scan(const ScanScene& scene, const Pose& X_WM_true, const ScanParams& params);

/// Which of `points_W` the view would measure, by the scanner's own rules (sweep and fan or
/// field of view, measuring range, laser incidence at most `max_incidence` and the camera on
/// the lit side where a normal is given, nothing in the scene on the way from the laser and
/// to the camera). A zero normal skips the incidence tests (a probe point in free space). For
/// scan planning: one exact answer per point, no noise, no sampling.
std::vector<char> view_sees(const ScanScene& scene, const Pose& X_WM, const ScanView& view,
                            const std::vector<Vec3>& points_W, const std::vector<Vec3>& normals_W,
                            double max_incidence);

}  // namespace flashtwin::sim
