#include "flashtwin/sim/scan_cell.hpp"

#include <cmath>

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

CellScan scan_cell(const std::string& mjcf_path, const Casting& casting, const ScanParams& params,
                   const Pose& X_WM_nominal, const Pose& X_WM_true, const std::string& keyframe) {
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
  // The casting as exact meshes at the pose MuJoCo gives its body.
  Pose X_WC = Pose::Identity();
  X_WC.translation() = Vec3(d->xpos[3 * casting_body], d->xpos[3 * casting_body + 1],
                            d->xpos[3 * casting_body + 2]);
  Mat3 R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R(r, c) = d->xmat[9 * casting_body + 3 * r + c];
  X_WC.linear() = R;
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
