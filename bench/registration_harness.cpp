#include "registration_harness.hpp"

#include <sys/utsname.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <ctime>
#include <fstream>
#include <limits>
#include <memory>
#include <numeric>
#include <set>
#include <sstream>
#include <thread>
#include <unordered_set>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/baselines.hpp"
#include "flashtwin/perception/registration.hpp"
#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/scanner.hpp"

namespace flashtwin::bench {

namespace {

const std::vector<std::string> kDatasets{"bunny", "dragon", "armadillo", "casting"};
const std::vector<std::string> kMethods{"ours", "sacia-ndt", "sacia-ndt-icp", "ndt-icp", "iss-3dsc-icp",
                                        "fpcs-icp"};
const std::vector<std::string> kOverlaps{"full", "partial"};

constexpr double kSuccessRotationDeg = 1.0;
constexpr double kSuccessTranslation = 0.005;  // of the diagonal

bool contains(const std::vector<std::string>& v, const std::string& s) {
  return std::find(v.begin(), v.end(), s) != v.end();
}

std::string join(const std::vector<std::string>& v) {
  std::string s;
  for (const auto& x : v) s += (s.empty() ? "" : ", ") + x;
  return s;
}

// SplitMix64 finaliser and FNV-1a: seeds that depend on names, not on list positions, so a
// trial's pose and noise are the same whichever datasets and methods a run selects.
std::uint64_t mix(std::uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}
std::uint64_t fnv(const std::string& s) {
  std::uint64_t h = 1469598103934665603ULL;
  for (unsigned char c : s) h = (h ^ c) * 1099511628211ULL;
  return h;
}
std::uint64_t trial_seed(std::uint64_t seed, const std::string& dataset, const std::string& overlap,
                         double noise, int trial) {
  std::uint64_t h = mix(seed);
  h = mix(h ^ fnv(dataset));
  h = mix(h ^ fnv(overlap));
  h = mix(h ^ static_cast<std::uint64_t>(std::llround(noise * 1e9)));
  return mix(h ^ static_cast<std::uint64_t>(trial));
}

// Area-uniform samples on a mesh (triangle by cumulative area, then uniform barycentrics).
std::vector<Vec3> sample_surface(const TriangleMesh& m, int n, std::uint64_t seed) {
  std::vector<double> cum(m.triangles.size());
  double total = 0;
  for (std::size_t t = 0; t < m.triangles.size(); ++t) {
    const auto& f = m.triangles[t];
    total += 0.5 * (m.vertices[f[1]] - m.vertices[f[0]]).cross(m.vertices[f[2]] - m.vertices[f[0]]).norm();
    cum[t] = total;
  }
  Rng rng(seed);
  std::vector<Vec3> out;
  out.reserve(static_cast<std::size_t>(n));
  for (int i = 0; i < n; ++i) {
    const auto it = std::lower_bound(cum.begin(), cum.end(), rng.uniform() * total);
    const auto& f = m.triangles[static_cast<std::size_t>(std::min<std::ptrdiff_t>(
        it - cum.begin(), static_cast<std::ptrdiff_t>(cum.size()) - 1))];
    double a = rng.uniform(), b = rng.uniform();
    if (a + b > 1) a = 1 - a, b = 1 - b;
    out.push_back(m.vertices[f[0]] + a * (m.vertices[f[1]] - m.vertices[f[0]]) +
                  b * (m.vertices[f[2]] - m.vertices[f[0]]));
  }
  return out;
}

// Linear-interpolated quantile (q in [0, 1]) of unsorted values; NaN when empty.
double quantile(std::vector<double> v, double q) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  std::sort(v.begin(), v.end());
  const double pos = q * static_cast<double>(v.size() - 1);
  const auto lo = static_cast<std::size_t>(std::floor(pos));
  const auto hi = std::min(lo + 1, v.size() - 1);
  return v[lo] + (pos - static_cast<double>(lo)) * (v[hi] - v[lo]);
}

double mean(const std::vector<double>& v) {
  if (v.empty()) return std::numeric_limits<double>::quiet_NaN();
  return std::accumulate(v.begin(), v.end(), 0.0) / static_cast<double>(v.size());
}

// Voxel key for the coverage estimate.
std::uint64_t cell_key(const Vec3& p, double cell, int dx = 0, int dy = 0, int dz = 0) {
  const auto f = [&](double v, int d) {
    return static_cast<std::uint64_t>((static_cast<std::int64_t>(std::floor(v / cell)) + d) & 0x1fffff);
  };
  return (f(p.x(), dx) << 42) | (f(p.y(), dy) << 21) | f(p.z(), dz);
}

// Share of model points with a source point (mapped by the true pose) in their own or a
// neighbouring cell of size d/100: roughly "within d/100".
double coverage(const Dataset& ds, const PointCloud& source, const Pose& X_true) {
  const double cell = ds.diagonal / 100;
  std::unordered_set<std::uint64_t> occupied;
  occupied.reserve(source.size() * 2);
  for (const auto& s : source.points) occupied.insert(cell_key(X_true * s.cast<double>(), cell));
  std::size_t hit = 0;
  for (const auto& p : ds.points) {
    bool found = false;
    for (int dx = -1; dx <= 1 && !found; ++dx)
      for (int dy = -1; dy <= 1 && !found; ++dy)
        for (int dz = -1; dz <= 1 && !found; ++dz)
          found = occupied.count(cell_key(p, cell, dx, dy, dz)) > 0;
    hit += found ? 1 : 0;
  }
  return ds.points.empty() ? 0.0 : static_cast<double>(hit) / static_cast<double>(ds.points.size());
}

// One trial's source cloud in the source frame {S}: the model seen from X_TS = X_true⁻¹.
struct TrialInput {
  Pose X_true = Pose::Identity();  // T_target_source
  PointCloud source;
  Vec3 viewpoint_S = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  double coverage = 1;
};

void add_noise(PointCloud& c, double sigma, Rng& rng) {
  if (sigma <= 0) return;
  for (auto& p : c.points)
    p += Eigen::Vector3f(static_cast<float>(rng.normal() * sigma), static_cast<float>(rng.normal() * sigma),
                         static_cast<float>(rng.normal() * sigma));
}

TrialInput make_full(const Dataset& ds, double noise, std::uint64_t seed) {
  TrialInput in;
  in.X_true = random_pose(seed, ds.diagonal);
  const Pose X_ST = in.X_true.inverse();
  in.source.points.reserve(ds.points.size());
  for (const auto& p : ds.points) in.source.points.push_back((X_ST * p).cast<float>());
  Rng rng(mix(seed ^ 0x6e6f697365ULL));
  add_noise(in.source, noise * ds.diagonal, rng);
  return in;
}

// A single area-sensor view from a random direction at 2 d from the model's centre. The scene
// holds the model in the target frame {T}; the scanner frame {M} is put at X_TM = X_true, so
// the scan comes out in the source frame. The scanner's own noise is switched off; the
// harness adds Gaussian noise of the requested σ instead.
TrialInput make_partial(const Dataset& ds, const sim::ScanScene& scene, double noise,
                        std::uint64_t seed) {
  TrialInput in;
  in.X_true = random_pose(seed, ds.diagonal);
  Rng rng(mix(seed ^ 0x76696577ULL));
  // Viewing direction (sensor towards the centre): uniform on the sphere; for a part that
  // lies on a table, uniform over sensor positions at least 30° above its base plane.
  Vec3 dir;
  if (ds.from_above) {
    const double z = rng.uniform(0.5, 1.0), phi = rng.uniform(0, 2 * M_PI), r = std::sqrt(1 - z * z);
    dir = -Vec3(r * std::cos(phi), r * std::sin(phi), z);
  } else {
    do dir = Vec3(rng.normal(), rng.normal(), rng.normal());
    while (dir.norm() < 1e-6);
    dir.normalize();
  }
  const double d = ds.diagonal;
  // Sensor frame: +z along the viewing direction (towards the centre), x any perpendicular.
  Pose X_TS = Pose::Identity();
  const Vec3 x = dir.unitOrthogonal(), y = dir.cross(x);
  X_TS.linear().col(0) = x;
  X_TS.linear().col(1) = y;
  X_TS.linear().col(2) = dir;
  X_TS.translation() = -2.0 * d * dir;
  sim::ScanView view;
  view.kind = sim::SensorKind::kAreaSensor;
  view.X_MS = in.X_true.inverse() * X_TS;
  view.area.width = 480;
  view.area.height = 360;
  view.area.fov_x = 0.7;
  view.area.fov_y = 0.55;
  view.area.standoff = 2 * d;
  view.area.range_min = d;
  view.area.range_max = 3 * d;
  view.area.baseline = 0.4 * d;
  sim::ScanParams sp;
  sp.views = {view};
  sp.noise.sigma = 0;
  sp.noise.incidence_gain = 0;
  sp.noise.mixed_probability = 0;
  sp.noise.outlier_rate = 0;
  sp.seed = seed;
  sp.threads = 1;
  const sim::ScanResult scan = sim::scan(scene, in.X_true, sp);
  in.source.points = scan.cloud_M.points;  // normals dropped: a real cloud has none
  add_noise(in.source, noise * d, rng);
  in.viewpoint_S = view.X_MS.translation();
  in.coverage = coverage(ds, in.source, in.X_true);
  return in;
}

void score(TrialRecord& rec, const Dataset& ds, const Pose& X_true,
           const perception::RegistrationResult& r) {
  const Pose& X = r.T_target_source;
  rec.ran = r.ran;
  rec.confident = r.confident;
  rec.fitness = r.fitness;
  rec.residual_rmse_m = r.rmse;
  rec.stage = r.stage;
  rec.message = r.message;
  rec.rotation_error_deg = rotation_distance(X.linear(), X_true.linear()) * 180.0 / M_PI;
  rec.translation_error_m = (X.translation() - X_true.translation()).norm();
  rec.translation_error_pct = 100.0 * rec.translation_error_m / ds.diagonal;
  // Model points in the source frame, s = X_true⁻¹ p: |X s − X_true s| = |E p − p|.
  const Pose E = X * X_true.inverse();
  double sum2 = 0;
  for (const auto& p : ds.points) sum2 += (E * p - p).squaredNorm();
  rec.gt_rmse_m = std::sqrt(sum2 / static_cast<double>(std::max<std::size_t>(1, ds.points.size())));
  rec.success = is_success(rec);
}

std::string fmt(const char* f, double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, f, v);
  return buf;
}

