#include "flashtwin/sim/scan_cell.hpp"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <string>
#include <thread>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/mujoco_scene.hpp"

namespace flashtwin::sim {

std::vector<ScanView> default_scan_views() {
  std::vector<ScanView> views;
  auto line_view = [](double about_z, double tilt) {
    ScanView v;
    v.kind = SensorKind::kLineProfiler;
    // Sweep axis = view x; tilt about it so the laser looks at a side wall. The tilted views
    // start lower and off to the side so the stand-off point stays on the part.
    const Mat3 R = (Eigen::AngleAxisd(about_z, Vec3::UnitZ()) * Eigen::AngleAxisd(tilt, Vec3::UnitX()))
                       .toRotationMatrix();
    const double side = std::tan(tilt) * 0.30;
    v.X_MS.linear() = R;
    v.X_MS.translation() = Eigen::AngleAxisd(about_z, Vec3::UnitZ()) * Vec3(-0.2, side, 0.05);
    // 400 profiles x 800 points per view: 2 M rays for the five views, ~0.3 mm lateral and
    // 0.8 mm sweep spacing on the part.
    v.line.sweep_length = 0.4;
    v.line.profile_spacing = 0.0008;
    v.line.points_per_profile = 800;
    v.line.range_max = 0.6;
    return v;
  };
  views.push_back(line_view(0, 0));
  const double t = 30 * M_PI / 180;
  views.push_back(line_view(0, t));
  views.push_back(line_view(0, -t));
  views.push_back(line_view(M_PI / 2, t));
  views.push_back(line_view(M_PI / 2, -t));
  return views;
}

Pose perturb_pose(const Pose& X_WM, double translation, double rotation, std::uint64_t seed) {
  if (translation == 0 && rotation == 0) return X_WM;
  Rng rng(seed * 0x94D049BB133111EBULL + 11);
  auto unit = [&rng] {
    Vec3 v(rng.normal(), rng.normal(), rng.normal());
    return Vec3(v.normalized());
  };
  Pose dX = Pose::Identity();
  dX.translation() = translation * unit();
  dX.linear() = Eigen::AngleAxisd(rotation, unit()).toRotationMatrix();
  return X_WM * dX;
}

namespace {

/// The cell's geometry in {W} with the robot at `keyframe`: every geom except the casting's
/// and the scanner head's (background), and where MuJoCo puts the casting body.
std::vector<SceneMesh> cell_background(const std::string& mjcf_path, const std::string& keyframe, Pose* X_WC) {
  const MjModelPtr m = load_mjcf_file(mjcf_path);
  const MjDataPtr d = make_data(m.get());
  if (!keyframe.empty())
    mj_resetDataKeyframe(m.get(), d.get(), require_id(m.get(), mjOBJ_KEY, keyframe));
  mj_forward(m.get(), d.get());
  const int casting_body = require_id(m.get(), mjOBJ_BODY, "casting");
  const int scanner_body = require_id(m.get(), mjOBJ_BODY, "scanner");
  std::vector<SceneMesh> scene = tessellate_geoms(
      m.get(), d.get(),
      [&](int g) {
        const int b = m->geom_bodyid[g];
        return b != casting_body && b != scanner_body;
      },
      kTruthBackground);
  if (X_WC) {
    *X_WC = Pose::Identity();
    X_WC->translation() = Vec3(d->xpos[3 * casting_body], d->xpos[3 * casting_body + 1],
                               d->xpos[3 * casting_body + 2]);
    Mat3 R;
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c) R(r, c) = d->xmat[9 * casting_body + 3 * r + c];
    X_WC->linear() = R;
  }
  return scene;
}

}  // namespace

std::uint64_t cell_key(const Vec3& p, double cell) {
  const auto u = [cell](double v) {
    return static_cast<std::uint64_t>(std::llround(std::floor(v / cell)) + (1LL << 20)) & 0x1FFFFF;
  };
  return (u(p.x()) << 42) | (u(p.y()) << 21) | u(p.z());
}

