#include "flashtwin/pipeline/run.hpp"

#include <omp.h>

#include <spdlog/spdlog.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <memory>
#include <unistd.h>
#include <sstream>

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

double unseen_parting_fraction(const ScenarioScan& ss) {
  const Pose X_CM_true = ss.setup.spec.X_WC.inverse() * ss.scan.X_WM_true;
  const auto& r = ss.scan.result;
  std::vector<Vec3> flash_C;
  for (std::size_t i = 0; i < r.cloud_M.size(); ++i)
    if (r.truth[i] == sim::kTruthFlash) flash_C.push_back(X_CM_true * r.cloud_M.points[i].cast<double>());
  std::vector<Curve> roots;
  for (const auto& f : ss.setup.casting.fins) roots.push_back({f.root, f.closed});
  return unseen_root_fraction(roots, flash_C);
}

perception::RegistrationParams cell_registration_params() {
  perception::RegistrationParams rp;
  rp.remove_support_plane = true;
  rp.viewpoint = Vec3::Zero();
  return rp;
}

ScenarioScan scan_scenario(const Scenario& sc, const std::string& cell_dir, int threads) {
  ScenarioScan s;
  s.setup = setup_cell(sc);
  s.files = sim::write_cell(sc.robot, s.setup.spec, s.setup.casting, cell_dir);
  s.params = sc.scan;
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
    s.params.seed = sc.scan.seed + 7919;  // a new scan, not the survey's noise again
    s.planned = true;
    s.surveyed = true;
  }
  s.scan = sim::scan_cell(s.files.mjcf, s.setup.casting, s.params, s.setup.spec.X_WM, X_WM_true);
  return s;
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