// Three significant digits without exponents for the table.
std::string sig3(double v) {
  if (!std::isfinite(v)) return "–";
  const double a = std::fabs(v);
  if (a == 0) return "0";
  if (a >= 100) return fmt("%.0f", v);
  if (a >= 10) return fmt("%.1f", v);
  if (a >= 1) return fmt("%.2f", v);
  const int decimals = std::min(8, 2 - static_cast<int>(std::floor(std::log10(a))));
  char f[16];
  std::snprintf(f, sizeof f, "%%.%df", decimals);
  return fmt(f, v);
}

std::string read_first(const std::string& path, const std::string& key) {
  std::ifstream in(path);
  std::string line;
  while (std::getline(in, line))
    if (line.rfind(key, 0) == 0) {
      const auto c = line.find(':');
      if (c == std::string::npos) return "";
      std::string v = line.substr(c + 1);
      v.erase(0, v.find_first_not_of(" \t"));
      return v;
    }
  return "";
}

}  // namespace

int HarnessOptions::trials_for(const std::string& method) const {
  if (const auto it = method_trials.find(method); it != method_trials.end()) return it->second;
  return method == "ours" ? trials : baseline_trials;
}

void validate(const HarnessOptions& o) {
  const auto check_list = [](const std::string& what, const std::vector<std::string>& got,
                             const std::vector<std::string>& allowed) {
    if (got.empty()) throw ArgumentError(what + ": expected at least one of " + join(allowed) + ", got none");
    for (const auto& g : got)
      if (!contains(allowed, g))
        throw ArgumentError(what + ": expected one of " + join(allowed) + ", got \"" + g + "\"");
  };
  check_list("--datasets", o.datasets, kDatasets);
  check_list("--methods", o.methods, kMethods);
  check_list("--overlap", o.overlaps, kOverlaps);
  if (o.noise.empty()) throw ArgumentError("--noise: expected at least one level, got none");
  for (double n : o.noise)
    if (!(n >= 0 && n < 0.5))
      throw ArgumentError("--noise: expected fractions of the diagonal in [0, 0.5), got " + std::to_string(n));
  if (o.trials < 0) throw ArgumentError("--trials: expected >= 0, got " + std::to_string(o.trials));
  if (o.baseline_trials < 0)
    throw ArgumentError("--baseline-trials: expected >= 0, got " + std::to_string(o.baseline_trials));
  for (const auto& [m, n] : o.method_trials) {
    if (!contains(kMethods, m))
      throw ArgumentError("--trials: expected a method of " + join(kMethods) + ", got \"" + m + "\"");
    if (n < 0) throw ArgumentError("--trials " + m + ": expected >= 0, got " + std::to_string(n));
  }
  if (o.casting_samples < 100)
    throw ArgumentError("--casting-samples: expected >= 100, got " + std::to_string(o.casting_samples));
}

