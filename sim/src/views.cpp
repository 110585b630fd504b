#include "flashtwin/sim/views.hpp"

#include <filesystem>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/renderer.hpp"

namespace flashtwin::sim {

std::vector<std::string> render_views(const std::string& mjcf_path, const RenderRequest& request,
                                      const std::string& out_dir, const std::string& prefix) {
  const MjModelPtr m = load_mjcf_file(mjcf_path);
  const MjDataPtr d = make_data(m.get());
  if (!request.keyframe.empty())
    mj_resetDataKeyframe(m.get(), d.get(), require_id(m.get(), mjOBJ_KEY, request.keyframe));
  mj_forward(m.get(), d.get());
  ensure_directory(out_dir);
  // The off-screen buffer only as large as the images (the cell allows up to 1920×1080).
  if (request.width <= m->vis.global.offwidth && request.height <= m->vis.global.offheight) {
    m->vis.global.offwidth = request.width;
    m->vis.global.offheight = request.height;
  }
  OffscreenRenderer renderer(m.get(), request.width, request.height);
  PointOverlay overlay;
  overlay.points_W = request.points_W;
  overlay.colors = request.colors;
  overlay.radius = request.point_radius;
  overlay.max_points = request.max_points;
  overlay.cubes = request.cubes;
  std::vector<std::string> paths;
  for (const auto& cam : request.cameras) {
    const Image img =
        renderer.render(d.get(), cam, overlay.points_W.empty() ? nullptr : &overlay);
    const std::string path =
        (std::filesystem::path(out_dir) / (prefix + (cam.empty() ? "free" : cam) + ".png")).string();
    write_png(path, img);
    paths.push_back(path);
  }
  return paths;
}

}  // namespace flashtwin::sim
