#include "flashtwin/sim/scanner.hpp"

#include <embree3/rtcore.h>
#if defined(__SSE__)
#include <xmmintrin.h>
#endif

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <exception>
#include <limits>
#include <mutex>
#include <sstream>
#include <stdexcept>
#include <thread>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {

// ---------------------------------------------------------------------------------------------
// Scene
// ---------------------------------------------------------------------------------------------

struct ScanScene::Impl {
  struct DeviceDeleter {
    void operator()(RTCDeviceTy* d) const { rtcReleaseDevice(d); }
  };
  struct SceneDeleter {
    void operator()(RTCSceneTy* s) const { rtcReleaseScene(s); }
  };
  // Declaration order matters: the scene is released before its device.
  std::unique_ptr<RTCDeviceTy, DeviceDeleter> device;
  std::unique_ptr<RTCSceneTy, SceneDeleter> scene;
  std::vector<TruthLabel> label_of_geom;  ///< indexed by Embree geomID
  std::size_t triangles = 0;
};

namespace {

void check_embree(RTCDevice device, const char* what) {
  const RTCError e = rtcGetDeviceError(device);
  if (e != RTC_ERROR_NONE)
    throw std::runtime_error(std::string("Embree: error ") + std::to_string(static_cast<int>(e)) +
                             " while " + what);
}

}  // namespace

std::string default_embree_config() {
  const char* env = std::getenv("FLASHTWIN_EMBREE_CONFIG");
  return env && *env ? std::string(env) : std::string("max_isa=avx2");
}

ScanScene::ScanScene(const std::vector<SceneMesh>& meshes, const std::string& embree_config)
    : impl_(std::make_unique<Impl>()) {
  // Validate before touching Embree, so bad input never leaves a half-built scene behind.
  std::size_t total = 0;
  for (std::size_t i = 0; i < meshes.size(); ++i) {
    const TriangleMesh& m = meshes[i].mesh_W;
    const std::string where = "scene mesh " + std::to_string(i) + " ('" + meshes[i].name + "')";
    for (std::size_t v = 0; v < m.vertices.size(); ++v)
      if (!m.vertices[v].allFinite())
        throw ArgumentError(where + ": expected finite vertices, got a NaN/inf at vertex " +
                            std::to_string(v));
    const long nv = static_cast<long>(m.vertices.size());
    for (std::size_t t = 0; t < m.triangles.size(); ++t)
      for (int k = 0; k < 3; ++k)
        if (m.triangles[t][k] < 0 || m.triangles[t][k] >= nv)
          throw ArgumentError(where + ": expected vertex indices in [0, " + std::to_string(nv) +
                              "), got " + std::to_string(m.triangles[t][k]) + " in triangle " +
                              std::to_string(t));
    total += m.triangles.size();
  }
  if (total == 0)
    throw ArgumentError("scene: expected at least one triangle, got 0 (in " +
                        std::to_string(meshes.size()) + " meshes)");

  const std::string config = embree_config.empty() ? default_embree_config() : embree_config;
  impl_->device.reset(rtcNewDevice(config.c_str()));
  if (!impl_->device)
    throw ArgumentError("Embree device configuration: expected a valid rtcNewDevice string, got '" +
                        config + "' (error " +
                        std::to_string(static_cast<int>(rtcGetDeviceError(nullptr))) + ")");
  RTCDevice dev = impl_->device.get();
  impl_->scene.reset(rtcNewScene(dev));
  check_embree(dev, "creating the scene");
  RTCScene scn = impl_->scene.get();
  // Robust traversal: the scanner casts regular grids of rays at regularly tessellated meshes,
  // so rays through shared edges are common; they must not slip through closed surfaces.
  rtcSetSceneFlags(scn, RTC_SCENE_FLAG_ROBUST);
  rtcSetSceneBuildQuality(scn, RTC_BUILD_QUALITY_HIGH);

  for (const SceneMesh& sm : meshes) {
    const TriangleMesh& m = sm.mesh_W;
    if (m.triangles.empty()) continue;
    RTCGeometry g = rtcNewGeometry(dev, RTC_GEOMETRY_TYPE_TRIANGLE);
    check_embree(dev, "creating a triangle geometry");
    auto* vb = static_cast<float*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_VERTEX, 0, RTC_FORMAT_FLOAT3, 3 * sizeof(float), m.vertices.size()));
    auto* ib = static_cast<unsigned*>(rtcSetNewGeometryBuffer(
        g, RTC_BUFFER_TYPE_INDEX, 0, RTC_FORMAT_UINT3, 3 * sizeof(unsigned), m.triangles.size()));
    if (!vb || !ib) {
      rtcReleaseGeometry(g);
      check_embree(dev, "allocating geometry buffers");
      throw std::runtime_error("Embree: cannot allocate geometry buffers");
    }
    for (std::size_t v = 0; v < m.vertices.size(); ++v)
      for (int k = 0; k < 3; ++k) vb[3 * v + k] = static_cast<float>(m.vertices[v][k]);
    for (std::size_t t = 0; t < m.triangles.size(); ++t)
      for (int k = 0; k < 3; ++k) ib[3 * t + k] = static_cast<unsigned>(m.triangles[t][k]);
    rtcSetGeometryBuildQuality(g, RTC_BUILD_QUALITY_HIGH);
    rtcCommitGeometry(g);
    const unsigned id = rtcAttachGeometry(scn, g);
    rtcReleaseGeometry(g);  // the scene holds its own reference
    check_embree(dev, "attaching a geometry");
    if (impl_->label_of_geom.size() <= id) impl_->label_of_geom.resize(id + 1, kTruthBackground);
    impl_->label_of_geom[id] = sm.label;
    impl_->triangles += m.triangles.size();
  }
  rtcCommitScene(scn);
  check_embree(dev, "building the BVH");
}

