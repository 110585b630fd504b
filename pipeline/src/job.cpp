#include "flashtwin/pipeline/job.hpp"

#include <omp.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <filesystem>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/pipeline/pose_json.hpp"
#include "flashtwin/pipeline/execution.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/pipeline/view3d.hpp"
#include "flashtwin/planner/program_replay.hpp"
#include "flashtwin/sim/cell.hpp"
#include "stages.hpp"

namespace flashtwin::pipeline {

namespace fs = std::filesystem;
using json = nlohmann::ordered_json;

namespace {

// Guessed units: a part and a scan of a cell are under 5 m across, so a larger bounding-box
// diagonal is taken as millimetres.
double unit_scale(Units u, double diagonal, const std::string& what) {
  if (u == Units::kMetres) return 1.0;
  if (u == Units::kMillimetres) return 1e-3;
  const bool mm = diagonal > 5.0;
  spdlog::info("{}: bounding-box diagonal {:.4g}, read as {}", what, diagonal,
               mm ? "millimetres" : "metres");
  return mm ? 1e-3 : 1.0;
}

// Bounding-box diagonal of points (float or double).
template <typename Points>
double diagonal_of(const Points& points) {
  if (points.empty()) return 0;
  Vec3 lo = points.front().template cast<double>(), hi = lo;
  for (const auto& p : points) {
    lo = lo.cwiseMin(p.template cast<double>());
    hi = hi.cwiseMax(p.template cast<double>());
  }
  return (hi - lo).norm();
}

PointCloud read_scan(const JobInputs& in) {
  PointCloud cloud = load_cloud(in.scan);
  if (cloud.size() < 100)
    throw InputError(in.scan + ": expected a scan of at least 100 points, got " +
                     std::to_string(cloud.size()));
  const double s = unit_scale(in.scan_units, diagonal_of(cloud.points), in.scan);
  for (auto& p : cloud.points) p *= static_cast<float>(s);
  return cloud;
}

TriangleMesh read_cad(const JobInputs& in) {
  TriangleMesh cad = load_mesh(in.cad);
  const double s = unit_scale(in.cad_units, diagonal_of(cad.vertices), in.cad);
  for (auto& v : cad.vertices) v *= s;
  return cad;
}

// What a job writes that a real cell would run or rely on: removed before it starts, so that a
// refusal never leaves an earlier job's programs standing beside its reason.
constexpr const char* kJobResults[] = {"plan", "plans.json", "trajectory.csv", "job.json",
                                       "view3d.html"};

// The job's refusal: DIR/job.json says why; no program is written.
JobResult refuse(JobResult r, const std::string& reason, const fs::path& dir) {
  r.refused = true;
  r.reason = reason;
  r.summary["refused"] = true;
  r.summary["reason"] = reason;
  spdlog::warn("job refused: {}", reason);
  write_text_file((dir / "job.json").string(), r.summary.dump(1) + "\n");
  return r;
}

// ---- Rehearsal: the flash as the scan shows it, as material on the CAD part, ground in the
// twin with the planned motions.

// Heights along a path: each flash point of its region (in {C}) raises the height at the path
// point nearest to it to its distance from the CAD; path points no flash point fell to take
// the nearest assigned neighbour's; none at all: the region's height.
std::vector<double> heights_along(const perception::FlashPath& path,
                                  const std::vector<Vec3>& flash_C, const MeshBvh& cad) {
  const std::size_t n = path.points_C.size();
  std::vector<double> h(n, -1.0);
  for (const Vec3& q : flash_C) {
    std::size_t best = 0;
    double best_d = 1e300;
    for (std::size_t i = 0; i < n; ++i) {
      const double d = (path.points_C[i] - q).squaredNorm();
      if (d < best_d) {
        best_d = d;
        best = i;
      }
    }
    h[best] = std::max(h[best], cad.closest(q, 0.05).distance);
  }
  for (std::size_t i = 0; i < n; ++i) {
    if (h[i] >= 0) continue;
    double v = -1;
    for (std::size_t r = 1; r < n && v < 0; ++r) {
      if (i >= r && h[i - r] >= 0) v = h[i - r];
      else if (i + r < n && h[i + r] >= 0) v = h[i + r];
    }
    h[i] = v >= 0 ? v : path.fin_height;
  }
  return h;
}

// A fin as a closed slab along the root: at each root point a cross-section of `thickness`
// across the fin plane normal, from `sink` inside the body up to the local height along the
// outward CAD normal; quads between sections, end caps on an open line; outward-oriented.
sim::Fin fin_from_path(const perception::FlashPath& path, const std::vector<double>& h,
                       double thickness) {
  constexpr double kSink = 3e-4;  // [m] into the body, so the fin meets it without a gap
  const std::size_t n = path.points_C.size();
  sim::Fin fin;
  fin.kind = "rehearsal";
  fin.root = path.points_C;
  fin.closed = path.closed;
  fin.thickness = thickness;
  TriangleMesh& m = fin.mesh;
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3 up = path.normals_C[i].normalized();
    Vec3 across = path.fin_normal_C - path.fin_normal_C.dot(up) * up;
    if (across.norm() < 1e-6) across = up.unitOrthogonal();
    across.normalize();
    const Vec3& r = path.points_C[i];
    const Vec3 a = 0.5 * thickness * across;
    for (const Vec3& v : {Vec3(r - a - kSink * up), Vec3(r + a - kSink * up),
                          Vec3(r + a + h[i] * up), Vec3(r - a + h[i] * up)})
      m.vertices.push_back(v);
    fin.max_height = std::max(fin.max_height, h[i]);
  }
  const auto quad = [&](int a, int b, int c, int d) {
    m.triangles.push_back({a, b, c});
    m.triangles.push_back({a, c, d});
  };
  const std::size_t segments = path.closed ? n : n - 1;
  for (std::size_t i = 0; i < segments; ++i) {
    const int s = static_cast<int>(4 * i), t = static_cast<int>(4 * ((i + 1) % n));
    for (int k = 0; k < 4; ++k) quad(s + k, t + k, t + (k + 1) % 4, s + (k + 1) % 4);
  }
  if (!path.closed) {
    const int e = static_cast<int>(4 * (n - 1));
    quad(0, 3, 2, 1);
    quad(e, e + 1, e + 2, e + 3);
  }
  if (m.volume() < 0)
    for (auto& t : m.triangles) std::swap(t[1], t[2]);
  fin.volume = std::abs(m.volume());
  return fin;
}

// The part the scan shows: the CAD body and one fin per detected path (regions unseen at their
// edge get a 0.8 mm thickness, the middle of the 0.3-1.5 mm castings have).
sim::Casting part_as_scanned(const TriangleMesh& cad, const MeshBvh& bvh, const Perception& perc,
                             const PointCloud& scan_M) {
  sim::Casting part;
  part.nominal = cad;
  const auto& det = perc.detection;
  for (const auto& path : det.paths) {
    if (path.points_C.size() < 2) continue;
    std::vector<Vec3> flash_C;
    double thickness = 8e-4;
    if (path.region >= 0 && path.region < static_cast<int>(det.regions.size())) {
      const auto& reg = det.regions[static_cast<std::size_t>(path.region)];
      for (const auto idx : reg.points)
        flash_C.push_back(perc.X_CM_est * scan_M.points[idx].cast<double>());
      if (reg.thickness > 0) thickness = reg.thickness;
    }
    part.fins.push_back(fin_from_path(path, heights_along(path, flash_C, bvh), thickness));
  }
  return part;
}

// What the rehearsal ground and predicted.
struct Rehearsal {
  std::string refusal;  ///< why the job must refuse; "" when the rehearsed part is within limits
  ScenarioScan cell;    ///< the part as scanned, in the twin's cell (setup, files)
  ExecutionSummary execution;  ///< ran = false when no program would run
};

// Grinds the part as scanned in the twin with the written programs as the controller runs them
// (the plans themselves for a robot without a program language): DIR/rehearsal/cell/ and the
// rehearsal.* metrics (removal, execution, force, quality) into `m`.
Rehearsal rehearse(const Scenario& sc, const CellSetup& cell, const MeshBvh& cad_bvh,
                   const Perception& perc, const PointCloud& scan_M, const Plans& plans,
                   const fs::path& staging, const fs::path& dir, json& m) {
  Rehearsal out;
  std::vector<Motion> motions;
  if (sc.robot.controller.language == "none") {
    for (const auto& p : plans.paths) motions.push_back(motion_of(p));
    m["rehearsal.motion"] = "plan";
  } else {
    ProgramMotions pm = program_motions(sc.robot, staging.string());
    m["rehearsal.motion"] = "program";
    m["rehearsal.programs"] = pm.programs;
    m["rehearsal.program_time_s"] = pm.time_s;
    m["rehearsal.program_max_joint_velocity_ratio"] = pm.max_joint_velocity_ratio;
    if (!pm.ok()) {
      out.refusal = "a program would not run: " + pm.failure;
      return out;
    }
    motions = std::move(pm.motions);
  }
  ScenarioScan& ss = out.cell;
  ss.setup.casting = part_as_scanned(cell.casting.nominal, cad_bvh, perc, scan_M);
  ss.setup.spec = cell.spec;
  ss.setup.spec.X_WC = cell.spec.X_WM * perc.X_CM_est.inverse();
  ss.files = sim::write_cell(sc.robot, ss.setup.spec, ss.setup.casting,
                             (dir / "rehearsal" / "cell").string());
  ss.scan.result.cloud_M = scan_M;  // for the 3D view
  ss.scan.X_WM_nominal = ss.scan.X_WM_true = cell.spec.X_WM;
  Execution ex(sc, ss.setup.casting);
  ex.run_motions(ss, motions);
  json r;
  out.execution = ex.finish(r);
  const auto failures = quality_failures(sc.quality, r);
  r["quality.pass"] = failures.empty();
  r["quality.failures"] = failures;
  for (auto it = r.begin(); it != r.end(); ++it) m["rehearsal." + it.key()] = it.value();
  if (!failures.empty())
    out.refusal = "the rehearsal predicts a part outside its quality limits: " + json(failures).dump();
  return out;
}

// DIR/view3d.html of the job: the CAD, the scan by perception's labels, the detected paths, the
// planned tool paths, the rehearsal's predicted residual flash and gouges and the arm along the
// rehearsed programs, all at the estimated pose.
void write_job_view(const Scenario& sc, const Rehearsal& reh, const Perception& perc,
                    const Plans& plans, const std::string& verdict, bool refused,
                    const std::string& scan_path, const fs::path& dir) {
  RunResult result;
  result.detection = perc.detection;
  result.registration = perc.registration;
  result.verdict = verdict;
  result.exit_code = refused ? 1 : 0;
  const ReportInputs in{sc, reh.cell, result, plans.paths, reh.execution};
  View3dParams vp;
  vp.title = "job on " + fs::path(scan_path).filename().string() + " (" + sc.robot.name +
             "; residual and gouges as the rehearsal predicts them)";
  write_text_file((dir / "view3d.html").string(), view3d_html(in, vp));
}

// A JSON file a job wrote. @throws IoError (missing), InputError (not JSON) naming it.
json read_job_json(const std::string& path) {
  try {
    return json::parse(read_text_file(path));
  } catch (const json::exception& e) {
    throw InputError(path + ": expected the JSON a job writes, got " + e.what());
  }
}

}  // namespace

