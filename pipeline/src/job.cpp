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
#include "flashtwin/pipeline/scenario.hpp"
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

double diagonal_of(const std::vector<Eigen::Vector3f>& points) {
  if (points.empty()) return 0;
  Eigen::Vector3f lo = points.front(), hi = points.front();
  for (const auto& p : points) {
    lo = lo.cwiseMin(p);
    hi = hi.cwiseMax(p);
  }
  return static_cast<double>((hi - lo).norm());
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
  const TriangleMesh raw = load_mesh(in.cad);
  std::vector<Eigen::Vector3f> v;
  for (const auto& p : raw.vertices) v.push_back(p.cast<float>());
  return load_mesh(in.cad, unit_scale(in.cad_units, diagonal_of(v), in.cad));
}

// The job's refusal: DIR/job.json says why; nothing else is left behind.
JobResult refuse(JobResult r, const std::string& reason, const fs::path& dir) {
  r.refused = true;
  r.reason = reason;
  r.summary["refused"] = true;
  r.summary["reason"] = reason;
  spdlog::warn("job refused: {}", reason);
  write_text_file((dir / "job.json").string(), r.summary.dump(1) + "\n");
  return r;
}

}  // namespace

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

  JobResult r;
  json& m = r.summary;
  m["scan"] = in.scan;
  m["cad"] = in.cad;
  m["cell"] = in.cell;
  m["robot"] = sc.robot.name;
  m["scan.points"] = scan_M.size();

  Perception perc;
  const auto target = perception::ModelTarget::from_mesh_cached(setup.casting.nominal);
  perception::RegistrationParams rp = cell_registration_params();
  perc.registration = perception::register_scan(scan_M, *target, rp);
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

  const MeshBvh cad_bvh(setup.casting.nominal);
  perception::DetectionParams dp = sc.detection;
  perc.detection = perception::detect_flash(scan_M, cad_bvh, perc.X_CM_est, dp);
  write_paths(dir.string(), perc.detection);
  m["paths.count"] = perc.detection.paths.size();

  // Plans into a staging folder: the programs are kept only when every path is feasible.
  const fs::path staging = dir / ".staging";
  fs::remove_all(staging);
  RunOptions opt;
  opt.report = false;
  json tm;
  const Plans plans = plan_setup(sc, setup, perc, opt, staging, tm);
  for (auto it = tm.begin(); it != tm.end(); ++it) m[it.key()] = it.value();
  if (!plans.failed_paths.empty()) {
    fs::remove_all(staging);
    return refuse(std::move(r), "not every path is feasible: " + plans.first_failure, dir);
  }
  for (const char* name : {"plan", "plans.json", "trajectory.csv"}) {
    fs::remove_all(dir / name);
    if (fs::exists(staging / name)) fs::rename(staging / name, dir / name);
  }
  fs::remove_all(staging);
  m["refused"] = false;
  m["programs"] = sc.robot.controller.language;
  m["rehearsal"] = "not implemented: the programs are not replayed on the twin";
  write_text_file((dir / "job.json").string(), m.dump(1) + "\n");
  return r;
}

}  // namespace flashtwin::pipeline