ScanScene::~ScanScene() = default;

std::size_t ScanScene::num_triangles() const {
  return impl_->triangles;
}

// ---------------------------------------------------------------------------------------------
// Scanning
// ---------------------------------------------------------------------------------------------

namespace {

using Vec3f = Eigen::Vector3f;

// ---- Counter-based random numbers: draw i of ray (seed, view, row, ray) is a pure function,
// so neither the thread count nor the order of work changes any value.

constexpr std::uint64_t kGolden = 0x9E3779B97F4A7C15ull;

inline std::uint64_t splitmix64(std::uint64_t x) {
  std::uint64_t z = x + kGolden;
  z = (z ^ (z >> 30)) * 0xBF58476D1CE4E5B9ull;
  z = (z ^ (z >> 27)) * 0x94D049BB133111EBull;
  return z ^ (z >> 31);
}

/// Draw i of the stream keyed by `key`, uniform in [0, 1).
inline double draw(std::uint64_t key, std::uint64_t i) {
  return static_cast<double>(splitmix64(key + i * kGolden) >> 11) * 0x1.0p-53;
}

// Draw slots of one ray's stream.
enum Draw : std::uint64_t {
  kDrawOutlier = 0,
  kDrawNormal = 1,
  kDrawOutlierOffset = 2,
  kDrawMixed = 3,
  kDrawMixedPosition = 4,
};

/// Polynomial c[0] x^(N-1) + ... + c[N-1] (Horner).
template <std::size_t N>
inline double horner(const double (&c)[N], double x) {
  double y = c[0];
  for (std::size_t i = 1; i < N; ++i) y = y * x + c[i];
  return y;
}

/// Standard normal from one draw by the inverse normal CDF (P. J. Acklam's rational
/// approximation, relative error < 1.2e-9). Cheaper than Box-Muller: 95 % of the draws need
/// no log, sqrt or cos.
inline double normal_from(std::uint64_t key, std::uint64_t slot) {
  static constexpr double a[] = {-3.969683028665376e+01, 2.209460984245205e+02,
                                 -2.759285104469687e+02, 1.383577518672690e+02,
                                 -3.066479806614716e+01, 2.506628277459239e+00};
  static constexpr double b[] = {-5.447609879822406e+01, 1.615858368580409e+02,
                                 -1.556989798598866e+02, 6.680131188771972e+01,
                                 -1.328068155288572e+01, 1.0};
  static constexpr double c[] = {-7.784894002430293e-03, -3.223964580411365e-01,
                                 -2.400758277161838e+00, -2.549732539343734e+00,
                                 4.374664141464968e+00,  2.938163982698783e+00};
  static constexpr double d[] = {7.784695709041462e-03, 3.224671290700398e-01,
                                 2.445134137142996e+00, 3.754408661907416e+00, 1.0};
  constexpr double kLow = 0.02425;
  // p in (0, 1), never 0 or 1.
  const double p = (static_cast<double>(splitmix64(key + slot * kGolden) >> 11) + 0.5) * 0x1.0p-53;
  if (p >= kLow && p <= 1.0 - kLow) {
    const double q = p - 0.5, r = q * q;
    return horner(a, r) * q / horner(b, r);
  }
  const double q = std::sqrt(-2.0 * std::log(p < kLow ? p : 1.0 - p));
  const double x = horner(c, q) / horner(d, q);
  return p < kLow ? x : -x;
}

// ---- Parameter validation (messages: "<field>: expected X, got Y").

std::string num(double v) {
  std::ostringstream s;
  s.precision(10);
  s << v;
  return s.str();
}

[[noreturn]] void bad(const std::string& field, const std::string& expected,
                      const std::string& got) {
  throw ArgumentError(field + ": expected " + expected + ", got " + got);
}

void require_positive(const std::string& f, double v) {
  if (!(v > 0) || !std::isfinite(v)) bad(f, "> 0", num(v));
}
void require_nonnegative(const std::string& f, double v) {
  if (!(v >= 0) || !std::isfinite(v)) bad(f, ">= 0", num(v));
}
void require_in(const std::string& f, double v, double lo, double hi, const std::string& text) {
  if (!(v >= lo && v <= hi)) bad(f, text, num(v));
}
void require_angle(const std::string& f, double v) {
  if (!(v > 0 && v < M_PI)) bad(f, "an angle in (0, pi) rad", num(v));
}
void require_range(const std::string& f, double range_min, double range_max, double standoff) {
  require_nonnegative(f + ".range_min", range_min);
  if (!(range_max > range_min) || !std::isfinite(range_max))
    bad(f + ".range_max", "> range_min (" + num(range_min) + ")", num(range_max));
  if (!(standoff >= range_min && standoff <= range_max))
    bad(f + ".standoff",
        "within [range_min, range_max] = [" + num(range_min) + ", " + num(range_max) + "]",
        num(standoff));
}

constexpr double kMaxRaysPerView = 1e9;

/// Profiles of a line-profiler view (validated parameters).
long num_profiles(const LineProfilerParams& p) {
  return static_cast<long>(std::floor(p.sweep_length / p.profile_spacing + 1e-9)) + 1;
}

void validate(const Pose& X_WM_true, const ScanParams& params) {
  if (!is_rigid(X_WM_true.matrix()))
    bad("X_WM_true", "a rigid transform", "a matrix that is not (or holds NaN/inf)");
  if (params.views.empty()) bad("scan.views", "at least one view", "0");
  for (std::size_t i = 0; i < params.views.size(); ++i) {
    const ScanView& v = params.views[i];
    const std::string f = "scan.views[" + std::to_string(i) + "]";
    if (!is_rigid(v.X_MS.matrix()))
      bad(f + ".X_MS", "a rigid transform", "a matrix that is not (or holds NaN/inf)");
    double rays = 0;
    if (v.kind == SensorKind::kLineProfiler) {
      const LineProfilerParams& l = v.line;
      const std::string g = f + ".line";
      if (l.points_per_profile <= 0)
        bad(g + ".points_per_profile", "> 0", std::to_string(l.points_per_profile));
      require_angle(g + ".fov", l.fov);
      require_range(g, l.range_min, l.range_max, l.standoff);
      require_positive(g + ".profile_spacing", l.profile_spacing);
      require_nonnegative(g + ".sweep_length", l.sweep_length);
      require_nonnegative(g + ".baseline", l.baseline);
      const double profiles = std::floor(l.sweep_length / l.profile_spacing + 1e-9) + 1;
      rays = profiles * l.points_per_profile;
    } else if (v.kind == SensorKind::kAreaSensor) {
      const AreaSensorParams& a = v.area;
      const std::string g = f + ".area";
      if (a.width <= 0) bad(g + ".width", "> 0", std::to_string(a.width));
      if (a.height <= 0) bad(g + ".height", "> 0", std::to_string(a.height));
      require_angle(g + ".fov_x", a.fov_x);
      require_angle(g + ".fov_y", a.fov_y);
      require_range(g, a.range_min, a.range_max, a.standoff);
      require_nonnegative(g + ".baseline", a.baseline);
      rays = static_cast<double>(a.width) * a.height;
    } else {
      bad(f + ".kind", "kLineProfiler or kAreaSensor", std::to_string(static_cast<int>(v.kind)));
    }
    if (rays > kMaxRaysPerView) bad(f, "at most 1e9 rays per view", num(rays));
  }
  const NoiseParams& n = params.noise;
  require_nonnegative("scan.noise.sigma", n.sigma);
  require_nonnegative("scan.noise.incidence_gain", n.incidence_gain);
  // Open at pi/2: sigma(θ) grows like tan²θ and is infinite at grazing incidence.
  if (!(n.max_incidence > 0 && n.max_incidence < M_PI / 2))
    bad("scan.noise.max_incidence", "an angle in (0, pi/2) rad", num(n.max_incidence));
  require_positive("scan.noise.mixed_jump", n.mixed_jump);
  require_in("scan.noise.mixed_probability", n.mixed_probability, 0, 1, "a probability in [0, 1]");
  require_in("scan.noise.outlier_rate", n.outlier_rate, 0, 1, "a probability in [0, 1]");
  require_nonnegative("scan.noise.outlier_range", n.outlier_range);
  if (params.threads < 1 || params.threads > 1024)
    bad("scan.threads", "an integer in [1, 1024]", std::to_string(params.threads));
}

// ---- Work description.

/// One view, prepared: everything a row needs, in {M} (double, for the output) and in {W}
/// (float, for Embree).
struct ViewPlan {
  int index = 0;
  SensorKind kind = SensorKind::kLineProfiler;
  int rows = 0, cols = 0;
  float range_min = 0, range_max = 0;
  // Line profiler: origin of profile k is o0_M + k · step_M; directions fixed for the view.
  Vec3 o0_M = Vec3::Zero(), step_M = Vec3::Zero();
  std::vector<Vec3> dir_M;   // [cols]
  std::vector<Vec3f> dir_W;  // [cols]
  // Area sensor: fixed origin, directions per row from the pinhole model.
  Mat3 R_MS = Mat3::Identity();
  double tan_x = 0, tan_y = 0;
  Vec3 cam_offset_M = Vec3::Zero();  // camera = ray origin + cam_offset_M
  std::uint64_t key = 0;             // hash of (seed, view)
};

/// A block of consecutive rows of one view.
struct Task {
  const ViewPlan* view = nullptr;
  int row_begin = 0, row_end = 0;
};

/// Output of one task: sized for the worst case, the first `count` entries used. Blocks are
/// recycled, so their pages are faulted in once per scan rather than once per task.
struct Block {
  std::vector<Vec3f> points, normals;
  std::vector<std::uint8_t> truth;
  std::size_t count = 0;
};

/// Per-thread scratch for one row.
struct RowScratch {
  std::vector<float> t;           // laser hit distance within range, or -1
  std::vector<std::uint8_t> ret;  // 1 when the ray gives a return
  std::vector<float> cos_inc;     // cosine of the laser incidence angle
  std::vector<Vec3f> n_W;         // unit normal facing the sensor
  std::vector<std::uint8_t> label;
  std::vector<Vec3> dir_M;
  std::vector<Vec3f> dir_W;
  void resize(int n) {
    t.resize(n);
    ret.resize(n);
    cos_inc.resize(n);
    n_W.resize(n);
    label.resize(n);
    dir_M.resize(n);
    dir_W.resize(n);
  }
};

/// Constant state of one scan() call shared by all workers.
struct ScanContext {
  RTCScene scene = nullptr;
  const std::vector<TruthLabel>* labels = nullptr;
  Pose X_WM;
  Mat3 R_MW;
  NoiseParams noise;
  float cos_max_incidence = 0;
};

/// True when Embree may be handed this ray: finite origin, finite non-zero direction and
/// 0 <= tnear <= tfar < inf. Debian's Embree asserts this for every active lane of a packet,
/// and elsewhere such a lane is undefined behaviour.
bool ray_is_valid(const Vec3f& org, const Vec3f& dir, float tnear, float tfar) {
  return org.allFinite() && dir.allFinite() && dir.squaredNorm() > 0.0f && tnear >= 0.0f &&
         tnear <= tfar && std::isfinite(tfar);
}

/// Writes one lane of a ray packet. Every lane is written, also the inactive ones, so that no
/// stale or uninitialised value ever reaches Embree; a lane whose ray is not valid is masked.
template <class RayK>
void set_lane(RayK& r, int* valid, int i, bool active, const Vec3f& org, const Vec3f& dir,
              float tnear, float tfar) {
  const bool ok = active && ray_is_valid(org, dir, tnear, tfar);
  // A benign ray for masked lanes: from the origin along +z over an empty interval.
  const Vec3f o = ok ? org : Vec3f::Zero();
  const Vec3f d = ok ? dir : Vec3f::UnitZ();
  r.org_x[i] = o.x();
  r.org_y[i] = o.y();
  r.org_z[i] = o.z();
  r.dir_x[i] = d.x();
  r.dir_y[i] = d.y();
  r.dir_z[i] = d.z();
  r.tnear[i] = ok ? tnear : 0.0f;
  r.tfar[i] = ok ? tfar : 0.0f;
  r.time[i] = 0.0f;
  r.mask[i] = ~0u;
  r.id[i] = static_cast<unsigned>(i);
  r.flags[i] = 0;
  valid[i] = ok ? -1 : 0;
}

/// Traces the rays of one row: laser hits, incidence and camera visibility, in packets of 16.
/// Fills s.t, s.ret, s.cos_inc, s.n_W, s.label for rays [0, cols).
void trace_row(const ScanContext& C, const Vec3f& o_W, const Vec3f& cam_W, const Vec3f* dir_W,
               int cols, float range_min, float range_max, RowScratch& s) {
  RTCIntersectContext ictx;
  rtcInitIntersectContext(&ictx);
  ictx.flags = RTC_INTERSECT_CONTEXT_FLAG_COHERENT;

  alignas(64) RTCRayHit16 rh;
  alignas(64) RTCRay16 sh;
  alignas(64) int valid[16];
  alignas(64) int svalid[16];

  for (int j0 = 0; j0 < cols; j0 += 16) {
    const int n = std::min(16, cols - j0);
    bool any_laser = false;
    for (int i = 0; i < 16; ++i) {
      // Beyond range_max nothing matters; nearer than range_min still blocks the laser.
      const bool active = i < n;
      set_lane(rh.ray, valid, i, active, o_W, active ? dir_W[j0 + i] : Vec3f::UnitZ(), 0.0f,
               range_max);
      any_laser = any_laser || valid[i];
      rh.hit.geomID[i] = RTC_INVALID_GEOMETRY_ID;
      rh.hit.instID[0][i] = RTC_INVALID_GEOMETRY_ID;
    }
    if (any_laser) rtcIntersect16(valid, C.scene, &ictx, &rh);

    bool any_shadow = false;
    for (int i = 0; i < 16; ++i) {
      set_lane(sh, svalid, i, false, Vec3f::Zero(), Vec3f::UnitZ(), 0.0f, 0.0f);
      if (i >= n) continue;
      const int j = j0 + i;
      s.t[j] = -1.0f;
      s.ret[j] = 0;
      if (!valid[i] || rh.hit.geomID[i] == RTC_INVALID_GEOMETRY_ID) continue;
      const float t = rh.ray.tfar[i];
      if (t < range_min) continue;  // too close to measure
      s.t[j] = t;
      const Vec3f& d = dir_W[j];
      Vec3f ng(rh.hit.Ng_x[i], rh.hit.Ng_y[i], rh.hit.Ng_z[i]);
      const float len = ng.norm();
      if (!(len > 0)) continue;
      ng /= len;
      // Face the normal towards the sensor; both sides of a triangle reflect.
      float c = -ng.dot(d);
      if (c < 0) {
        ng = -ng;
        c = -c;
      }
      if (c < C.cos_max_incidence) continue;  // laser too grazing: no return
      const Vec3f p = o_W + t * d;
      Vec3f to_cam = cam_W - p;
      const float dist = to_cam.norm();
      // The camera must look at the lit side of the surface (the visibility ray below would
      // find that too, through the surface itself; this is cheaper and immune to rounding).
      if (!(dist > 0) || ng.dot(to_cam) <= 0) continue;
      to_cam /= dist;
      // Start the camera ray just off the surface so it does not hit the lit triangle again.
      const float eps = 1e-5f * (1.0f + p.cwiseAbs().maxCoeff());
      set_lane(sh, svalid, i, true, p + eps * ng, to_cam, 0.0f, std::max(0.0f, dist - eps));
      if (!svalid[i]) continue;
      any_shadow = true;
      s.n_W[j] = ng;
      s.cos_inc[j] = c;
      const unsigned g = rh.hit.geomID[i];
      s.label[j] = g < C.labels->size() ? (*C.labels)[g] : kTruthBackground;
    }
    if (!any_shadow) continue;
    rtcOccluded16(svalid, C.scene, &ictx, &sh);
    // An occluded ray comes back with tfar = -inf.
    for (int i = 0; i < n; ++i)
      if (svalid[i] && sh.tfar[i] >= 0.0f) s.ret[j0 + i] = 1;
  }
}

/// Turns a traced row into points (noise, outliers, mixed points), appended to the task.
void emit_row(const ScanContext& C, const ViewPlan& V, int row, const Vec3& o_M, const Vec3* dir_M,
              const RowScratch& s, Block& out) {
  const NoiseParams& N = C.noise;
  const std::uint64_t row_key = splitmix64(V.key ^ static_cast<std::uint64_t>(row));
  const Eigen::Matrix3f R_MW = C.R_MW.cast<float>();
  const int cols = V.cols;
  for (int j = 0; j < cols; ++j) {
    if (!s.ret[j] && s.t[j] < 0) continue;  // nothing to emit for this ray
    const std::uint64_t key = splitmix64(row_key ^ static_cast<std::uint64_t>(j));
    if (s.ret[j]) {
      const double t = s.t[j];
      double tm;
      std::uint8_t label = s.label[j];
      if (N.outlier_rate > 0 && draw(key, kDrawOutlier) < N.outlier_rate) {
        tm = t + (2.0 * draw(key, kDrawOutlierOffset) - 1.0) * N.outlier_range;
        label = kTruthOutlier;
      } else if (N.sigma > 0) {
        const double c = s.cos_inc[j];
        const double tan2 = std::max(0.0, (1.0 - c * c) / (c * c));
        const double sigma = N.sigma * (1.0 + N.incidence_gain * tan2);
        tm = t + sigma * normal_from(key, kDrawNormal);
      } else {
        tm = t;
      }
      const std::size_t k = out.count++;
      out.points[k] = (o_M + tm * dir_M[j]).cast<float>();
      out.normals[k] = R_MW * s.n_W[j];
      out.truth[k] = label;
    }
    // Mixed point: the spot straddles a depth jump between rays j and j+1.
    if (j + 1 < cols && s.t[j] >= 0 && s.t[j + 1] >= 0 && N.mixed_probability > 0 &&
        std::abs(static_cast<double>(s.t[j + 1]) - s.t[j]) > N.mixed_jump &&
        draw(key, kDrawMixed) < N.mixed_probability) {
      const double a = draw(key, kDrawMixedPosition);
      const double tm = s.t[j] + a * (static_cast<double>(s.t[j + 1]) - s.t[j]);
      const Vec3 d = (dir_M[j] + dir_M[j + 1]).normalized();
      const std::size_t k = out.count++;
      out.points[k] = (o_M + tm * d).cast<float>();
      out.normals[k] = (-d).cast<float>();
      out.truth[k] = kTruthMixed;
    }
  }
}

/// Runs one task (a block of rows of one view).
void run_task(const ScanContext& C, const Task& task, RowScratch& s, Block& out) {
  const ViewPlan& V = *task.view;
  s.resize(V.cols);
  // At most one return per ray plus one mixed point per neighbour pair. Vector3f's default
  // constructor leaves memory untouched, so unused capacity costs no page faults.
  const std::size_t bound = static_cast<std::size_t>(task.row_end - task.row_begin) *
                            (2 * static_cast<std::size_t>(V.cols) - 1);
  if (out.points.size() < bound) {
    out.points.resize(bound);
    out.normals.resize(bound);
    out.truth.resize(bound);
  }
  out.count = 0;
  const Mat3 R_WM = C.X_WM.linear();
  for (int row = task.row_begin; row < task.row_end; ++row) {
    Vec3 o_M, cam_M;
    const Vec3* dir_M;
    const Vec3f* dir_W;
    if (V.kind == SensorKind::kLineProfiler) {
      o_M = V.o0_M + static_cast<double>(row) * V.step_M;
      dir_M = V.dir_M.data();
      dir_W = V.dir_W.data();
    } else {
      o_M = V.o0_M;
      const double y = V.tan_y * (2.0 * (row + 0.5) / V.rows - 1.0);
      for (int u = 0; u < V.cols; ++u) {
        const double x = V.tan_x * (2.0 * (u + 0.5) / V.cols - 1.0);
        s.dir_M[u] = V.R_MS * Vec3(x, y, 1.0).normalized();
        s.dir_W[u] = (R_WM * s.dir_M[u]).cast<float>();
      }
      dir_M = s.dir_M.data();
      dir_W = s.dir_W.data();
    }
    cam_M = o_M + V.cam_offset_M;
    const Vec3f o_W = (C.X_WM * o_M).cast<float>();
    const Vec3f cam_W = (C.X_WM * cam_M).cast<float>();
    trace_row(C, o_W, cam_W, dir_W, V.cols, V.range_min, V.range_max, s);
    emit_row(C, V, row, o_M, dir_M, s, out);
  }
}

/// Flush-to-zero / denormals-are-zero (as Embree recommends), restored on scope exit. Every
/// worker sets it, so results do not depend on which thread ran a block.
class FastFloatScope {
 public:
#if defined(__SSE__)
  FastFloatScope() : saved_(_mm_getcsr()) {
    _mm_setcsr(saved_ | 0x8040u);
  }
  ~FastFloatScope() {
    _mm_setcsr(saved_);
  }
#else
  FastFloatScope() = default;
#endif
  FastFloatScope(const FastFloatScope&) = delete;
  FastFloatScope& operator=(const FastFloatScope&) = delete;

