#include "flashtwin/pipeline/video.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/core/plot.hpp"
#include "flashtwin/sim/renderer.hpp"

namespace flashtwin::pipeline {

namespace {

Vec3 site_position(const mjData* d, int site) {
  return {d->site_xpos[3 * site], d->site_xpos[3 * site + 1], d->site_xpos[3 * site + 2]};
}

// Whether the straight sight line from `eye_W` to `target_W` reaches within `slack` of the
// target without meeting the casting, the fixture or the table (geom group 0: the arm's geoms
// are group 1 and drawn translucent where they are in the way).
bool in_sight(const mjModel* m, const mjData* d, const Vec3& eye_W, const Vec3& target_W,
              double slack) {
  const Vec3 v = target_W - eye_W;
  const double dist = v.norm();
  const mjtByte groups[mjNGROUP] = {1, 0, 0, 0, 0, 0};
  mjtNum pnt[3] = {eye_W.x(), eye_W.y(), eye_W.z()};
  mjtNum vec[3] = {v.x() / dist, v.y() / dist, v.z() / dist};
  int geom = -1;
  const mjtNum hit = mj_ray(m, d, pnt, vec, groups, 1, -1, &geom);
  return hit < 0 || hit > dist - slack;
}

// The follow camera's view of the burr at tcp_W: from outside the casting (horizontally away
// from its centre), looking down 25°, else the first free line of sight among lower, steeper
// and sideways views (a fixture block in front, a flange above, inside a hole); 25° from
// outside when none is free.
sim::FreeCamera follow_view(const mjModel* m, const mjData* d, const Pose& X_WC,
                            const Vec3& tcp_W, double distance) {
  Vec3 out = tcp_W - X_WC.translation();
  out.z() = 0;
  if (out.norm() < 1e-6) out = Vec3::UnitX();
  out.normalize();
  const double az_out = std::atan2(-out.y(), -out.x()) * 180 / M_PI;  // looking back at the part
  sim::FreeCamera cam;
  cam.lookat_W = tcp_W;
  cam.distance = distance;
  for (const double turn : {0.0, 40.0, -40.0, 80.0, -80.0}) {
    for (const double el : {-25.0, -10.0, -45.0, -65.0, -85.0}) {
      const double a = (az_out + turn) * M_PI / 180, e = el * M_PI / 180;
      const Vec3 forward(std::cos(e) * std::cos(a), std::cos(e) * std::sin(a), std::sin(e));
      if (in_sight(m, d, tcp_W - distance * forward, tcp_W, 0.006)) {
        cam.azimuth = az_out + turn;
        cam.elevation = el;
        return cam;
      }
    }
  }
  cam.azimuth = az_out;
  cam.elevation = -25;
  return cam;
}

// Time, path, TCP speed, force and removal, top-left on a translucent band.
void draw_overlay(Image& img, double t, double speedup, std::size_t path, double speed,
                  double force, double removed) {
  char lines[5][96];
  std::snprintf(lines[0], sizeof lines[0], "t %.1f s (x%.0f)", t, speedup);
  std::snprintf(lines[1], sizeof lines[1], "path %zu", path);
  std::snprintf(lines[2], sizeof lines[2], "TCP speed %.1f mm/s", speed * 1e3);
  std::snprintf(lines[3], sizeof lines[3], "F/T sensor |F| %.0f N", force);
  std::snprintf(lines[4], sizeof lines[4], "flash removed %.1f %%", removed * 100);
  const int scale = img.width() >= 640 ? 2 : 1, line_h = 10 * scale;
  int w = 0;
  for (const auto& l : lines) w = std::max(w, Image::text_width(l, scale));
  for (int y = 0; y < 5 * line_h + 8; ++y)
    for (int x = 0; x < w + 12; ++x) img.blend(x, y, {0, 0, 0}, 0.45);
  for (int i = 0; i < 5; ++i) img.text(6, 5 + i * line_h, lines[i], {255, 255, 255}, scale);
}

}  // namespace

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

void VideoRecorder::on_step(const mjModel* m, mjData* d, double t, const sim::MaterialGrid& grid,
                            std::size_t path) {
  if (!ffmpeg_ || t + 1e-9 < next_t_) return;
  const bool follow = opt_.camera == "follow";
  if (!renderer_) {
    // A render copy of the model with the static flash mesh hidden (the flash is drawn from
    // the voxel grid instead) and, for the follow camera, the spindle translucent.
    model_ = mj_copyModel(nullptr, m);
    for (int g = 0; g < model_->ngeom; ++g) {
      const char* name = mj_id2name(model_, mjOBJ_GEOM, g);
      // A flash mesh over MuJoCo's face limit is written as several parts (sim::split_mesh).
      if (name && sim::is_mesh_part(name, "casting_flash")) model_->geom_rgba[4 * g + 3] = 0;
      if (follow && name && std::string(name) == "spindle") {
        model_->geom_matid[g] = -1;
        const float rgba[4] = {0.7f, 0.72f, 0.75f, 0.3f};
        std::copy(rgba, rgba + 4, model_->geom_rgba + 4 * g);
      }
    }
    flash_initial_ = grid.flash_voxels_initial();
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
  const int tcp = mj_name2id(m, mjOBJ_SITE, "tcp");
  const Vec3 tcp_W = tcp >= 0 ? site_position(d, tcp) : X_WC_.translation();
  Image img = [&] {
    if (!follow) return renderer_->render(d, opt_.camera, &overlay);
    sim::FreeCamera cam = follow_view(model_, d, X_WC_, tcp_W, opt_.follow_distance);
    // Smoothed (a fifth of the way per frame, the short way round) so the view does not jump.
    if (have_view_) {
      const double da = std::remainder(cam.azimuth - azimuth_, 360.0);
      azimuth_ += 0.2 * da;
      elevation_ += 0.2 * (cam.elevation - elevation_);
    } else {
      azimuth_ = cam.azimuth;
      elevation_ = cam.elevation;
      have_view_ = true;
    }
    cam.azimuth = azimuth_;
    cam.elevation = elevation_;
    return renderer_->render(d, cam, &overlay);
  }();
  const double speed =
      last_t_ >= 0 && t > last_t_ ? (tcp_W - last_tcp_W_).norm() / (t - last_t_) : 0.0;
  last_tcp_W_ = tcp_W;
  last_t_ = t;
  const int fs = mj_name2id(m, mjOBJ_SENSOR, "flange_force");
  const double force = fs >= 0 ? Vec3(d->sensordata[m->sensor_adr[fs]],
                                      d->sensordata[m->sensor_adr[fs] + 1],
                                      d->sensordata[m->sensor_adr[fs] + 2]).norm()
                               : 0.0;
  const double removed =
      flash_initial_ ? 1.0 - static_cast<double>(grid.flash_voxels_remaining()) /
                                 static_cast<double>(flash_initial_)
                     : 0.0;
  draw_overlay(img, t, speedup_, path, speed, force, removed);
  const auto& px = img.pixels();
  if (!ffmpeg_->write(px.data(), px.size()))
    throw IoError(opt_.path + ": ffmpeg stopped taking frames");
  ++frames_;
  next_t_ += speedup_ / opt_.fps;
  if (next_t_ < t) next_t_ = t + speedup_ / opt_.fps;
}

void VideoRecorder::new_setup() {
  renderer_.reset();
  if (model_) mj_deleteModel(model_);
  model_ = nullptr;
  flash_sample_C_.clear();
  have_view_ = false;
  last_t_ = -1;
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
