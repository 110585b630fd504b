#include "flashtwin/pipeline/execution.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <map>
#include <optional>
#include <utility>

#include "flashtwin/core/format.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/perception/flash_detection.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/planner/transit.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/scan_cell.hpp"

namespace flashtwin::pipeline {

using json = nlohmann::ordered_json;

namespace {

// Binary little-endian PLY of points with one float scalar and an optional uchar flag.
std::string scalar_ply(const std::vector<Vec3>& pts, const std::vector<float>& value,
                       const char* value_name, const std::vector<std::uint8_t>& flag,
                       const char* flag_name) {
  std::string out = "ply\nformat binary_little_endian 1.0\ncomment flashtwin material map, "
                    "frame {C}, metres (ground truth)\nelement vertex " +
                    std::to_string(pts.size()) +
                    "\nproperty float x\nproperty float y\nproperty float z\nproperty float " +
                    value_name + "\n";
  if (flag_name) out += std::string("property uchar ") + flag_name + "\n";
  out += "end_header\n";
  const std::size_t row = 16 + (flag_name ? 1 : 0);
  const std::size_t head = out.size();
  out.resize(head + row * pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    const float f[4] = {static_cast<float>(pts[i].x()), static_cast<float>(pts[i].y()),
                        static_cast<float>(pts[i].z()), value[i]};
    std::memcpy(out.data() + head + i * row, f, 16);  // x86-64: little-endian
    if (flag_name) out[head + i * row + 16] = static_cast<char>(flag[i]);
  }
  return out;
}

}  // namespace

sim::Casting casting_with_residual(const sim::Casting& casting, const TriangleMesh& remaining_C,
                                   double volume) {
  sim::Casting now;
  now.family = casting.family;
  now.description = casting.description;
  now.nominal = casting.nominal;
  now.parting_height = casting.parting_height;
  now.size = casting.size;
  if (!remaining_C.triangles.empty()) {
    sim::Fin fin;
    fin.kind = "residual";
    fin.mesh = remaining_C;
    fin.volume = volume;
    now.fins.push_back(std::move(fin));
  }
  return now;
}


void write_material_maps(const std::string& dir, const sim::MaterialGrid& grid) {
  const MeshBvh& cad = grid.nominal();
  const sim::RemainingFlash rem = sim::split_remaining_flash(grid);
  std::vector<Vec3> flash = rem.attached;
  flash.insert(flash.end(), rem.loose.begin(), rem.loose.end());
  std::vector<float> height(flash.size());
  std::vector<std::uint8_t> loose(flash.size(), 0);
  for (std::size_t i = 0; i < flash.size(); ++i) {
    height[i] = static_cast<float>(cad.closest(flash[i]).distance * 1e3);
    loose[i] = i >= rem.attached.size();
  }
  write_text_file((std::filesystem::path(dir) / "residual_flash.ply").string(),
                  scalar_ply(flash, height, "height_mm", loose, "loose"));
  const std::vector<Vec3> gouge = sim::voxel_points(grid, sim::VoxelLabel::kGouge);
  std::vector<float> depth(gouge.size());
  for (std::size_t i = 0; i < gouge.size(); ++i)
    depth[i] = static_cast<float>(cad.closest(gouge[i]).distance * 1e3);
  write_text_file((std::filesystem::path(dir) / "gouges.ply").string(),
                  scalar_ply(gouge, depth, "depth_mm", {}, nullptr));
}

Motion motion_of(const PlannedPath& plan) {
  const planner::GrindResult& g = plan.second;
  Motion m;
  m.path = plan.first;
  m.trajectory.t = g.trajectory.t;
  m.trajectory.q = g.trajectory.q;
  m.trajectory.dq = g.trajectory.dq;
  m.tcp_B = g.tcp_B;
  m.tool_radius = g.tool_radius;
  // Each run of approach segments starts at rest in free air (the first at the motion's start,
  // later ones where the plan left the part before its finishing pass and on the way through
  // it, GrindParams::retare_before_finish): the controller tares there.
  for (std::size_t i = 0; i < g.segments.size(); ++i)
    if (g.segments[i].kind == planner::SampleKind::kApproach &&
        (i == 0 || g.segments[i - 1].kind != planner::SampleKind::kApproach))
      m.trajectory.tare_t.push_back(g.trajectory.t[g.segments[i].first_step]);
  return m;
}

namespace {

// A transit's motion: its trajectory and the tool poses it passes.
Motion transit_motion(const planner::TransitResult& tr, std::size_t path) {
  Motion m;
  m.path = path;
  m.transit = true;
  m.trajectory.t = tr.trajectory.t;
  m.trajectory.q = tr.trajectory.q;
  m.trajectory.dq = tr.trajectory.dq;
  m.tcp_B = tr.tcp_B;
  return m;
}

}  // namespace

double duration_of(const Motion& m) {
  return m.trajectory.t.empty() ? 0.0 : m.trajectory.t.back() - m.trajectory.t.front();
}

PlanningWorld::PlanningWorld(const Scenario& sc, const CellSetup& setup, const MeshBvh& cad_C,
                             const Pose& X_WC_plan, double burr_radius, const std::vector<Vec3>& flash_C,
                             bool burr_checks_body) {
  sim::CellSpec spec = setup.spec;
  if (spec.fixtures.empty()) spec.fixtures = sim::fixture_blocks(spec, setup.casting.nominal);
  model_ = sim::load_mjcf_string(sim::cell_mjcf(sc.robot, spec), "planning_world.xml");
  data_ = sim::make_data(model_.get());
  const sim::BurrHolder holder = sim::holder_for(sc.robot.tool, burr_radius);
  cell_ = std::make_unique<sim::CellCollision>(*model_, cad_C, X_WC_plan, nullptr, holder.shank_radius,
                                               holder.collet_radius);
  cell_->set_burr_checks_body(burr_checks_body);
  if (!flash_C.empty()) {
    std::vector<Vec3> flash_W;
    flash_W.reserve(flash_C.size());
    for (const Vec3& p : flash_C) flash_W.push_back(X_WC_plan * p);
    cell_->set_known_flash(flash_W);
  }
  dynamics_data_ = sim::make_data(model_.get());
  tau_.resize(static_cast<std::size_t>(model_->nv));
  for (int i = 0; i < kNumJoints; ++i) {
    const int j = sim::require_id(model_.get(), mjOBJ_JOINT, "joint" + std::to_string(i + 1));
    qadr_[i] = model_->jnt_qposadr[j];
    dadr_[i] = model_->jnt_dofadr[j];
  }
}

planner::TorqueFn PlanningWorld::torque() {
  return [this](const Vector6& q, const Vector6& dq, const Vector6& ddq) {
    mjData* d = dynamics_data_.get();
    for (int i = 0; i < kNumJoints; ++i) {
      d->qpos[qadr_[i]] = q[i];
      d->qvel[dadr_[i]] = dq[i];
      d->qacc[dadr_[i]] = ddq[i];
    }
    sim::rigid_inverse_dynamics(model_.get(), d, tau_.data());
    Vector6 out;
    for (int i = 0; i < kNumJoints; ++i) out[i] = tau_[static_cast<std::size_t>(dadr_[i])];
    return out;
  };
}

planner::ClearanceFn PlanningWorld::clearance(double reach) {
  return [this, reach](const Vector6& q) {
    for (int i = 0; i < kNumJoints; ++i) data_->qpos[qadr_[i]] = q[i];
    mj_kinematics(model_.get(), data_.get());
    const sim::CollisionHit hit = cell_->check(*data_, reach);
    return planner::Clearance{hit.clearance, hit.robot_geom + " – " + hit.obstacle};
  };
}

JobMotions plan_job_motions(const Scenario& sc, const ScenarioScan& ss, const Pose& X_WC_plan,
                            const MeshBvh& cad_C, const std::vector<PlannedPath>& plans,
                            const std::vector<Vec3>& flash_C) {
  JobMotions out;
  out.min_clearance = sim::CellCollision::kReach;
  if (plans.empty()) return out;
  // The planner's world: the cell's obstacles, the CAD where the plan put the casting and the
  // flash perception found there; one per burr, each in its own holder (the rack's in the slim
  // one). A transit carries the burr in the spindle: the tool is changed at home, so a path
  // ground with another burr than the one before it is reached over home (the way there with
  // the old burr, the way on with the new one). Checked with the mounted burr's holder at the
  // start of a rack path in a bolt hole, the transit's end put the 25 mm collet nut 0.7 mm into
  // the wall the slim holder clears, and the path was left alone (housing 7341).
  std::map<double, std::unique_ptr<PlanningWorld>> worlds;
  std::map<double, planner::ClearanceFn> clearances;
  const auto clearance_for = [&](double burr_radius) -> const planner::ClearanceFn& {
    auto& fn = clearances[burr_radius];
    if (!fn) {
      auto& w = worlds[burr_radius];
      w = std::make_unique<PlanningWorld>(sc, ss.setup, cad_C, X_WC_plan, burr_radius, flash_C, true);
      fn = w->clearance();
    }
    return fn;
  };
  const double mounted = sc.robot.tool.radius;
  const auto burr_of = [&](const PlannedPath& plan) {
    return plan.second.tool_radius > 0 ? plan.second.tool_radius : mounted;
  };
  planner::TransitParams tp;
  tp.clearance = sc.execution.transit_clearance;
  tp.speed_ratio = sc.execution.transit_speed;
  tp.up_B = ss.setup.spec.X_WB.linear().transpose() * Vec3::UnitZ();
  tp.via = {sc.robot.home};
  struct Move {
    Motion motion;
    bool lifted = false;
    double clearance = 0;  // [m]
  };
  // The transit from `from` to `to` with the burr of radius `burr`, appended to `into`; why not.
  const auto add_transit = [&](const Vector6& from, const Vector6& to, std::size_t path, double burr,
                               std::vector<Move>& into) {
    const planner::TransitResult tr = planner::plan_transit(sc.robot, from, to, clearance_for(burr), tp);
    if (!tr.ok) return std::optional<std::string>(tr.message);
    spdlog::debug("transit to path {}: {}, {:.1f} s, clearance {:.1f} mm, {} checks", path,
                  tr.message, tr.duration(), tr.min_clearance * 1e3, tr.checks);
    Move mv{transit_motion(tr, path), tr.lifted, tr.min_clearance};
    mv.motion.tool_radius = burr == mounted ? 0.0 : burr;
    into.push_back(std::move(mv));
    return std::optional<std::string>();
  };
  // The transits kept in the job.
  const auto keep = [&](std::vector<Move>& moves) {
    for (Move& mv : moves) {
      ++out.transits;
      out.lifted += mv.lifted;
      out.transit_time += duration_of(mv.motion);
      out.min_clearance = std::min(out.min_clearance, mv.clearance);
      out.motions.push_back(std::move(mv.motion));
    }
  };
  Vector6 q_at = sc.robot.home;
  double burr_at = mounted;  // the burr in the spindle
  std::size_t last_path = plans.front().first;
  for (const PlannedPath& plan : plans) {
    Motion grind = motion_of(plan);
    const double burr = burr_of(plan);
    // Home first to change the burr (unless the arm is there), then on to the path.
    std::vector<Move> moves;
    std::optional<std::string> why;
    const bool change = burr != burr_at && (q_at - sc.robot.home).norm() > 1e-9;
    if (change) why = add_transit(q_at, sc.robot.home, last_path, burr_at, moves);
    if (!why) why = add_transit(change ? sc.robot.home : q_at, grind.trajectory.q.front(), plan.first, burr, moves);
    if (why) {
      spdlog::warn("path {}: left alone: {}", plan.first, *why);
      out.refused_paths.push_back(plan.first);
      if (out.first_refusal.empty()) out.first_refusal = "path " + std::to_string(plan.first) + ": " + *why;
      continue;
    }
    keep(moves);
    q_at = grind.trajectory.q.back();
    burr_at = burr;
    last_path = plan.first;
    out.motions.push_back(std::move(grind));
  }
  if (!out.motions.empty()) {
    std::vector<Move> moves;
    if (const auto why = add_transit(q_at, sc.robot.home, last_path, burr_at, moves)) {
      spdlog::warn("the way home from path {}: {}", last_path, *why);
      out.home_refused = true;
      if (out.first_refusal.empty()) out.first_refusal = "the way home: " + *why;
    }
    keep(moves);
  }
  return out;
}

Execution::Execution(const Scenario& sc, const sim::Casting& casting)
    : sc_(sc),
      grid_(std::make_shared<sim::MaterialGrid>(sim::make_material_grid(casting, sc.execution.material))) {
  summary_.ran = true;
  summary_.target_force = sc.execution.exec.force_control.target_force;
}

void Execution::run(const ScenarioScan& ss, const std::vector<PlannedPath>& plans,
                    const FrameHook& frame_hook, std::size_t path_offset) {
  std::vector<Motion> motions;
  motions.reserve(plans.size());
  for (const auto& p : plans) motions.push_back(motion_of(p));
  run_motions(ss, motions, frame_hook, path_offset);
}

void Execution::run_motions(const ScenarioScan& ss, const std::vector<Motion>& motions,
                            const FrameHook& frame_hook, std::size_t path_offset) {
  if (summary_.failed) return;
  const sim::MjModelPtr model = sim::load_mjcf_file(ss.files.mjcf);
  const sim::ToolParams tool = sim::tool_params_from(sc_.robot.tool);
  sim::ExecParams ep = sc_.execution.exec;
  ep.analyze_residual = false;  // once, in finish()
  ep.tcp_offset_T = sc_.faults.tcp_offset_T;    // drills: the world, not what the controller
  ep.sensor_step_E = sc_.faults.sensor_bias_E;  // is told
  sim::MaterialGrid& grid = *grid_;
  const int setup_index = static_cast<int>(summary_.X_CB.size());
  summary_.X_CB.push_back(ss.setup.spec.X_WC.inverse() * ss.setup.spec.X_WB);
  // The twin's collision measurement: the casting where it truly stands, its standing flash;
  // one per burr (a rack burr stands on its own, thinner shank in the slim holder).
  // In a transit the burr touching the casting's body is a collision too (it is no cut).
  std::map<std::pair<double, bool>, std::unique_ptr<sim::CellCollision>> cells;
  const auto cell_for = [&](double burr_radius, bool transit) -> const sim::CellCollision* {
    auto& c = cells[{burr_radius, transit}];
    if (!c) {
      const sim::BurrHolder holder = sim::holder_for(sc_.robot.tool, burr_radius);
      c = std::make_unique<sim::CellCollision>(*model, grid.nominal(), ss.setup.spec.X_WC, &grid,
                                               holder.shank_radius, holder.collet_radius);
      c->set_burr_checks_body(transit);
    }
    return c.get();
  };
  const Motion* previous = nullptr;
  sim::ExecutionResult last;
  for (const Motion& motion : motions) {
    const std::size_t k = motion.path + path_offset;
    // Joined to the previous motion (a job's transit and path): on from where the arm was left.
    const bool joined = previous && last.status != sim::ExecStatus::kForceLimit &&
                        (previous->trajectory.q.back() - motion.trajectory.q.front()).norm() < 1e-9;
    ep.start_qpos = joined ? last.q_end : std::vector<double>{};
    ep.start_qvel = joined ? last.qvel_end : std::vector<double>{};
    // The executor's trajectory: the tool poses it should pass in the cell's world {W}.
    sim::JointTrajectory tr = motion.trajectory;
    tr.planned_tcp_W.clear();
    for (const Pose& X_BT : motion.tcp_B) tr.planned_tcp_W.push_back(ss.setup.spec.X_WB * X_BT);
    const double t0 = sim_time_;
    if (frame_hook) {
      ep.on_step = [&, t0, k](const mjModel* mm, mjData* d, double t) {
        frame_hook(mm, d, t0 + t, grid, k);
      };
    }
    // The burr this path was planned for (a rack burr after a tool change; same length).
    sim::ToolParams path_tool = tool;
    if (motion.tool_radius > 0) path_tool.radius = motion.tool_radius;
    ep.collisions = cell_for(path_tool.radius, motion.transit);
    path_tool.radius += sc_.faults.tool_radius_error;  // a drill: not the burr planned for
    // The flange sensor's noise, offset and drift: one stream per motion of this run.
    ep.sensor_seed = sc_.seed * 0x9E3779B97F4A7C15ull + 0x5E15E0ull + 131 * static_cast<std::uint64_t>(k) +
                     static_cast<std::uint64_t>(setup_index) + (motion.transit ? 0x7A5u : 0u);
    last = sim::execute_trajectory(*model, tr, &grid, path_tool, sc_.execution.force, ep);
    const sim::ExecutionResult& r = last;
    previous = &motion;
    cycle_time_ += duration_of(motion);
    if (r.collision_steps > 0) {
      const Vec3 deepest_C = ss.setup.spec.X_WC.inverse() * r.deepest_collision.point_W;
      if (collision_steps_ == 0)
        first_collision_ = strf("%s – %s at %.2f s (%s %zu)", r.first_collision.robot_geom.c_str(),
                                r.first_collision.obstacle.c_str(), sim_time_ + r.first_collision_time,
                                motion.transit ? "transit to path" : "path", k);
      spdlog::warn("execution: {} {}: {} step(s) with a collision; first {} – {} at {:.2f} s; "
                   "deepest {} – {}, {:.2f} mm at {:.2f} s at ({:.1f}, {:.1f}, {:.1f}) mm in {{C}}",
                   motion.transit ? "transit to path" : "path", k, r.collision_steps,
                   r.first_collision.robot_geom, r.first_collision.obstacle, r.first_collision_time,
                   r.deepest_collision.robot_geom, r.deepest_collision.obstacle,
                   r.collision_max_depth * 1e3, r.deepest_collision_time, deepest_C.x() * 1e3,
                   deepest_C.y() * 1e3, deepest_C.z() * 1e3);
    }
    collision_steps_ += r.collision_steps;
    collision_depth_ = std::max(collision_depth_, r.collision_max_depth);
    min_clearance_ = std::min(min_clearance_, r.min_clearance);
    if (motion.transit) {
      ++transits_;
      transit_track_max_ = std::max(transit_track_max_, r.tracking_max);
    } else {
      ++executed_;
    }
    spdlog::debug("execution: path {}: {} ({}), {:.1f} s simulated in {:.2f} s, tracking rmse "
                  "{:.3f} mm, flash removed {:.2f} mm3, gouge {:.3f} mm3, {} removal steps in {} steps; "
                  "deepest {:.3f} mm at {:.2f} s (tracking error {:.3f} mm)",
                  k, sim::to_string(r.status), r.message, r.sim_time, r.wall_time,
                  r.tracking_rmse * 1e3, r.removed_flash_volume * 1e9,
                  r.removed_body_volume * 1e9, r.removal_steps, r.steps, r.max_penetration * 1e3,
                  r.max_penetration_time, r.max_penetration_tracking * 1e3);
    const auto& L = r.log;
    auto& out = summary_;
    for (std::size_t i = 0; i < L.t.size(); ++i) {
      out.t.push_back(t0 + L.t[i]);
      out.normal_force.push_back(L.normal_force[i]);
      out.tangential_force.push_back(L.tangential_force[i]);
      out.tracking_error.push_back(
          i < L.planned_tcp_W.size() ? (L.tcp_W[i] - L.planned_tcp_W[i]).norm() : 0.0);
      out.sensor_force.push_back(i < L.sensor_force_W.size() ? L.sensor_force_W[i].norm() : 0.0);
      out.q.push_back(L.q[i]);
      out.path.push_back(static_cast<int>(k));
      out.setup.push_back(setup_index);
    }
    sim_time_ += r.sim_time;
    wall_ += r.wall_time;
    steps_ += r.steps;
    if (!motion.transit) {  // the grinding motions' tracking (transits': transit_tracking_max)
      track_sq_ += r.tracking_rmse * r.tracking_rmse * static_cast<double>(r.tracking_samples);
      track_n_ += r.tracking_samples;
      track_max_ = std::max(track_max_, r.tracking_max);
      track_rot_max_ = std::max(track_rot_max_, r.tracking_max_rotation);
    }
    violations_ += r.joint_limit_violations;
    limit_excess_ = std::max(limit_excess_, r.max_limit_excess);
    clamped_ += r.clamped_steps;
    if (r.contact_time > 0) {
      contact_ += r.contact_time;
      f_sum_ += r.force_mean * r.contact_time;
      f_sq_ += r.force_rmse * r.force_rmse * r.contact_time;
    }
    f_max_ = std::max(f_max_, r.force_max);
    out.untracked_gouge_max = std::max(out.untracked_gouge_max, r.untracked_penetration_max);
    if (r.untracked_penetration_max > sc_.quality.max_gouge_mm * 1e-3)
      spdlog::warn("execution: path {}: the cutter went {:.2f} mm into steel the voxels do not "
                   "track (away from the flash) at {:.2f} s",
                   k, r.untracked_penetration_max * 1e3, r.untracked_penetration_time);
    if (r.load_estimate_rmse > 0) {
      load_est_sq_ += r.load_estimate_rmse * r.load_estimate_rmse * r.contact_time;
      load_est_n_ += r.contact_time;
    }
    if (r.status != sim::ExecStatus::kOk && status_ == "ok") status_ = sim::to_string(r.status);
    if (r.status == sim::ExecStatus::kForceLimit) {
      ++force_stops_;
      spdlog::warn("execution: path {}: {}", k, r.message);
    }
    if (r.status == sim::ExecStatus::kUnstable) {
      out.failed = true;
      out.failure = "execution of path " + std::to_string(k) + " stopped: " + r.message;
      break;
    }
  }
}

ExecutionSummary Execution::finish(json& m) {
  ExecutionSummary out = summary_;
  const sim::MaterialGrid& grid = *grid_;
  out.residual = sim::analyze_residual(grid);
  out.remaining_flash_C = sim::remaining_flash_mesh(grid);
  out.grid = grid_;

  m["execution.paths_executed"] = executed_;
  m["execution.paths_stopped_force_limit"] = force_stops_;
  m["execution.status"] = status_;
  m["execution.tracking_rmse_mm"] = track_n_ ? std::sqrt(track_sq_ / track_n_) * 1e3 : 0.0;
  m["execution.tracking_max_mm"] = track_max_ * 1e3;
  m["execution.tracking_max_rotation_deg"] = track_rot_max_ * 180 / M_PI;
  m["execution.joint_limit_violations"] = violations_;
  m["execution.max_limit_excess_rad"] = limit_excess_;
  m["execution.clamped_steps"] = clamped_;
  m["execution.force_control"] = sc_.execution.exec.force_control.enabled;
  m["execution.compensation"] = sim::to_string(sc_.execution.exec.compensation_source);
  m["execution.transits"] = transits_;
  m["execution.transit_tracking_max_mm"] = transit_track_max_ * 1e3;
  m["execution.collisions"] = collision_steps_;
  m["execution.collision_max_depth_mm"] = collision_depth_ * 1e3;
  m["execution.first_collision"] = first_collision_;
  m["execution.min_clearance_mm"] = min_clearance_ * 1e3;
  // Program time of what ran: with transits the whole job, else the grinding motions alone.
  if (transits_ > 0) m["cycle.time_s"] = cycle_time_;
  m["execution.load_estimate_rmse_n"] = load_est_n_ ? std::sqrt(load_est_sq_ / load_est_n_) : 0.0;
  const auto& res = out.residual;
  m["removal.flash_volume_mm3"] = res.flash_volume_initial * 1e9;
  m["removal.flash_remaining_mm3"] = res.flash_volume_remaining * 1e9;
  m["removal.flash_removed_fraction"] = res.flash_removed_fraction;
  m["removal.residual_flash_max_mm"] = res.residual_flash_max * 1e3;
  m["removal.loose_flash_mm3"] = res.loose_flash_volume * 1e9;
  // The voxels' gouge near the fins, or the exact CAD check's where they track no steel.
  m["removal.gouge_max_mm"] = std::max(res.gouge_max_depth, out.untracked_gouge_max) * 1e3;
  m["removal.gouge_voxel_max_mm"] = res.gouge_max_depth * 1e3;
  m["removal.gouge_untracked_max_mm"] = out.untracked_gouge_max * 1e3;
  m["removal.gouge_volume_mm3"] = res.gouge_volume * 1e9;
  m["removal.voxel_size_mm"] = grid.voxel_size() * 1e3;
  m["force.target_n"] = out.target_force;
  m["force.contact_time_s"] = contact_;
  m["force.mean_n"] = contact_ > 0 ? f_sum_ / contact_ : 0.0;
  m["force.rmse_n"] = contact_ > 0 ? std::sqrt(f_sq_ / contact_) : 0.0;
  m["force.rmse_ratio"] = contact_ > 0 ? std::sqrt(f_sq_ / contact_) / out.target_force : 0.0;
  m["force.max_n"] = f_max_;
  m["sim.time_s"] = sim_time_;
  m["sim.steps"] = steps_;
  m["sim.realtime_factor"] = finite_or_null(wall_ > 0 ? sim_time_ / wall_ : NAN);
  m["sim.step_us"] = steps_ ? wall_ / static_cast<double>(steps_) * 1e6 : 0.0;
  return out;
}

ExecutionSummary execute_plans(const Scenario& sc, const ScenarioScan& ss,
                               const std::vector<PlannedPath>& plans, json& m,
                               const FrameHook& frame_hook) {
  Execution e(sc, ss.setup.casting);
  e.run(ss, plans, frame_hook);
  return e.finish(m);
}

void rescan_after(const Scenario& sc, const ScenarioScan& ss, const Pose& X_CM_est,
                  ExecutionSummary& summary, json& m) {
  // The part as it is now: the nominal body and the remaining flash (voxel surface).
  const sim::Casting after = casting_with_residual(ss.setup.casting, summary.remaining_flash_C,
                                                   summary.residual.flash_volume_remaining);
  sim::ScanParams params = ss.params;  // the same views as the first scan
  params.seed = sc.seed + 1000003;  // a new scan, not a replay of the first one's noise
  params.threads = std::max(1, params.threads);
  const sim::CellScan scan = sim::scan_cell(ss.files.mjcf, after, params, ss.scan.X_WM_nominal,
                                            ss.scan.X_WM_true);
  const MeshBvh& cad = summary.grid->nominal();  // the CAD's closest-point tree, built once
  const auto det = detect_off_fixture(sc, ss.setup, scan.result.cloud_M, cad, X_CM_est);
  std::size_t flash_pts = 0;
  double worst = 0;
  for (std::size_t i = 0; i < det.labels.size(); ++i) {
    if (det.labels[i] != 1) continue;
    ++flash_pts;
    const Vec3 p_C = X_CM_est * scan.result.cloud_M.points[i].cast<double>();
    summary.rescan_flash_C.push_back(p_C);
    worst = std::max(worst, cad.closest(p_C).distance);
  }
  m["rescan.points"] = scan.result.cloud_M.size();
  m["rescan.flash_points"] = flash_pts;
  m["rescan.flash_regions"] = det.regions.size();
  m["rescan.residual_max_mm"] = worst * 1e3;
  m["rescan.paths"] = det.paths.size();
}

}  // namespace flashtwin::pipeline