 private:
  unsigned saved_ = 0;
};

ViewPlan plan_view(int index, const ScanView& v, const Pose& X_WM, std::uint64_t seed) {
  ViewPlan V;
  V.index = index;
  V.kind = v.kind;
  V.key = splitmix64(splitmix64(seed) ^ static_cast<std::uint64_t>(index));
  V.R_MS = v.X_MS.linear();
  const Vec3 x_M = V.R_MS.col(0);
  V.o0_M = v.X_MS.translation();
  if (v.kind == SensorKind::kLineProfiler) {
    const LineProfilerParams& l = v.line;
    V.rows = static_cast<int>(num_profiles(l));
    V.cols = l.points_per_profile;
    V.range_min = static_cast<float>(l.range_min);
    V.range_max = static_cast<float>(l.range_max);
    V.step_M = l.profile_spacing * x_M;
    V.cam_offset_M = -l.baseline * x_M;
    V.dir_M.resize(V.cols);
    V.dir_W.resize(V.cols);
    for (int j = 0; j < V.cols; ++j) {
      const double phi = V.cols > 1 ? -0.5 * l.fov + l.fov * j / (V.cols - 1) : 0.0;
      V.dir_M[j] = V.R_MS * Vec3(0.0, std::sin(phi), std::cos(phi));
      V.dir_W[j] = (X_WM.linear() * V.dir_M[j]).cast<float>();
    }
  } else {
    const AreaSensorParams& a = v.area;
    V.rows = a.height;
    V.cols = a.width;
    V.range_min = static_cast<float>(a.range_min);
    V.range_max = static_cast<float>(a.range_max);
    V.tan_x = std::tan(0.5 * a.fov_x);
    V.tan_y = std::tan(0.5 * a.fov_y);
    V.cam_offset_M = a.baseline * x_M;
  }
  return V;
}

}  // namespace

