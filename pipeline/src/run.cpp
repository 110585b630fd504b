#include "flashtwin/pipeline/run.hpp"

#include <omp.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iomanip>
#include <map>
#include <memory>
#include <optional>
#include <unistd.h>
#include <sstream>
#include <unordered_set>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/format.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/pipeline/scoring.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/pipeline/execution.hpp"
#include "flashtwin/pipeline/report.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/scan_cell.hpp"
#include "stages.hpp"

namespace flashtwin::pipeline {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

namespace {

using Clock = std::chrono::steady_clock;
double seconds_since(Clock::time_point t0) {
  return std::chrono::duration<double>(Clock::now() - t0).count();
}

// Runs without an output folder (sweeps, several threads) each get their own temporary cell.
std::size_t next_temp_id() {
  static std::atomic<std::size_t> id{0};
  return id++;
}

/// A scratch folder removed when the run leaves scope, by return or by exception (a sweep's
/// failed runs once left half a gigabyte each in /tmp). Empty path: nothing to remove.
struct ScratchFolder {
  fs::path path;
  explicit ScratchFolder(fs::path p) : path(std::move(p)) {}
  ScratchFolder(const ScratchFolder&) = delete;
  ScratchFolder& operator=(const ScratchFolder&) = delete;
  ~ScratchFolder() {
    if (path.empty()) return;
    std::error_code ec;
    fs::remove_all(path, ec);
  }
};

void progress(const RunOptions& o, const std::string& stage, double f) {
  if (o.progress) o.progress(stage, f);
}

}  // namespace

json finite_or_null(double v) { return std::isfinite(v) ? json(v) : json(nullptr); }

planner::GrindPath grind_path_of(const perception::FlashPath& path) {
  planner::GrindPath gp;
  gp.points_C = path.points_C;
  gp.normals_C = path.normals_C;
  gp.fin_normal_C = path.fin_normal_C;
  gp.closed = path.closed;
  gp.fin_height = path.fin_height;
  return gp;
}

void write_paths(const std::string& dir, const perception::DetectionResult& det) {
  ensure_directory(dir);
  json j;
  j["frame"] = "C (casting)";
  j["units"] = "m";
  j["noise_sigma"] = det.noise_sigma;
  j["threshold"] = det.threshold;
  j["message"] = det.message;
  json regions = json::array();
  for (const auto& r : det.regions) {
    regions.push_back({{"points", r.points.size()},
                       {"centroid", {r.centroid_C.x(), r.centroid_C.y(), r.centroid_C.z()}},
                       {"normal", {r.normal_C.x(), r.normal_C.y(), r.normal_C.z()}},
                       {"extent_major", r.extent_major},
                       {"extent_minor", r.extent_minor},
                       {"max_height", r.max_height},
                       {"thickness", r.thickness},
                       {"boundary_points", r.boundary_points},
                       {"inner_points", r.inner_points}});
  }
  j["regions"] = regions;
  json paths = json::array();
  std::ostringstream vert, edges;
  std::size_t nv = 0, ne = 0;
  for (const auto& p : det.paths) {
    json pts = json::array(), nrm = json::array();
    const std::size_t first = nv;
    for (std::size_t i = 0; i < p.points_C.size(); ++i) {
      const auto& a = p.points_C[i];
      const auto& n = p.normals_C[i];
      pts.push_back({a.x(), a.y(), a.z()});
      nrm.push_back({n.x(), n.y(), n.z()});
      vert << a.x() << ' ' << a.y() << ' ' << a.z() << ' ' << n.x() << ' ' << n.y() << ' ' << n.z()
           << ' ' << p.region << '\n';
      ++nv;
      if (i > 0) {
        edges << nv - 2 << ' ' << nv - 1 << '\n';
        ++ne;
      }
    }
    if (p.closed && p.points_C.size() > 2) {
      edges << nv - 1 << ' ' << first << '\n';
      ++ne;
    }
    paths.push_back({{"region", p.region},
                     {"closed", p.closed},
                     {"length", p.length()},
                     {"fin_height", p.fin_height},
                     {"fin_normal", {p.fin_normal_C.x(), p.fin_normal_C.y(), p.fin_normal_C.z()}},
                     {"points", pts},
                     {"normals", nrm}});
  }
  j["paths"] = paths;
  write_text_file((fs::path(dir) / "paths.json").string(), j.dump(1) + "\n");
  std::ostringstream ply;
  ply << std::setprecision(9);
  ply << "ply\nformat ascii 1.0\ncomment flashtwin grinding paths, frame {C}, metres\n"
      << "element vertex " << nv
      << "\nproperty double x\nproperty double y\nproperty double z\nproperty float nx\n"
         "property float ny\nproperty float nz\nproperty int region\n"
      << "element edge " << ne << "\nproperty int vertex1\nproperty int vertex2\nend_header\n"
      << vert.str() << edges.str();
  write_text_file((fs::path(dir) / "paths.ply").string(), ply.str());
}

std::vector<std::string> quality_failures(const QualityLimits& q, const json& m) {
  std::vector<std::string> bad;
  const auto number = [&](const char* key, double missing) {
    return m.contains(key) && m[key].is_number() ? m[key].get<double>() : missing;
  };
  const bool ground = m.contains("removal.flash_removed_fraction");
  const double flash_mm3 = number("casting.flash_volume_mm3", 0);
  if (!ground && flash_mm3 <= 0) return bad;  // nothing on the part, nothing to remove
  const double removed = number("removal.flash_removed_fraction", 0);
  if (!(removed >= q.min_removed_fraction))
    bad.push_back(strf("removed %.1f %% of the flash (limit %.1f %%)", removed * 100,
                       q.min_removed_fraction * 100));
  if (!ground) return bad;
  const double residual = number("removal.residual_flash_max_mm", 1e300);
  if (!(residual <= q.max_residual_mm))
    bad.push_back(strf("flash left %.2f mm high (limit %.2f mm)", residual, q.max_residual_mm));
  const double gouge = number("removal.gouge_max_mm", 1e300);
  if (!(gouge <= q.max_gouge_mm))
    bad.push_back(strf("gouged %.2f mm into the casting (limit %.2f mm)", gouge, q.max_gouge_mm));
  const double stops = number("execution.paths_stopped_force_limit", 0);
  if (stops > q.max_protective_stops)
    bad.push_back(strf("%.0f protective stop(s) (limit %d)", stops, q.max_protective_stops));
  const double collisions = number("execution.collisions", 0);
  if (collisions > q.max_collisions)
    bad.push_back(strf("%.0f step(s) with a collision, first: %s (limit %d)", collisions,
                       m.value("execution.first_collision", std::string("?")).c_str(), q.max_collisions));
  return bad;
}

std::vector<std::string> check_expectations(const Scenario& sc, const json& metrics) {
  std::vector<std::string> bad;
  for (const auto& e : sc.expect) {
    if (!metrics.contains(e.key)) {
      bad.push_back(e.key + ": expected by the scenario, missing from the metrics");
      continue;
    }
    const auto& v = metrics[e.key];
    std::ostringstream os;
    if (e.is_flag) {
      if (!v.is_boolean() || v.get<bool>() != e.flag) {
        os << e.key << ": expected " << (e.flag ? "true" : "false") << ", got " << v.dump();
        bad.push_back(os.str());
      }
    } else if (!v.is_number()) {
      os << e.key << ": expected a number in [" << e.lo << ", " << e.hi << "], got " << v.dump();
      bad.push_back(os.str());
    } else {
      const double x = v.get<double>();
      if (!(x >= e.lo && x <= e.hi)) {
        os << e.key << ": expected within [" << (e.lo < -1e299 ? std::string("-inf") : std::to_string(e.lo))
           << ", " << (e.hi > 1e299 ? std::string("inf") : std::to_string(e.hi)) << "], got " << x;
        bad.push_back(os.str());
      }
    }
  }
  return bad;
}

std::vector<Vec3> flash_points_seen_C(const ScenarioScan& ss) {
  const Pose X_CM_true = ss.setup.spec.X_WC.inverse() * ss.scan.X_WM_true;
  const auto& r = ss.scan.result;
  std::vector<Vec3> flash_C;
  for (std::size_t i = 0; i < r.cloud_M.size(); ++i)
    if (r.truth[i] == sim::kTruthFlash) flash_C.push_back(X_CM_true * r.cloud_M.points[i].cast<double>());
  return flash_C;
}

std::vector<Curve> true_roots(const sim::Casting& casting) {
  std::vector<Curve> roots;
  for (const auto& f : casting.fins)
    if (!f.root.empty()) roots.push_back({f.root, f.closed});
  return roots;
}

double unseen_parting_fraction(const ScenarioScan& ss) {
  return unseen_root_fraction(true_roots(ss.setup.casting), flash_points_seen_C(ss));
}

perception::RegistrationParams cell_registration_params() {
  perception::RegistrationParams rp;
  rp.remove_support_plane = true;
  rp.viewpoint = Vec3::Zero();
  return rp;
}

ScenarioScan scan_setup(const Scenario& sc, const CellSetup& setup, const std::string& cell_dir,
                        int threads, std::uint64_t scan_seed) {
  ScenarioScan s;
  s.setup = setup;
  s.files = sim::write_cell(sc.robot, s.setup.spec, s.setup.casting, cell_dir);
  s.params = sc.scan;
  s.params.seed = scan_seed;
  s.params.threads = std::max(1, threads);
  const Pose X_WM_true = sim::perturb_pose(s.setup.spec.X_WM, sc.calibration_translation,
                                           sc.calibration_rotation, sc.seed);
  // Scan planning from the CAD (views: auto). Nothing of the flashes is known here. At a
  // nominal placement (the fixture's) the plan starts from it. A randomly placed part has none:
  // the cell first scans with the scenario's fixed views (a survey), registers that scan as
  // perception would, and plans from the pose it found; without a confident pose the survey is
  // the scan.
  if (sc.auto_views && !sc.placement.random) {
    s.plan = sim::plan_scan_views(s.files.mjcf, s.setup.casting.nominal, s.setup.spec.X_WC, s.setup.spec.X_WM,
                                  sc.scan.noise, sc.view_plan, s.params.threads);
    s.params.views = s.plan.views;
    s.planned = true;
  } else if (sc.auto_views) {
    const sim::CellScan survey =
        sim::scan_cell(s.files.mjcf, s.setup.casting, s.params, s.setup.spec.X_WM, X_WM_true);
    const auto reg = perception::register_scan(survey.result.cloud_M,
                                               *perception::ModelTarget::from_mesh_cached(s.setup.casting.nominal),
                                               cell_registration_params());
    if (!reg.confident) {
      spdlog::info("scan plan: the survey scan's pose is not confident ({}): the survey is the scan", reg.message);
      s.scan = survey;
      return s;
    }
    const Pose X_WC_est = s.setup.spec.X_WM * reg.T_target_source.inverse();
    s.plan = sim::plan_scan_views(s.files.mjcf, s.setup.casting.nominal, X_WC_est, s.setup.spec.X_WM,
                                  sc.scan.noise, sc.view_plan, s.params.threads);
    s.params.views = s.plan.views;
    s.params.seed = scan_seed + 7919;  // a new scan, not the survey's noise again
    s.planned = true;
    s.surveyed = true;
  }
  s.scan = sim::scan_cell(s.files.mjcf, s.setup.casting, s.params, s.setup.spec.X_WM, X_WM_true);
  return s;
}

ScenarioScan scan_scenario(const Scenario& sc, const std::string& cell_dir, int threads) {
  return scan_setup(sc, setup_cell(sc), cell_dir, threads, sc.scan.seed);
}

void save_scan(const ScenarioScan& s, const std::string& dir, bool pcd) {
  PointCloud points;
  points.points = s.scan.result.cloud_M.points;
  save_ply((fs::path(dir) / "scan.ply").string(), points);
  if (pcd) save_pcd((fs::path(dir) / "scan.pcd").string(), points);
  PointCloud labelled = points;
  labelled.labels = s.scan.result.truth;
  save_ply((fs::path(s.files.truth) / "scan_labels.ply").string(), labelled);
}

namespace {

constexpr double kFixtureMargin = 0.003;  // [m] scan points this near a fixture block are on it

// The cell's fixture blocks (locating blocks and riser): the scenario's, or laid out for the
// casting's nominal placement.
std::vector<sim::FixtureBlock> cell_fixture(const CellSetup& setup) {
  return setup.spec.fixtures.empty() ? sim::fixture_blocks(setup.spec, setup.casting.nominal)
                                     : setup.spec.fixtures;
}

// What the cell knows of its fixture (the locating blocks and the riser stand where the cell's
// design puts them for the casting's nominal placement) removes their points before
// registration and detection: a block's top and faces beside a casting that is nearly symmetric
// about a turn (a housing's flange) otherwise explain the turned pose's overhanging flange, and
// the riser's top seen through a bolt hole lies off the CAD where the hole's rim is (false
// flash). The indices of the points outside every block grown by `margin` (noise, calibration
// error) in {M}, with the calibrated mount X_WM. A randomly placed casting has no fixture the
// cell could know: every point is kept then.
std::vector<std::uint32_t> off_fixture(const PointCloud& cloud_M, const Scenario& sc,
                                       const CellSetup& setup, double margin) {
  std::vector<std::uint32_t> kept;
  kept.reserve(cloud_M.size());
  const std::vector<sim::FixtureBlock> blocks =
      sc.placement.random ? std::vector<sim::FixtureBlock>{} : cell_fixture(setup);
  std::vector<Pose> X_FM;
  for (const auto& b : blocks) X_FM.push_back(b.X_WF.inverse() * setup.spec.X_WM);
  for (std::size_t i = 0; i < cloud_M.size(); ++i) {
    bool inside = false;
    for (std::size_t k = 0; k < blocks.size() && !inside; ++k) {
      const Vec3 q = X_FM[k] * cloud_M.points[i].cast<double>();
      inside = (q.cwiseAbs() - blocks[k].half_size).maxCoeff() <= margin;
    }
    if (!inside) kept.push_back(static_cast<std::uint32_t>(i));
  }
  return kept;
}

PointCloud subset(const PointCloud& cloud, const std::vector<std::uint32_t>& index) {
  PointCloud out;
  out.points.reserve(index.size());
  for (const std::uint32_t i : index) out.points.push_back(cloud.points[i]);
  return out;
}

// The points [first, first + count) of a path (indices wrap round a closed one) as an open path.
planner::GrindPath sub_path(const planner::GrindPath& gp, std::size_t first, std::size_t count) {
  planner::GrindPath out = gp;
  out.closed = false;
  out.points_C.clear();
  out.normals_C.clear();
  for (std::size_t k = 0; k < count; ++k) {
    const std::size_t i = (first + k) % gp.points_C.size();
    out.points_C.push_back(gp.points_C[i]);
    out.normals_C.push_back(gp.normals_C[i]);
  }
  return out;
}

// A path the arm cannot follow in one go (its wrist would pass a joint limit partway round a
// dome or a boss, the burr leaning with the wall) is ground in pieces, split where the plan
// failed: a piece ends 4 points before the failure and the next starts 8 points before that
// end, each with its own approach, run-out and retract (the root where they meet is ground
// twice, not left standing). A closed loop first opens at its failure and runs once round. At
// most `max_pieces` pieces of at least 20 points; otherwise the whole path's failure stands. An
// open path that fails within its first 20 points is first tried from farther in (`may_trim`).
std::vector<planner::GrindResult> plan_in_pieces(const RobotModel& robot, const Pose& X_BC,
                                                 const planner::GrindPath& gp,
                                                 const planner::GrindParams& P, int max_pieces,
                                                 bool may_trim = true) {
  planner::GrindResult whole = planner::plan_grind(robot, X_BC, gp, P);
  const int i = whole.failed_path_index;
  const auto n = static_cast<int>(gp.points_C.size());
  constexpr int kMinPiece = 20, kOverlap = 8;
  if (whole.ok() || whole.status != planner::GrindStatus::kJointLimit || i < 0 || i >= n)
    return {whole};
  spdlog::debug("path of {} points not planned in one go: {}", n, whole.message);
  const int end = i - kOverlap / 2, next = end - kOverlap;
  // The wrist cannot reach the path's first points (its first pose, even with the whole path
  // leaning, or a later pass returning there, is past a joint's range), or they are too few to
  // make a piece of their own: the path starts farther in, 4 points at a time up to 64, and the
  // root before it is left (a real cell would turn the part; the residual shows it). (Cover
  // seed 11 failed at point 21: too late to trim and too early to split, the whole path stood.)
  if (end < kMinPiece && may_trim && !gp.closed) {
    for (int s = 4; s <= 64 && n - s >= kMinPiece; s += 4) {
      auto pieces = plan_in_pieces(robot, X_BC, sub_path(gp, static_cast<std::size_t>(s), static_cast<std::size_t>(n - s)), P,
                                   max_pieces, false);
      if (!pieces.front().ok()) continue;
      spdlog::info("a path's first {} points are out of the wrist's reach: it is ground from there on (the root before stays)", s);
      return pieces;
    }
    return {whole};
  }
  if (max_pieces < 2) return {whole};
  if (gp.closed) {
    auto pieces = plan_in_pieces(robot, X_BC, sub_path(gp, static_cast<std::size_t>(i), static_cast<std::size_t>(n + kOverlap)),
                                 P, max_pieces, may_trim);
    if (pieces.front().ok()) return pieces;
    return {whole};
  }
  if (end < kMinPiece || n - next < kMinPiece) return {whole};
  planner::GrindResult head = planner::plan_grind(robot, X_BC, sub_path(gp, 0, static_cast<std::size_t>(end)), P);
  if (!head.ok()) return {whole};
  auto rest = plan_in_pieces(robot, X_BC, sub_path(gp, static_cast<std::size_t>(next), static_cast<std::size_t>(n - next)), P,
                             max_pieces - 1, false);
  if (!rest.front().ok()) return {whole};
  rest.insert(rest.begin(), std::move(head));
  return rest;
}

}  // namespace

std::vector<Vec3> detected_flash_C(const perception::DetectionResult& det, const PointCloud& scan_M,
                                   const Pose& X_CM) {
  std::vector<Vec3> out;
  for (const auto& region : det.regions)
    for (const std::uint32_t i : region.points) out.push_back(X_CM * scan_M.points[i].cast<double>());
  return out;
}

PointCloud registration_cloud(const Scenario& sc, const ScenarioScan& ss) {
  return subset(ss.scan.result.cloud_M, off_fixture(ss.scan.result.cloud_M, sc, ss.setup, kFixtureMargin));
}

perception::DetectionResult detect_off_fixture(const Scenario& sc, const CellSetup& setup,
                                               const PointCloud& cloud_M, const MeshBvh& cad_C,
                                               const Pose& X_CM) {
  const std::vector<std::uint32_t> kept = off_fixture(cloud_M, sc, setup, kFixtureMargin);
  perception::DetectionResult det = perception::detect_flash(subset(cloud_M, kept), cad_C, X_CM, sc.detection);
  std::vector<std::uint8_t> labels(cloud_M.size(), perception::kDetectIgnored);
  for (std::size_t i = 0; i < det.labels.size(); ++i) labels[kept[i]] = det.labels[i];
  det.labels = std::move(labels);
  for (auto& region : det.regions)
    for (std::uint32_t& i : region.points) i = kept[i];
  return det;
}

namespace {

// --- Stages of a run. Each writes its metrics into the json it is given (a second setup's go
// under "setup2.", merge_second_setup).

// Pose, then flashes. Inputs: the scan in {M}, the CAD model, X_WM as calibrated (nominal),
// never the truth; the truth only scores the pose (registration.*).
Perception perceive(const Scenario& sc, const ScenarioScan& ss, const RunOptions& opt, json& m) {
  const auto t0 = Clock::now();
  Perception p;
  const CellSetup& setup = ss.setup;
  progress(opt, "registration", 0.15);
  const auto target = perception::ModelTarget::from_mesh_cached(setup.casting.nominal);
  p.registration = perception::register_scan(registration_cloud(sc, ss), *target, cell_registration_params());
  const auto& reg = p.registration;
  p.X_CM_est = reg.T_target_source;
  // Truth: where {M} really is relative to {C} (the calibrated X_WM is what perception used;
  // the pose error counts what registration got wrong about the casting in the cell).
  const Pose X_CM_true = setup.spec.X_WC.inverse() * ss.scan.X_WM_true;
  const Pose X_WC_est = setup.spec.X_WM * p.X_CM_est.inverse();
  m["registration.confident"] = reg.confident;
  m["registration.rotation_error_deg"] =
      rotation_distance(X_WC_est.linear(), setup.spec.X_WC.linear()) * 180 / M_PI;
  m["registration.translation_error_mm"] =
      (X_WC_est.translation() - setup.spec.X_WC.translation()).norm() * 1000;
  // The error that matters for grinding: how far points of the casting land from where they
  // are (max over the CAD vertices), in the scanner frame.
  double worst = 0;
  for (const auto& v : setup.casting.nominal.vertices)
    worst = std::max(worst, (p.X_CM_est * (X_CM_true.inverse() * v) - v).norm());
  m["registration.surface_error_max_mm"] = worst * 1000;
  m["registration.fitness"] = reg.fitness;
  m["registration.rmse_mm"] = reg.rmse * 1000;
  m["registration.time_s"] = reg.time_s;
  m["registration.message"] = reg.message;
  if (reg.confident) {
    progress(opt, "detection", 0.3);
    const MeshBvh cad_bvh(setup.casting.nominal);
    p.detection = detect_off_fixture(sc, ss.setup, ss.scan.result.cloud_M, cad_bvh, p.X_CM_est);
    p.flash_C = detected_flash_C(p.detection, ss.scan.result.cloud_M, p.X_CM_est);
  }
  p.time_s = seconds_since(t0);
  return p;
}

// Scoring (reads the truth): extracted paths against the true roots (path.count, path.coverage,
// path.rmse_mm, ...).
void score_paths(const std::vector<Curve>& extracted, const std::vector<Curve>& roots, json& m) {
  const auto ps = score_path(extracted, roots);
  m["path.count"] = extracted.size();
  m["path.true_count"] = roots.size();
  m["path.mean_mm"] = finite_or_null(ps.mean * 1000);
  m["path.rmse_mm"] = finite_or_null(ps.rmse * 1000);
  m["path.max_mm"] = finite_or_null(ps.max * 1000);
  m["path.coverage"] = ps.coverage;
  m["path.spurious_max_mm"] = finite_or_null(ps.spurious_max * 1000);
  m["path.length_m"] = ps.path_length;
  m["path.true_length_m"] = ps.true_length;
}

// Scoring (reads the truth): the segmentation against the scan's labels and the extracted
// paths against the true roots (segmentation.*, path.*).
void score_detection(const perception::DetectionResult& det, const sim::CellScan& scan,
                     const std::vector<Curve>& extracted, const std::vector<Curve>& roots, json& m) {
  const auto seg = score_segmentation(det.labels, scan.result.truth);
  m["segmentation.precision"] = seg.precision;
  m["segmentation.recall"] = seg.recall;
  m["segmentation.flash_points_detected"] = seg.true_positive + seg.false_positive;
  m["segmentation.flash_points_true"] = seg.true_positive + seg.false_negative;
  m["segmentation.regions"] = det.regions.size();
  m["segmentation.noise_sigma_mm"] = det.noise_sigma * 1000;
  m["segmentation.threshold_mm"] = det.threshold * 1000;
  m["segmentation.time_s"] = det.time_s;
  m["path.points_before_voxel"] = det.path_points_before;
  m["path.points_after_voxel"] = det.path_points_after;
  m["timing.path_voxel_ms"] = det.path_voxel_time_s * 1000;
  score_paths(extracted, roots, m);
}

std::vector<Curve> curves_of(const perception::DetectionResult& det) {
  std::vector<Curve> out;
  for (const auto& p : det.paths) out.push_back({p.points_C, p.closed});
  return out;
}

// Whether every piece planned with no sample leaning the burr off the wall (tilt).
bool upright(const std::vector<planner::GrindResult>& pieces) {
  for (const auto& g : pieces) {
    if (!g.ok()) return false;
    for (const auto& smp : g.samples)
      if (smp.extra_tilt != 0) return false;
  }
  return true;
}

// A path's plan, in pieces when the wrist cannot follow it in one go (plan_in_pieces), with a
// smaller burr from the rack when the hole is too narrow for the mounted one or the mounted one
// cannot grind it upright.
// `clearance_for(r)`: the planner's world with a burr of radius r (its shank).
std::vector<planner::GrindResult> plan_path(
    const Scenario& sc, planner::GrindParams P, const Pose& X_BC_plan, const planner::GrindPath& gp,
    std::size_t k, int& tool_changes, const std::function<planner::ClearanceFn(double)>& clearance_for) {
  constexpr int kMaxPieces = 8;
  std::vector<planner::GrindResult> pieces(1);
  try {
    if (sc.clearance_check) P.clearance = clearance_for(sc.robot.tool.radius);
    pieces = plan_in_pieces(sc.robot, X_BC_plan, gp, P, kMaxPieces);
    // A hole too narrow for the mounted burr: the largest burr of the rack that fits. A hole the
    // mounted burr fits but cannot grind upright (its collet nut too near a wall beside the hole,
    // a joint limit): the largest rack burr (in its slim holder) that grinds it upright. (Leaning
    // about the hole's own wall turns the tool axis round a cone once per turn of the hole: the
    // wrist whirls and the spline through those samples swung the burr 75 mm out of a housing's
    // bolt hole and into it again, seed 602.)
    const bool too_large = pieces.front().status == planner::GrindStatus::kToolTooLarge;
    if (too_large || (pieces.front().hole_radius > 0 && !upright(pieces))) {
      std::vector<double> rack = sc.tool_rack;
      std::sort(rack.rbegin(), rack.rend());
      for (const double r : rack) {
        if (r >= sc.robot.tool.radius) continue;
        RobotModel smaller = sc.robot;
        smaller.tool.radius = r;
        if (sc.clearance_check) P.clearance = clearance_for(r);
        auto ps = plan_in_pieces(smaller, X_BC_plan, gp, P, kMaxPieces);
        if (ps.front().status == planner::GrindStatus::kToolTooLarge) continue;
        if (!too_large && !upright(ps)) continue;
        spdlog::info("path {}: burr of radius {:.1f} mm from the tool rack ({})", k, r * 1e3,
                     ps.front().ok() ? "planned" : ps.front().message);
        tool_changes += ps.front().ok();
        pieces = std::move(ps);
        break;
      }
    }
  } catch (const ArgumentError& e) {
    pieces.assign(1, planner::GrindResult{});
    pieces.front().status = planner::GrindStatus::kDiscontinuous;
    pieces.front().message = std::string("path rejected: ") + e.what();
  }
  return pieces;
}

// The plan's files for one grinding motion: DIR/plan/NAME (trajectory, plots with the report,
// the program in the robot's controller language). Returns the program's path relative to DIR,
// "" when none was written.
std::string write_plan_files(const Scenario& sc, const planner::GrindResult& g,
                             const fs::path& dir, const std::string& name, bool report) {
  const std::string pd = (dir / "plan" / name).string();
  // The joint plots belong to the report (--no-report skips them).
  const std::string csv = planner::trajectory_csv(g);
  planner::write_grind_outputs(g, pd, report, csv);
  // The robot program the arm's own controller would run (its language and axis convention,
  // frames declared in it); none for a controller without an exporter.
  if (sc.robot.controller.language == "none") return "";
  planner::ProgramParams pp = planner::program_params_for(sc.robot);
  pp.name = "flashtwin_" + name;
  try {
    return fs::relative(planner::export_program_file(sc.robot, g.trajectory, pp, pd), dir).string();
  } catch (const ArgumentError& e) {
    spdlog::warn("{}: no {} program: {}", name, sc.robot.controller.language, e.what());
  }
  return "";
}

}  // namespace

// One grinding motion per path (or per piece of it), on the casting where perception put it
// (trajectory.*). `dir` empty: nothing written.
Plans plan_setup(const Scenario& sc, const CellSetup& setup, const Perception& perc,
                 const RunOptions& opt, const fs::path& dir, json& m) {
  Plans out;
  const auto& det = perc.detection;
  progress(opt, "planning", 0.5);
  const auto t0 = Clock::now();
  // A part-offset drill (faults.part_offset, Δ in {C}): the part stands at X_BC·Δ when the
  // robot grinds it while the plan is made for the pose perception gave. The simulated part
  // stays where it was scanned, so the robot runs the plan for X_BC_est·Δ⁻¹ (X_BC_plan) instead: the same
  // motion of the burr relative to the part (the arm's own joints differ by the offset).
  const Pose X_BC_plan = setup.spec.X_WB.inverse() * setup.spec.X_WM * perc.X_CM_est.inverse() *
                         sc.faults.part_offset_C.inverse();
  // The worktable's top, where the plan puts the part: the burr keeps clear of it.
  planner::GrindParams P = sc.grind;
  const Pose X_CTable = (setup.spec.X_WB * X_BC_plan).inverse() * setup.spec.X_WTable;
  if (sc.floor_check) {
    P.floor_C = std::make_pair(Vec3(X_CTable.translation()), Vec3(X_CTable.linear().col(2)));
    // The riser the part stands on (cell hardware, where the cell set it up): a floor of its own.
    for (const sim::FixtureBlock& b : cell_fixture(setup))
      if (b.name == "riser") {
        planner::GrindParams::Riser r;
        r.X_CR = (setup.spec.X_WB * X_BC_plan).inverse() * b.X_WF *
                 Pose(Eigen::Translation3d(0, 0, b.half_size.z()));
        r.half = b.half_size.head<2>();
        P.riser_C = r;
      }
  }
  // Every sample's arm and tool clear of the cell and of the CAD where perception put it.
  const MeshBvh cad_C(setup.casting.nominal);
  const Pose X_WC_plan = setup.spec.X_WB * X_BC_plan;
  out.X_WC_plan = X_WC_plan;
  out.flash_C = perc.flash_C;
  std::map<double, std::unique_ptr<PlanningWorld>> worlds;
  const auto world_for = [&](double burr_radius) -> PlanningWorld& {
    auto& w = worlds[burr_radius];
    if (!w) w = std::make_unique<PlanningWorld>(sc, setup, cad_C, X_WC_plan, burr_radius);
    return *w;
  };
  const auto clearance_for = [&](double burr_radius) {
    return world_for(burr_radius).clearance(std::max(2e-3, 2 * sc.grind.min_clearance));
  };
  // Every timed motion within the arm's torques (the cell model's inverse dynamics: the mounted
  // burr's world, the one the clearance check uses first).
  P.torque = world_for(sc.robot.tool.radius).torque();
  double vmax = 0, amax = 0, manip = 1e300, total_time = 0, length = 0;
  int planned = 0, skipped = 0, tool_changes = 0, path_pieces = 0;
  json plans = json::array();
  for (std::size_t k = 0; k < det.paths.size(); ++k) {
    const auto pieces = plan_path(sc, P, X_BC_plan, grind_path_of(det.paths[k]), k, tool_changes, clearance_for);
    const planner::GrindResult& g = pieces.front();
    json pj = {{"path", k}, {"status", planner::to_string(g.status)}, {"message", g.message}};
    if (pieces.size() > 1) {
      pj["pieces"] = pieces.size();
      spdlog::info("path {}: ground in {} pieces (the wrist cannot follow it in one go)", k, pieces.size());
    }
    if (g.ok()) {
      ++planned;
      for (std::size_t piece = 0; piece < pieces.size(); ++piece) {
        const planner::GrindResult& gk = pieces[piece];
        ++path_pieces;
        vmax = std::max(vmax, gk.max_joint_velocity_ratio);
        amax = std::max(amax, gk.max_joint_accel_ratio);
        manip = std::min(manip, gk.min_manipulability);
        total_time += gk.total_time;
        length += gk.cut_length;
        pj["time_s"] = pj.value("time_s", 0.0) + gk.total_time;
        pj["cut_length_m"] = pj.value("cut_length_m", 0.0) + gk.cut_length;
        out.paths.push_back({k, gk});
        if (dir.empty()) continue;
        // path_K, then path_K_2, path_K_3 for the further pieces of a path ground in pieces.
        const std::string name = "path_" + std::to_string(k) + (piece ? "_" + std::to_string(piece + 1) : "");
        const std::string program = write_plan_files(sc, gk, dir, name, opt.report);
        // What the cell runs for this motion: the program and the burr it was planned for.
        json pr = {{"program", program},
                   {"tool_radius_mm", gk.tool_radius * 1e3}};
        pj["motions"].push_back(pr);
        if (planned == 1 && piece == 0) write_text_file((dir / "trajectory.csv").string(), planner::trajectory_csv(gk));
      }
    } else if (g.status == planner::GrindStatus::kToolTooLarge) {
      // Not a failure of the plan: this tool cannot do it (a real cell drills such holes or
      // changes the burr); reported and counted apart.
      ++skipped;
      spdlog::info("path {} skipped: {}", k, g.message);
    } else {
      out.failed_paths.push_back(k);
      if (out.first_failure.empty()) out.first_failure = "path " + std::to_string(k) + ": " + g.message;
    }
    plans.push_back(pj);
  }
  out.time_s = seconds_since(t0);
  m["trajectory.paths_planned"] = planned;
  m["trajectory.paths_failed"] = out.failed_paths.size();
  m["trajectory.paths_skipped_tool_too_large"] = skipped;
  m["trajectory.paths_with_rack_tool"] = tool_changes;
  m["trajectory.path_pieces"] = path_pieces;  // grinding motions: a path ground in pieces counts each
  m["trajectory.max_joint_velocity_ratio"] = vmax;
  m["trajectory.max_joint_accel_ratio"] = amax;
  m["trajectory.min_manipulability"] = finite_or_null(planned ? manip : NAN);
  m["trajectory.total_time_s"] = total_time;
  m["trajectory.cut_length_m"] = length;
  if (!out.first_failure.empty()) m["trajectory.first_failure"] = out.first_failure;
  if (!dir.empty()) write_text_file((dir / "plans.json").string(), plans.dump(1) + "\n");
  return out;
}

namespace {

// The cell's scan metrics (scan.*) of one setup.
void scan_metrics(const ScenarioScan& ss, json& m) {
  m["scan.points"] = ss.scan.result.cloud_M.size();
  m["scan.rays_per_s"] = ss.scan.result.rays_per_s();
  m["scan.views"] = ss.params.views.size();
  m["scan.surveyed"] = ss.surveyed;
  if (ss.planned) {
    m["scan.plan_unseen_fraction"] = ss.plan.unseen_fraction;
    m["scan.plan_unseen_by_any"] = ss.plan.unseen_by_any;
  }
}

/// What the cell knows is left to do on a part after a setup, in {C}.
struct WorkLeft {
  double unseen_fraction = 0;  ///< share of the CAD surface no point of the scan came near
  std::vector<Vec3> normals_C;  ///< outward normals where work is left (unseen surface, roots)
  std::vector<double> weights;  ///< [m^2] the surface each stands for
};

// From what perception and planning made of a setup (never the truth): CAD surface samples
// (3 mm cells) with no scan point, by the estimated pose, within about a millimetre outside
// them (1 mm cells round the point 0.5 mm out along the normal: the wall behind a thin flange
// does not count) are unseen, flash may stand there; the roots of paths that could not be
// planned are known flash, each root point standing for its spacing times 30 mm of surface.
WorkLeft work_left(const ScenarioScan& ss, const Perception& perc, const Plans& plans) {
  constexpr double kCell = 0.003, kSeen = 0.001, kRootBand = 0.03;
  WorkLeft w;
  std::unordered_set<std::uint64_t> seen;
  for (const auto& p : ss.scan.result.cloud_M.points)
    seen.insert(sim::cell_key(perc.X_CM_est * p.cast<double>(), kSeen));
  const auto near_seen = [&](const Vec3& q, const Vec3& n) {
    const Vec3 c = q + 0.5 * kSeen * n;
    for (int dx = -1; dx <= 1; ++dx)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dz = -1; dz <= 1; ++dz)
          if (seen.count(sim::cell_key(c + kSeen * Vec3(dx, dy, dz), kSeen))) return true;
    return false;
  };
  const sim::SurfaceSamples S = sim::surface_samples(ss.setup.casting.nominal, kCell);
  for (std::size_t i = 0; i < S.points_C.size(); ++i) {
    if (near_seen(S.points_C[i], S.normals_C[i])) continue;
    w.normals_C.push_back(S.normals_C[i]);
    w.weights.push_back(kCell * kCell);
  }
  w.unseen_fraction = static_cast<double>(w.normals_C.size()) /
                      static_cast<double>(std::max<std::size_t>(1, S.points_C.size()));
  for (const std::size_t k : plans.failed_paths) {
    const auto& path = perc.detection.paths[k];
    for (std::size_t i = 0; i + 1 < path.points_C.size(); ++i) {
      w.normals_C.push_back(path.normals_C[i]);
      w.weights.push_back((path.points_C[i + 1] - path.points_C[i]).norm() * kRootBand);
    }
  }
  return w;
}

// The direction of {C} to turn up for the next setup: where the work left faces sideways or up
// (a wall facing up to 15° below the horizon is still reached and seen, as the fixture-held
// parts show) over as much of its surface as possible, the part lying low (its height along the
// direction, over its largest extent, costs a quarter: a plate standing on its edge puts its
// far roots out of the arm's reach). Candidates: 256 directions spread over the sphere and
// {C}'s six axis directions; the first best is taken (deterministic).
Vec3 turn_up_direction(const WorkLeft& w, const TriangleMesh& cad_C) {
  constexpr double kBelowHorizon = -0.26, kHeightCost = 0.25;
  std::vector<Vec3> cand{Vec3::UnitZ(), -Vec3::UnitZ(), Vec3::UnitX(), -Vec3::UnitX(), Vec3::UnitY(), -Vec3::UnitY()};
  constexpr int kSpread = 256;
  const double golden = M_PI * (3.0 - std::sqrt(5.0));
  for (int i = 0; i < kSpread; ++i) {  // a Fibonacci sphere
    const double z = 1.0 - 2.0 * (i + 0.5) / kSpread, r = std::sqrt(1.0 - z * z);
    cand.emplace_back(r * std::cos(golden * i), r * std::sin(golden * i), z);
  }
  double total = 0;
  for (const double x : w.weights) total += x;
  Vec3 lo = cad_C.vertices.front(), hi = lo;
  for (const auto& v : cad_C.vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
  const double extent = std::max(1e-9, (hi - lo).norm());
  Vec3 best = cand.front();
  double best_score = -1e300;
  for (const Vec3& u : cand) {
    double reached = 0;
    for (std::size_t i = 0; i < w.normals_C.size(); ++i)
      if (w.normals_C[i].dot(u) >= kBelowHorizon) reached += w.weights[i];
    double top = -1e300, bottom = 1e300;
    for (const auto& v : cad_C.vertices) {
      top = std::max(top, v.dot(u));
      bottom = std::min(bottom, v.dot(u));
    }
    const double score = (total > 0 ? reached / total : 1.0) - kHeightCost * (top - bottom) / extent;
    if (score > best_score + 1e-12) {
      best_score = score;
      best = u;
    }
  }
  return best;
}

/// The second setup of a part (placement.turn_over): what it scanned, perceived and planned.
struct SecondSetup {
  ScenarioScan scan;
  Perception perception;
  Plans plans;
  json metrics;  ///< its own scan.*, registration.*, segmentation.*, path.*, trajectory.*
  std::string error;  ///< why it did not run (the turned part did not fit the cell); empty: it ran
  double time_s = 0;  ///< scan, perception and planning
};

// The part, as the first setup left it, is turned over (turned_over), scanned (a survey and the
// views planned from its pose), registered, searched for flash and planned for, exactly as in
// the first setup; what is planned is ground on the same material (the caller runs it).
SecondSetup second_setup(const Scenario& sc, const CellSetup& first, sim::Casting now,
                         const WorkLeft& left, const fs::path& cell_dir, const fs::path& dir,
                         const RunOptions& opt) {
  SecondSetup s;
  progress(opt, "second setup", 0.7);
  const auto t0 = Clock::now();
  CellSetup setup;
  try {
    setup = turned_over(sc, first, std::move(now), turn_up_direction(left, first.casting.nominal));
  } catch (const ConfigError& e) {
    // The first setup's work stands; the part is judged as it is.
    s.error = e.what();
    return s;
  }
  // A turned part has no nominal placement: the views are always planned from a survey.
  s.scan = scan_setup(sc, setup, (cell_dir / "setup2").string(), opt.threads, sc.scan.seed + 104729);
  scan_metrics(s.scan, s.metrics);
  s.perception = perceive(sc, s.scan, opt, s.metrics);
  const auto& det = s.perception.detection;
  if (!det.ran) return s;
  // The residual fin has no root: the paths are scored against the casting's true roots.
  score_detection(det, s.scan.scan, curves_of(det), true_roots(first.casting), s.metrics);
  const fs::path out = dir.empty() ? fs::path() : dir / "setup2";
  if (!out.empty()) write_paths(out.string(), det);
  if (!det.paths.empty()) s.plans = plan_setup(sc, setup, s.perception, opt, out, s.metrics);
  s.time_s = seconds_since(t0);
  return s;
}

// A second setup's metrics go under "setup2."; the part's totals count both setups: paths
// planned (a root found in both counts twice), grinding motions, tool changes, planned time and
// length, the worst joint-rate ratios and the least manipulability. Holes skipped as too narrow
// and the first failure are the second setup's (it saw the part last).
void merge_second_setup(const json& m2, json& m) {
  for (const auto& [key, v] : m2.items()) m["setup2." + key] = v;
  for (const char* key : {"trajectory.paths_skipped_tool_too_large", "trajectory.first_failure"}) {
    if (m2.contains(key)) m[key] = m2[key];
    else m.erase(key);
  }
  if (m2.contains("trajectory.min_manipulability") && m2["trajectory.min_manipulability"].is_number()) {
    const double v = m2["trajectory.min_manipulability"].get<double>();
    const json& mine = m.contains("trajectory.min_manipulability") ? m["trajectory.min_manipulability"] : json();
    m["trajectory.min_manipulability"] = mine.is_number() ? std::min(mine.get<double>(), v) : v;
  }
  for (const char* key : {"trajectory.paths_planned", "trajectory.paths_failed",
                          "trajectory.paths_with_rack_tool",
                          "trajectory.path_pieces", "trajectory.total_time_s", "trajectory.cut_length_m"}) {
    if (!m2.contains(key)) continue;
    if (m2[key].is_number_integer() && (!m.contains(key) || m[key].is_number_integer()))
      m[key] = (m.contains(key) ? m[key].get<std::int64_t>() : 0) + m2[key].get<std::int64_t>();
    else
      m[key] = (m.contains(key) ? m[key].get<double>() : 0.0) + m2[key].get<double>();
  }
  for (const char* key : {"trajectory.max_joint_velocity_ratio", "trajectory.max_joint_accel_ratio"}) {
    if (!m2.contains(key)) continue;
    m[key] = std::max(m.contains(key) ? m[key].get<double>() : 0.0, m2[key].get<double>());
  }
}

}  // namespace

RunResult run_scenario(const Scenario& sc, const RunOptions& opt) {
  const auto t_total = Clock::now();
  // Perception's parallel loops use this run's thread budget (a sweep runs each casting on
  // one thread); its results are the same for any count.
  omp_set_num_threads(std::max(1, opt.threads));
  RunResult out;
  json& m = out.metrics;
  const bool write = !opt.out_dir.empty();
  const fs::path dir = write ? fs::path(opt.out_dir) : fs::path();
  if (write) ensure_directory(dir.string());
  m["scenario"] = sc.name;
  m["seed"] = sc.seed;
  // A turned part has no nominal placement the cell could know (load_scenario refuses it too).
  if (sc.placement.turn_over && !sc.placement.random)
    throw ConfigError("casting.placement: expected turn_over only together with random: true");
  if (sc.faults.any()) {
    const double mm = sc.faults.part_offset_C.translation().norm() * 1e3;
    const double deg = Eigen::AngleAxisd(sc.faults.part_offset_C.linear()).angle() * 180 / M_PI;
    m["faults.part_offset_mm"] = mm;
    m["faults.part_offset_deg"] = deg;
    m["faults.tool_radius_error_mm"] = sc.faults.tool_radius_error * 1e3;
    m["faults.tcp_offset_mm"] = sc.faults.tcp_offset_T.norm() * 1e3;
    m["faults.sensor_bias_n"] = sc.faults.sensor_bias_E.force.norm();
    m["faults.sensor_bias_nm"] = sc.faults.sensor_bias_E.torque.norm();
    spdlog::warn("fault drill: the part stands {:.2f} mm / {:.2f} deg from where it is scanned, the "
                 "burr's radius is {:+.2f} mm off the plan's, its TCP {:.2f} mm off the controller's, "
                 "the F/T sensor's zero steps by {:.1f} N / {:.2f} N*m after each tare",
                 mm, deg, sc.faults.tool_radius_error * 1e3, sc.faults.tcp_offset_T.norm() * 1e3,
                 sc.faults.sensor_bias_E.force.norm(), sc.faults.sensor_bias_E.torque.norm());
  }

  // --- Cell and scan (the simulator).
  progress(opt, "cell and scan", 0.0);
  const fs::path cell_dir = write ? dir / "cell" : fs::temp_directory_path() /
                                                       ("flashtwin_run_" + std::to_string(::getpid()) + "_" +
                                                        std::to_string(next_temp_id()));
  const auto t_scan = Clock::now();
  const ScratchFolder scratch{write ? fs::path() : cell_dir};  // (an output folder keeps its cell)
  const ScenarioScan ss = scan_scenario(sc, cell_dir.string(), opt.threads);
  const double scan_s = seconds_since(t_scan);
  const CellSetup& setup = ss.setup;
  const sim::CellScan& scan = ss.scan;
  m["casting.family"] = sim::to_string(sc.casting.family);
  m["casting.flashes"] = setup.casting.fins.size();
  m["casting.flash_volume_mm3"] = setup.casting.flash_volume() * 1e9;
  scan_metrics(ss, m);
  m["scan.unseen_parting_fraction"] = unseen_parting_fraction(ss);
  if (write && opt.write_scan) save_scan(ss, dir.string(), false);

  // --- Perception: pose, then flashes.
  const Perception perc = perceive(sc, ss, opt, m);
  out.registration = perc.registration;
  out.detection = perc.detection;
  const auto& det = out.detection;
  const double perception_s = perc.time_s;
  if (!perc.registration.confident) {
    out.refused = true;
    out.exit_code = 1;
    out.verdict = "refused: registration not confident (" + perc.registration.message + ")";
  }

  // --- Scoring of perception (ground truth from here on).
  progress(opt, "scoring", 0.4);
  if (det.ran) {
    score_detection(det, scan, curves_of(det), true_roots(setup.casting), m);
    if (write) write_paths(dir.string(), det);
    if (write && opt.write_scan) {
      PointCloud lab;
      lab.points.reserve(scan.result.cloud_M.size());
      for (const auto& p : scan.result.cloud_M.points) lab.points.push_back((perc.X_CM_est * p.cast<double>()).cast<float>());
      lab.labels = det.labels;
      save_ply((dir / "scan_detected_C.ply").string(), lab);
    }
  }

  // --- Planning: one grinding motion per path (or per piece of it, plan_in_pieces), on the
  // casting where perception put it.
  Plans plans;
  if (!out.refused && !det.paths.empty()) plans = plan_setup(sc, setup, perc, opt, dir, m);
  const double planning_s = plans.time_s;
  const std::vector<PlannedPath>& planned_paths = plans.paths;
  // With a second setup to come, what this one cannot reach is left for it (deferred).
  const bool second = sc.placement.turn_over && !out.refused && sc.execution.enabled;
  const auto fail_plans = [&out](const Plans& p, std::size_t paths, const std::string& setup_name) {
    if (p.failed_paths.empty() || out.exit_code != 0) return;
    out.exit_code = 1;
    out.verdict = setup_name + std::to_string(p.failed_paths.size()) + " of " + std::to_string(paths) +
                  " path(s) could not be planned (" + p.first_failure + ")";
  };
  if (!second) fail_plans(plans, det.paths.size(), "");

  // --- Execution: every planned path runs in MuJoCo while the process model grinds the
  // casting's material (the simulated world, fins included); a part turned over
  // (placement.turn_over) is scanned, perceived, planned and ground again in its second setup;
  // then the part is scanned again.
  double execution_s = 0;
  ExecutionSummary& exec_summary = out.execution;
  bool ground_twice = false;  // a second setup registered its part and ground what it planned
  if (!out.refused && sc.execution.enabled && (!planned_paths.empty() || second)) {
    progress(opt, "execution", 0.6);
    const auto t_exec = Clock::now();
    Execution exec(sc, setup.casting);
    // The whole job of a setup: transits planned on the CAD where perception put the part (a
    // part-offset drill: where the plan thinks it is), then run with the paths continuously.
    std::size_t transits = 0, lifted = 0, left_alone = 0;
    double transit_time = 0, min_clearance = sim::CellCollision::kReach;
    std::string refusal;
    const auto job_of = [&](const ScenarioScan& s, const Plans& pl) {
      std::vector<Motion> motions;
      if (!sc.execution.transits) {
        for (const auto& pp : pl.paths) motions.push_back(motion_of(pp));
        return motions;
      }
      JobMotions job = plan_job_motions(sc, s, pl.X_WC_plan, exec.grid().nominal(), pl.paths, pl.flash_C);
      transits += job.transits;
      lifted += job.lifted;
      left_alone += job.refused_paths.size() + job.home_refused;
      transit_time += job.transit_time;
      min_clearance = std::min(min_clearance, job.min_clearance);
      if (refusal.empty()) refusal = job.first_refusal;
      return std::move(job.motions);
    };
    const std::vector<Motion> motions1 = job_of(ss, plans);
    std::unique_ptr<VideoRecorder> video;
    FrameHook hook;
    if (!opt.video.path.empty()) {
      double duration = 0;
      for (const auto& mo : motions1) duration += duration_of(mo) + sc.execution.exec.settle_time;
      // The second setup's motions are not planned yet: as long again, and at least two minutes.
      if (second) duration = std::max(2 * duration, 120.0);
      VideoOptions vo = opt.video;
      vo.camera = sc.video.camera;
      vo.length = sc.video.length;
      vo.width = sc.video.width;
      vo.height = sc.video.height;
      vo.fps = sc.video.fps;
      video = std::make_unique<VideoRecorder>(vo, duration);
      hook = [&video](const mjModel* mm, mjData* d, double t, const sim::MaterialGrid& grid,
                      std::size_t path) { video->on_step(mm, d, t, grid, path); };
    }
    exec.run_motions(ss, motions1, hook);
    const ScenarioScan* last_scan = &ss;
    Pose last_X_CM_est = perc.X_CM_est;
    std::optional<SecondSetup> s2;
    if (second && !exec.failed()) {
      execution_s += seconds_since(t_exec);
      const WorkLeft left = work_left(ss, perc, plans);
      m["setup1.unseen_surface_fraction"] = left.unseen_fraction;
      const sim::ResidualReport after_first = sim::analyze_residual(exec.grid());
      m["setup1.removal.flash_removed_fraction"] = after_first.flash_removed_fraction;
      sim::Casting now = casting_with_residual(setup.casting, sim::remaining_flash_mesh(exec.grid()),
                                                     after_first.flash_volume_remaining);
      s2 = second_setup(sc, setup, std::move(now), left, cell_dir, dir, opt);
      m["timing.setup2_s"] = s2->time_s;
      ground_twice = s2->error.empty() && s2->perception.registration.confident;
      if (ground_twice) {
        const auto t_exec2 = Clock::now();
        if (video) video->new_setup();
        exec.run_motions(s2->scan, job_of(s2->scan, s2->plans), hook, det.paths.size());
        execution_s += seconds_since(t_exec2);
        last_scan = &s2->scan;
        last_X_CM_est = s2->perception.X_CM_est;
        // The part's roots either setup saw, and the paths either found (path.* of the
        // segmentation and of the voxel filter stay the first setup's; setup2.* has its own).
        std::vector<Vec3> seen = flash_points_seen_C(ss), seen2 = flash_points_seen_C(s2->scan);
        seen.insert(seen.end(), seen2.begin(), seen2.end());
        m["scan.unseen_parting_fraction"] = unseen_root_fraction(true_roots(setup.casting), seen);
        std::vector<Curve> found = curves_of(det), found2 = curves_of(s2->perception.detection);
        found.insert(found.end(), found2.begin(), found2.end());
        score_paths(found, true_roots(setup.casting), m);
        merge_second_setup(s2->metrics, m);
        // The first setup's unplanned paths were the second's to grind: what fails is what the
        // second could not plan.
        m["trajectory.paths_deferred"] = plans.failed_paths.size();
        m["trajectory.paths_failed"] = s2->plans.failed_paths.size();
        fail_plans(s2->plans, s2->perception.detection.paths.size(), "second setup: ");
      } else {
        const std::string why = s2->error.empty() ? "registration not confident (" + s2->perception.registration.message + ")"
                                        : s2->error;
        spdlog::warn("second setup: {}: nothing ground in it", why);
        for (const auto& [key, v] : s2->metrics.items()) m["setup2." + key] = v;
        m["setup2.error"] = why;
        fail_plans(plans, det.paths.size(), "");
      }
    } else {
      execution_s += seconds_since(t_exec);
      fail_plans(plans, det.paths.size(), "");
    }
    if (sc.execution.transits) {
      m["trajectory.transits"] = transits;
      m["trajectory.transits_lifted"] = lifted;
      m["trajectory.transit_time_s"] = transit_time;
      m["trajectory.transit_min_clearance_mm"] = min_clearance * 1e3;
      m["trajectory.transits_refused"] = left_alone;
      if (left_alone > 0 && out.exit_code == 0) {
        out.exit_code = 1;
        out.verdict = std::to_string(left_alone) + " transit(s) not clear, their path(s) left alone (" + refusal + ")";
      }
    }
    const auto t_fin = Clock::now();
    exec_summary = exec.finish(m);
    if (video) {
      m["video.frames"] = video->finish();
      m["video.speedup"] = video->speedup();
    }
    execution_s += seconds_since(t_fin);
    if (exec_summary.failed && out.exit_code == 0) {
      out.exit_code = 1;
      out.verdict = exec_summary.failure;
    }
    if (sc.execution.rescan && !exec_summary.failed) {
      progress(opt, "re-scan", 0.85);
      rescan_after(sc, *last_scan, last_X_CM_est, exec_summary, m);
    }
  }

  m["timing.scan_s"] = scan_s;
  m["timing.perception_s"] = perception_s;
  m["timing.planning_s"] = planning_s;
  m["timing.execution_s"] = execution_s;
  m["timing.total_s"] = seconds_since(t_total);
  // --- Quality: the part against the scenario's limits (a refusal leaves it as it came).
  if (!out.refused && sc.execution.enabled) {
    const auto bad = quality_failures(sc.quality, m);
    m["quality.pass"] = bad.empty();
    m["quality.failures"] = bad;
    if (!bad.empty()) {
      std::string why;
      for (const auto& b : bad) why += (why.empty() ? "" : "; ") + b;
      // After another failure (paths not planned, transits refused) the part's own verdict too.
      out.verdict = out.exit_code == 0 ? "bad part: " + why : out.verdict + "; bad part: " + why;
      out.exit_code = 1;
    }
  }
  if (!out.refused && out.exit_code == 0) {
    if (!exec_summary.ran && det.paths.empty()) {
      out.verdict = "nothing to grind";
    } else if (exec_summary.ran) {
      std::ostringstream os;
      os << std::fixed << std::setprecision(1) << "ground " << m.value("execution.paths_executed", 0)
         << " path(s)" << (ground_twice ? " in two setups" : "") << ": "
         << exec_summary.residual.flash_removed_fraction * 100
         << " % of the flash removed, highest residual " << std::setprecision(2)
         << exec_summary.residual.residual_flash_max * 1e3 << " mm, deepest gouge "
         << m.value("removal.gouge_max_mm", 0.0) << " mm";
      const int skipped = m.value("trajectory.paths_skipped_tool_too_large", 0);
      if (skipped > 0) os << "; " << skipped << " hole(s) too narrow for the burr left alone";
      out.verdict = os.str();
    } else {
      out.verdict = det.message;
    }
  }
  m["verdict"] = out.verdict;
  m["exit_code"] = out.exit_code;
  if (write) {
    write_text_file((dir / "metrics.json").string(), m.dump(2) + "\n");
    if (exec_summary.grid) write_material_maps(dir.string(), *exec_summary.grid);
    if (opt.report) {
      progress(opt, "report", 0.95);
      ReportInputs ri{sc, ss, out, planned_paths, exec_summary};
      write_report(dir.string(), ri);
    }
  }
  progress(opt, "done", 1.0);
  return out;
}

}  // namespace flashtwin::pipeline