Dataset load_dataset(const std::string& name, const std::string& data_dir, std::uint64_t seed,
                     int casting_samples) {
  Dataset ds;
  ds.name = name;
  if (name == "bunny") {
    ds.origin = "bunny/bun_zipper.ply";
    ds.mesh = load_mesh(data_dir + "/" + ds.origin);
  } else if (name == "dragon") {
    ds.origin = "dragon/dragon.obj";
    ds.mesh = load_mesh(data_dir + "/" + ds.origin);
  } else if (name == "armadillo") {
    ds.origin = "armadillo/armadillo.obj (x 0.001)";
    ds.mesh = load_mesh(data_dir + "/armadillo/armadillo.obj", 0.001);
  } else if (name == "casting") {
    sim::CastingParams cp;
    cp.family = sim::CastingFamily::kFlangedPlate;
    cp.seed = seed;
    const sim::Casting c = sim::make_casting(cp);
    ds.origin = "flanged plate, seed " + std::to_string(seed) + " (" + c.description + ")";
    ds.mesh = c.nominal;
    ds.from_above = true;
  } else {
    throw ArgumentError("dataset: expected one of " + join(kDatasets) + ", got \"" + name + "\"");
  }
  // Model points: the scanned models' vertices (for the bunny all 35,947 of the PLY, also
  // those no face uses); a CAD mesh's vertices are sparse and uneven, so the casting gets
  // area-uniform samples instead.
  if (name == "casting") {
    ds.points = sample_surface(ds.mesh, casting_samples, mix(seed ^ 0x63617374ULL));
  } else if (name == "bunny") {
    for (const auto& p : load_cloud(data_dir + "/" + ds.origin).points) ds.points.push_back(p.cast<double>());
  } else {
    ds.points = ds.mesh.vertices;
  }
  // Centre on the points' bounding box so the pose's translation is measured near the model;
  // d is that box's diagonal.
  Eigen::AlignedBox3d box;
  for (const auto& p : ds.points) box.extend(p);
  const Vec3 c = box.center();
  for (auto& v : ds.mesh.vertices) v -= c;
  for (auto& p : ds.points) p -= c;
  ds.diagonal = box.diagonal().norm();
  return ds;
}