ScanResult scan(const ScanScene& scene, const Pose& X_WM_true, const ScanParams& params) {
  const auto t0 = std::chrono::steady_clock::now();
  validate(X_WM_true, params);

  ScanContext C;
  C.scene = scene.impl().scene.get();
  C.labels = &scene.impl().label_of_geom;
  C.X_WM = X_WM_true;
  C.R_MW = X_WM_true.linear().transpose();
  C.noise = params.noise;
  C.cos_max_incidence = static_cast<float>(std::cos(params.noise.max_incidence));

  std::vector<ViewPlan> views;
  views.reserve(params.views.size());
  for (std::size_t i = 0; i < params.views.size(); ++i)
    views.push_back(plan_view(static_cast<int>(i), params.views[i], X_WM_true, params.seed));

  // Blocks of about 64k rays: small enough to balance threads, large enough to amortise.
  std::vector<Task> tasks;
  ScanResult result;
  for (const ViewPlan& V : views) {
    result.rays += static_cast<std::uint64_t>(V.rows) * V.cols;
    const int block = std::max(1, 65536 / V.cols);
    for (int r = 0; r < V.rows; r += block) {
      Task t;
      t.view = &V;
      t.row_begin = r;
      t.row_end = std::min(V.rows, r + block);
      tasks.push_back(std::move(t));
    }
  }

  // Workers pull tasks in order and write into blocks of their own; a finished block is
  // appended to the result as soon as all blocks before it are in (so the output order is
  // (view, row, ray) whatever the thread count), then recycled.
  result.cloud_M.points.reserve(result.rays);
  result.cloud_M.normals.reserve(result.rays);
  result.truth.reserve(result.rays);
  std::mutex mutex;
  std::vector<std::unique_ptr<Block>> finished(tasks.size());
  std::vector<std::unique_ptr<Block>> spare;
  std::size_t next_commit = 0;
  auto commit = [&](std::size_t i, std::unique_ptr<Block> block) {
    std::lock_guard<std::mutex> lock(mutex);
    finished[i] = std::move(block);
    for (; next_commit < tasks.size() && finished[next_commit]; ++next_commit) {
      const Block& b = *finished[next_commit];
      const std::size_t at = result.truth.size(), n = b.count;
      // Plain byte copies (Eigen's vectors are not trivially copyable to the library).
      result.cloud_M.points.resize(at + n);
      result.cloud_M.normals.resize(at + n);
      result.truth.resize(at + n);
      std::memcpy(static_cast<void*>(result.cloud_M.points.data() + at), b.points.data(),
                  n * sizeof(Vec3f));
      std::memcpy(static_cast<void*>(result.cloud_M.normals.data() + at), b.normals.data(),
                  n * sizeof(Vec3f));
      std::memcpy(result.truth.data() + at, b.truth.data(), n);
      spare.push_back(std::move(finished[next_commit]));
    }
  };
  auto take_block = [&]() {
    std::lock_guard<std::mutex> lock(mutex);
    if (spare.empty()) return std::make_unique<Block>();
    std::unique_ptr<Block> b = std::move(spare.back());
    spare.pop_back();
    return b;
  };

  std::atomic<std::size_t> next{0};
  std::exception_ptr error;
  std::atomic<bool> failed{false};
  auto worker = [&]() {
    try {
      FastFloatScope ftz;
      RowScratch scratch;
      for (std::size_t i = next++; i < tasks.size() && !failed; i = next++) {
        std::unique_ptr<Block> block = take_block();
        run_task(C, tasks[i], scratch, *block);
        commit(i, std::move(block));
      }
    } catch (...) {  // only allocation failures can end up here
      std::lock_guard<std::mutex> lock(mutex);
      if (!failed.exchange(true)) error = std::current_exception();
    }
  };
  const int nthreads = static_cast<int>(
      std::min<std::size_t>(static_cast<std::size_t>(params.threads), tasks.size()));
  if (nthreads <= 1) {
    worker();
  } else {
    std::vector<std::thread> pool;
    pool.reserve(nthreads);
    try {
      for (int k = 0; k < nthreads; ++k) pool.emplace_back(worker);
    } catch (...) {  // cannot start a thread: stop the others before unwinding
      failed = true;
      for (auto& th : pool) th.join();
      throw;
    }
    for (auto& th : pool) th.join();
  }
  if (error) std::rethrow_exception(error);
  FT_ASSERT(next_commit == tasks.size());
  result.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  return result;
}

}  // namespace flashtwin::sim

