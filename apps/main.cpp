// flashtwin command line: thin argument parsing over the libraries.
// Exit codes: 0 success, 1 the job ran but failed or refused, 2 bad input.
#include <CLI/CLI.hpp>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <tuple>
#include <iostream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <unistd.h>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/robot.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/pipeline/job.hpp"
#include "flashtwin/pipeline/paths_io.hpp"
#include "flashtwin/pipeline/pose_json.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/pipeline/sweep.hpp"
#include "flashtwin/planner/grind_planner.hpp"
#include "flashtwin/planner/program_export.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/planner/workspace.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/views.hpp"
#include "flashtwin/sim/scan_cell.hpp"
#include "flashtwin/perception/baselines.hpp"
#include "flashtwin/perception/registration.hpp"
#include "flashtwin/core/mesh.hpp"

#ifndef FLASHTWIN_SOURCE_DIR
#define FLASHTWIN_SOURCE_DIR "."
#endif

namespace ft = flashtwin;
using json = nlohmann::json;

namespace {

using ft::pipeline::pose_json;
using ft::pipeline::read_paths_file;
using ft::pipeline::read_pose_file;

constexpr int kExitOk = 0, kExitFailed = 1, kExitBadInput = 2;

std::string default_robot_path() {
  const char* home = std::getenv("FLASHTWIN_HOME");
  const std::string root = home ? home : FLASHTWIN_SOURCE_DIR;
  return root + "/models/robots/ft6.yaml";
}

// Whitespace- or comma-separated numbers of an option value, exactly n of them.
std::vector<double> parse_numbers(const std::string& text, std::size_t n, const std::string& what) {
  std::string s = text;
  for (char& c : s)
    if (c == ',' || c == ';' || c == '[' || c == ']') c = ' ';
  std::istringstream is(s);
  std::vector<double> v;
  std::string tok;
  while (is >> tok) {
    char* end = nullptr;
    const double x = std::strtod(tok.c_str(), &end);
    if (end == tok.c_str() || *end != '\0')
      throw ft::ArgumentError(what + ": expected numbers, got '" + tok + "'");
    if (!std::isfinite(x)) throw ft::ArgumentError(what + ": expected finite numbers, got " + tok);
    v.push_back(x);
  }
  if (v.size() != n)
    throw ft::ArgumentError(what + ": expected " + std::to_string(n) + " numbers, got " +
                            std::to_string(v.size()));
  return v;
}

ft::Vector6 to_q(const std::vector<double>& v, bool degrees) {
  ft::Vector6 q;
  for (int i = 0; i < ft::kNumJoints; ++i) q[i] = degrees ? v[i] * M_PI / 180 : v[i];
  return q;
}

void print_pose(const char* name, const ft::Pose& X) {
  std::printf("%s =\n", name);
  const Eigen::Matrix4d M = X.matrix();
  for (int r = 0; r < 4; ++r)
    std::printf("  [% .9f % .9f % .9f % .9f]\n", M(r, 0), M(r, 1), M(r, 2), M(r, 3));
}

struct Common {
  std::string robot = default_robot_path();
  bool json = false;
};

int cmd_fk(const Common& c, const std::string& q_text, bool degrees, bool axes) {
  const ft::RobotModel robot = ft::load_robot(c.robot);
  ft::Vector6 q = to_q(parse_numbers(q_text, 6, "--q"), degrees);
  if (axes) q = robot.controller.joints(q);
  const ft::Pose X_BE = ft::planner::fk_flange(robot, q);
  const ft::Pose X_BT = X_BE * robot.tool.X_ET;
  const auto sing = ft::planner::check_singularity(robot, q);
  const bool inside = robot.within_limits(q);
  if (!inside) spdlog::warn("configuration outside the joint limits of {}", c.robot);
  if (c.json) {
    json j;
    j["q"] = std::vector<double>(q.data(), q.data() + 6);
    j["X_BE"] = pose_json(X_BE);
    j["X_BT"] = pose_json(X_BT);
    j["within_limits"] = inside;
    j["manipulability"] = sing.manipulability;
    std::cout << j.dump() << "\n";
  } else {
    print_pose("X_BE (flange in base)", X_BE);
    print_pose("X_BT (tool in base)", X_BT);
    std::printf("within limits: %s, manipulability: %.6g\n", inside ? "yes" : "NO",
                sing.manipulability);
  }
  return kExitOk;
}

int cmd_ik(const Common& c, const std::string& pose_text, bool tool, bool all,
           const std::string& ref_text, bool degrees, bool axes) {
  const ft::RobotModel robot = ft::load_robot(c.robot);
  const auto v = parse_numbers(pose_text, 16, "--pose");
  std::array<double, 16> m{};
  std::copy(v.begin(), v.end(), m.begin());
  const ft::Pose X = ft::pose_from_row_major(m, "--pose", 1e-6);
  ft::planner::IkParams p;
  p.within_limits_only = !all;
  if (!ref_text.empty()) {
    p.q_ref = to_q(parse_numbers(ref_text, 6, "--ref"), degrees);
    if (axes) p.q_ref = robot.controller.joints(*p.q_ref);
  }
  auto res = tool ? ft::planner::ik_tool(robot, X, p) : ft::planner::ik_flange(robot, X, p);
  if (axes)
    for (auto& s : res.solutions) s.q = robot.controller.axes(s.q);
  const double scale = degrees ? 180 / M_PI : 1.0;
  if (c.json) {
    json j;
    j["status"] = ft::planner::to_string(res.status);
    j["message"] = res.message;
    json sols = json::array(), branches = json::array();
    for (const auto& s : res.solutions) {
      std::vector<double> q(6);
      for (int i = 0; i < 6; ++i) q[i] = s.q[i] * scale;
      sols.push_back(q);
      branches.push_back(s.branch.name());
    }
    j["solutions"] = sols;
    j["branches"] = branches;
    j["units"] = degrees ? "deg" : "rad";
    j["discarded_by_limits"] = res.discarded_by_limits;
    j["wrist_singular"] = res.wrist_singular;
    j["shoulder_singular"] = res.shoulder_singular;
    j["elbow_singular"] = res.elbow_singular;
    std::cout << j.dump() << "\n";
  } else {
    std::printf("status: %s (%s)\n", ft::planner::to_string(res.status).c_str(),
                res.message.c_str());
    for (const auto& s : res.solutions) {
      std::printf("  %-17s", s.branch.name().c_str());
      for (int i = 0; i < 6; ++i) std::printf(" % .9f", s.q[i] * scale);
      std::printf("\n");
    }
  }
  return res.ok() ? kExitOk : kExitFailed;
}

int cmd_workspace(const Common& c, int samples, std::uint64_t seed, bool tool,
                  const std::string& out) {
  const ft::RobotModel robot = ft::load_robot(c.robot);
  ft::planner::WorkspaceParams p;
  p.samples = samples;
  p.seed = seed;
  p.tool_point = tool;
  const auto ws = ft::planner::sample_workspace(robot, p);
  ft::ensure_directory(out);
  const std::string png = (std::filesystem::path(out) / "workspace.png").string();
  ft::write_png(png, ft::planner::plot_workspace(ws, robot.name + (tool ? " TCP" : " flange")));
  json j;
  j["robot"] = robot.name;
  j["point"] = tool ? "tcp" : "flange";
  j["samples"] = samples;
  j["seed"] = seed;
  j["max_reach_m"] = ws.max_reach;
  j["max_horizontal_reach_m"] = ws.max_horizontal_reach;
  j["min_m"] = {ws.min.x(), ws.min.y(), ws.min.z()};
  j["max_m"] = {ws.max.x(), ws.max.y(), ws.max.z()};
  j["plot"] = png;
  ft::write_text_file((std::filesystem::path(out) / "workspace.json").string(), j.dump(2) + "\n");
  if (c.json)
    std::cout << j.dump() << "\n";
  else
    std::printf("max reach %.4f m (horizontal %.4f m) over %d samples; plot: %s\n",
                ws.max_reach, ws.max_horizontal_reach, samples, png.c_str());
  return kExitOk;
}

int cmd_cell(const Common& c, const std::string& scenario_path, const std::string& out) {
  const ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path);
  const auto setup = ft::pipeline::setup_cell(sc);
  spdlog::info("casting: {} ({} triangles, {} flashes, flash volume {:.1f} mm^3)",
               setup.casting.description, setup.casting.nominal.num_triangles(),
               setup.casting.fins.size(), setup.casting.flash_volume() * 1e9);
  const auto files = ft::sim::write_cell(sc.robot, setup.spec, setup.casting, out);
  const auto& sum = files.model;
  if (c.json) {
    json j;
    j["scenario"] = sc.name;
    j["mjcf"] = files.mjcf;
    j["cad"] = files.cad;
    j["truth"] = files.truth;
    j["casting"] = setup.casting.description;
    j["flashes"] = setup.casting.fins.size();
    j["urdf"] = files.urdf;
    j["nbody"] = sum.nbody;
    j["njnt"] = sum.njnt;
    j["nu"] = sum.nu;
    j["ncam"] = sum.ncam;
    j["timestep"] = sum.timestep;
    std::cout << j.dump() << "\n";
  } else {
    std::printf("cell of scenario '%s' written: %s (MuJoCo: %d bodies, %d joints, %d actuators, "
                "%d cameras)\nURDF: %s\nCAD model of the casting: %s\nground truth (scoring only): %s\n"
                "view it: mujoco-simulate %s\n",
                sc.name.c_str(), files.mjcf.c_str(), sum.nbody, sum.njnt, sum.nu, sum.ncam,
                files.urdf.c_str(), files.cad.c_str(), files.truth.c_str(), files.mjcf.c_str());
  }
  return kExitOk;
}