Pose random_pose(std::uint64_t seed, double diagonal) {
  Rng rng(seed);
  const double u1 = rng.uniform(), u2 = rng.uniform(), u3 = rng.uniform();
  const double a = std::sqrt(1 - u1), b = std::sqrt(u1);
  const Eigen::Quaterniond q(b * std::cos(2 * M_PI * u3), a * std::sin(2 * M_PI * u2),
                             a * std::cos(2 * M_PI * u2), b * std::sin(2 * M_PI * u3));
  Pose X = Pose::Identity();
  X.linear() = q.normalized().toRotationMatrix();
  X.translation() = Vec3(rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5), rng.uniform(-0.5, 0.5)) * diagonal;
  return X;
}

bool is_success(const TrialRecord& r) {
  return r.ran && r.rotation_error_deg < kSuccessRotationDeg &&
         r.translation_error_pct < 100.0 * kSuccessTranslation;
}

std::vector<Summary> summarize(const std::vector<TrialRecord>& trials,
                               const std::vector<Dataset>& datasets) {
  std::vector<Summary> out;
  std::vector<std::vector<const TrialRecord*>> groups;
  for (const auto& t : trials) {
    std::size_t g = 0;
    for (; g < out.size(); ++g)
      if (out[g].method == t.method && out[g].dataset == t.dataset && out[g].overlap == t.overlap &&
          out[g].noise == t.noise)
        break;
    if (g == out.size()) {
      Summary s;
      s.method = t.method;
      s.dataset = t.dataset;
      s.overlap = t.overlap;
      s.noise = t.noise;
      for (const auto& d : datasets)
        if (d.name == t.dataset) s.diagonal = d.diagonal;
      out.push_back(s);
      groups.emplace_back();
    }
    groups[g].push_back(&t);
  }
  for (std::size_t g = 0; g < out.size(); ++g) {
    Summary& s = out[g];
    const auto& ts = groups[g];
    s.trials = static_cast<int>(ts.size());
    std::vector<double> rot, tr, trp, gt, res, time, pts, cov;
    int ok = 0, conf = 0, ran = 0;
    for (const auto* t : ts) {
      ok += t->success;
      conf += t->confident;
      ran += t->ran;
      rot.push_back(t->rotation_error_deg);
      tr.push_back(t->translation_error_m);
      trp.push_back(t->translation_error_pct);
      gt.push_back(t->gt_rmse_m);
      res.push_back(t->residual_rmse_m);
      time.push_back(t->time_s);
      pts.push_back(static_cast<double>(t->source_points));
      cov.push_back(t->coverage);
    }
    const double n = std::max(1, s.trials);
    s.success_rate = ok / n;
    s.confident_rate = conf / n;
    s.ran_rate = ran / n;
    s.rotation_median_deg = quantile(rot, 0.5);
    s.rotation_mean_deg = mean(rot);
    s.translation_median_m = quantile(tr, 0.5);
    s.translation_median_pct = quantile(trp, 0.5);
    s.gt_rmse_median_m = quantile(gt, 0.5);
    s.residual_rmse_median_m = quantile(res, 0.5);
    s.time_median_s = quantile(time, 0.5);
    s.time_p95_s = quantile(time, 0.95);
    s.mean_source_points = mean(pts);
    s.mean_coverage = mean(cov);
  }
  return out;
}

