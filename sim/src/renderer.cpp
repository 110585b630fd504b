// Off-screen rendering: an OSMesa (software OpenGL) context, MuJoCo's abstract scene and its
// OpenGL rendering context, drawing into MuJoCo's offscreen framebuffer object. Each C handle
// has its own small RAII owner; Impl declares them in creation order so that they are freed
// in reverse: scene, then MuJoCo's GL resources (with the context current), then the context.
#include "flashtwin/sim/renderer.hpp"

#include <GL/osmesa.h>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <stdexcept>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {
namespace {

// Scene geoms reserved for the model's own geoms, sites and decorations (contacts, frames,
// labels) on top of m->ngeom + m->nsite.
constexpr int kDecorGeoms = 2000;

// An OSMesa context with the client buffer it draws to. MuJoCo renders into its own
// framebuffer object, so this buffer only has to exist for OSMesaMakeCurrent.
class OsmesaContext {
 public:
  OsmesaContext(int width, int height)
      : width_(width),
        height_(height),
        buffer_(static_cast<std::size_t>(width) * static_cast<std::size_t>(height)) {
    ctx_ = OSMesaCreateContextExt(OSMESA_RGBA, 24, 8, 0, nullptr);
    if (!ctx_) throw std::runtime_error("renderer: OSMesaCreateContextExt(RGBA, 24, 8) failed");
    if (!make_current()) {
      OSMesaDestroyContext(ctx_);
      throw std::runtime_error("renderer: OSMesaMakeCurrent failed for a " + std::to_string(width) +
                               "x" + std::to_string(height) + " buffer");
    }
  }
  ~OsmesaContext() {
    // Unbind before destroying so the thread is not left with a dangling current context.
    if (OSMesaGetCurrentContext() == ctx_) OSMesaMakeCurrent(nullptr, nullptr, 0, 0, 0);
    OSMesaDestroyContext(ctx_);
  }
  OsmesaContext(const OsmesaContext&) = delete;
  OsmesaContext& operator=(const OsmesaContext&) = delete;

  /// Makes this context current on the calling thread (a no-op when it already is).
  bool make_current() noexcept {
    if (OSMesaGetCurrentContext() == ctx_) return true;
    return OSMesaMakeCurrent(ctx_, buffer_.data(), GL_UNSIGNED_BYTE, width_, height_) == GL_TRUE;
  }

 private:
  OSMesaContext ctx_ = nullptr;
  int width_, height_;
  std::vector<std::uint32_t> buffer_;  // RGBA8 pixels; uint32 keeps the 4-byte alignment
};

// MuJoCo's OpenGL resources (offscreen FBO, textures, meshes uploaded as display lists).
class RenderContext {
 public:
  /// @pre `gl` is current.
  RenderContext(const mjModel* m, OsmesaContext& gl) : gl_(gl) {
    mjr_defaultContext(&con_);
    mjr_makeContext(m, &con_, mjFONTSCALE_150);
    if (con_.offFBO == 0) {
      mjr_freeContext(&con_);
      throw std::runtime_error("renderer: MuJoCo could not create its offscreen framebuffer");
    }
    mjr_setBuffer(mjFB_OFFSCREEN, &con_);
    if (con_.currentBuffer != mjFB_OFFSCREEN) {
      mjr_freeContext(&con_);
      throw std::runtime_error("renderer: MuJoCo's offscreen framebuffer is not usable");
    }
  }
  ~RenderContext() {
    // glDelete* needs the owning context current. If it cannot be bound, destroying the
    // OSMesa context right after frees these GL objects anyway; mjrContext owns no heap.
    if (gl_.make_current()) mjr_freeContext(&con_);
  }
  RenderContext(const RenderContext&) = delete;
  RenderContext& operator=(const RenderContext&) = delete;

  mjrContext& get() { return con_; }

 private:
  OsmesaContext& gl_;
  mjrContext con_;
};

// MuJoCo's abstract scene (geom buffer); plain heap memory, no GL.
class Scene {
 public:
  Scene(const mjModel* m, int maxgeom) {
    mjv_defaultScene(&scn_);
    mjv_makeScene(m, &scn_, maxgeom);
  }
  ~Scene() { mjv_freeScene(&scn_); }
  Scene(const Scene&) = delete;
  Scene& operator=(const Scene&) = delete;

