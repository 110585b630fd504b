#pragma once
// High-level, MuJoCo-free entry points of sim for the pipeline and the CLI: render a written
// cell from its named cameras, with an optional point overlay.
#include <string>
#include <vector>

#include "flashtwin/core/plot.hpp"
#include "flashtwin/core/transform.hpp"

namespace flashtwin::sim {

struct RenderRequest {
  std::vector<std::string> cameras{"overview", "casting_closeup", "top"};
  int width = 800, height = 600;           ///< [px]
  std::string keyframe = "home";           ///< robot configuration ("" = all joints zero)
  std::vector<Vec3> points_W;              ///< optional overlay (scan points) in {W}
  std::vector<Rgb> colors;                 ///< one per point, one for all, or empty
  double point_radius = 0.0008;            ///< [m]
  int max_points = 8000;                   ///< overlay budget (each sphere costs ~0.2 ms)
  bool cubes = false;                      ///< draw the points as cubes (cheaper; PointOverlay)
};

/// Renders the MJCF file from each requested camera into out_dir/<prefix><camera>.png and
/// returns the paths. @throws InputError (model will not load, unknown camera or keyframe),
/// ArgumentError (size beyond the model's off-screen buffer), IoError.
std::vector<std::string> render_views(const std::string& mjcf_path, const RenderRequest& request,
                                      const std::string& out_dir, const std::string& prefix = "");

}  // namespace flashtwin::sim
