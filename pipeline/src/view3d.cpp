#include "flashtwin/pipeline/view3d.hpp"

#include <algorithm>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <vector>

#include <nlohmann/json.hpp>

#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/sim/process.hpp"
#include "view3d_assets.hpp"

namespace flashtwin::pipeline {

namespace {

using json = nlohmann::json;

// Typed arrays travel as base64 of their little-endian bytes (the page decodes them into
// Float32Array / Uint32Array / Uint8Array without parsing numbers).
template <typename T>
std::string b64(const std::vector<T>& v) {
  std::string bytes(v.size() * sizeof(T), '\0');
  if (!v.empty()) std::memcpy(bytes.data(), v.data(), bytes.size());
  return base64_encode(bytes);
}

// Positions in {C} as float millimetres.
void push_mm(std::vector<float>& out, const Vec3& p_C) {
  for (int k = 0; k < 3; ++k) out.push_back(static_cast<float>(p_C[k] * 1e3));
}

// Indices 0..n-1 thinned evenly to at most `budget`.
std::vector<std::size_t> thin(std::size_t n, std::size_t budget) {
  std::vector<std::size_t> idx;
  const double step = std::max(1.0, static_cast<double>(n) / static_cast<double>(std::max<std::size_t>(budget, 1)));
  for (double f = 0; f < static_cast<double>(n); f += step) idx.push_back(static_cast<std::size_t>(f));
  return idx;
}

// The same indices in a fixed pseudo-random order (Fisher-Yates with a 64-bit LCG, the same
// on every platform) from position `from` on: any prefix is then an even sample of the whole,
// so the page's density control draws the first N points.
void shuffle_from(std::vector<std::size_t>& idx, std::size_t from) {
  std::uint64_t state = 0x9e3779b97f4a7c15ull;
  for (std::size_t i = idx.size(); i > from + 1; --i) {
    state = state * 6364136223846793005ull + 1442695040888963407ull;
    const std::size_t j = from + static_cast<std::size_t>((state >> 33) % (i - from));
    std::swap(idx[i - 1], idx[j]);
  }
}

json polyline(const std::vector<Vec3>& pts_C, bool closed) {
  std::vector<float> xyz;
  for (const auto& p : pts_C) push_mm(xyz, p);
  return {{"xyz", b64(xyz)}, {"closed", closed}};
}

json cad_layer(const TriangleMesh& mesh) {
  std::vector<float> xyz;
  std::vector<std::uint32_t> idx;
  for (const auto& v : mesh.vertices) push_mm(xyz, v);
  for (const auto& t : mesh.triangles)
    for (int k = 0; k < 3; ++k) idx.push_back(static_cast<std::uint32_t>(t[k]));
  return {{"xyz", b64(xyz)}, {"index", b64(idx)}};
}

// The scan in {C} as perception placed it (its estimated pose), with its labels.
json scan_layer(const ReportInputs& in, const View3dParams& P) {
  const auto& cloud = in.scan.scan.result.cloud_M;
  const auto& labels = in.result.detection.labels;
  const Pose X_CM = in.result.registration.T_target_source;
  std::vector<float> xyz;
  std::vector<std::uint8_t> lab;
  std::vector<std::size_t> keep = thin(cloud.size(), P.scan_points);
  shuffle_from(keep, 0);
  for (const std::size_t i : keep) {
    push_mm(xyz, X_CM * cloud.points[i].cast<double>());
    lab.push_back(i < labels.size() ? labels[i] : 2);
  }
  return {{"xyz", b64(xyz)}, {"label", b64(lab)}, {"total", cloud.size()}};
}

// Material voxels with a value [mm] (height of residual flash above the CAD, depth of a gouge
// below it), thinned to the budget, the extreme one first (the page's "worst" button goes to
// it), the rest shuffled.
json map_layer(const std::vector<Vec3>& pts_C, const MeshBvh& cad, std::size_t budget) {
  std::vector<float> value(pts_C.size());
  std::size_t worst = 0;
  for (std::size_t i = 0; i < pts_C.size(); ++i) {
    value[i] = static_cast<float>(cad.closest(pts_C[i]).distance * 1e3);
    if (value[i] > value[worst]) worst = i;
  }
  std::vector<float> xyz, val;
  std::vector<std::size_t> keep = thin(pts_C.size(), budget);
  if (!pts_C.empty()) {  // the worst first, always drawn
    keep.erase(std::remove(keep.begin(), keep.end(), worst), keep.end());
    keep.insert(keep.begin(), worst);
  }
  shuffle_from(keep, 1);
  for (const std::size_t i : keep) {
    push_mm(xyz, pts_C[i]);
    val.push_back(value[i]);
  }
  json j = {{"xyz", b64(xyz)}, {"value", b64(val)}, {"total", pts_C.size()}};
  if (!pts_C.empty()) {
    std::vector<float> w;
    push_mm(w, pts_C[worst]);
    j["worst"] = {{"xyz", w}, {"value", value[worst]}};
  }
  return j;
}

// Planned tool paths: the TCP of every sample in {C} and its kind (approach, cut, link,
// retract), one entry per planned path (pieces of a path each their own).
json toolpath_layer(const ReportInputs& in) {
  json paths = json::array();
  for (const auto& [k, g] : in.plans) {
    std::vector<float> xyz;
    std::vector<std::uint8_t> kind;
    for (const auto& s : g.samples) {
      push_mm(xyz, s.X_CT.translation());
      kind.push_back(static_cast<std::uint8_t>(s.kind));
    }
    paths.push_back({{"path", k}, {"xyz", b64(xyz)}, {"kind", b64(kind)}});
  }
  return paths;
}

// The arm along the executed motion: per keyframe the origins of the D-H frames {0}..{6} and
// the TCP, in {C} (the true placement: the real arm moves relative to the real casting).
json robot_layer(const ReportInputs& in, const View3dParams& P) {
  const auto& ex = in.execution;
  const RobotModel& robot = in.scenario.robot;
  // Each setup's rows relative to the casting as that setup placed it (ex.X_CB[ex.setup[i]]).
  std::vector<float> t, force, xyz;
  std::vector<std::int32_t> path;
  for (const std::size_t i : thin(ex.q.size(), P.robot_frames)) {
    t.push_back(static_cast<float>(ex.t[i]));
    force.push_back(static_cast<float>(ex.normal_force[i]));
    path.push_back(ex.path[i]);
    const Pose& X_CB = ex.X_CB[static_cast<std::size_t>(ex.setup[i])];
    const auto X_B = planner::fk_frames(robot, ex.q[i]);
    for (const auto& X : X_B) push_mm(xyz, X_CB * X.translation());
    push_mm(xyz, X_CB * (X_B.back() * robot.tool.X_ET).translation());
  }
  return {{"t", b64(t)},
          {"force", b64(force)},
          {"path", b64(path)},
          {"xyz", b64(xyz)},
          {"points_per_frame", kNumJoints + 2},
          {"tool_radius_mm", robot.tool.radius * 1e3}};
}

json page_data(const ReportInputs& in, const View3dParams& P) {
  const auto& casting = in.scan.setup.casting;
  json d;
  d["meta"] = {{"scenario", in.scenario.name},
               {"seed", in.scenario.seed},
               {"verdict", in.result.verdict},
               {"exit_code", in.result.exit_code},
               {"frame", "{C}"},
               {"units", "mm"}};
  if (!P.title.empty()) d["meta"]["title"] = P.title;
  d["cad"] = cad_layer(casting.nominal);
  // The true flash roots: a twin's castings have them; a job's part (its flash rebuilt from the
  // scan along the detected paths) has none to show.
  json roots = json::array();
  for (const auto& f : casting.fins)
    if (f.kind != "rehearsal") roots.push_back(polyline(f.root, f.closed));
  if (!roots.empty()) d["roots"] = roots;
  if (in.result.detection.ran) {
    d["scan"] = scan_layer(in, P);
    json paths = json::array();
    for (const auto& p : in.result.detection.paths) paths.push_back(polyline(p.points_C, p.closed));
    d["paths"] = paths;
  }
  if (!in.plans.empty()) d["toolpath"] = toolpath_layer(in);
  const auto& ex = in.execution;
  if (ex.ran && ex.grid) {
    const MeshBvh& cad = ex.grid->nominal();
    const sim::RemainingFlash rem = sim::split_remaining_flash(*ex.grid);
    std::vector<Vec3> flash = rem.attached;
    flash.insert(flash.end(), rem.loose.begin(), rem.loose.end());
    d["residual"] = map_layer(flash, cad, P.map_points);
    d["gouges"] = map_layer(sim::voxel_points(*ex.grid, sim::VoxelLabel::kGouge), cad, P.map_points);
  }
  if (ex.ran && !ex.q.empty()) d["robot"] = robot_layer(in, P);
  return d;
}

// A JSON text inside <script type="application/json">: "</" must not close the element.
std::string script_safe(std::string s) {
  for (std::size_t at = s.find("</"); at != std::string::npos; at = s.find("</", at + 2))
    s.replace(at, 2, "<\\/");
  return s;
}

}  // namespace

std::string view3d_html(const ReportInputs& in, const View3dParams& params) {
  std::ostringstream h;
  h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n"
    << "<title>flashtwin 3D view: " << in.scenario.name << " (seed " << in.scenario.seed
    << ")</title>\n<style>\n" << view3d_assets::css() << "</style></head><body>\n"
    << view3d_assets::body() << "\n<script type=\"application/json\" id=\"ft-data\">"
    << script_safe(page_data(in, params).dump()) << "</script>\n"
    // three.js as published (CommonJS build), wrapped so that it defines a global THREE.
    << "<script>\nvar THREE = (function () { var module = { exports: {} }; var exports = "
       "module.exports;\n"
    << view3d_assets::three_js() << "\nreturn module.exports; })();\n</script>\n<script>\n"
    << view3d_assets::viewer_js() << "\n</script>\n</body></html>\n";
  return h.str();
}

}  // namespace flashtwin::pipeline