  mjvScene& get() { return scn_; }

 private:
  mjvScene scn_;
};

std::string size_text(int w, int h) {
  return std::to_string(w) + "x" + std::to_string(h);
}

// "'a', 'b'" for the error message of an unknown camera.
std::string camera_names(const mjModel* m) {
  std::string s;
  for (int i = 0; i < m->ncam; ++i) {
    const char* name = mj_id2name(m, mjOBJ_CAMERA, i);
    if (!s.empty()) s += ", ";
    if (name) {
      s.append(1, '\'').append(name).append(1, '\'');
    } else {
      s.append("#").append(std::to_string(i)).append(" (unnamed)");
    }
  }
  return s;
}

void check_overlay(const PointOverlay& o) {
  const std::size_t n = o.points_W.size();
  if (!(o.colors.empty() || o.colors.size() == 1 || o.colors.size() == n))
    throw ArgumentError("overlay.colors: expected 0, 1 or " + std::to_string(n) +
                        " colours (one per point), got " + std::to_string(o.colors.size()));
  if (!(o.radius > 0.0) || !std::isfinite(o.radius))
    throw ArgumentError("overlay.radius: expected a finite radius > 0 [m], got " +
                        std::to_string(o.radius));
  if (o.max_points < 0)
    throw ArgumentError("overlay.max_points: expected >= 0, got " + std::to_string(o.max_points));
}

// Appends the overlay's points as spheres after the model's geoms, evenly subsampled to
// the smaller of max_points and the scene's free geom slots.
void add_overlay(const PointOverlay& o, mjvScene& scn) {
  const std::size_t n = o.points_W.size();
  const std::size_t free_slots = static_cast<std::size_t>(std::max(0, scn.maxgeom - scn.ngeom));
  const std::size_t count = std::min({n, static_cast<std::size_t>(o.max_points), free_slots});
  if (count == 0) return;

  constexpr Rgb kOrange{255, 140, 0};
  const mjtNum size[3] = {o.radius, o.radius, o.radius};
  for (std::size_t k = 0; k < count; ++k) {
    // k * n / count spreads the picks over the whole cloud (scan order is spatial order).
    const std::size_t i = k * n / count;
    const Vec3& p = o.points_W[i];
    if (!p.allFinite()) continue;
    const Rgb c = o.colors.empty() ? kOrange : o.colors.size() == 1 ? o.colors[0] : o.colors[i];
    const float rgba[4] = {c.r / 255.0f, c.g / 255.0f, c.b / 255.0f, 1.0f};
    const mjtNum pos[3] = {p.x(), p.y(), p.z()};
    mjvGeom* g = &scn.geoms[scn.ngeom];
    mjv_initGeom(g, o.cubes ? mjGEOM_BOX : mjGEOM_SPHERE, size, pos, nullptr, rgba);
    // Decoration, not a model object: no selection, no segmentation label of its own.
    g->category = mjCAT_DECOR;
    g->objtype = mjOBJ_UNKNOWN;
    g->objid = -1;
    g->segid = scn.ngeom;
    ++scn.ngeom;
  }
}

}  // namespace

struct OffscreenRenderer::Impl {
  Impl(const mjModel* m, int w, int h)
      : model(m),
        width(w),
        height(h),
        gl(w, h),
        con(m, gl),
        scene(m, PointOverlay{}.max_points + kDecorGeoms + m->ngeom + m->nsite),
        rgb(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 3) {
    mjv_defaultOption(&opt);
    // Free camera: the model's centre from 1.5 extents, at the model's default view angles.
    mjv_defaultFreeCamera(m, &free_cam);
    free_cam.type = mjCAMERA_FREE;
    for (int k = 0; k < 3; ++k) free_cam.lookat[k] = m->stat.center[k];
    free_cam.distance = 1.5 * m->stat.extent;
  }

  const mjModel* model;
  int width, height;
  // Declaration order = creation order; destruction runs in reverse.
  OsmesaContext gl;
  RenderContext con;
  Scene scene;
  mjvOption opt;
  mjvCamera free_cam;
  std::vector<unsigned char> rgb;  // OpenGL rows, bottom-up
};