// Builds the scenario's cell in out/cell and scans it; writes the scan files into out.
using ScanRun = ft::pipeline::ScenarioScan;

ScanRun run_scan(const ft::pipeline::Scenario& sc, const std::string& out) {
  namespace fs = std::filesystem;
  ScanRun r = ft::pipeline::scan_scenario(sc, (fs::path(out) / "cell").string(), sc.scan.threads);
  ft::pipeline::save_scan(r, out, true);
  const auto& res = r.scan.result;
  json meta;
  meta["frame"] = "M (scanner)";
  meta["X_WM"] = pose_json(r.scan.X_WM_nominal);
  meta["X_BM"] = pose_json(r.setup.spec.X_WB.inverse() * r.scan.X_WM_nominal);
  meta["points"] = res.cloud_M.size();
  meta["rays"] = res.rays;
  meta["time_s"] = res.time_s;
  meta["rays_per_s"] = res.rays_per_s();
  meta["cad"] = r.files.cad;
  ft::write_text_file((fs::path(out) / "scan.json").string(), meta.dump(2) + "\n");
  return r;
}

int cmd_scan(const Common& c, const std::string& scenario_path, const std::string& out,
             long long seed_override) {
  ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path);
  if (seed_override >= 0) ft::pipeline::set_seed(sc, static_cast<std::uint64_t>(seed_override));
  const ScanRun r = run_scan(sc, out);
  const auto& res = r.scan.result;
  std::size_t flash = 0;
  for (auto l : res.truth) flash += l == ft::sim::kTruthFlash;
  if (c.json) {
    json j;
    j["points"] = res.cloud_M.size();
    j["flash_points_truth"] = flash;
    j["rays"] = res.rays;
    j["time_s"] = res.time_s;
    j["rays_per_s"] = res.rays_per_s();
    j["scene_triangles"] = r.scan.scene_triangles;
    j["ply"] = (std::filesystem::path(out) / "scan.ply").string();
    j["pcd"] = (std::filesystem::path(out) / "scan.pcd").string();
    std::cout << j.dump() << "\n";
  } else {
    std::printf("scan of '%s': %zu points (%zu on flashes) from %llu rays in %.3f s = %.2f M rays/s "
                "over %zu triangles\n%s/scan.ply, scan.pcd (frame {M}; X_WM in scan.json)\n",
                sc.name.c_str(), res.cloud_M.size(), flash,
                static_cast<unsigned long long>(res.rays), res.time_s, res.rays_per_s() / 1e6,
                r.scan.scene_triangles, out.c_str());
  }
  return kExitOk;
}

ft::Rgb truth_colour(std::uint8_t label) {
  switch (label) {
    case ft::sim::kTruthBody: return {70, 140, 230};
    case ft::sim::kTruthFlash: return {255, 60, 20};
    case ft::sim::kTruthOutlier: return {230, 0, 230};
    case ft::sim::kTruthMixed: return {250, 220, 0};
    default: return {40, 200, 200};
  }
}

