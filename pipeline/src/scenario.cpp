#include "flashtwin/pipeline/scenario.hpp"

#include "flashtwin/pipeline/sweep.hpp"

#include <cmath>
#include <optional>

#include "flashtwin/core/config.hpp"
#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/ik.hpp"
#include "flashtwin/sim/scan_cell.hpp"

namespace flashtwin::pipeline {

namespace {

void read_flash(const ConfigNode& f, sim::FlashParams& fp) {
  fp.parting_line = f.get_bool("parting_line", fp.parting_line);
  fp.holes = f.get_bool("holes", fp.holes);
  fp.parting_height = f.get_double("parting_height", 0.0, 2.0, fp.parting_height);
  if (f.has("thickness")) {
    const auto v = f.at("thickness").as_doubles(2);
    fp.thickness_min = v[0];
    fp.thickness_max = v[1];
    if (!(v[0] > 0 && v[0] <= v[1] && v[1] <= 0.005))
      f.at("thickness").fail("expected [min, max] with 0 < min <= max <= 0.005 m");
  }
  if (f.has("height")) {
    const auto v = f.at("height").as_doubles(2);
    fp.height_min = v[0];
    fp.height_max = v[1];
    if (!(v[0] > 0 && v[0] <= v[1] && v[1] <= 0.05))
      f.at("height").fail("expected [min, max] with 0 < min <= max <= 0.05 m");
  }
  fp.hole_height_max = f.get_double("hole_height_max", 1e-4, 0.02, fp.hole_height_max);
  fp.wave_amplitude = f.get_double("wave_amplitude", 0.0, 0.9, fp.wave_amplitude);
  fp.wave_length = f.get_double("wave_length", 0.001, 0.5, fp.wave_length);
  fp.gaps = static_cast<int>(f.get_int("gaps", 0, 50, fp.gaps));
  fp.gap_length_max = f.get_double("gap_length_max", 0.001, 0.5, fp.gap_length_max);
  fp.root_spacing = f.get_double("root_spacing", 1e-4, 0.005, fp.root_spacing);
}

Pose view_pose(const ConfigNode& v) {
  return pose_from_xyz_rpy(v.get_vec3("xyz", Vec3::Zero()), v.get_vec3("rpy", Vec3::Zero()));
}

// expect_sweep: {seeds: "201-208", pass_rate: 0.75, path.coverage: {p50: [0.9, null]}, ...}
void read_expect_sweep(const ConfigNode& ex, SweepExpectation& out) {
  if (!ex.is_map()) ex.fail("expected {seeds: ..., pass_rate: ..., METRIC: {p50: [min, max]}}");
  const ConfigNode seeds = ex.at("seeds");
  try {
    out.seeds = parse_seeds(seeds.as_string());
  } catch (const ArgumentError& e) {
    seeds.fail(std::string("expected seeds like 201-208 or 1,5,9 (") + e.what() + ")");
  }
  out.min_pass_rate = ex.get_double("pass_rate", 0, 1, 0);
  for (const auto& key : ex.keys()) {
    if (key == "seeds" || key == "pass_rate") continue;
    const ConfigNode m = ex.at(key);
    if (!m.is_map()) m.fail("expected {mean|min|p10|p50|p90|max: [min, max]}, got " + m.describe());
    for (const auto& stat : m.keys()) {
      const ConfigNode v = m.at(stat);
      if (stat != "mean" && stat != "min" && stat != "p10" && stat != "p50" && stat != "p90" &&
          stat != "max")
        v.fail("expected a statistic mean, min, p10, p50, p90 or max, got '" + stat + "'");
      if (!v.is_sequence() || v.size() != 2) v.fail("expected [min, max] (null for an open end)");
      SweepBound b;
      b.key = key;
      b.statistic = stat;
      if (!v[0].is_null()) b.lo = v[0].as_double();
      if (!v[1].is_null()) b.hi = v[1].as_double();
      if (!(b.lo <= b.hi)) v.fail("expected min <= max");
      out.bounds.push_back(b);
    }
  }
}

void read_scanner(const ConfigNode& s, Scenario& sc) {
  sim::ScanParams& sp = sc.scan;
  sp.seed = static_cast<std::uint64_t>(s.get_int("seed", 0, (1LL << 62), static_cast<long long>(sp.seed)));
  sp.threads = static_cast<int>(s.get_int("threads", 1, 64, sp.threads));
  if (s.has("noise")) {
    const ConfigNode n = s.at("noise");
    sim::NoiseParams& np = sp.noise;
    np.sigma = n.get_double("sigma", 0.0, 0.01, np.sigma);
    np.incidence_gain = n.get_double("incidence_gain", 0.0, 100.0, np.incidence_gain);
    np.max_incidence = n.get_double("max_incidence_deg", 1.0, 89.9, np.max_incidence * 180 / M_PI) * M_PI / 180;
    np.mixed_jump = n.get_double("mixed_jump", 1e-5, 1.0, np.mixed_jump);
    np.mixed_probability = n.get_double("mixed_probability", 0.0, 1.0, np.mixed_probability);
    np.outlier_rate = n.get_double("outlier_rate", 0.0, 0.5, np.outlier_rate);
    np.outlier_range = n.get_double("outlier_range", 0.0, 1.0, np.outlier_range);
  }
  if (s.has("calibration_error")) {
    const ConfigNode c = s.at("calibration_error");
    sc.calibration_translation = c.get_double("translation", 0.0, 0.1, 0.0);
    sc.calibration_rotation = c.get_double("rotation", 0.0, 0.2, 0.0);
  }
  if (s.has("auto_views")) {
    const ConfigNode a = s.at("auto_views");
    auto& vp = sc.view_plan;
    vp.max_views = static_cast<int>(a.get_int("max_views", 1, 32, vp.max_views));
    vp.min_gain = a.get_double("min_gain", 0.0, 1.0, vp.min_gain);
    vp.cell = a.get_double("cell", 1e-4, 0.05, vp.cell);
    vp.azimuths = static_cast<int>(a.get_int("azimuths", 1, 72, vp.azimuths));
    vp.standoff = a.get_double("standoff", 0.05, 2.0, vp.standoff);
  }
  if (s.has("views") && s.at("views").is_scalar()) {
    const ConfigNode vs = s.at("views");
    const std::string mode = vs.as_string();
    if (mode == "auto") sc.auto_views = true;
    else if (mode == "default") sc.auto_views = false;  // the five fixed sweeps
    else vs.fail("expected auto, default or a list of views, got '" + mode + "'");
  } else if (s.has("views")) {
    const ConfigNode vs = s.at("views");
    if (!vs.is_sequence() || vs.size() == 0) vs.fail("expected auto, default or a non-empty list of views");
    sc.auto_views = false;
    sp.views.clear();
    for (std::size_t i = 0; i < vs.size(); ++i) {
      const ConfigNode v = vs[i];
      if (!v.is_map()) v.fail("expected a view {kind: line|area, ...}, got " + v.describe());
      sim::ScanView view;
      const std::string kind = v.get_string("kind", "line");
      view.X_MS = view_pose(v);
      if (kind == "line") {
        view.kind = sim::SensorKind::kLineProfiler;
        auto& l = view.line;
        l.points_per_profile = static_cast<int>(v.get_int("points_per_profile", 1, 100000, l.points_per_profile));
        l.fov = v.get_double("fov", 1e-3, 3.0, l.fov);
        l.standoff = v.get_double("standoff", 0.01, 10.0, l.standoff);
        if (v.has("range")) {
          const auto r = v.at("range").as_doubles(2);
          if (!(r[0] > 0 && r[0] < r[1])) v.at("range").fail("expected [min, max] with 0 < min < max");
          l.range_min = r[0];
          l.range_max = r[1];
        }
        l.profile_spacing = v.get_double("profile_spacing", 1e-6, 0.1, l.profile_spacing);
        l.sweep_length = v.get_double("sweep_length", 1e-4, 10.0, l.sweep_length);
        l.baseline = v.get_double("baseline", 0.0, 2.0, l.baseline);
      } else if (kind == "area") {
        view.kind = sim::SensorKind::kAreaSensor;
        auto& a = view.area;
        a.width = static_cast<int>(v.get_int("width", 1, 20000, a.width));
        a.height = static_cast<int>(v.get_int("height", 1, 20000, a.height));
        if (v.has("fov")) {
          const auto f = v.at("fov").as_doubles(2);
          if (!(f[0] > 0 && f[0] < 3 && f[1] > 0 && f[1] < 3)) v.at("fov").fail("expected two angles in (0, 3) rad");
          a.fov_x = f[0];
          a.fov_y = f[1];
        }
        a.standoff = v.get_double("standoff", 0.01, 10.0, a.standoff);
        if (v.has("range")) {
          const auto r = v.at("range").as_doubles(2);
          if (!(r[0] > 0 && r[0] < r[1])) v.at("range").fail("expected [min, max] with 0 < min < max");
          a.range_min = r[0];
          a.range_max = r[1];
        }
        a.baseline = v.get_double("baseline", 0.0, 2.0, a.baseline);
      } else {
        v.at("kind").fail("expected line or area, got '" + kind + "'");
      }
      sp.views.push_back(view);
    }
  }
}

}  // namespace

Scenario load_scenario(const std::string& path) { return load_scenario(path, {}); }

void set_seed(Scenario& sc, std::uint64_t seed) {
  sc.seed = seed;
  sc.scan.seed = seed;
  sc.casting.seed = seed;
}

namespace {

YAML::Node apply_overrides(const std::string& path, const std::vector<std::string>& overrides) {
  YAML::Node doc;
  try {
    doc = YAML::LoadFile(path);
  } catch (const YAML::BadFile&) {
    throw IoError(path + ": cannot read the scenario file");
  } catch (const YAML::Exception& e) {
    throw ConfigError(path + ": malformed YAML: " + e.what());
  }
  for (const auto& o : overrides) {
    const auto eq = o.find('=');
    if (eq == std::string::npos || eq == 0)
      throw ConfigError("--set " + o + ": expected dotted.key=value");
    const std::string key = o.substr(0, eq);
    YAML::Node value;
    try {
      value = YAML::Load(o.substr(eq + 1));
    } catch (const YAML::Exception& e) {
      throw ConfigError("--set " + o + ": the value is not valid YAML: " + e.what());
    }
    std::vector<std::string> parts;
    std::size_t start = 0;
    while (true) {
      const auto dot = key.find('.', start);
      parts.push_back(key.substr(start, dot - start));
      if (dot == std::string::npos) break;
      start = dot + 1;
    }
    // Walk with fresh handles (YAML::Node assignment would rebind, not copy).
    const auto index_of = [&](const std::string& part, std::size_t size) {
      if (part.empty() || part.find_first_not_of("0123456789") != std::string::npos ||
          part.size() > 9 || std::stoul(part) >= size)
        throw ConfigError("--set " + o + ": expected a list index below " + std::to_string(size) +
                          ", got '" + part + "'");
      return static_cast<std::size_t>(std::stoul(part));
    };
    std::vector<YAML::Node> chain{doc};
    for (std::size_t i = 0; i + 1 < parts.size(); ++i) {
      YAML::Node cur = chain.back();
      const std::string& p = parts[i];
      if (p.empty()) throw ConfigError("--set " + o + ": empty key part");
      if (cur.IsSequence()) {
        chain.push_back(cur[index_of(p, cur.size())]);
      } else if (cur.IsMap() || cur.IsNull()) {
        if (!cur[p] || cur[p].IsNull()) cur[p] = YAML::Node(YAML::NodeType::Map);
        chain.push_back(cur[p]);
      } else {
        throw ConfigError("--set " + o + ": '" + p + "' is below a scalar");
      }
    }
    YAML::Node last = chain.back();
    if (last.IsScalar()) throw ConfigError("--set " + o + ": the parent of the key is a scalar");
    if (last.IsSequence()) {
      last[index_of(parts.back(), last.size())] = value;
    } else {
      last[parts.back()] = value;
    }
  }
  return doc;
}

}  // namespace

namespace {

// planning.branches: the IK branches a path may be ground in, as the planner names them
// (front|back / up|down / noflip|flip), each part optional: [front] allows the four front
// branches (the wrist centre ahead of the shoulder), [front/up] two.
unsigned branch_mask_of(const ConfigNode& list) {
  if (!list.is_sequence() || list.size() == 0)
    list.fail("expected a list of IK branches, e.g. [front] or [front/up/noflip, front/up/flip]");
  unsigned mask = 0;
  for (std::size_t i = 0; i < list.size(); ++i) {
    const std::string want = list[i].as_string();
    unsigned matched = 0;
    for (int b = 0; b < 8; ++b) {
      const planner::IkBranch branch{b < 4, (b & 2) == 0, (b & 1) != 0};  // index() == b
      const std::string name = branch.name();
      if (name == want || name.rfind(want + "/", 0) == 0) matched |= 1u << branch.index();
    }
    if (!matched)
      list[i].fail("expected a branch such as front, back, front/up or front/up/noflip, got '" +
                   want + "'");
    mask |= matched;
  }
  return mask;
}

}  // namespace

Scenario load_scenario(const std::string& path, const std::vector<std::string>& overrides) {
  const ConfigNode root =
      overrides.empty() ? ConfigNode::load_file(path)
                        : ConfigNode::load_string(YAML::Dump(apply_overrides(path, overrides)), path);
  Scenario sc;
  sc.file = path;
  sc.name = root.get_string("name");
  sc.description = root.get_string("description", "");
  sc.seed = static_cast<std::uint64_t>(root.get_int("seed", 0, (1LL << 62), 1));

  const ConfigNode robot = root.at("robot");
  const std::string robot_file = resolve_relative(path, robot.as_string());
  try {
    sc.robot = load_robot(robot_file);
  } catch (const IoError&) {
    robot.fail("expected a robot description file, got '" + robot.as_string() +
               "' (resolved to " + robot_file + ", not found)");
  }

  // `robot_home`: the parking (and scanning) pose, in place of the robot file's (a URDF arm's is
  // its zero pose) [rad, D-H angles].
  if (root.has("robot_home")) {
    const ConfigNode h = root.at("robot_home");
    const auto v = h.as_doubles(kNumJoints);
    Vector6 q;
    for (int i = 0; i < kNumJoints; ++i) q[i] = v[static_cast<std::size_t>(i)];
    if (!q.allFinite() || !sc.robot.within_limits(q))
      h.fail("expected 6 finite joint angles [rad] within the robot's joint limits");
    sc.robot.home = q;
  }

  sim::CellSpec& cell = sc.cell;
  bool riser_given = false;
  if (root.has("cell")) {
    const ConfigNode c = root.at("cell");
    cell.X_WB = c.get_pose("robot_base", cell.X_WB);
    cell.base_height = c.get_double("base_height", 0.0, 3.0, cell.base_height);
    if (cell.X_WB.translation().z() < cell.base_height)
      c.fail("expected the robot base at least base_height (" +
             std::to_string(cell.base_height) + " m) above the floor");
    if (c.has("table")) {
      const ConfigNode t = c.at("table");
      cell.X_WTable = t.get_pose("pose", cell.X_WTable);
      if (t.has("size")) {
        cell.table_size = t.get_vec3("size");
        if (cell.table_size.minCoeff() <= 0 || cell.table_size.maxCoeff() > 10)
          t.at("size").fail("expected three extents in (0, 10] m (metres, not millimetres)");
      }
      if (cell.X_WTable.translation().z() <= cell.table_size.z())
        t.fail("expected the table top above the floor by more than its thickness");
    }
    if (c.has("riser")) {
      riser_given = true;
      const ConfigNode r = c.at("riser");
      cell.riser_height = r.get_double("height", 0.0, 0.5, cell.riser_height);
      cell.riser_inset = r.get_double("inset", 0.0, 0.2, cell.riser_inset);
    }
    cell.X_WM = c.get_pose("scanner_mount", cell.X_WM);
    cell.timestep = c.get_double("timestep", 1e-5, 0.001, cell.timestep);
  }

  const ConfigNode casting = root.at("casting");
  sim::CastingParams& cp = sc.casting;
  try {
    cp.family = sim::family_from_string(casting.get_string("family"));
  } catch (const ArgumentError&) {
    casting.at("family").fail("expected flanged_plate, round_flange, housing, cover or mesh, got '" +
                              casting.get_string("family") + "'");
  }
  cp.seed = static_cast<std::uint64_t>(casting.get_int("seed", 0, (1LL << 62),
                                                        static_cast<long long>(sc.seed)));
  if (cp.family == sim::CastingFamily::kMesh) {
    cp.mesh_path = resolve_relative(path, casting.get_string("mesh"));
    cp.mesh_scale = casting.get_double("scale", 1e-6, 1e3, 1.0);
  } else if (casting.has("mesh")) {
    casting.at("mesh").fail("expected no mesh for a parametric family (family: mesh uses it)");
  }
  if (casting.has("flash")) read_flash(casting.at("flash"), cp.flash);

  Placement& pl = sc.placement;
  if (casting.has("placement")) {
    const ConfigNode p = casting.at("placement");
    if (p.is_scalar()) {
      if (p.as_string() != "random") p.fail("expected 'random' or a mapping {x, y, yaw, ...}");
      pl.random = true;
    } else {
      pl.x = p.get_double("x", -2, 2, pl.x);
      pl.y = p.get_double("y", -2, 2, pl.y);
      pl.yaw = p.get_double("yaw", -4 * M_PI, 4 * M_PI, pl.yaw);
      pl.roll = p.get_double("roll", -4 * M_PI, 4 * M_PI, pl.roll);
      pl.pitch = p.get_double("pitch", -4 * M_PI, 4 * M_PI, pl.pitch);
      pl.random = p.get_bool("random", pl.random);
      pl.xy_range = p.get_double("xy_range", 0.0, 1.0, pl.xy_range);
      pl.random_tilt = p.get_bool("tilt", pl.random_tilt);
      if (pl.random_tilt && !pl.random) p.fail("expected tilt only together with random: true");
      pl.turn_over = p.get_bool("turn_over", pl.turn_over);
      if (pl.turn_over && !pl.random)
        p.fail("expected turn_over only together with random: true (a fixture holds the part one way up)");
    }
    const Vec3& ts = cell.table_size;
    if (std::abs(pl.x) > ts.x() / 2 || std::abs(pl.y) > ts.y() / 2)
      p.fail("expected a position on the table top (|x| <= " + std::to_string(ts.x() / 2) +
             ", |y| <= " + std::to_string(ts.y() / 2) + " m)");
  }

  // A part held by the fixture stands on a riser 40 mm over the table unless `cell.riser` says
  // otherwise: the burr grinding a fin low on the part (a housing's flange, a bracket's parting
  // line 7 mm up) hangs up to its 20 mm length below the fin, under the part's bottom; on the
  // table it cut into the table top. A randomly placed part lies on the table (no fixture is
  // laid out for it before it lands; raised, a tilted part's high walls took the forearm into
  // the scanner head).
  if (!riser_given) cell.riser_height = pl.random ? 0.0 : 0.04;

  sc.scan.views = sim::default_scan_views();
  sc.scan.seed = sc.seed;
  sc.scan.threads = 2;
  if (root.has("scanner")) read_scanner(root.at("scanner"), sc);

  if (root.has("perception")) {
    const ConfigNode pr = root.at("perception");
    if (pr.has("detection")) {
      const ConfigNode d = pr.at("detection");
      auto& dp = sc.detection;
      dp.crop_margin = d.get_double("crop_margin", 0, 0.5, dp.crop_margin);
      dp.noise_sigma = d.get_double("noise_sigma", -1, 0.005, dp.noise_sigma);
      dp.threshold_sigmas = d.get_double("threshold_sigmas", 0.5, 50, dp.threshold_sigmas);
      dp.min_threshold = d.get_double("min_threshold", 1e-6, 0.01, dp.min_threshold);
      dp.max_threshold = d.get_double("max_threshold", dp.min_threshold, 0.02, dp.max_threshold);
      dp.cluster_tolerance = d.get_double("cluster_tolerance", 0, 0.05, dp.cluster_tolerance);
      dp.min_region_points =
          static_cast<int>(d.get_int("min_region_points", 3, 1000000, dp.min_region_points));
      dp.fragment_merge = d.get_double("fragment_merge", 0, 20, dp.fragment_merge);
      dp.alpha = d.get_double("alpha", 0, 0.05, dp.alpha);
      dp.inner_band = d.get_double("inner_band", 0, 0.05, dp.inner_band);
      dp.hidden_root_band = d.get_double("hidden_root_band", 0, 0.05, dp.hidden_root_band);
      dp.path_voxel = d.get_double("path_voxel", 1e-5, 0.05, dp.path_voxel);
      const std::string vm = d.get_string("path_voxel_method", "nearest");
      if (vm != "nearest" && vm != "centroid")
        d.at("path_voxel_method").fail("expected nearest or centroid, got '" + vm + "'");
      dp.path_voxel_nearest = vm == "nearest";
      dp.gap = d.get_double("gap", 0, 0.5, dp.gap);
      dp.min_path_length = d.get_double("min_path_length", 0, 1, dp.min_path_length);
      dp.smoothing = static_cast<int>(d.get_int("smoothing", 0, 100, dp.smoothing));
      dp.mid_plane = d.get_bool("mid_plane", dp.mid_plane);
      dp.close_holes = d.get_bool("close_holes", dp.close_holes);
    }
  }

  // planning.retare_before_finish: by default the plan stops in free air (for the sensor's
  // zero) when the controller reads the F/T sensor for the tool's position (compensation from
  // the sensor, force control); the oracle compensation needs no stops.
  std::optional<bool> retare;
  if (root.has("planning")) {
    const ConfigNode pl2 = root.at("planning");
    auto& g = sc.grind;
    g.spacing = pl2.get_double("spacing", 1e-5, 0.05, g.spacing);
    g.feed = pl2.get_double("feed", 1e-4, 1.0, g.feed);
    g.approach_feed = pl2.get_double("approach_feed", 1e-4, 1.0, g.approach_feed);
    g.plunge_feed = pl2.get_double("plunge_feed", 1e-4, 1.0, g.plunge_feed);
    g.approach_distance = pl2.get_double("approach_distance", 0, 0.5, g.approach_distance);
    if (pl2.has("retare_before_finish"))
      retare = pl2.get_bool("retare_before_finish", g.retare_before_finish);
    g.retare_length = pl2.get_double("retare_length", 0, 10, g.retare_length);
    g.retare_ramp_time = pl2.get_double("retare_ramp_time", 0, 10, g.retare_ramp_time);
    g.lead = pl2.get_double("lead", -0.8, 0.8, g.lead);
    g.tilt = pl2.get_double("tilt", -0.8, 0.8, g.tilt);
    g.max_depth_of_cut = pl2.get_double("max_depth_of_cut", 1e-5, 0.05, g.max_depth_of_cut);
    g.finish_depth = pl2.get_double("finish_depth", 0.0, 0.01, g.finish_depth);
    sc.clearance_check = pl2.get_bool("clearance_check", sc.clearance_check);
    g.min_clearance = pl2.get_double("min_clearance", 0.0, 0.05, g.min_clearance);
    sc.floor_check = pl2.get_bool("floor_check", sc.floor_check);
    g.floor_clearance = pl2.get_double("floor_clearance", 0.0, 0.05, g.floor_clearance);
    g.lead_clearance = pl2.get_double("lead_clearance", 0.0, 0.01, g.lead_clearance);
    g.roughing_feed = pl2.get_double("roughing_feed", 1e-4, 1.0, g.roughing_feed);
    g.limit_margin = pl2.get_double("limit_margin", 0.0, 0.2, g.limit_margin);
    g.overrun = pl2.get_double("overrun", 0.0, 0.05, g.overrun);
    g.stock_allowance = pl2.get_double("stock_allowance", 0.0, 0.005, g.stock_allowance);
    g.manipulability_threshold =
        pl2.get_double("manipulability_threshold", 0, 1, g.manipulability_threshold);
    g.max_extra_tilt = pl2.get_double("max_extra_tilt", 0, M_PI / 4, g.max_extra_tilt);
    g.max_extra_lead = pl2.get_double("max_extra_lead", 0, M_PI / 2, g.max_extra_lead);
    if (pl2.has("branches")) g.branch_mask = branch_mask_of(pl2.at("branches"));
  }

  if (root.has("tool")) {
    // The burr on the spindle (the robot file's tool, resized): the cell draws it, the planner
    // and the process model use it.
    const ConfigNode t = root.at("tool");
    sc.robot.tool.radius = t.get_double("radius", 5e-4, 0.05, sc.robot.tool.radius);
    sc.robot.tool.length = t.get_double("length", 1e-3, 0.2, sc.robot.tool.length);
    sc.robot.tool.shank_radius = t.get_double("shank_radius", 1e-4, 0.05, sc.robot.tool.shank_radius);
    sc.robot.tool.shank_length = t.get_double("shank_length", 0.0, 0.3, sc.robot.tool.shank_length);
    sc.robot.tool.collet_radius = t.get_double("collet_radius", 1e-4, 0.1, sc.robot.tool.collet_radius);
    sc.robot.tool.collet_length = t.get_double("collet_length", 0.0, 0.3, sc.robot.tool.collet_length);
    sc.robot.tool.rack_collet_radius =
        t.get_double("rack_collet_radius", 1e-4, 0.1, sc.robot.tool.rack_collet_radius);
    if (sc.robot.tool.length < sc.robot.tool.radius)
      t.fail("expected length >= radius (the ball-ended burr needs it)");
  }
  if (root.has("tool_rack")) {
    const ConfigNode r = root.at("tool_rack");
    if (!r.is_sequence()) r.fail("expected a list of burr radii [m], e.g. [0.004, 0.003] (may be empty)");
    sc.tool_rack.clear();
    for (std::size_t i = 0; i < r.size(); ++i) {
      const double v = r[i].as_double();
      if (!(v >= 5e-4 && v <= 0.05)) r[i].fail("expected a burr radius in [0.0005, 0.05] m");
      if (v > sc.robot.tool.length) r[i].fail("expected a radius <= the burr length");
      sc.tool_rack.push_back(v);
    }
  }
  if (root.has("video")) {
    const ConfigNode v = root.at("video");
    auto& vs = sc.video;
    vs.camera = v.get_string("camera", vs.camera);
    if (vs.camera.empty()) v.at("camera").fail("expected \"follow\" or a camera of the cell");
    vs.length = v.get_double("length", 1, 600, vs.length);
    vs.width = static_cast<int>(v.get_int("width", 16, 1920, vs.width));
    vs.height = static_cast<int>(v.get_int("height", 16, 1080, vs.height));
    if (vs.width % 2) v.at("width").fail("expected an even number of pixels (H.264)");
    if (vs.height % 2) v.at("height").fail("expected an even number of pixels (H.264)");
    vs.fps = static_cast<int>(v.get_int("fps", 1, 120, vs.fps));
  }
  if (root.has("execution")) {
    const ConfigNode ex = root.at("execution");
    auto& e = sc.execution;
    e.enabled = ex.get_bool("enabled", e.enabled);
    e.rescan = ex.get_bool("rescan", e.rescan);
    e.transits = ex.get_bool("transits", e.transits);
    e.transit_clearance = ex.get_double("transit_clearance", 1e-3, 0.2, e.transit_clearance);
    e.transit_speed = ex.get_double("transit_speed", 0.01, 1.0, e.transit_speed);
    e.exec.settle_time = ex.get_double("settle_time", 0, 10, e.exec.settle_time);
    e.exec.max_force = ex.get_double("max_force", 0, 1e7, e.exec.max_force);
    e.exec.feedforward = ex.get_bool("feedforward", e.exec.feedforward);
    e.exec.load_compensation = ex.get_bool("load_compensation", e.exec.load_compensation);
    e.exec.tcp_damping = ex.get_double("tcp_damping", 0, 1e6, e.exec.tcp_damping);
    e.exec.cad_check_motion = ex.get_double("cad_check_motion", 0, 0.01, e.exec.cad_check_motion);
    if (ex.has("compensation")) {
      const std::string src = ex.get_string("compensation", "");
      if (src == "sensor") e.exec.compensation_source = sim::CompensationSource::kSensor;
      else if (src == "process_model") e.exec.compensation_source = sim::CompensationSource::kProcessModel;
      else ex.at("compensation").fail("expected \"sensor\" or \"process_model\"");
    }
    if (ex.has("sensor")) {
      const ConfigNode sn = ex.at("sensor");
      auto& fs = e.exec.sensor;
      fs.period = sn.get_double("period", 1e-4, 0.1, fs.period);
      fs.cutoff = sn.get_double("cutoff", 0.1, 1e5, fs.cutoff);
      fs.force_noise = sn.get_double("force_noise", 0, 1e3, fs.force_noise);
      fs.torque_noise = sn.get_double("torque_noise", 0, 1e2, fs.torque_noise);
      fs.force_offset = sn.get_double("force_offset", 0, 1e4, fs.force_offset);
      fs.torque_offset = sn.get_double("torque_offset", 0, 1e3, fs.torque_offset);
      fs.force_drift = sn.get_double("force_drift", 0, 1e3, fs.force_drift);
      fs.torque_drift = sn.get_double("torque_drift", 0, 1e2, fs.torque_drift);
      fs.force_range = sn.get_double("force_range", 1, 1e6, fs.force_range);
      fs.torque_range = sn.get_double("torque_range", 0.1, 1e5, fs.torque_range);
      fs.tare_time = sn.get_double("tare_time", 0, 1, fs.tare_time);
    }
    e.exec.log_decimation =
        static_cast<int>(ex.get_int("log_decimation", 1, 100000, e.exec.log_decimation));
    if (ex.has("force_control")) {
      const ConfigNode fc = ex.at("force_control");
      auto& f = e.exec.force_control;
      f.enabled = fc.get_bool("enabled", f.enabled);
      f.target_force = fc.get_double("target_force", 0.01, 1000, f.target_force);
      f.gain = fc.get_double("gain", 0, 1, f.gain);
      f.max_correction = fc.get_double("max_correction", 0, 0.05, f.max_correction);
      f.release_time = fc.get_double("release_time", 0, 10, f.release_time);
      f.contact_force = fc.get_double("contact_force", 0, 1000, f.contact_force);
    }
  }
  if (root.has("process")) {
    const ConfigNode pr = root.at("process");
    auto& mp = sc.execution.material;
    mp.voxel_size = pr.get_double("voxel_size", 2e-5, 2e-3, mp.voxel_size);
    mp.body_band = pr.get_double("body_band", 1e-4, 0.01, mp.body_band);
    mp.body_margin = pr.get_double("body_margin", 0, 0.05, mp.body_margin);
    auto& f = sc.execution.force;
    f.specific_energy = pr.get_double("specific_energy", 1e8, 1e12, f.specific_energy);
    f.force_ratio = pr.get_double("force_ratio", 0.1, 10, f.force_ratio);
    f.spindle_rpm = pr.get_double("spindle_rpm", 100, 200000, f.spindle_rpm);
    f.contact_stiffness = pr.get_double("contact_stiffness", 0, 1e9, f.contact_stiffness);
    f.contact_damping = pr.get_double("contact_damping", 0, 1e6, f.contact_damping);
  }

  if (root.has("faults")) {
    const ConfigNode f = root.at("faults");
    if (!f.is_map()) f.fail("expected a mapping of faults (part_offset, tool_radius_error, tcp_offset, sensor_bias)");
    if (f.has("part_offset")) {
      const ConfigNode o = f.at("part_offset");
      if (!o.is_map()) o.fail("expected {xyz: [x, y, z] (m), rpy: [r, p, y] (rad)}");
      const Vec3 xyz = o.get_vec3("xyz", Vec3::Zero()), rpy = o.get_vec3("rpy", Vec3::Zero());
      if (xyz.norm() > 0.05)
        o.at("xyz").fail("expected an offset within 0.05 m (a drill, not another placement), got " +
                         std::to_string(xyz.norm()) + " m");
      if (rpy.cwiseAbs().maxCoeff() > 0.2)
        o.at("rpy").fail("expected each angle within 0.2 rad, got " + std::to_string(rpy.cwiseAbs().maxCoeff()));
      sc.faults.part_offset_C = pose_from_xyz_rpy(xyz, rpy);
    }
    sc.faults.tool_radius_error = f.get_double("tool_radius_error", -0.005, 0.005, 0.0);
    sc.faults.tcp_offset_T = f.get_vec3("tcp_offset", Vec3::Zero());
    if (!(sc.faults.tcp_offset_T.norm() <= 0.01))
      f.at("tcp_offset").fail("expected an offset [x, y, z] within 0.01 m (a drill), got " +
                              std::to_string(sc.faults.tcp_offset_T.norm()) + " m");
    if (f.has("sensor_bias")) {
      const ConfigNode b = f.at("sensor_bias");
      if (!b.is_map()) b.fail("expected {force: [fx, fy, fz] (N), torque: [tx, ty, tz] (N*m)} in the flange frame");
      auto& bias = sc.faults.sensor_bias_E;
      bias.force = b.get_vec3("force", Vec3::Zero());
      bias.torque = b.get_vec3("torque", Vec3::Zero());
      const auto& range = sc.execution.exec.sensor;  // the sensor block is read before faults
      if (!(bias.force.cwiseAbs().maxCoeff() <= range.force_range))
        b.at("force").fail("expected each axis within the sensor's force_range " +
                           std::to_string(range.force_range) + " N");
      if (!(bias.torque.cwiseAbs().maxCoeff() <= range.torque_range))
        b.at("torque").fail("expected each axis within the sensor's torque_range " +
                            std::to_string(range.torque_range) + " N*m");
    }
    // Every burr the job may use (the spindle's, the rack's) stays a ball-ended burr with it.
    std::vector<double> burrs{sc.robot.tool.radius};
    burrs.insert(burrs.end(), sc.tool_rack.begin(), sc.tool_rack.end());
    for (const double r : burrs) {
      const double e = r + sc.faults.tool_radius_error;
      if (e < 0.5e-3 || e > sc.robot.tool.length)
        f.at("tool_radius_error").fail("expected every burr (spindle and tool_rack) to keep a radius in [0.0005 m, its length " +
                                       std::to_string(sc.robot.tool.length) + " m], got " + std::to_string(e) +
                                       " m for the burr of " + std::to_string(r) + " m");
    }
  }
  if (root.has("quality")) {
    const ConfigNode q = root.at("quality");
    if (!q.is_map()) q.fail("expected a mapping of limits (removed_min, residual_max_mm, gouge_max_mm, protective_stops_max, collisions_max)");
    auto& ql = sc.quality;
    ql.min_removed_fraction = q.get_double("removed_min", 0, 1, ql.min_removed_fraction);
    ql.max_residual_mm = q.get_double("residual_max_mm", 0, 100, ql.max_residual_mm);
    ql.max_gouge_mm = q.get_double("gouge_max_mm", 0, 100, ql.max_gouge_mm);
    ql.max_protective_stops =
        static_cast<int>(q.get_int("protective_stops_max", 0, 1000000, ql.max_protective_stops));
    ql.max_collisions = static_cast<int>(q.get_int("collisions_max", 0, 1000000000, ql.max_collisions));
  }
  if (root.has("expect")) {
    const ConfigNode ex = root.at("expect");
    if (!ex.is_map()) ex.fail("expected a mapping of metric key: [min, max] or true/false");
    for (const auto& key : ex.keys()) {
      const ConfigNode v = ex.at(key);
      Expectation e;
      e.key = key;
      if (v.is_sequence()) {
        if (v.size() != 2) v.fail("expected [min, max] (use null for an open end)");
        const auto bound = [&](std::size_t i, double open) {
          const ConfigNode b = v[i];
          if (b.is_null()) return open;
          return b.as_double();
        };
        e.lo = bound(0, -1e300);
        e.hi = bound(1, 1e300);
        if (!(e.lo <= e.hi)) v.fail("expected min <= max");
      } else if (v.is_scalar() && (v.as_string() == "true" || v.as_string() == "false")) {
        e.is_flag = true;
        e.flag = v.as_bool();
      } else if (v.is_scalar()) {
        e.lo = e.hi = v.as_double();
      } else {
        v.fail("expected [min, max], a number or true/false");
      }
      sc.expect.push_back(e);
    }
  }

  if (root.has("expect_sweep")) read_expect_sweep(root.at("expect_sweep"), sc.expect_sweep);

  const sim::ExecParams& xp = sc.execution.exec;
  sc.grind.retare_before_finish = retare.value_or(
      (xp.load_compensation && xp.compensation_source == sim::CompensationSource::kSensor) ||
      xp.force_control.enabled);

  root.check_all_used();
  return sc;
}

CellSetup setup_cell(const Scenario& sc) {
  CellSetup s;
  s.casting = sim::make_casting(sc.casting);
  s.spec = sc.cell;
  const Placement& pl = sc.placement;
  double x = pl.x, y = pl.y;
  Mat3 R = (Eigen::AngleAxisd(pl.yaw, Vec3::UnitZ()) * Eigen::AngleAxisd(pl.pitch, Vec3::UnitY()) *
            Eigen::AngleAxisd(pl.roll, Vec3::UnitX()))
               .toRotationMatrix();
  if (pl.random) {
    // Its own stream, so placement draws do not change the casting's shape.
    Rng rng(sc.seed * 0xD1B54A32D192ED03ULL + 3);
    x = rng.uniform(-pl.xy_range, pl.xy_range);
    y = rng.uniform(-pl.xy_range, pl.xy_range);
    if (pl.random_tilt) {
      // Uniform rotation from a uniform unit quaternion (Shoemake).
      const double u1 = rng.uniform(), u2 = rng.uniform(), u3 = rng.uniform();
      const Eigen::Quaterniond q(std::sqrt(u1) * std::cos(2 * M_PI * u3),
                                 std::sqrt(1 - u1) * std::sin(2 * M_PI * u2),
                                 std::sqrt(1 - u1) * std::cos(2 * M_PI * u2),
                                 std::sqrt(u1) * std::sin(2 * M_PI * u3));
      R = q.toRotationMatrix();
    } else {
      R = Eigen::AngleAxisd(rng.uniform(-M_PI, M_PI), Vec3::UnitZ()).toRotationMatrix();
    }
  }
  s.spec.X_WC = sim::rest_on_table(s.spec, s.casting.nominal, x, y, R);
  // Refuse a cell that makes no sense (casting off the table, fixture in the casting, robot base
  // or scanner in the table) before anything runs in it; the message names the scenario field.
  try {
    sim::check_cell_layout(s.spec, s.casting.nominal);
    sim::check_arm_clear_of_scanner(sc.robot, s.spec);
  } catch (const ConfigError& e) {
    if (sc.file.empty()) throw;
    throw ConfigError(sc.file + ": " + e.what());
  }
  return s;
}

CellSetup turned_over(const Scenario& sc, const CellSetup& first, sim::Casting now, const Vec3& up_C) {
  if (!(up_C.norm() > 0.5)) throw ArgumentError("turned_over: expected a unit direction to turn up");
  CellSetup s;
  s.casting = std::move(now);
  s.spec = first.spec;
  // Its own stream (the first placement's is seed·k + 3).
  Rng rng(sc.seed * 0xD1B54A32D192ED03ULL + 5);
  const double x = rng.uniform(-sc.placement.xy_range, sc.placement.xy_range);
  const double y = rng.uniform(-sc.placement.xy_range, sc.placement.xy_range);
  const double yaw = rng.uniform(-M_PI, M_PI);
  const Mat3 R = Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix() *
                 Eigen::Quaterniond::FromTwoVectors(up_C.normalized(), Vec3::UnitZ()).toRotationMatrix();
  s.spec.X_WC = sim::rest_on_table(s.spec, s.casting.nominal, x, y, R);
  try {
    sim::check_cell_layout(s.spec, s.casting.nominal);
  } catch (const ConfigError& e) {
    throw ConfigError((sc.file.empty() ? std::string() : sc.file + ": ") + "the part turned over: " + e.what());
  }
  return s;
}

}  // namespace flashtwin::pipeline
