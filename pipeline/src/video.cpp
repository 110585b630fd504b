#include "flashtwin/pipeline/video.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/renderer.hpp"

namespace flashtwin::pipeline {

std::vector<std::string> ffmpeg_arguments(const VideoOptions& o) {
  return {"ffmpeg", "-nostdin", "-loglevel", "error", "-y", "-f", "rawvideo", "-pix_fmt", "rgb24",
          "-s", std::to_string(o.width) + "x" + std::to_string(o.height), "-r",
          std::to_string(o.fps), "-i", "pipe:0", "-c:v", "libx264", "-pix_fmt", "yuv420p",
          "-crf", "23", "-movflags", "+faststart",
          // "file:" keeps a path such as "a:b.mp4" or "-x.mp4" from reading as a protocol or
          // an option.
          "file:" + o.path};
}

VideoRecorder::VideoRecorder(const VideoOptions& o, double sim_duration) : opt_(o) {
  if (o.width < 16 || o.height < 16 || o.width % 2 || o.height % 2 || o.width > 1920 ||
      o.height > 1080)
    throw ArgumentError("video: expected an even width and height within 16..1920 x 16..1080, got " +
                        std::to_string(o.width) + "x" + std::to_string(o.height));
  if (o.fps < 1 || o.fps > 120) throw ArgumentError("video.fps: expected 1..120");
  if (!(o.length > 0)) throw ArgumentError("video.length: expected > 0 s");
  if (o.flash_points < 0) throw ArgumentError("video.flash_points: expected >= 0");
  speedup_ = std::max(1.0, sim_duration / o.length);
  ffmpeg_ = std::make_unique<PipedProcess>(ffmpeg_arguments(o));
}

VideoRecorder::~VideoRecorder() {
  ffmpeg_.reset();
  if (model_) mj_deleteModel(model_);
}

void VideoRecorder::on_step(const mjModel* m, mjData* d, double t, const sim::MaterialGrid& grid) {
  if (!ffmpeg_ || t + 1e-9 < next_t_) return;
  if (!renderer_) {
    // A render copy of the model with the static flash mesh hidden; the flash is drawn from
    // the voxel grid instead.
    model_ = mj_copyModel(nullptr, m);
    for (int g = 0; g < model_->ngeom; ++g) {
      const char* name = mj_id2name(model_, mjOBJ_GEOM, g);
      // A flash mesh over MuJoCo's face limit is written as several parts (sim::split_mesh).
      if (name && sim::is_mesh_part(name, "casting_flash")) model_->geom_rgba[4 * g + 3] = 0;
    }
    renderer_ = std::make_unique<sim::OffscreenRenderer>(model_, opt_.width, opt_.height);
    const auto all = sim::remaining_flash_points(grid);
    const double step = std::max(1.0, static_cast<double>(all.size()) / std::max(1, opt_.flash_points));
    for (double k = 0; k < static_cast<double>(all.size()); k += step)
      flash_sample_C_.push_back(all[static_cast<std::size_t>(k)]);
    // The casting is fixed in the cell: its pose is read once.
    const int body = mj_name2id(m, mjOBJ_BODY, "casting");
    if (body >= 0) {
      Mat3 R;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) R(r, c) = d->xmat[9 * body + 3 * r + c];
      X_WC_.linear() = R;
      X_WC_.translation() = Vec3(d->xpos[3 * body], d->xpos[3 * body + 1], d->xpos[3 * body + 2]);
    }
  }
  sim::PointOverlay overlay;
  overlay.radius = opt_.point_radius;
  overlay.cubes = true;  // flash voxels; spheres took three quarters of a frame's rendering
  overlay.colors = {{217, 89, 26}};
  for (const auto& p : flash_sample_C_)
    if (grid.label_at(p) == sim::VoxelLabel::kFlash) overlay.points_W.push_back(X_WC_ * p);
  const Image img = renderer_->render(d, opt_.camera, &overlay);
  const auto& px = img.pixels();
  if (!ffmpeg_->write(px.data(), px.size()))
    throw IoError(opt_.path + ": ffmpeg stopped taking frames");
  ++frames_;
  next_t_ += speedup_ / opt_.fps;
  if (next_t_ < t) next_t_ = t + speedup_ / opt_.fps;
}

std::size_t VideoRecorder::finish() {
  if (ffmpeg_) {
    const int rc = ffmpeg_->finish();
    ffmpeg_.reset();
    if (rc != 0) throw IoError(opt_.path + ": ffmpeg failed (exit status " + std::to_string(rc) + ")");
  }
  renderer_.reset();
  return frames_;
}

}  // namespace flashtwin::pipeline