int cmd_render(const Common& c, const std::string& scenario_path, const std::string& out,
               const std::vector<std::string>& cameras, int width, int height, bool with_scan,
               bool truth) {
  const ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path);
  ft::sim::RenderRequest req;
  if (!cameras.empty()) req.cameras = cameras;
  req.width = width;
  req.height = height;
  std::string mjcf;
  if (with_scan || truth) {
    const ScanRun r = run_scan(sc, out);
    mjcf = r.files.mjcf;
    const auto& res = r.scan.result;
    // Points placed with the calibrated pose, as perception would place them; only those
    // near the casting (its box grown by 2 cm) are drawn: each drawn point costs render time.
    ft::Vec3 lo, hi;
    r.setup.casting.nominal.bounds(lo, hi);
    const Eigen::AlignedBox3d roi(lo - ft::Vec3::Constant(0.02), hi + ft::Vec3::Constant(0.02));
    const ft::Pose X_CM = r.setup.spec.X_WC.inverse() * r.scan.X_WM_nominal;
    std::vector<std::size_t> near;
    for (std::size_t i = 0; i < res.cloud_M.size(); ++i)
      if (roi.contains(X_CM * res.cloud_M.points[i].cast<double>())) near.push_back(i);
    const std::size_t budget = 15000;
    const double step = std::max(1.0, static_cast<double>(near.size()) / budget);
    for (double k = 0; k < static_cast<double>(near.size()); k += step) {
      const std::size_t i = near[static_cast<std::size_t>(k)];
      req.points_W.push_back(r.scan.X_WM_nominal * res.cloud_M.points[i].cast<double>());
      req.colors.push_back(truth ? truth_colour(res.truth[i]) : ft::Rgb{40, 200, 200});
    }
    req.max_points = static_cast<int>(budget);
    req.point_radius = 0.0005;
  } else {
    const auto setup = ft::pipeline::setup_cell(sc);
    mjcf = ft::sim::write_cell(sc.robot, setup.spec, setup.casting,
                               (std::filesystem::path(out) / "cell").string())
               .mjcf;
  }
  const auto paths = ft::sim::render_views(mjcf, req, out, with_scan || truth ? "scan_" : "render_");
  if (c.json) {
    json j;
    j["images"] = paths;
    std::cout << j.dump() << "\n";
  } else {
    for (const auto& p : paths) std::printf("%s\n", p.c_str());
  }
  return kExitOk;
}

// A point cloud file, or a mesh file (its vertices) for the source.
ft::PointCloud read_points(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext == ".pcd" || ext == ".ply") {
    try {
      return ft::load_cloud(path);
    } catch (const ft::ArgumentError&) {
    }
  }
  const ft::TriangleMesh mesh = ft::load_mesh(path);
  ft::PointCloud c;
  for (const auto& v : mesh.vertices) c.points.push_back(v.cast<float>());
  return c;
}

// The target: a mesh is sampled (area-uniform with its normals), a cloud is used as it is.
std::shared_ptr<const ft::perception::ModelTarget> read_target(const std::string& path) {
  const std::string ext = std::filesystem::path(path).extension().string();
  if (ext == ".stl" || ext == ".obj" || ext == ".ply" || ext == ".off") {
    try {
      return ft::perception::ModelTarget::from_mesh(ft::load_mesh(path));
    } catch (const ft::IoError&) {
      throw;
    } catch (const ft::InputError&) {
      if (ext != ".ply") throw;  // a PLY without faces is a cloud
    }
  }
  const ft::PointCloud c = ft::load_cloud(path);
  try {
    return ft::perception::ModelTarget::from_cloud(c);
  } catch (const ft::ArgumentError& e) {
    throw ft::InputError(path + ": " + e.what());
  }
}

int cmd_register(const Common& c, const std::string& source_path, const std::string& target_path,
                 const std::string& method, bool remove_plane, const std::string& viewpoint) {
  const ft::PointCloud source = read_points(source_path);
  const auto target = read_target(target_path);
  ft::perception::RegistrationResult r;
  if (method == "ours") {
    ft::perception::RegistrationParams p;
    p.remove_support_plane = remove_plane;
    if (!viewpoint.empty()) {
      const auto v = parse_numbers(viewpoint, 3, "--viewpoint");
      p.viewpoint = ft::Vec3(v[0], v[1], v[2]);
    }
    r = ft::perception::register_scan(source, *target, p);
  } else {
    r = ft::perception::register_baseline(ft::perception::baseline_from_string(method), source,
                                          target->dense());
  }
  if (!r.ran) throw ft::InputError(source_path + ": " + r.message);
  if (c.json) {
    json j;
    j["T_target_source"] = pose_json(r.T_target_source);
    j["confident"] = r.confident;
    j["fitness"] = r.fitness;
    j["rmse"] = r.rmse;
    j["ambiguity"] = r.ambiguity;
    j["time_s"] = r.time_s;
    j["method"] = method;
    j["stage"] = r.stage;
    j["message"] = r.message;
    std::cout << j.dump() << "\n";
  } else {
    print_pose("T_target_source (maps source points into the target frame)", r.T_target_source);
    std::printf("%s: fitness %.3f, inlier RMSE %.4f mm, ambiguity %.3f, %.1f ms (%s)\n",
                r.confident ? "confident" : "NOT confident", r.fitness, r.rmse * 1000, r.ambiguity,
                r.time_s * 1000, r.message.c_str());
  }
  return r.confident ? kExitOk : kExitFailed;
}

int cmd_job(const Common& c, ft::pipeline::JobInputs in, const std::string& scan_units,
            const std::string& cad_units) {
  const auto units = [](const std::string& u) {
    return u == "m" ? ft::pipeline::Units::kMetres
                    : (u == "mm" ? ft::pipeline::Units::kMillimetres : ft::pipeline::Units::kAuto);
  };
  in.scan_units = units(scan_units);
  in.cad_units = units(cad_units);
  const auto r = ft::pipeline::run_job(in);
  if (c.json) {
    std::cout << r.summary.dump() << "\n";
  } else if (r.refused) {
    std::printf("job refused: %s\n", r.reason.c_str());
  } else {
    std::printf("job: %zu path(s) planned for %s; rehearsal: %.1f %% of the scanned flash removed, "
                "highest residual %.2f mm, deepest gouge %.2f mm; programs (%s) in %s/plan/; "
                "%s/job.json\n",
                r.summary.value("paths.count", std::size_t{0}),
                r.summary.value("robot", std::string()).c_str(),
                100 * r.summary.value("rehearsal.removal.flash_removed_fraction", 0.0),
                r.summary.value("rehearsal.removal.residual_flash_max_mm", 0.0),
                r.summary.value("rehearsal.removal.gouge_max_mm", 0.0),
                r.summary.value("programs", std::string()).c_str(), in.out_dir.c_str(),
                in.out_dir.c_str());
  }
  return r.refused ? kExitFailed : kExitOk;
}