ProgramMotions program_motions(const RobotModel& robot, const std::string& dir) {
  const std::string plans_file = (fs::path(dir) / "plans.json").string();
  const json plans = read_job_json(plans_file);
  const planner::ProgramParams pp = planner::program_params_for(robot);
  ProgramMotions out;
  for (const auto& path : plans) {
    if (!path.is_object() || !path.contains("motions")) continue;  // not planned
    const std::size_t k = path.value("path", std::size_t{0});
    for (const auto& mo : path["motions"]) {
      const std::string rel = mo.value("program", std::string());
      if (rel.empty())
        throw InputError(plans_file + ": path " + std::to_string(k) +
                         ": expected a program for each motion, got none");
      const std::string file = (fs::path(dir) / rel).string();
      planner::ParsedProgram parsed;
      try {
        parsed = planner::parse_program(read_text_file(file), pp);
      } catch (const ArgumentError& e) {
        throw InputError(file + ": " + e.what());
      }
      ++out.programs;
      Motion motion;
      motion.path = k;
      motion.tool_radius = mo.value("tool_radius_mm", 0.0) * 1e-3;
      try {
        planner::ReplayedProgram rp = planner::replay_program(robot, parsed);
        motion.trajectory.t = rp.trajectory.t;
        motion.trajectory.q = rp.trajectory.q;
        motion.trajectory.dq = rp.trajectory.dq;
        motion.tcp_B = std::move(rp.X_BT);
        out.time_s += rp.trajectory.duration();
        spdlog::debug("{}: {} targets, {:.3f} s as the controller runs it, path {:.1f} mm",
                      rel, parsed.points.size(), rp.trajectory.duration(), rp.path_length * 1e3);
        out.max_joint_velocity_ratio = std::max(out.max_joint_velocity_ratio, rp.max_joint_velocity_ratio);
      } catch (const ArgumentError& e) {
        if (out.failure.empty()) out.failure = rel + ": " + e.what();
        continue;
      }
      out.motions.push_back(std::move(motion));
    }
  }
  return out;
}