SurfaceSamples surface_samples(const TriangleMesh& cad_C, double cell,
                               const std::function<bool(const Vec3&)>& skip) {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed;  // (cell, sample)
  std::vector<Vec3> pts, nrm;
  const double step = 0.5 * cell;
  for (std::size_t t = 0; t < cad_C.triangles.size(); ++t) {
    const Vec3 n = cad_C.triangle_normal(t);
    if (skip && skip(n)) continue;
    const auto& tri = cad_C.triangles[t];
    const Vec3 a = cad_C.vertices[static_cast<std::size_t>(tri[0])];
    const Vec3 b = cad_C.vertices[static_cast<std::size_t>(tri[1])];
    const Vec3 c = cad_C.vertices[static_cast<std::size_t>(tri[2])];
    const double longest = std::max({(b - a).norm(), (c - a).norm(), (c - b).norm()});
    const int k = std::max(1, static_cast<int>(std::ceil(longest / step)));
    for (int i = 0; i <= k; ++i)
      for (int j = 0; i + j <= k; ++j) {
        const Vec3 q = a + (b - a) * (static_cast<double>(i) / k) + (c - a) * (static_cast<double>(j) / k);
        keyed.emplace_back(cell_key(q, cell), static_cast<std::uint32_t>(pts.size()));
        pts.push_back(q);
        nrm.push_back(n);
      }
  }
  std::stable_sort(keyed.begin(), keyed.end(), [](const auto& x, const auto& y) { return x.first < y.first; });
  SurfaceSamples S;
  for (std::size_t i = 0; i < keyed.size(); ++i) {
    if (i > 0 && keyed[i].first == keyed[i - 1].first) continue;
    S.points_C.push_back(pts[keyed[i].second]);
    S.normals_C.push_back(nrm[keyed[i].second]);
  }
  return S;
}

namespace {

/// What a plan must see, in {C}: one CAD surface sample per cell that faces up or sideways in
/// the world (samples about half a cell apart on each triangle, the first in each cell kept),
/// with its normal; and for each sideways sample a probe `probe` off the wall along its normal
/// (zero normal), where a fin standing out of the wall shows its face next to the root.
struct Targets {
  std::vector<Vec3> points_C, normals_C;
  std::size_t surface = 0;  // the first `surface` entries are on the CAD, the rest probes
};

Targets plan_targets(const TriangleMesh& cad_C, const Mat3& R_WC, double cell, double probe) {
  // Not what faces the table.
  const SurfaceSamples S =
      surface_samples(cad_C, cell, [&R_WC](const Vec3& n) { return (R_WC * n).z() < -0.5; });
  Targets T;
  T.points_C = S.points_C;
  T.normals_C = S.normals_C;
  T.surface = T.points_C.size();
  for (std::size_t i = 0; i < T.surface; ++i) {
    if (std::abs((R_WC * T.normals_C[i]).z()) > 0.5) continue;  // not a wall
    T.points_C.push_back(T.points_C[i] + probe * T.normals_C[i]);
    T.normals_C.push_back(Vec3::Zero());
  }
  return T;
}

/// A line-profiler sweep in {M}: sweep axis at `azimuth` about {M}'s z, tilted by `tilt` about
/// the sweep axis, aimed through the part's centre `c_M` at `standoff`, `lane` across the fan,
/// long enough to pass the part (`vertices_M`) by `margin` at both ends.
ScanView sweep_view(double azimuth, double tilt, double lane, const Vec3& c_M, const std::vector<Vec3>& vertices_M,
                    double standoff, double margin, const LineProfilerParams& line) {
  ScanView v;
  v.kind = SensorKind::kLineProfiler;
  v.line = line;
  const Mat3 R = (Eigen::AngleAxisd(azimuth, Vec3::UnitZ()) * Eigen::AngleAxisd(tilt, Vec3::UnitX())).toRotationMatrix();
  const Vec3 x = R.col(0), y = R.col(1), z = R.col(2);
  double lo = 1e300, hi = -1e300;
  for (const auto& q : vertices_M) {
    lo = std::min(lo, x.dot(q - c_M));
    hi = std::max(hi, x.dot(q - c_M));
  }
  v.line.sweep_length = hi - lo + 2 * margin;
  v.X_MS.linear() = R;
  v.X_MS.translation() = c_M - standoff * z + (lo - margin) * x + lane * y;
  return v;
}

}  // namespace