int cmd_replay(const Common& c, const std::string& scenario_path, const std::string& job_dir,
               const std::string& out, long long seed_override, const std::vector<std::string>& sets) {
  ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path, sets);
  if (seed_override >= 0) ft::pipeline::set_seed(sc, static_cast<std::uint64_t>(seed_override));
  const auto r = ft::pipeline::replay_job(sc, job_dir, out);
  const auto& m = r.metrics;
  if (c.json) {
    std::cout << m.dump() << "\n";
  } else {
    std::printf("replay of %s's %zu program(s) on %s seed %llu (%.1f s as the controller runs "
                "them): %.2f %% of the true flash removed, highest residual %.3f mm, deepest "
                "gouge %.3f mm; %s/metrics.json\n",
                job_dir.c_str(), m.value("program.count", std::size_t{0}), sc.name.c_str(),
                static_cast<unsigned long long>(sc.seed), m.value("program.time_s", 0.0),
                100 * m.value("removal.flash_removed_fraction", 0.0),
                m.value("removal.residual_flash_max_mm", 0.0), m.value("removal.gouge_max_mm", 0.0),
                out.c_str());
    if (!r.pass) std::printf("part FAILS: %s\n", r.reason.c_str());
  }
  return r.pass ? kExitOk : kExitFailed;
}

int cmd_detect(const Common& c, const std::string& scan_path, const std::string& cad_path,
               const std::string& pose_path, const std::string& out) {
  const ft::PointCloud scan = read_points(scan_path);
  const ft::TriangleMesh cad = ft::load_mesh(cad_path);
  const ft::Pose X_CM = read_pose_file(pose_path);
  const ft::MeshBvh bvh(cad);
  ft::perception::DetectionResult r;
  try {
    r = ft::perception::detect_flash(scan, bvh, X_CM, {});
  } catch (const ft::ArgumentError& e) {
    throw ft::InputError(scan_path + " / " + cad_path + ": " + e.what());
  }
  ft::pipeline::write_paths(out, r);
  ft::PointCloud lab;
  for (const auto& p : scan.points) lab.points.push_back((X_CM * p.cast<double>()).cast<float>());
  lab.labels = r.labels;
  ft::save_ply((std::filesystem::path(out) / "scan_labelled.ply").string(), lab);
  std::size_t flash = 0;
  for (auto l : r.labels) flash += l == ft::perception::kDetectFlash;
  double len = 0;
  for (const auto& p : r.paths) len += p.length();
  if (c.json) {
    json j;
    j["regions"] = r.regions.size();
    j["paths"] = r.paths.size();
    j["path_length"] = len;
    j["flash_points"] = flash;
    j["noise_sigma"] = r.noise_sigma;
    j["threshold"] = r.threshold;
    j["time_s"] = r.time_s;
    j["message"] = r.message;
    j["nothing_to_grind"] = r.paths.empty();
    j["paths_json"] = (std::filesystem::path(out) / "paths.json").string();
    std::cout << j.dump() << "\n";
  } else {
    std::printf("%s\n%zu flash points, %zu region(s), %zu path(s), %.1f mm of grinding line; noise "
                "sigma %.4f mm, threshold %.4f mm; %.3f s\n%s/paths.json, paths.ply, "
                "scan_labelled.ply (frame {C})\n",
                r.message.c_str(), flash, r.regions.size(), r.paths.size(), len * 1000,
                r.noise_sigma * 1000, r.threshold * 1000, r.time_s, out.c_str());
  }
  return kExitOk;
}

// Progress bar on a terminal, stage lines otherwise, nothing with --json.
std::function<void(const std::string&, double)> progress_printer(const Common& c) {
  const bool tty = !c.json && isatty(fileno(stderr));
  return [tty, json_out = c.json](const std::string& stage, double f) {
    if (json_out) return;
    if (tty) {
      const int w = 30, k = static_cast<int>(f * w);
      std::fprintf(stderr, "\r[%s%s] %3.0f%% %-14s", std::string(k, '#').c_str(),
                   std::string(w - k, '.').c_str(), f * 100, stage.c_str());
      if (f >= 1) std::fprintf(stderr, "\n");
    } else {
      spdlog::info("stage: {}", stage);
    }
  };
}

// The one-screen summary of a run: the metrics a reviewer looks at first.
void print_run_summary(const ft::pipeline::Scenario& sc, const ft::pipeline::RunResult& r,
                       const std::string& out, bool report) {
  std::printf("scenario '%s' (seed %llu): %s\n", sc.name.c_str(),
              static_cast<unsigned long long>(sc.seed), r.verdict.c_str());
  static const char* keys[] = {
      "scan.points", "registration.confident", "registration.rotation_error_deg",
      "registration.translation_error_mm", "segmentation.precision", "segmentation.recall",
      "path.count", "path.true_count", "path.rmse_mm", "path.coverage",
      "trajectory.paths_planned", "trajectory.paths_failed",
      "trajectory.max_joint_velocity_ratio", "trajectory.max_joint_accel_ratio",
      "execution.tracking_rmse_mm", "execution.joint_limit_violations",
      "removal.flash_removed_fraction", "removal.residual_flash_max_mm", "removal.gouge_max_mm",
      "quality.pass", "force.mean_n", "force.rmse_n", "force.max_n", "rescan.flash_points",
      "sim.realtime_factor", "timing.scan_s", "timing.perception_s", "timing.planning_s",
      "timing.execution_s", "timing.total_s"};
  for (const char* k : keys) {
    if (!r.metrics.contains(k)) continue;
    const auto& v = r.metrics[k];
    if (v.is_number_float()) std::printf("  %-36s %.4g\n", k, v.get<double>());
    else std::printf("  %-36s %s\n", k, v.dump().c_str());
  }
  std::printf("all metrics: %s/metrics.json%s%s\n", out.c_str(),
              report ? "\nreport:      " : "", report ? (out + "/report.html").c_str() : "");
}