HarnessOutput run_registration_benchmark(const HarnessOptions& o,
                                         const std::function<void(const std::string&)>& progress) {
  validate(o);
  const auto wall0 = std::chrono::steady_clock::now();
  const auto say = [&](const std::string& s) {
    if (progress) progress(s);
  };
  HarnessOutput out;
  int max_trials = 0;
  for (const auto& m : o.methods) max_trials = std::max(max_trials, o.trials_for(m));

  for (const auto& name : o.datasets) {
    Dataset ds = load_dataset(name, o.data_dir, o.seed, o.casting_samples);
    say(name + ": " + std::to_string(ds.points.size()) + " model points, " +
        std::to_string(ds.mesh.num_triangles()) + " triangles, diagonal " + sig3(ds.diagonal * 1e3) + " mm");

    // Targets, built once per dataset: ours from the mesh, the baselines' as a cloud.
    std::shared_ptr<const perception::ModelTarget> target;
    double build_s = 0;
    if (contains(o.methods, "ours")) {
      const auto t0 = std::chrono::steady_clock::now();
      target = perception::ModelTarget::from_mesh(ds.mesh);
      build_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      say("  ours: target built in " + sig3(build_s) + " s");
    }
    PointCloud target_cloud;
    for (const auto& p : ds.points) target_cloud.points.push_back(p.cast<float>());
    std::unique_ptr<sim::ScanScene> scene;
    if (contains(o.overlaps, "partial"))
      scene = std::make_unique<sim::ScanScene>(
          std::vector<sim::SceneMesh>{sim::SceneMesh{ds.mesh, sim::kTruthBody, name}});

    Dataset info;  // for the progress summaries
    info.name = name;
    info.diagonal = ds.diagonal;
    for (const auto& overlap : o.overlaps)
      for (double noise : o.noise) {
        const std::size_t first = out.trials.size();
        for (int trial = 0; trial < max_trials; ++trial) {
          const std::uint64_t seed = trial_seed(o.seed, name, overlap, noise, trial);
          const TrialInput in = overlap == "full" ? make_full(ds, noise, seed)
                                                  : make_partial(ds, *scene, noise, seed);
          for (const auto& method : o.methods) {
            if (trial >= o.trials_for(method)) continue;
            perception::RegistrationResult r;
            const auto t0 = std::chrono::steady_clock::now();
            if (method == "ours") {
              perception::RegistrationParams params;
              params.viewpoint = in.viewpoint_S;  // known for a scan, NaN for full copies
              r = perception::register_scan(in.source, *target, params);
            } else {
              r = perception::register_baseline(perception::baseline_from_string(method), in.source,
                                                target_cloud, mix(seed ^ fnv(method)));
            }
            const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
            TrialRecord rec;
            rec.method = method;
            rec.dataset = name;
            rec.overlap = overlap;
            rec.noise = noise;
            rec.trial = trial;
            rec.source_points = in.source.size();
            rec.coverage = in.coverage;
            score(rec, ds, in.X_true, r);
            rec.time_s = wall;
            if (o.verbose)
              say("  " + name + " " + overlap + " noise " + sig3(noise * 100) + "% #" + std::to_string(trial) +
                  " " + method + ": rot " + sig3(rec.rotation_error_deg) + " deg, trans " +
                  sig3(rec.translation_error_m * 1e3) + " mm, " + sig3(wall) + " s" +
                  (rec.success ? "" : "  FAIL") + (rec.message.empty() ? "" : "  (" + rec.message + ")"));
            out.trials.push_back(std::move(rec));
          }
        }
        // Progress: one line per method for this configuration.
        const std::vector<TrialRecord> block(out.trials.begin() + static_cast<std::ptrdiff_t>(first),
                                             out.trials.end());
        for (const auto& s : summarize(block, {info}))
          say("  " + name + " " + overlap + " noise " + sig3(noise * 100) + "% " + s.method + ": " +
              std::to_string(s.trials) + " trials, success " + sig3(100 * s.success_rate) +
              "%, median rot " + sig3(s.rotation_median_deg) + " deg, median time " +
              sig3(s.time_median_s) + " s");
      }
    out.triangles.push_back(ds.mesh.num_triangles());
    out.target_build_s.push_back(build_s);
    ds.mesh = TriangleMesh{};
    out.datasets.push_back(std::move(ds));
  }
  out.summaries = summarize(out.trials, out.datasets);
  out.wall_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - wall0).count();
  return out;
}