OffscreenRenderer::OffscreenRenderer(const mjModel* model, int width, int height) {
  FT_ASSERT(model != nullptr);
  const int off_w = model->vis.global.offwidth, off_h = model->vis.global.offheight;
  if (width < 1 || height < 1 || width > off_w || height > off_h)
    throw ArgumentError("renderer: expected an image size within the model's offscreen buffer " +
                        size_text(off_w, off_h) +
                        " (raise <visual><global offwidth/offheight> in the MJCF), got " +
                        size_text(width, height));
  impl_ = std::make_unique<Impl>(model, width, height);
}

OffscreenRenderer::~OffscreenRenderer() = default;

int OffscreenRenderer::width() const {
  return impl_->width;
}
int OffscreenRenderer::height() const {
  return impl_->height;
}

Image OffscreenRenderer::render(const mjData* data, const FreeCamera& camera,
                                const PointOverlay* overlay) {
  if (!camera.lookat_W.allFinite() || !(camera.distance > 0) || !std::isfinite(camera.azimuth) ||
      !(std::abs(camera.elevation) < 90))
    throw ArgumentError("renderer: expected a finite free camera with distance > 0 and "
                        "elevation within (-90, 90) deg");
  mjvCamera cam;
  mjv_defaultCamera(&cam);
  cam.type = mjCAMERA_FREE;
  for (int k = 0; k < 3; ++k) cam.lookat[k] = camera.lookat_W[k];
  cam.distance = camera.distance;
  cam.azimuth = camera.azimuth;
  cam.elevation = camera.elevation;
  return render_camera(data, cam, overlay);
}

Image OffscreenRenderer::render(const mjData* data, const std::string& camera,
                                const PointOverlay* overlay) {
  FT_ASSERT(data != nullptr);
  const mjModel* m = impl_->model;
  mjvCamera cam = impl_->free_cam;
  if (!camera.empty()) {
    const int id = mj_name2id(m, mjOBJ_CAMERA, camera.c_str());
    if (id < 0) {
      const std::string names = camera_names(m);
      throw InputError(
          "renderer: expected a camera of the model (" +
          (names.empty() ? std::string("it has none; \"\" is the free camera") : names) +
          "), got '" + camera + "'");
    }
    mjv_defaultCamera(&cam);
    cam.type = mjCAMERA_FIXED;
    cam.fixedcamid = id;
  }
  return render_camera(data, cam, overlay);
}

Image OffscreenRenderer::render_camera(const mjData* data, const mjvCamera& camera,
                                       const PointOverlay* overlay) {
  FT_ASSERT(data != nullptr);
  Impl& s = *impl_;
  const mjModel* m = s.model;
  mjvCamera cam = camera;
  // Validate everything before touching OpenGL.
  if (overlay) check_overlay(*overlay);

  // Another renderer of this thread may have bound its own context since the last frame.
  if (!s.gl.make_current())
    throw std::runtime_error(
        "renderer: OSMesaMakeCurrent failed (is the renderer used from "
        "another thread than the one that created it?)");
  mjrContext& con = s.con.get();
  mjr_setBuffer(mjFB_OFFSCREEN, &con);

  // mjv_updateScene takes mjData* only to borrow its scratch stack (restored on return);
  // the simulation state is read, not written.
  mjvScene& scn = s.scene.get();
  mjv_updateScene(m, const_cast<mjData*>(data), &s.opt, nullptr, &cam, mjCAT_ALL, &scn);
  if (overlay) add_overlay(*overlay, scn);

  const mjrRect viewport{0, 0, s.width, s.height};
  mjr_render(viewport, &scn, &con);
  mjr_readPixels(s.rgb.data(), nullptr, viewport, &con);

  // OpenGL's first row is the bottom one; Image's is the top one.
  Image img(s.width, s.height);
  const std::size_t row = static_cast<std::size_t>(s.width) * 3;
  for (int y = 0; y < s.height; ++y)
    std::memcpy(img.pixels().data() + static_cast<std::size_t>(y) * row,
                s.rgb.data() + static_cast<std::size_t>(s.height - 1 - y) * row, row);
  return img;
}

}  // namespace flashtwin::sim