int cmd_run(const Common& c, const std::string& scenario_path, const std::string& out,
            long long seed_override, const std::vector<std::string>& sets, bool video,
            const std::string& video_path, bool no_report, bool check, int threads) {
  ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path, sets);
  if (seed_override >= 0) ft::pipeline::set_seed(sc, static_cast<std::uint64_t>(seed_override));
  ft::pipeline::RunOptions opt;
  opt.out_dir = out;
  opt.report = !no_report;
  opt.threads = threads;
  if (video || !video_path.empty())
    opt.video.path = video_path.empty() ? (std::filesystem::path(out) / "run.mp4").string()
                                        : video_path;
  opt.progress = progress_printer(c);
  const auto r = ft::pipeline::run_scenario(sc, opt);
  const auto violations = ft::pipeline::check_expectations(sc, r.metrics);
  if (c.json) {
    std::cout << r.metrics.dump() << "\n";
  } else {
    print_run_summary(sc, r, out, opt.report);
    if (!opt.video.path.empty()) std::printf("video:       %s\n", opt.video.path.c_str());
  }
  if (check)
    for (const auto& v : violations) std::fprintf(stderr, "flashtwin: expectation failed: %s\n", v.c_str());
  else if (!violations.empty())
    // Outside --check the expect: block is information: the exit code is the part's quality.
    for (const auto& v : violations) std::fprintf(stderr, "flashtwin: note: outside an expect: bound: %s\n", v.c_str());
  if (check) {
    if (sc.expect.empty()) {
      std::fprintf(stderr, "flashtwin: --check: %s has no expect: block\n", scenario_path.c_str());
      return kExitFailed;
    }
    if (violations.empty() && !c.json)
      std::printf("check: all %zu expect: bounds hold\n", sc.expect.size());
    return violations.empty() ? kExitOk : kExitFailed;
  }
  return r.exit_code;
}

int cmd_sweep(const Common& c, const std::string& scenario_path, const std::string& out,
              const std::string& seeds, const std::vector<std::string>& sets,
              const std::string& shard, int threads, bool seeds_given, bool check) {
  const ft::pipeline::Scenario sc = ft::pipeline::load_scenario(scenario_path, sets);
  if (check && sc.expect_sweep.seeds.empty())
    throw ft::ConfigError(scenario_path + ": --check: expected an expect_sweep: block (seeds and "
                          "distribution bounds), got none");
  ft::pipeline::SweepOptions o;
  o.seeds = check && !seeds_given ? sc.expect_sweep.seeds : ft::pipeline::parse_seeds(seeds);
  std::tie(o.shard, o.shards) = ft::pipeline::parse_shard(shard);
  o.threads = threads;
  o.out_dir = out;
  const bool tty = !c.json && isatty(fileno(stderr));
  o.progress = [&](std::size_t done, std::size_t total, std::uint64_t seed, int code) {
    if (c.json) return;
    if (tty) {
      std::fprintf(stderr, "\r%zu/%zu runs (seed %llu: exit %d)   ", done, total,
                   static_cast<unsigned long long>(seed), code);
      if (done == total) std::fprintf(stderr, "\n");
    } else {
      spdlog::info("run {}/{}: seed {} exit {}", done, total, seed, code);
    }
  };
  const auto r = ft::pipeline::run_sweep(sc, o);
  if (c.json) {
    std::cout << r.summary.dump() << "\n";
  } else {
    std::printf("%s", ft::read_text_file(r.table_path).c_str());
    std::printf("\nruns: %s\nsummary: %s, %s\n", r.jsonl_path.c_str(), r.summary_path.c_str(),
                r.table_path.c_str());
  }
  if (check) {
    // The distribution decides, not single runs: a refused or failed run lowers the pass rate.
    const auto bad = ft::pipeline::check_sweep_expectations(sc.expect_sweep, r.summary);
    for (const auto& b : bad) std::fprintf(stderr, "flashtwin: sweep expectation failed: %s\n", b.c_str());
    return bad.empty() ? kExitOk : kExitFailed;
  }
  return r.failures ? kExitFailed : kExitOk;
}