std::string machine_description() {
  std::string cpu = read_first("/proc/cpuinfo", "model name");
  if (cpu.empty()) cpu = "unknown CPU";
  const unsigned cores = std::thread::hardware_concurrency();
  std::string mem = read_first("/proc/meminfo", "MemTotal");
  double gib = 0;
  if (!mem.empty()) gib = std::atof(mem.c_str()) / (1024.0 * 1024.0);
  std::string os = "unknown OS";
  utsname u{};
  if (uname(&u) == 0) os = std::string(u.sysname) + " " + u.release + " " + u.machine;
  std::string s = std::to_string(cores) + "-core " + cpu;
  if (gib > 0) s += ", " + fmt("%.0f", gib) + " GiB";
  s += ", " + os;
#ifdef __VERSION__
  s += ", g++ " + std::string(__VERSION__);
#endif
  return s;
}

namespace {

std::string today() {
  const std::time_t t = std::time(nullptr);
  char buf[32];
  std::strftime(buf, sizeof buf, "%Y-%m-%d %H:%M", std::localtime(&t));
  return buf;
}

}  // namespace

std::string to_json(const HarnessOptions& o, const HarnessOutput& out, const std::string& command_line) {
  using nlohmann::json;
  json j;
  j["command"] = command_line;
  j["date"] = today();
  j["machine"] = machine_description();
  j["wall_s"] = out.wall_s;
  j["protocol"] = {
      {"rotation", "uniform in SO(3) (Shoemake quaternions)"},
      {"translation", "uniform in [-0.5, 0.5]^3 x diagonal"},
      {"noise", "Gaussian per coordinate, sigma = fraction x diagonal"},
      {"full", "all model points moved by the inverse true pose, plus noise"},
      {"partial", "one area-sensor view (480x360 rays) from a random direction at 2 diagonals (casting: from at least 30 deg above its base plane), scanner noise off, plus noise"},
      {"success", "rotation error < 1 deg and translation error < 0.5 % of the diagonal"},
      {"gt_rmse", "RMS over all model points of |T_est s - T_true s|, s = model point in the source frame"},
      {"models", "centred on their bounding-box centre"},
  };
  json opt;
  opt["datasets"] = o.datasets;
  opt["methods"] = o.methods;
  json tr = json::object();
  for (const auto& m : o.methods) tr[m] = o.trials_for(m);
  opt["trials"] = tr;
  opt["noise"] = o.noise;
  opt["overlap"] = o.overlaps;
  opt["seed"] = o.seed;
  opt["data_dir"] = o.data_dir;
  opt["casting_samples"] = o.casting_samples;
  j["options"] = opt;
  json ds = json::array();
  for (std::size_t i = 0; i < out.datasets.size(); ++i) {
    const auto& d = out.datasets[i];
    ds.push_back({{"name", d.name},
                  {"origin", d.origin},
                  {"points", d.points.size()},
                  {"triangles", out.triangles[i]},
                  {"diagonal_m", d.diagonal},
                  {"ours_target_build_s", out.target_build_s[i]}});
  }
  j["datasets"] = ds;
  json rows = json::array();
  for (const auto& s : out.summaries)
    rows.push_back({{"method", s.method},
                    {"dataset", s.dataset},
                    {"overlap", s.overlap},
                    {"noise", s.noise},
                    {"trials", s.trials},
                    {"success_rate", s.success_rate},
                    {"confident_rate", s.confident_rate},
                    {"ran_rate", s.ran_rate},
                    {"rotation_error_deg_median", s.rotation_median_deg},
                    {"rotation_error_deg_mean", s.rotation_mean_deg},
                    {"translation_error_mm_median", s.translation_median_m * 1e3},
                    {"translation_error_pct_median", s.translation_median_pct},
                    {"gt_rmse_mm_median", s.gt_rmse_median_m * 1e3},
                    {"residual_rmse_mm_median", s.residual_rmse_median_m * 1e3},
                    {"time_s_median", s.time_median_s},
                    {"time_s_p95", s.time_p95_s},
                    {"source_points_mean", s.mean_source_points},
                    {"coverage_mean", s.mean_coverage}});
  j["summary"] = rows;
  json trials = json::array();
  for (const auto& t : out.trials)
    trials.push_back({{"method", t.method},
                      {"dataset", t.dataset},
                      {"overlap", t.overlap},
                      {"noise", t.noise},
                      {"trial", t.trial},
                      {"source_points", t.source_points},
                      {"coverage", t.coverage},
                      {"ran", t.ran},
                      {"confident", t.confident},
                      {"success", t.success},
                      {"rotation_error_deg", t.rotation_error_deg},
                      {"translation_error_mm", t.translation_error_m * 1e3},
                      {"translation_error_pct", t.translation_error_pct},
                      {"gt_rmse_mm", t.gt_rmse_m * 1e3},
                      {"residual_rmse_mm", t.residual_rmse_m * 1e3},
                      {"fitness", t.fitness},
                      {"time_s", t.time_s},
                      {"stage", t.stage},
                      {"message", t.message}});
  j["trials"] = trials;
  return j.dump(1) + "\n";
}

