#pragma once
// Off-screen rendering of a MuJoCo model with OSMesa (no display needed): named cameras,
// optional coloured point overlay (scan points). Only sim/ and its tests include this.
#include <mujoco/mujoco.h>

#include <memory>
#include <string>
#include <vector>

#include "flashtwin/core/plot.hpp"
#include "flashtwin/core/transform.hpp"

namespace flashtwin::sim {

/// Points drawn into the scene as small spheres, in the world frame {W}. Each sphere is a
/// full tessellated geom drawn in every pass (shadow, reflection, colour): with software
/// OpenGL, tens of thousands of points cost seconds per frame.
struct PointOverlay {
  std::vector<Vec3> points_W;  ///< non-finite points are skipped
  std::vector<Rgb> colors;     ///< one per point, or one for all, or empty (= orange)
  double radius = 0.0008;      ///< [m], > 0 (a cube's half edge)
  /// Spheres, or cubes: 12 triangles instead of MuJoCo's ~900 per sphere, for many points in a
  /// software-rendered video (the remaining flash drawn as its voxels).
  bool cubes = false;
  int max_points = 20000;      ///< >= 0; evenly subsampled beyond this (and beyond the
                               ///< scene's free geom slots: MuJoCo scene geom budget)
};

/// A free camera (MuJoCo's mjCAMERA_FREE): it looks at `lookat_W` from `distance` away, its
/// viewing direction turned `azimuth` about +z from +x and tilted `elevation` above the
/// horizontal (negative: looking down).
struct FreeCamera {
  Vec3 lookat_W = Vec3::Zero();  ///< [m]
  double distance = 0.5;         ///< [m], > 0
  double azimuth = 0;            ///< [deg]
  double elevation = -30;        ///< [deg], within (-90, 90)
};

/// An OSMesa (software OpenGL) context plus MuJoCo's scene and rendering context for one
/// model; renders into MuJoCo's offscreen framebuffer, so no X display is needed.
///
/// Threads: an OpenGL context is current in at most one thread, and each thread has one
/// current context. Create, use and destroy a renderer in one thread; use one renderer per
/// thread (each render() re-binds its own context first, so several renderers used in turn
/// from the same thread also work, but never share one renderer between threads).
class OffscreenRenderer {
 public:
  /// Creates the contexts for `model`, rendering frames of width x height pixels.
  /// @pre `model` outlives the renderer and is not recompiled meanwhile.
  /// @throws ArgumentError when width or height is < 1 or exceeds the model's offscreen
  ///   buffer (<visual><global offwidth="..." offheight="..."/>).
  /// @throws std::runtime_error when the OSMesa context or MuJoCo's offscreen framebuffer
  ///   cannot be created. (MuJoCo itself aborts the process via mju_error if the OpenGL
  ///   implementation lacks what it needs; Mesa's llvmpipe has it.)
  OffscreenRenderer(const mjModel* model, int width, int height);
  ~OffscreenRenderer();
  OffscreenRenderer(const OffscreenRenderer&) = delete;
  OffscreenRenderer& operator=(const OffscreenRenderer&) = delete;

  /// Renders the state `data` (positions as left by mj_forward/mj_kinematics) from the named
  /// camera ("" = free camera looking at the model centre m->stat.center from
  /// 1.5 * m->stat.extent). Returns a width() x height() image, origin top-left.
  /// `data` keeps its state; MuJoCo borrows its scratch stack while building the scene, so
  /// no other thread may use `data` during the call.
  /// @throws InputError when no camera has that name.
  /// @throws ArgumentError when overlay->colors has neither 0, 1 nor one entry per point,
  ///   radius is not > 0 or max_points < 0.
  Image render(const mjData* data, const std::string& camera,
               const PointOverlay* overlay = nullptr);
  /// The same from a free camera. @throws ArgumentError when the camera is not finite or its
  /// distance is not > 0.
  Image render(const mjData* data, const FreeCamera& camera,
               const PointOverlay* overlay = nullptr);

  int width() const;
  int height() const;

  struct Impl;

 private:
  Image render_camera(const mjData* data, const mjvCamera& camera, const PointOverlay* overlay);
  std::unique_ptr<Impl> impl_;
};

}  // namespace flashtwin::sim