int cmd_plan(const Common& c, const std::string& paths_path, const std::string& cad_path,
             const std::string& pose_path, const std::string& out, const std::string& export_lang,
             double feed, double lead_deg, double tilt_deg) {
  const ft::RobotModel robot = ft::load_robot(c.robot);
  auto paths = read_paths_file(paths_path);
  const ft::TriangleMesh cad = ft::load_mesh(cad_path);
  const ft::Pose X_BC = read_pose_file(pose_path, {"X_BC", "T_base_casting"});
  const ft::MeshBvh bvh(cad);
  // The CAD gives the wall normals (where the file has none) and checks units and frame: the
  // path must lie on the CAD surface.
  for (std::size_t k = 0; k < paths.size(); ++k) {
    auto& g = paths[k];
    const bool fill = g.normals_C.empty();
    double worst = 0;
    for (const auto& p : g.points_C) {
      const auto cp = bvh.closest(p);
      worst = std::max(worst, cp.distance);
      if (fill) g.normals_C.push_back(cad.triangle_normal(static_cast<std::size_t>(cp.triangle)));
    }
    if (worst > 0.005)
      throw ft::InputError(paths_path + ": paths[" + std::to_string(k) + "] lies up to " +
                           std::to_string(worst * 1000) + " mm off the CAD surface of " + cad_path +
                           " (expected on it, within 5 mm: same frame {C}, metres)");
  }
  ft::planner::GrindParams gp;
  gp.feed = feed;
  gp.lead = lead_deg * M_PI / 180;
  gp.tilt = tilt_deg * M_PI / 180;
  json summary = json::array();
  int failed = 0;
  for (std::size_t k = 0; k < paths.size(); ++k) {
    ft::planner::GrindResult g;
    try {
      g = ft::planner::plan_grind(robot, X_BC, paths[k], gp);
    } catch (const ft::ArgumentError& e) {
      throw ft::InputError(paths_path + ": paths[" + std::to_string(k) + "]: " + e.what());
    }
    const std::string dir = (std::filesystem::path(out) / ("path_" + std::to_string(k))).string();
    ft::planner::write_grind_outputs(g, dir);
    json pj = {{"path", k}, {"status", ft::planner::to_string(g.status)}, {"message", g.message}};
    if (g.ok()) {
      pj["time_s"] = g.total_time;
      pj["max_joint_velocity_ratio"] = g.max_joint_velocity_ratio;
      pj["max_joint_accel_ratio"] = g.max_joint_accel_ratio;
      pj["min_manipulability"] = g.min_manipulability;
      if (!export_lang.empty()) {
        ft::planner::ProgramParams pp = ft::planner::program_params_for(robot);
        pp.dialect = export_lang == "krl"     ? ft::planner::ProgramDialect::kKrl
                     : export_lang == "rapid" ? ft::planner::ProgramDialect::kRapid
                                              : ft::planner::ProgramDialect::kUrScript;
        pp.name = "flashtwin_path_" + std::to_string(k);
        pj["program"] = ft::planner::export_program_file(robot, g.trajectory, pp, dir);
      }
    } else {
      ++failed;
    }
    summary.push_back(pj);
  }
  ft::ensure_directory(out);
  ft::write_text_file((std::filesystem::path(out) / "plans.json").string(), summary.dump(1) + "\n");
  if (c.json) {
    std::cout << summary.dump() << "\n";
  } else {
    for (const auto& pj : summary)
      std::printf("path %zu: %s%s\n", pj["path"].get<std::size_t>(),
                  pj["status"].get<std::string>().c_str(),
                  pj.contains("time_s") ? (", " + std::to_string(pj["time_s"].get<double>()) + " s").c_str()
                                        : (": " + pj["message"].get<std::string>()).c_str());
    std::printf("%zu path(s), %d failed; outputs in %s/path_*/ and %s/plans.json\n", paths.size(),
                failed, out.c_str(), out.c_str());
  }
  if (paths.empty() && !c.json) std::printf("nothing to grind\n");
  return failed ? kExitFailed : kExitOk;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "flashtwin: digital twin of a robotic flash-grinding cell (MuJoCo cell, virtual "
      "scanner, perception, planning, grinding).\nExit codes: 0 success, 1 ran but failed or "
      "refused, 2 bad input."};
  app.require_subcommand(1);
  app.set_version_flag("--version", "flashtwin 0.1.0");
  int verbosity = 0;
  bool quiet = false;
  app.add_flag("-v,--verbose", verbosity, "More log output (repeat for trace)");
  app.add_flag("-q,--quiet", quiet, "Only warnings and errors on stderr");

  Common common;
  auto add_robot = [&](CLI::App* sub) {
    sub->add_option("--robot", common.robot,
                    "Robot description: YAML (models/robots/) or URDF (.urdf: a serial 6R arm)")
        ->capture_default_str();
  };

  auto* fk = app.add_subcommand("fk", "Forward kinematics: flange pose X_BE for joint angles");
  std::string q_text;
  bool deg = false;
  fk->add_option("--q", q_text, "Six joint angles \"q1 .. q6\" [rad, or deg with --deg]")
      ->required();
  fk->add_flag("--deg", deg, "Angles in degrees");
  bool axes = false;
  fk->add_flag("--axes", axes,
               "--q holds the controller's axis values (the robot file's controller: sign, "
               "offset; a URDF's own joint values), not D-H angles");
  fk->add_flag("--json", common.json, "Print JSON: X_BE and X_BT as 16 row-major numbers");
  add_robot(fk);

  auto* ik = app.add_subcommand(
      "ik", "Inverse kinematics: all joint solutions (up to 8) for a flange or tool pose");
  std::string pose_text, ref_text;
  bool ik_tool = false, ik_all = false;
  ik->add_option("--pose", pose_text, "16 numbers, row-major 4x4 X_BE (or X_BT with --tool) [m]")
      ->required();
  ik->add_flag("--tool", ik_tool, "The pose is the tool frame X_BT");
  ik->add_flag("--all", ik_all, "Also list solutions outside the joint limits");
  ik->add_option("--ref", ref_text, "Reference angles \"q1 .. q6\": nearest 2pi-equivalents");
  ik->add_flag("--deg", deg, "Print (and read --ref) in degrees");
  ik->add_flag("--axes", axes, "Print (and read --ref) the controller's axis values, not D-H angles");
  ik->add_flag("--json", common.json, "Print JSON {\"solutions\": [[q1..q6], ...], ...}");
  add_robot(ik);

  auto* ws = app.add_subcommand(
      "workspace", "Monte Carlo workspace: max reach and a PNG plot (top and side views)");
  int samples = 100000;
  std::uint64_t seed = 1;
  bool ws_tool = false;
  std::string out;
  ws->add_option("--samples", samples, "Random joint configurations")->capture_default_str();
  ws->add_option("--seed", seed, "Random seed")->capture_default_str();
  ws->add_flag("--tool", ws_tool, "Sample the tool point instead of the flange");
  ws->add_option("-o,--output", out, "Output folder (workspace.png, workspace.json)")->required();
  ws->add_flag("--json", common.json, "Print the result as JSON");
  add_robot(ws);

  auto* cell = app.add_subcommand(
      "cell", "Write the scenario's MuJoCo cell (cell.xml) and the robot's URDF");
  std::string scenario;
  cell->add_option("scenario", scenario, "Scenario YAML")->required();
  cell->add_option("-o,--output", out, "Output folder")->required();
  cell->add_flag("--json", common.json, "Print a JSON summary");

  auto* render = app.add_subcommand(
      "render", "Render the scenario's cell off-screen (OSMesa) from named cameras to PNG");
  std::vector<std::string> cameras;
  int width = 800, height = 600;
  render->add_option("scenario", scenario, "Scenario YAML")->required();
  render->add_option("-o,--output", out, "Output folder (PNGs; the cell in OUT/cell)")->required();
  render->add_option("--camera", cameras,
                     "Camera name(s): overview, front, top, casting_closeup, scanner_view "
                     "(default: overview casting_closeup top)");
  render->add_option("--width", width, "Image width [px] (<= 1920)")->capture_default_str();
  render->add_option("--height", height, "Image height [px] (<= 1080)")->capture_default_str();
  bool with_scan = false, with_truth = false;
  render->add_flag("--scan", with_scan, "Scan the cell and draw the scan points");
  render->add_flag("--truth", with_truth,
                   "With the scan: colour points by ground truth (flash red, body blue, "
                   "background cyan, outliers magenta, mixed yellow)");
  render->add_flag("--json", common.json, "Print the image paths as JSON");

  auto* scan = app.add_subcommand(
      "scan", "Scan the scenario's cell with the virtual laser scanner (Embree): PLY + PCD");
  scan->add_option("scenario", scenario, "Scenario YAML")->required();
  scan->add_option("-o,--output", out, "Output folder (scan.ply, scan.pcd, scan.json, cell/)")
      ->required();
  scan->add_flag("--json", common.json, "Print points, time and rays/s as JSON");
  long long scan_seed = -1;
  scan->add_option("--seed", scan_seed,
                   "Override the scenario's seed (casting, placement, scan), as run and sweep do");

  auto* reg = app.add_subcommand(
      "register", "Register a scan (source) to a CAD model or cloud (target): the pose that maps "
                  "source points into the target frame; exit 1 when not confident");
  std::string source_path, target_path, method = "ours", viewpoint;
  bool remove_plane = false;
  reg->add_option("--source", source_path, "Scan: PLY/PCD cloud (or a mesh's vertices)")->required();
  reg->add_option("--target", target_path, "CAD model STL/OBJ/PLY (sampled) or a PLY/PCD cloud")
      ->required();
  reg->add_option("--method", method, "ours | sacia-ndt | sacia-ndt-icp | ndt-icp | iss-3dsc-icp | fpcs-icp")
      ->capture_default_str()
      ->check(CLI::IsMember({"ours", "sacia-ndt", "sacia-ndt-icp", "ndt-icp", "iss-3dsc-icp", "fpcs-icp"}));
  reg->add_flag("--remove-plane", remove_plane,
                "Remove the support plane (table) and keep the largest cluster above it (ours)");
  reg->add_option("--viewpoint", viewpoint,
                  "Sensor position \"x y z\" in the source frame, for normal orientation (ours)");
  reg->add_flag("--json", common.json, "Print T_target_source (16 numbers, row-major) and the verdict");

  auto* job = app.add_subcommand(
      "job", "A real cell's scan and the part's CAD (no ground truth) to the part's pose, its flash "
             "paths, their plans, a rehearsal on the twin (the scanned flash as material, ground "
             "in MuJoCo) and one robot program per path; or a refusal (exit 1, job.json says why) "
             "when the pose is not confident, a path is not feasible or the rehearsal misses the "
             "quality limits");
  ft::pipeline::JobInputs job_in;
  std::string job_scan_units = "auto", job_cad_units = "auto";
  job->add_option("--scan", job_in.scan, "Scan PLY/PCD, points in the scanner frame {M}")->required();
  job->add_option("--cad", job_in.cad, "CAD model of the part (STL/OBJ/PLY, its frame {C})")->required();
  job->add_option("--cell", job_in.cell,
                  "The cell: a scenario file (robot, cell.robot_base and cell.scanner_mount as "
                  "calibrated, tool, tool_rack, planning, perception.detection); its casting block is "
                  "not used")
      ->required();
  job->add_option("-o,--output", job_in.out_dir, "Output folder (job.json, paths.json, plans.json, plan/)")
      ->required();
  job->add_option("--scan-units", job_scan_units, "m, mm, or auto (a diagonal over 5 is mm)")
      ->check(CLI::IsMember({"auto", "m", "mm"}))->capture_default_str();
  job->add_option("--cad-units", job_cad_units, "m, mm, or auto")
      ->check(CLI::IsMember({"auto", "m", "mm"}))->capture_default_str();
  job->add_option("--threads", job_in.threads, "Threads of registration and detection")
      ->capture_default_str()->check(CLI::Range(1, 64));
  job->add_flag("--json", common.json, "Print job.json's content");

  auto* rep = app.add_subcommand(
      "replay", "Run a job's written robot programs on the twin's own part for a scenario's seed "
                "(its true casting, flash and placement: what `flashtwin scan` scanned with that "
                "seed): each program read back and interpolated as its controller runs it, ground "
                "in MuJoCo, scored against the truth into DIR/metrics.json; exit 1 when the part "
                "misses the scenario's quality: limits or a program would not run");
  std::string rep_job;
  long long rep_seed = -1;
  std::vector<std::string> rep_sets;
  rep->add_option("scenario", scenario, "Scenario YAML (the one the scan was made with)")->required();
  rep->add_option("--job", rep_job, "A `flashtwin job` output folder (job.json, plans.json, plan/)")
      ->required();
  rep->add_option("-o,--output", out, "Output folder (metrics.json, cell/)")->required();
  rep->add_option("--seed", rep_seed, "Override the scenario's seed (the scan's --seed)");
  rep->add_option("--set", rep_sets, "Override a scenario key: dotted.key=value; repeatable");
  rep->add_flag("--json", common.json, "Print metrics.json to stdout");

  auto* det = app.add_subcommand(
      "detect", "Find flashes in a registered scan: grinding paths on the CAD surface (exit 0 "
                "with an empty path when there is nothing to grind)");
  std::string scan_path, cad_path, pose_path;
  det->add_option("--scan", scan_path, "Scan PLY/PCD (points in the scanner frame {M})")->required();
  det->add_option("--cad", cad_path, "CAD model of the casting (STL/OBJ/PLY, metres, frame {C})")
      ->required();
  det->add_option("--pose", pose_path,
                  "JSON pose X_CM mapping scan points into {C}: 16 row-major numbers, or the "
                  "output of `register --json` (key T_target_source)")
      ->required();
  det->add_option("-o,--output", out, "Output folder (paths.json, paths.ply, scan_labelled.ply)")
      ->required();
  det->add_flag("--json", common.json, "Print a JSON summary");

  auto* run = app.add_subcommand(
      "run", "Run a scenario end to end (cell, scan, registration, flash detection, scoring) "
             "and write DIR/metrics.json; exit 1 when the job was refused or the part fails the "
             "scenario's quality: limits (defaults: removed >= 99 %, residual <= 0.2 mm, gouge <= "
             "0.1 mm, no protective stop)");
  long long run_seed = -1;
  int run_threads = 2;
  run->add_option("scenario", scenario, "Scenario YAML")->required();
  run->add_option("-o,--output", out, "Output folder")->required();
  run->add_option("--seed", run_seed, "Override the scenario's seed (casting, placement, scan)");
  run->add_option("--threads", run_threads,
                  "Threads for the scan and perception; results are identical for any count")
      ->check(CLI::Range(1, 256))
      ->capture_default_str();
  run->add_flag("--json", common.json, "Print metrics.json to stdout");
  std::vector<std::string> sets;
  bool run_video = false, no_report = false, run_check = false;
  std::string video_path;
  run->add_option("--set", sets, "Override a scenario key: dotted.key=value (YAML value); repeatable");
  run->add_flag("--video", run_video, "Also write DIR/run.mp4 of the execution (slower)");
  run->add_option("--video-path", video_path, "Write the video here instead (implies --video)");
  run->add_flag("--no-report", no_report, "Skip report.html, its renders and the per-path joint plots (plan/path_K/*.png)");
  run->add_flag("--check", run_check,
                "Regression mode: exit 0 when every bound of the scenario's expect: block holds "
                "(an expected refusal, exit_code: 1, included), else 1");

  auto* sweep = app.add_subcommand(
      "sweep", "Run a scenario for many seeds in parallel threads (algorithm tuning): one JSON "
               "line per run and a summary table (mean, min, max, failures per metric); exit 1 "
               "when any run failed");
  std::string seeds_text = "1-10", shard_text = "0/1";
  int sweep_threads = 2;
  sweep->add_option("scenario", scenario, "Scenario YAML")->required();
  sweep->add_option("-o,--output", out, "Output folder (runs.jsonl, summary.json, summary.md)")
      ->required();
  auto* seeds_opt = sweep->add_option("--seeds", seeds_text, "Seeds: 1-100, 5, or 1-10,20,30-32")
                        ->capture_default_str();
  bool sweep_check = false;
  sweep->add_flag("--check", sweep_check,
                  "Regression check over the scenario's expect_sweep: seeds (unless --seeds is "
                  "given): exit 1 unless its pass rate and percentile bounds hold");
  sweep->add_option("--set", sets, "Override a scenario key: dotted.key=value; repeatable");
  sweep->add_option("--shard", shard_text,
                    "Run only seeds i with i % N == k (k/N; e.g. $SLURM_ARRAY_TASK_ID/16)")
      ->capture_default_str();
  sweep->add_option("--threads", sweep_threads, "Runs at once")->capture_default_str();
  sweep->add_flag("--json", common.json, "Print summary.json to stdout");

  auto* plan = app.add_subcommand(
      "plan", "Plan grinding trajectories for detected paths (paths.json of `detect`) on a casting "
              "at a known pose in the robot base: trajectory.csv, plots, optional robot program; "
              "exit 1 when a path cannot be planned");
  std::string plan_paths, export_lang;
  double plan_feed = ft::planner::GrindParams{}.feed, plan_lead = 0, plan_tilt = 0;
  plan->add_option("--path", plan_paths, "Paths JSON ({C}, metres) as `flashtwin detect` writes it")
      ->required();
  plan->add_option("--cad", cad_path, "CAD model of the casting (STL/OBJ/PLY, metres, frame {C})")
      ->required();
  plan->add_option("--pose", pose_path,
                   "JSON pose X_BC of the casting in the robot base {B}: 16 row-major numbers "
                   "(or under key X_BC)")
      ->required();
  plan->add_option("-o,--output", out, "Output folder (path_k/ per path, plans.json)")->required();
  plan->add_option("--export", export_lang,
                   "Robot program per path: krl (KUKA .src), rapid (ABB .mod) or urscript (UR "
                   ".script), in the robot file's controller axis convention")
      ->check(CLI::IsMember({"krl", "rapid", "urscript"}));
  plan->add_option("--feed", plan_feed, "Cutting feed [m/s]")->capture_default_str()
      ->check(CLI::Range(1e-4, 1.0));
  plan->add_option("--lead", plan_lead, "Lead angle [deg]")->capture_default_str()
      ->check(CLI::Range(-45.0, 45.0));
  plan->add_option("--tilt", plan_tilt, "Tilt angle [deg]")->capture_default_str()
      ->check(CLI::Range(-45.0, 45.0));
  plan->add_flag("--json", common.json, "Print the per-path summary as JSON");
  add_robot(plan);

  try {
    app.parse(argc, argv);
  } catch (const CLI::CallForHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForAllHelp& e) {
    return app.exit(e);
  } catch (const CLI::CallForVersion& e) {
    return app.exit(e);
  } catch (const CLI::ParseError& e) {
    app.exit(e);
    return kExitBadInput;
  }

  auto logger = spdlog::stderr_color_mt("flashtwin");
  spdlog::set_default_logger(logger);
  spdlog::set_pattern("[%l] %v");
  spdlog::set_level(quiet ? spdlog::level::warn
                          : verbosity >= 2 ? spdlog::level::trace
                          : verbosity == 1 ? spdlog::level::debug
                                           : spdlog::level::info);
  try {
    if (*fk) return cmd_fk(common, q_text, deg, axes);
    if (*ik) return cmd_ik(common, pose_text, ik_tool, ik_all, ref_text, deg, axes);
    if (*ws) return cmd_workspace(common, samples, seed, ws_tool, out);
    if (*cell) return cmd_cell(common, scenario, out);
    if (*render)
      return cmd_render(common, scenario, out, cameras, width, height, with_scan, with_truth);
    if (*scan) return cmd_scan(common, scenario, out, scan_seed);
    if (*det) return cmd_detect(common, scan_path, cad_path, pose_path, out);
    if (*job) return cmd_job(common, job_in, job_scan_units, job_cad_units);
    if (*rep) return cmd_replay(common, scenario, rep_job, out, rep_seed, rep_sets);
    if (*run)
      return cmd_run(common, scenario, out, run_seed, sets, run_video, video_path, no_report,
                     run_check, run_threads);
    if (*sweep)
      return cmd_sweep(common, scenario, out, seeds_text, sets, shard_text, sweep_threads,
                       seeds_opt->count() > 0, sweep_check);
    if (*plan)
      return cmd_plan(common, plan_paths, cad_path, pose_path, out, export_lang, plan_feed,
                      plan_lead, plan_tilt);
    if (*reg) return cmd_register(common, source_path, target_path, method, remove_plane, viewpoint);
  } catch (const ft::InputError& e) {
    std::fprintf(stderr, "flashtwin: error: %s\n", e.what());
    return kExitBadInput;
  } catch (const std::exception& e) {
    std::fprintf(stderr, "flashtwin: failed: %s\n", e.what());
    return kExitFailed;
  }
  return kExitBadInput;
}