namespace flashtwin::sim {

namespace {

/// True when nothing in the scene lies on the open segment from `from` to `to` (both in {W}),
/// apart from the last `eps` before `to` (the surface the point lies on).
bool segment_clear(RTCScene scene, const Vec3& from, const Vec3& to, double eps) {
  const Vec3 d = to - from;
  const double len = d.norm();
  if (!(len > eps)) return true;
  RTCIntersectContext ctx;
  rtcInitIntersectContext(&ctx);
  RTCRay ray;
  ray.org_x = static_cast<float>(from.x());
  ray.org_y = static_cast<float>(from.y());
  ray.org_z = static_cast<float>(from.z());
  const Vec3 u = d / len;
  ray.dir_x = static_cast<float>(u.x());
  ray.dir_y = static_cast<float>(u.y());
  ray.dir_z = static_cast<float>(u.z());
  ray.tnear = 0.0f;
  ray.tfar = static_cast<float>(len - eps);
  ray.time = 0.0f;
  ray.mask = ~0u;
  ray.id = 0;
  ray.flags = 0;
  rtcOccluded1(scene, &ctx, &ray);
  return ray.tfar >= 0.0f;  // an occluded ray comes back with tfar = -inf
}

}  // namespace

std::vector<char> view_sees(const ScanScene& scene, const Pose& X_WM, const ScanView& view,
                            const std::vector<Vec3>& points_W, const std::vector<Vec3>& normals_W,
                            double max_incidence) {
  FT_ASSERT(normals_W.size() == points_W.size());
  std::vector<char> seen(points_W.size(), 0);
  const RTCScene s = scene.impl().scene.get();
  const Pose X_WS = X_WM * view.X_MS;
  const Pose X_SW = X_WS.inverse();
  const Vec3 x_W = X_WS.linear().col(0);
  const double cos_max = std::cos(max_incidence);
  constexpr double eps = 2e-4;  // [m] the last bit before the point: its own surface
  for (std::size_t i = 0; i < points_W.size(); ++i) {
    const Vec3 q_S = X_SW * points_W[i];
    Vec3 laser_W, cam_W;
    double range = 0;
    if (view.kind == SensorKind::kLineProfiler) {
      // The profile whose laser plane (x = const in {S}) holds the point, if the sweep has it.
      const LineProfilerParams& l = view.line;
      const double x = q_S.x();
      const double last = static_cast<double>(num_profiles(l) - 1) * l.profile_spacing;
      if (x < 0 || x > last || q_S.z() <= 0) continue;
      if (std::abs(std::atan2(q_S.y(), q_S.z())) > 0.5 * l.fov) continue;
      range = std::hypot(q_S.y(), q_S.z());
      if (range < l.range_min || range > l.range_max) continue;
      laser_W = X_WS * Vec3(x, 0, 0);
      cam_W = laser_W - l.baseline * x_W;
    } else {
      const AreaSensorParams& a = view.area;
      if (q_S.z() <= 0 || std::abs(q_S.x() / q_S.z()) > std::tan(0.5 * a.fov_x) ||
          std::abs(q_S.y() / q_S.z()) > std::tan(0.5 * a.fov_y))
        continue;
      range = q_S.norm();
      if (range < a.range_min || range > a.range_max) continue;
      laser_W = X_WS.translation();
      cam_W = laser_W + a.baseline * x_W;
    }
    const Vec3& n = normals_W[i];
    if (n.squaredNorm() > 0) {
      // Laser incidence (either side reflects) and the camera on the lit side.
      const Vec3 to_laser = (laser_W - points_W[i]).normalized();
      const double c = n.dot(to_laser);
      if (std::abs(c) < cos_max) continue;
      const Vec3 lit = c > 0 ? n : Vec3(-n);
      if (lit.dot(cam_W - points_W[i]) <= 0) continue;
    }
    seen[i] = segment_clear(s, laser_W, points_W[i], eps) && segment_clear(s, cam_W, points_W[i], eps);
  }
  return seen;
}

}  // namespace flashtwin::sim