ReplayResult replay_job(const Scenario& sc, const std::string& job_dir, const std::string& out_dir) {
  if (out_dir.empty()) throw ArgumentError("replay: expected an output folder");
  const std::string job_file = (fs::path(job_dir) / "job.json").string();
  const json job = read_job_json(job_file);
  if (job.value("refused", false))
    throw InputError(job_file + ": expected a job that wrote programs, got a refusal (" +
                     job.value("reason", std::string("no reason")) + ")");
  if (job.value("robot", std::string()) != sc.robot.name)
    throw InputError(job_file + ": robot: expected " + sc.robot.name + " (the scenario's), got '" +
                     job.value("robot", std::string()) + "'");
  ProgramMotions pm = program_motions(sc.robot, job_dir);
  if (pm.programs == 0)
    throw InputError((fs::path(job_dir) / "plans.json").string() + ": expected programs, got none");

  ReplayResult r;
  json& m = r.metrics;
  m["job"] = job_dir;
  m["scenario"] = sc.name;
  m["seed"] = sc.seed;
  m["robot"] = sc.robot.name;
  m["program.count"] = pm.programs;
  m["program.time_s"] = pm.time_s;
  m["program.max_joint_velocity_ratio"] = pm.max_joint_velocity_ratio;
  ensure_directory(out_dir);
  if (!pm.ok()) {
    r.reason = "a program would not run: " + pm.failure;
    m["quality.pass"] = false;
    m["quality.failures"] = json::array({r.reason});
  } else {
    // The twin's part for this seed, where it truly lies; the robot base as the cell has it.
    ScenarioScan ss;
    ss.setup = setup_cell(sc);
    ss.files = sim::write_cell(sc.robot, ss.setup.spec, ss.setup.casting,
                               (fs::path(out_dir) / "cell").string());
    m["casting.flash_volume_mm3"] = ss.setup.casting.flash_volume() * 1e9;
    Execution ex(sc, ss.setup.casting);
    ex.run_motions(ss, pm.motions);
    ex.finish(m);
    const auto failures = quality_failures(sc.quality, m);
    m["quality.pass"] = failures.empty();
    m["quality.failures"] = failures;
    if (!failures.empty()) r.reason = "the part misses its quality limits: " + json(failures).dump();
  }
  r.pass = r.reason.empty();
  write_text_file((fs::path(out_dir) / "metrics.json").string(), m.dump(1) + "\n");
  return r;
}

