#pragma once
// The run's video: OSMesa frames of the cell while the arm grinds, piped into ffmpeg (H.264
// MP4). The flash is drawn from the process model's voxel grid, so it visibly disappears where
// the burr has passed: the cell's static flash mesh is hidden and a fixed sample of the flash
// voxels is drawn as small cubes for as long as their voxel still holds flash. The default
// camera follows the burr from the side where the casting does not hide it (the spindle drawn
// translucent), and each frame carries an overlay: time, path, TCP speed, the flange F/T
// sensor's force and the share of the flash removed.
#include <memory>
#include <string>
#include <vector>

#include "flashtwin/core/subprocess.hpp"
#include "flashtwin/sim/executor.hpp"
#include "flashtwin/sim/process.hpp"

namespace flashtwin::sim {
class OffscreenRenderer;
}

namespace flashtwin::pipeline {

struct VideoOptions {
  std::string path;                       ///< output .mp4
  int width = 800, height = 600;          ///< [px], even numbers (H.264 4:2:0)
  int fps = 20;
  double length = 12;                     ///< [s] target video length: the run is sped up to fit
  /// "follow" (see above) or a camera of the cell ("casting_closeup", "overview", ...).
  std::string camera = "follow";
  double follow_distance = 0.25;          ///< [m] of the follow camera from the burr
  int flash_points = 1200;                ///< flash voxels drawn (each sphere costs render time)
  double point_radius = 0.0009;           ///< [m]
};

/// ffmpeg's argument vector for raw RGB24 frames of the options' size on standard input,
/// encoded to H.264 MP4 at options.path (passed as one argument: never through a shell).
std::vector<std::string> ffmpeg_arguments(const VideoOptions& options);

/// Collects frames during execution. Not copyable; one per run.
class VideoRecorder {
 public:
  /// @param sim_duration the simulated time the execution will take [s] (sets the speed-up)
  /// @throws ArgumentError (sizes, fps, length), IoError (ffmpeg cannot be started)
  VideoRecorder(const VideoOptions& options, double sim_duration);
  ~VideoRecorder();
  VideoRecorder(const VideoRecorder&) = delete;
  VideoRecorder& operator=(const VideoRecorder&) = delete;

  /// Called every simulation step; renders when the next frame is due (t: run time [s],
  /// path: the detected path being ground, for the overlay).
  void on_step(const mjModel* model, mjData* data, double t, const sim::MaterialGrid& grid,
               std::size_t path = 0);

  /// The part has been placed anew (a second setup, its own MuJoCo model): the next frame
  /// builds the scene from the model it is given, the casting's pose read again.
  void new_setup();

  /// Closes the stream; returns the number of frames. @throws IoError when ffmpeg failed.
  std::size_t finish();

  double speedup() const { return speedup_; }

 private:
  VideoOptions opt_;
  double speedup_ = 1, next_t_ = 0;
  std::size_t frames_ = 0;
  std::unique_ptr<PipedProcess> ffmpeg_;
  mjModel* model_ = nullptr;  ///< render copy (flash mesh hidden)
  std::unique_ptr<sim::OffscreenRenderer> renderer_;
  std::vector<Vec3> flash_sample_C_;
  Pose X_WC_ = Pose::Identity();
  // Follow camera: smoothed view angles [deg] and the previous TCP (for its speed).
  bool have_view_ = false;
  double azimuth_ = 0, elevation_ = -30;
  Vec3 last_tcp_W_ = Vec3::Zero();
  double last_t_ = -1;
  std::size_t flash_initial_ = 0;
};

}  // namespace flashtwin::pipeline