ViewPlan plan_scan_views(const std::string& mjcf_path, const TriangleMesh& cad_C, const Pose& X_WC_nominal,
                         const Pose& X_WM, const NoiseParams& noise, const ViewPlanParams& p, int threads,
                         const std::string& keyframe) {
  if (p.max_views < 1) throw ArgumentError("view plan: max_views: expected >= 1, got " + std::to_string(p.max_views));
  if (!(p.cell > 0)) throw ArgumentError("view plan: cell: expected > 0");
  if (p.azimuths < 1) throw ArgumentError("view plan: azimuths: expected >= 1");
  if (cad_C.triangles.empty()) throw ArgumentError("view plan: the CAD model has no triangle");
  std::vector<SceneMesh> scene = cell_background(mjcf_path, keyframe, nullptr);
  scene.push_back({cad_C.transformed(X_WC_nominal), kTruthBody, "casting_nominal"});
  const ScanScene embree_scene(scene);

  ViewPlan plan;
  const Targets T = plan_targets(cad_C, X_WC_nominal.linear(), p.cell, p.probe);
  plan.target_cells = T.points_C.size();
  std::vector<Vec3> target_W(T.points_C.size()), normal_W(T.points_C.size());
  for (std::size_t i = 0; i < T.points_C.size(); ++i) {
    target_W[i] = X_WC_nominal * T.points_C[i];
    normal_W[i] = X_WC_nominal.linear() * T.normals_C[i];
  }
  const Pose X_MC = X_WM.inverse() * X_WC_nominal;
  std::vector<Vec3> vertices_M;
  vertices_M.reserve(cad_C.vertices.size());
  Vec3 lo = Vec3::Constant(1e300), hi = Vec3::Constant(-1e300);
  for (const auto& v : cad_C.vertices) {
    vertices_M.push_back(X_MC * v);
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  const Vec3 c_M = X_MC * (0.5 * (lo + hi));

  // Candidates: each azimuth, straight down and each tilt of either sign, in lanes.
  struct Candidate {
    ScanView view;
    std::string name;
    std::vector<std::uint32_t> seen;  // indices into target, sorted
  };
  std::vector<Candidate> cands;
  const double half_fan = std::tan(0.5 * p.line.fov) * p.standoff;
  for (int a = 0; a < p.azimuths; ++a) {
    const double az = 2 * M_PI * a / p.azimuths;
    for (double t0 : p.tilts)
      for (double sign : {1.0, -1.0}) {
        if (t0 == 0 && sign < 0) continue;
        const double tilt = sign * t0;
        // Lanes across the fan: the part's extent along the sensor's y, in fans of 80 % overlap.
        const Mat3 R = (Eigen::AngleAxisd(az, Vec3::UnitZ()) * Eigen::AngleAxisd(tilt, Vec3::UnitX())).toRotationMatrix();
        double ylo = 1e300, yhi = -1e300;
        for (const auto& q : vertices_M) {
          ylo = std::min(ylo, R.col(1).dot(q - c_M));
          yhi = std::max(yhi, R.col(1).dot(q - c_M));
        }
        const int lanes = std::max(1, static_cast<int>(std::ceil((yhi - ylo) / (1.6 * half_fan))));
        for (int k = 0; k < lanes; ++k) {
          const double lane = lanes == 1 ? 0.5 * (ylo + yhi) : ylo + half_fan * 0.8 + k * (yhi - ylo - 1.6 * half_fan) / (lanes - 1);
          Candidate c;
          c.view = sweep_view(az, tilt, lane, c_M, vertices_M, p.standoff, p.margin, p.line);
          c.name = "azimuth " + std::to_string(static_cast<int>(std::lround(az * 180 / M_PI))) + " tilt " +
                   std::to_string(static_cast<int>(std::lround(tilt * 180 / M_PI))) + " lane " + std::to_string(k);
          cands.push_back(std::move(c));
        }
      }
  }
  plan.candidates = cands.size();

  // What each candidate sees of the targets, by the scanner's own rules.
  const std::size_t n_targets = target_W.size();
  // Candidates are independent: `threads` workers take them in turn (Embree's queries are
  // thread-safe); each candidate's answer is the same for any thread count.
  std::atomic<std::size_t> next{0};
  auto work = [&] {
    for (std::size_t c; (c = next++) < cands.size();) {
      const std::vector<char> sees =
          view_sees(embree_scene, X_WM, cands[c].view, target_W, normal_W, noise.max_incidence);
      for (std::size_t i = 0; i < n_targets; ++i)
        if (sees[i]) cands[c].seen.push_back(static_cast<std::uint32_t>(i));
    }
  };
  {
    const int nt = std::max(1, std::min(threads, static_cast<int>(cands.size())));
    std::vector<std::thread> pool;
    for (int k = 1; k < nt; ++k) pool.emplace_back(work);
    work();
    for (auto& th : pool) th.join();
  }
  std::vector<char> any(n_targets, 0);
  for (const auto& c : cands)
    for (auto i : c.seen) any[i] = 1;
  // Greedy weighted set cover (ties: the earlier candidate). A target seen by few candidates
  // (in a hole, behind the fixture) weighs more than one every view sees (a top face): weight
  // 1/sqrt(candidates that see it); a wall probe (where a fin's face meets its root) weighs
  // twice and wants two views, since one oblique view gives only a few scan lines of a fin.
  std::vector<int> seen_by(n_targets, 0);
  for (const auto& c : cands)
    for (auto i : c.seen) ++seen_by[i];
  std::vector<double> weight(n_targets, 0.0);
  std::vector<int> need(n_targets, 1);
  double total_weight = 0;
  for (std::size_t i = 0; i < n_targets; ++i) {
    const bool probe = i >= T.surface;
    need[i] = probe ? 2 : 1;
    weight[i] = seen_by[i] > 0 ? (probe ? 2.0 : 1.0) / std::sqrt(static_cast<double>(seen_by[i])) : 0.0;
    total_weight += weight[i] * need[i];
  }
  std::vector<int> times(n_targets, 0);
  std::size_t n_covered = 0;
  std::vector<char> used(cands.size(), 0);
  const double total = static_cast<double>(std::max<std::size_t>(1, n_targets));
  while (static_cast<int>(plan.views.size()) < p.max_views) {
    std::size_t best = cands.size();
    double best_gain = 0;
    for (std::size_t c = 0; c < cands.size(); ++c) {
      if (used[c]) continue;
      double gain = 0;
      for (auto i : cands[c].seen) gain += times[i] < need[i] ? weight[i] : 0.0;
      if (gain > best_gain) {
        best_gain = gain;
        best = c;
      }
    }
    if (best == cands.size() || (!plan.views.empty() && best_gain < p.min_gain * total_weight)) break;
    used[best] = 1;
    for (auto i : cands[best].seen) {
      n_covered += times[i] == 0;
      ++times[i];
    }
    plan.views.push_back(cands[best].view);
    plan.names.push_back(cands[best].name);
  }
  plan.unseen_fraction = 1 - static_cast<double>(n_covered) / total;
  plan.unseen_by_any = 1 - static_cast<double>(std::count(any.begin(), any.end(), 1)) / total;
  return plan;
}

CellScan scan_cell(const std::string& mjcf_path, const Casting& casting, const ScanParams& params,
                   const Pose& X_WM_nominal, const Pose& X_WM_true, const std::string& keyframe) {
  // The casting as exact meshes at the pose MuJoCo gives its body.
  Pose X_WC;
  std::vector<SceneMesh> scene = cell_background(mjcf_path, keyframe, &X_WC);
  scene.push_back({casting.nominal.transformed(X_WC), kTruthBody, "casting_nominal"});
  for (std::size_t i = 0; i < casting.fins.size(); ++i)
    scene.push_back({casting.fins[i].mesh.transformed(X_WC), kTruthFlash, "fin" + std::to_string(i)});
  CellScan out;
  for (const auto& s : scene) out.scene_triangles += s.mesh_W.num_triangles();
  const ScanScene embree_scene(scene);
  out.result = scan(embree_scene, X_WM_true, params);
  out.X_WM_nominal = X_WM_nominal;
  out.X_WM_true = X_WM_true;
  return out;
}

}  // namespace flashtwin::sim