// What the cell knows of its fixture (the locating blocks stand where the cell's design puts
// them for the casting's nominal placement) removes their points before registration: a block's
// top and faces beside a casting that is nearly symmetric about a turn (a housing's flange)
// otherwise explain the turned pose's overhanging flange. Points inside a block grown by
// `margin` (noise, calibration error) in {M}, with the calibrated mount X_WM. A randomly placed
// casting has no fixture the cell could know: nothing is removed then.
PointCloud without_fixture(const PointCloud& cloud_M, const Scenario& sc, const CellSetup& setup,
                           double margin) {
  if (sc.placement.random) return cloud_M;
  const std::vector<sim::FixtureBlock> blocks =
      setup.spec.fixtures.empty() ? sim::fixture_blocks(setup.spec, setup.casting.nominal)
                                  : setup.spec.fixtures;
  std::vector<Pose> X_FM;
  for (const auto& b : blocks) X_FM.push_back(b.X_WF.inverse() * setup.spec.X_WM);
  PointCloud out;
  for (const auto& p : cloud_M.points) {
    bool inside = false;
    for (std::size_t k = 0; k < blocks.size() && !inside; ++k) {
      const Vec3 q = X_FM[k] * p.cast<double>();
      inside = (q.cwiseAbs() - blocks[k].half_size).maxCoeff() <= margin;
    }
    if (!inside) out.points.push_back(p);
  }
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

PointCloud registration_cloud(const Scenario& sc, const ScenarioScan& ss) {
  return without_fixture(ss.scan.result.cloud_M, sc, ss.setup, 0.003);
}

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
  if (sc.faults.any()) {
    const double mm = sc.faults.part_offset_C.translation().norm() * 1e3;
    const double deg = Eigen::AngleAxisd(sc.faults.part_offset_C.linear()).angle() * 180 / M_PI;
    m["faults.part_offset_mm"] = mm;
    m["faults.part_offset_deg"] = deg;
    m["faults.tool_radius_error_mm"] = sc.faults.tool_radius_error * 1e3;
    spdlog::warn("fault drill: the part stands {:.2f} mm / {:.2f} deg from where it is scanned, the "
                 "burr's radius is {:+.2f} mm off the plan's", mm, deg, sc.faults.tool_radius_error * 1e3);
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

  const PointCloud& cloud_M = scan.result.cloud_M;
  m["scan.points"] = cloud_M.size();
  m["scan.rays_per_s"] = scan.result.rays_per_s();
  m["scan.views"] = ss.params.views.size();
  m["scan.surveyed"] = ss.surveyed;
  if (ss.planned) {
    m["scan.plan_unseen_fraction"] = ss.plan.unseen_fraction;
    m["scan.plan_unseen_by_any"] = ss.plan.unseen_by_any;
  }
  m["scan.unseen_parting_fraction"] = unseen_parting_fraction(ss);
  if (write && opt.write_scan) save_scan(ss, dir.string(), false);

  // --- Perception: pose, then flashes. Inputs: the scan in {M}, the CAD model, X_WM as
  // calibrated (nominal), never the truth.
  progress(opt, "registration", 0.15);
  const auto t_perc = Clock::now();
  const auto target = perception::ModelTarget::from_mesh_cached(setup.casting.nominal);
  out.registration = perception::register_scan(registration_cloud(sc, ss), *target, cell_registration_params());
  const auto& reg = out.registration;
  const Pose X_CM_est = reg.T_target_source;
  // Truth: where {M} really is relative to {C} (the calibrated X_WM is what perception used;
  // the pose error counts what registration got wrong about the casting in the cell).
  const Pose X_CM_true = setup.spec.X_WC.inverse() * scan.X_WM_true;
  const Pose X_WC_est = setup.spec.X_WM * X_CM_est.inverse();
  m["registration.confident"] = reg.confident;
  m["registration.rotation_error_deg"] =
      rotation_distance(X_WC_est.linear(), setup.spec.X_WC.linear()) * 180 / M_PI;
  m["registration.translation_error_mm"] =
      (X_WC_est.translation() - setup.spec.X_WC.translation()).norm() * 1000;
  // The error that matters for grinding: how far points of the casting land from where they
  // are (max over the CAD vertices), in the scanner frame.
  double worst = 0;
  for (const auto& v : setup.casting.nominal.vertices)
    worst = std::max(worst, (X_CM_est * (X_CM_true.inverse() * v) - v).norm());
  m["registration.surface_error_max_mm"] = worst * 1000;
  m["registration.fitness"] = reg.fitness;
  m["registration.rmse_mm"] = reg.rmse * 1000;
  m["registration.time_s"] = reg.time_s;
  m["registration.message"] = reg.message;

  if (!reg.confident) {
    out.refused = true;
    out.exit_code = 1;
    out.verdict = "refused: registration not confident (" + reg.message + ")";
  } else {
    progress(opt, "detection", 0.3);
    const MeshBvh cad_bvh(setup.casting.nominal);
    out.detection = perception::detect_flash(cloud_M, cad_bvh, X_CM_est, sc.detection);
  }
  const double perception_s = seconds_since(t_perc);
  const auto& det = out.detection;

  // --- Scoring (ground truth from here on).
  progress(opt, "scoring", 0.9);
  if (det.ran) {
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
    std::vector<Curve> extracted, truth;
    for (const auto& p : det.paths) extracted.push_back({p.points_C, p.closed});
    for (const auto& f : setup.casting.fins) truth.push_back({f.root, f.closed});
    const auto ps = score_path(extracted, truth);
    m["path.count"] = det.paths.size();
    m["path.true_count"] = truth.size();
    m["path.mean_mm"] = finite_or_null(ps.mean * 1000);
    m["path.rmse_mm"] = finite_or_null(ps.rmse * 1000);
    m["path.max_mm"] = finite_or_null(ps.max * 1000);
    m["path.coverage"] = ps.coverage;
    m["path.spurious_max_mm"] = finite_or_null(ps.spurious_max * 1000);
    m["path.length_m"] = ps.path_length;
    m["path.true_length_m"] = ps.true_length;
    if (write) write_paths(dir.string(), det);
    if (write && opt.write_scan) {
      PointCloud lab;
      lab.points.reserve(cloud_M.size());
      for (const auto& p : cloud_M.points) lab.points.push_back((X_CM_est * p.cast<double>()).cast<float>());
      lab.labels = det.labels;
      save_ply((dir / "scan_detected_C.ply").string(), lab);
    }
  }

  // --- Planning: one grinding motion per path (or per piece of it, plan_in_pieces), on the
  // casting where perception put it.
  constexpr int kMaxPieces = 8;
  double planning_s = 0;
  std::vector<PlannedPath> planned_paths;
  if (!out.refused && !det.paths.empty()) {
    progress(opt, "planning", 0.5);
    const auto t_plan = Clock::now();
    // A part-offset drill (faults.part_offset, Δ in {C}): the part stands at X_BC·Δ when the
    // robot grinds it while the plan is made for the pose perception gave. The simulated part
    // stays where it was scanned, so the robot runs the plan for X_BC_est·Δ⁻¹ (X_BC_plan) instead: the same
    // motion of the burr relative to the part (the arm's own joints differ by the offset).
    const Pose X_BC_plan = setup.spec.X_WB.inverse() * setup.spec.X_WM * X_CM_est.inverse() *
                           sc.faults.part_offset_C.inverse();
    double vmax = 0, amax = 0, manip = 1e300, total_time = 0, length = 0;
    int planned = 0, failed = 0, skipped = 0, tool_changes = 0, path_pieces = 0;
    std::string first_failure;
    json plans = json::array();
    for (std::size_t k = 0; k < det.paths.size(); ++k) {
      const auto& p = det.paths[k];
      const planner::GrindPath gp = grind_path_of(p);
      std::vector<planner::GrindResult> pieces(1);
      try {
        pieces = plan_in_pieces(sc.robot, X_BC_plan, gp, sc.grind, kMaxPieces);
        // A hole too narrow for the mounted burr: the largest burr of the rack that fits.
        if (pieces.front().status == planner::GrindStatus::kToolTooLarge) {
          std::vector<double> rack = sc.tool_rack;
          std::sort(rack.rbegin(), rack.rend());
          for (const double r : rack) {
            if (r >= sc.robot.tool.radius) continue;
            RobotModel smaller = sc.robot;
            smaller.tool.radius = r;
            auto ps = plan_in_pieces(smaller, X_BC_plan, gp, sc.grind, kMaxPieces);
            if (ps.front().status == planner::GrindStatus::kToolTooLarge) continue;
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
          planned_paths.push_back({k, gk});
          if (!write) continue;
          // path_K, then path_K_2, path_K_3 for the further pieces of a path ground in pieces.
          const std::string name = "path_" + std::to_string(k) + (piece ? "_" + std::to_string(piece + 1) : "");
          const std::string pd = (dir / "plan" / name).string();
          // The joint plots belong to the report (--no-report skips them).
          const std::string csv = planner::trajectory_csv(gk);
          planner::write_grind_outputs(gk, pd, opt.report, csv);
          // The robot program a real KUKA controller would run (frames declared in it).
          planner::ProgramParams pp;
          pp.name = "flashtwin_" + name;
          try {
            planner::export_program_file(sc.robot, gk.trajectory, pp, pd);
          } catch (const ArgumentError& e) {
            spdlog::warn("{}: no KRL program: {}", name, e.what());
          }
          if (planned == 1 && piece == 0) write_text_file((dir / "trajectory.csv").string(), csv);
        }
      } else if (g.status == planner::GrindStatus::kToolTooLarge) {
        // Not a failure of the plan: this tool cannot do it (a real cell drills such holes or
        // changes the burr); reported and counted apart.
        ++skipped;
        spdlog::info("path {} skipped: {}", k, g.message);
      } else {
        ++failed;
        if (first_failure.empty()) first_failure = "path " + std::to_string(k) + ": " + g.message;
      }
      plans.push_back(pj);
    }
    planning_s = seconds_since(t_plan);
    m["trajectory.paths_planned"] = planned;
    m["trajectory.paths_failed"] = failed;
    m["trajectory.paths_skipped_tool_too_large"] = skipped;
    m["trajectory.paths_with_rack_tool"] = tool_changes;
    m["trajectory.path_pieces"] = path_pieces;  // grinding motions: a path ground in pieces counts each
    m["trajectory.max_joint_velocity_ratio"] = vmax;
    m["trajectory.max_joint_accel_ratio"] = amax;
    m["trajectory.min_manipulability"] = finite_or_null(planned ? manip : NAN);
    m["trajectory.total_time_s"] = total_time;
    m["trajectory.cut_length_m"] = length;
    if (!first_failure.empty()) m["trajectory.first_failure"] = first_failure;
    if (write) write_text_file((dir / "plans.json").string(), plans.dump(1) + "\n");
    if (failed > 0) {
      out.exit_code = 1;
      out.verdict = std::to_string(failed) + " of " + std::to_string(det.paths.size()) +
                    " path(s) could not be planned (" + first_failure + ")";
    }
  }

  // --- Execution: every planned path runs in MuJoCo while the process model grinds the
  // casting's material (the simulated world, fins included), then the part is scanned again.
  double execution_s = 0;
  ExecutionSummary& exec_summary = out.execution;
  if (!out.refused && sc.execution.enabled && !planned_paths.empty()) {
    progress(opt, "execution", 0.6);
    const auto t_exec = Clock::now();
    std::unique_ptr<VideoRecorder> video;
    FrameHook hook;
    if (!opt.video.path.empty()) {
      double duration = 0;
      for (const auto& p : planned_paths)
        duration += p.second.total_time + sc.execution.exec.settle_time;
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
    exec_summary = execute_plans(sc, ss, planned_paths, m, hook);
    if (video) {
      m["video.frames"] = video->finish();
      m["video.speedup"] = video->speedup();
    }
    execution_s = seconds_since(t_exec);
    if (exec_summary.failed && out.exit_code == 0) {
      out.exit_code = 1;
      out.verdict = exec_summary.failure;
    }
    if (sc.execution.rescan && !exec_summary.failed) {
      progress(opt, "re-scan", 0.85);
      rescan_after(sc, ss, X_CM_est, exec_summary, m);
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
    if (!bad.empty() && out.exit_code == 0) {
      out.exit_code = 1;
      std::string why;
      for (const auto& b : bad) why += (why.empty() ? "" : "; ") + b;
      out.verdict = "bad part: " + why;
    }
  }
  if (!out.refused && out.exit_code == 0) {
    if (det.paths.empty()) {
      out.verdict = "nothing to grind";
    } else if (exec_summary.ran) {
      std::ostringstream os;
      os << std::fixed << std::setprecision(1) << "ground " << planned_paths.size()
         << " path(s): " << exec_summary.residual.flash_removed_fraction * 100
         << " % of the flash removed, highest residual " << std::setprecision(2)
         << exec_summary.residual.residual_flash_max * 1e3 << " mm, deepest gouge "
         << exec_summary.residual.gouge_max_depth * 1e3 << " mm";
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