std::string to_markdown(const HarnessOptions& o, const HarnessOutput& out, const std::string& command_line) {
  std::ostringstream md;
  md << "# Registration comparison\n\n";
  md << "- Command: `" << command_line << "`\n";
  md << "- Date: " << today() << "; machine: " << machine_description() << "\n";
  md << "- Wall time of the run: " << sig3(out.wall_s) << " s\n";
  md << "- Poses: rotation uniform in SO(3) (Shoemake), translation uniform in ±0.5 d per axis "
        "(d = bounding-box diagonal; models centred on their bounding box). Noise: Gaussian per "
        "coordinate, σ as a fraction of d. Full: every model point moved, plus noise. Partial: one "
        "area-sensor view (480×360 rays, Embree, scanner noise off) from a random direction at 2 d "
        "(the casting, which lies on a table in the cell, from at least 30° above its base plane), "
        "plus noise; \"cover\" is the share of model points with a scan point within about d/100.\n";
  md << "- Success: rotation error < 1° and translation error < 0.5 % of d. GT RMSE: RMS over all "
        "model points of |T_est s − T_true s|. Residual RMSE: the method's own inlier RMSE (what the "
        "thesis reports). Times: wall time of the whole call (ours: per scan, target built once). "
        "Medians are over all trials, failures included.\n";
  md << "- Seed " << o.seed << "; trials per method:";
  for (const auto& m : o.methods) md << " " << m << " " << o.trials_for(m) << ";";
  md << " poses, noise and scans are shared across methods (paired trials).\n\n";

  md << "| dataset | source | model points | triangles | d [mm] | ours: target build [s] |\n";
  md << "|---|---|---:|---:|---:|---:|\n";
  for (std::size_t i = 0; i < out.datasets.size(); ++i) {
    const auto& d = out.datasets[i];
    md << "| " << d.name << " | " << d.origin << " | " << d.points.size() << " | " << out.triangles[i]
       << " | " << sig3(d.diagonal * 1e3) << " | "
       << (contains(o.methods, "ours") ? sig3(out.target_build_s[i]) : "–") << " |\n";
  }
  md << "\n";
  md << "| method | dataset | overlap | σ [% d] | trials | source pts | cover | success | confident | "
        "rot. med [°] | rot. mean [°] | trans. med [mm] | trans. med [% d] | GT RMSE med [mm] | "
        "resid. RMSE med [mm] | time med [s] | time p95 [s] |\n";
  md << "|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|---:|\n";
  for (const auto& s : out.summaries) {
    md << "| " << s.method << " | " << s.dataset << " | " << s.overlap << " | " << sig3(s.noise * 100)
       << " | " << s.trials << " | " << fmt("%.0f", s.mean_source_points) << " | "
       << fmt("%.0f", 100 * s.mean_coverage) << " % | " << fmt("%.0f", 100 * s.success_rate) << " % | "
       << fmt("%.0f", 100 * s.confident_rate) << " % | " << sig3(s.rotation_median_deg) << " | "
       << sig3(s.rotation_mean_deg) << " | " << sig3(s.translation_median_m * 1e3) << " | "
       << sig3(s.translation_median_pct) << " | " << sig3(s.gt_rmse_median_m * 1e3) << " | "
       << sig3(s.residual_rmse_median_m * 1e3) << " | " << sig3(s.time_median_s) << " | "
       << sig3(s.time_p95_s) << " |\n";
  }
  return md.str();
}

}  // namespace flashtwin::bench