JobResult run_job(const JobInputs& in) {
  if (in.out_dir.empty()) throw ArgumentError("job: expected an output folder");
  omp_set_num_threads(std::max(1, in.threads));
  const Scenario sc = load_scenario(in.cell);
  const PointCloud scan_M = read_scan(in);
  // The cell as the cell file states it: the robot base and the scanner mount as calibrated.
  CellSetup setup;
  setup.spec = sc.cell;
  setup.casting.nominal = read_cad(in);
  const fs::path dir(in.out_dir);
  ensure_directory(dir.string());
  for (const char* name : kJobResults) fs::remove_all(dir / name);

  JobResult r;
  json& m = r.summary;
  m["scan"] = in.scan;
  m["cad"] = in.cad;
  m["cell"] = in.cell;
  m["robot"] = sc.robot.name;
  m["scan.points"] = scan_M.size();

  Perception perc;
  const auto target = perception::ModelTarget::from_mesh_cached(setup.casting.nominal);
  perc.registration = perception::register_scan(scan_M, *target, cell_registration_params());
  const auto& reg = perc.registration;
  perc.X_CM_est = reg.T_target_source;
  const Pose X_BC = setup.spec.X_WB.inverse() * setup.spec.X_WM * perc.X_CM_est.inverse();
  m["registration.confident"] = reg.confident;
  m["registration.fitness"] = reg.fitness;
  m["registration.rmse_mm"] = reg.rmse * 1000;
  m["registration.message"] = reg.message;
  m["X_CM"] = pose_json(perc.X_CM_est);
  m["X_BC"] = pose_json(X_BC);
  if (!reg.confident) return refuse(std::move(r), "pose not confident: " + reg.message, dir);

  // The fixture (locating blocks, riser) holds the part: laid out round it where it was found.
  setup.spec.X_WC = setup.spec.X_WM * perc.X_CM_est.inverse();
  const MeshBvh cad_bvh(setup.casting.nominal);
  perc.detection = detect_off_fixture(sc, setup, scan_M, cad_bvh, perc.X_CM_est);
  perc.flash_C = detected_flash_C(perc.detection, scan_M, perc.X_CM_est);
  write_paths(dir.string(), perc.detection);
  m["paths.count"] = perc.detection.paths.size();

  // Plans into a staging folder: the programs are kept only when every path is feasible.
  const fs::path staging = dir / ".staging";
  fs::remove_all(staging);
  RunOptions opt;
  opt.report = false;
  const Plans plans = plan_setup(sc, setup, perc, opt, staging, m);
  if (!plans.failed_paths.empty()) {
    fs::remove_all(staging);
    return refuse(std::move(r), "not every path is feasible: " + plans.first_failure, dir);
  }
  const Rehearsal reh = rehearse(sc, setup, cad_bvh, perc, scan_M, plans, staging, dir, m);
  if (reh.execution.ran)
    write_job_view(sc, reh, perc, plans, reh.refusal.empty() ? "programs written" : "refused: " + reh.refusal,
                   !reh.refusal.empty(), in.scan, dir);
  if (!reh.refusal.empty()) {
    fs::remove_all(staging);
    return refuse(std::move(r), reh.refusal, dir);
  }
  for (const char* name : kJobResults)
    if (fs::exists(staging / name)) fs::rename(staging / name, dir / name);
  fs::remove_all(staging);
  m["refused"] = false;
  m["programs"] = sc.robot.controller.language;
  write_text_file((dir / "job.json").string(), m.dump(1) + "\n");
  return r;
}

}  // namespace flashtwin::pipeline
