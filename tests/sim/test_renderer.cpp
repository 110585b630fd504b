#include <gtest/gtest.h>

#include <functional>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/renderer.hpp"

using namespace flashtwin;

namespace {

// A floor, a red box "casting", a small blue marker box above it and a camera aimed at the
// casting from above and to the side (so "up" in the world is "up" in the image).
const char* const kScene = R"(
<mujoco model="render_test">
  <visual><global offwidth="800" offheight="600"/></visual>
  <worldbody>
    <light name="sun" directional="true" pos="0 0 3" dir="-0.2 0.3 -1" diffuse="0.8 0.8 0.8"/>
    <geom name="floor" type="plane" size="2 2 0.1" rgba="0.6 0.6 0.6 1"/>
    <body name="casting" pos="0 0 0.1">
      <geom name="casting_box" type="box" size="0.1 0.1 0.1" rgba="0.9 0.05 0.05 1"/>
    </body>
    <body name="marker" pos="0 0 0.32">
      <geom type="box" size="0.03 0.03 0.03" rgba="0.05 0.05 0.9 1"/>
    </body>
    <camera name="overview" mode="targetbody" target="casting" pos="0.9 -0.9 0.7"/>
  </worldbody>
</mujoco>
)";

struct Fixture {
  sim::MjModelPtr m = sim::load_mjcf_string(kScene, "render_test.xml");
  sim::MjDataPtr d = sim::make_data(m.get());
  Fixture() { mj_forward(m.get(), d.get()); }
};

int count_pixels(const Image& img, int x0, int y0, int x1, int y1,
                 const std::function<bool(Rgb)>& pred) {
  int n = 0;
  for (int y = y0; y < y1; ++y)
    for (int x = x0; x < x1; ++x) n += pred(img.get(x, y)) ? 1 : 0;
  return n;
}

bool reddish(Rgb c) {
  return c.r > 80 && c.r > 2 * c.g && c.r > 2 * c.b;
}
bool greenish(Rgb c) {
  return c.g > 80 && c.g > 2 * c.r && c.g > 2 * c.b;
}
bool bluish(Rgb c) {
  return c.b > 80 && c.b > 2 * c.r && c.b > 2 * c.g;
}

// Mean image row of the pixels satisfying `pred` (-1 when none).
double mean_row(const Image& img, const std::function<bool(Rgb)>& pred) {
  double sum = 0;
  int n = 0;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x)
      if (pred(img.get(x, y))) {
        sum += y;
        ++n;
      }
  return n ? sum / n : -1.0;
}

double luminance_variance(const Image& img) {
  double s = 0, s2 = 0;
  const auto& p = img.pixels();
  const std::size_t n = p.size() / 3;
  for (std::size_t i = 0; i < n; ++i) {
    const double l = 0.299 * p[3 * i] + 0.587 * p[3 * i + 1] + 0.114 * p[3 * i + 2];
    s += l;
    s2 += l * l;
  }
  const double mean = s / n;
  return s2 / n - mean * mean;
}

// A grid of points 0.3 m in front of camera `cam`, spanning 8 cm across its view axis.
sim::PointOverlay points_in_front_of_camera(const mjData* d, int cam, int side) {
  const Vec3 p_WC(d->cam_xpos[3 * cam], d->cam_xpos[3 * cam + 1], d->cam_xpos[3 * cam + 2]);
  Mat3 R_WC;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R_WC(r, c) = d->cam_xmat[9 * cam + 3 * r + c];
  // MuJoCo cameras look along their -z axis, x right, y up.
  sim::PointOverlay o;
  for (int i = 0; i < side; ++i)
    for (int j = 0; j < side; ++j) {
      const double u = -0.04 + 0.08 * i / (side - 1), v = -0.04 + 0.08 * j / (side - 1);
      o.points_W.push_back(p_WC + R_WC * Vec3(u, v, -0.3));
    }
  o.colors = {Rgb{20, 220, 20}};
  o.radius = 0.002;
  return o;
}

}  // namespace

TEST(Renderer, RendersNamedCameraAtRequestedSizeUprightAndLit) {
  Fixture f;
  sim::OffscreenRenderer r(f.m.get(), 640, 480);
  EXPECT_EQ(r.width(), 640);
  EXPECT_EQ(r.height(), 480);
  const Image img = r.render(f.d.get(), "overview");
  ASSERT_EQ(img.width(), 640);
  ASSERT_EQ(img.height(), 480);
  EXPECT_GT(luminance_variance(img), 100.0);

  // The camera targets the casting: the central 20% x 20% of the image is mostly red box.
  const int x0 = 640 * 2 / 5, x1 = 640 * 3 / 5, y0 = 480 * 2 / 5, y1 = 480 * 3 / 5;
  const int red = count_pixels(img, x0, y0, x1, y1, reddish);
  EXPECT_GT(red, (x1 - x0) * (y1 - y0) / 2) << "red pixels in the centre: " << red;

  // The blue marker sits above the casting in the world, so it is above it in the image
  // (rows counted from the top): checks the bottom-up OpenGL rows were flipped.
  const double row_red = mean_row(img, reddish), row_blue = mean_row(img, bluish);
  ASSERT_GE(row_blue, 0.0) << "blue marker not visible";
  EXPECT_LT(row_blue, row_red);
}

TEST(Renderer, FreeCameraSeesTheModel) {
  Fixture f;
  sim::OffscreenRenderer r(f.m.get(), 320, 240);
  const Image img = r.render(f.d.get(), "");
  ASSERT_EQ(img.width(), 320);
  EXPECT_GT(luminance_variance(img), 100.0);
  EXPECT_GT(count_pixels(img, 0, 0, 320, 240, reddish), 100);
}

TEST(Renderer, PointOverlayIsDrawnAndSubsampled) {
  Fixture f;
  sim::OffscreenRenderer r(f.m.get(), 640, 480);
  const int cam = sim::require_id(f.m.get(), mjOBJ_CAMERA, "overview");
  sim::PointOverlay o = points_in_front_of_camera(f.d.get(), cam, 20);  // 400 points

  const Image plain = r.render(f.d.get(), "overview");
  const Image with = r.render(f.d.get(), "overview", &o);
  EXPECT_EQ(count_pixels(plain, 0, 0, 640, 480, greenish), 0);
  const int green_all = count_pixels(with, 0, 0, 640, 480, greenish);
  EXPECT_GT(green_all, 400);

  // Fewer points drawn -> fewer green pixels; none drawn -> the plain frame exactly.
  o.max_points = 40;
  const int green_few = count_pixels(r.render(f.d.get(), "overview", &o), 0, 0, 640, 480, greenish);
  EXPECT_GT(green_few, 0);
  EXPECT_LT(green_few, green_all / 4);
  o.max_points = 0;
  EXPECT_EQ(r.render(f.d.get(), "overview", &o).pixels(), plain.pixels());

  // Per-point colours; a wrong number of colours is an argument error.
  o.max_points = 20000;
  o.colors.assign(o.points_W.size(), Rgb{20, 220, 20});
  EXPECT_EQ(r.render(f.d.get(), "overview", &o).pixels(), with.pixels());
  o.colors.resize(3);
  EXPECT_THROW(r.render(f.d.get(), "overview", &o), ArgumentError);
  o.colors.clear();
  o.radius = 0.0;
  EXPECT_THROW(r.render(f.d.get(), "overview", &o), ArgumentError);
}

TEST(Renderer, UnknownCameraThrowsInputError) {
  Fixture f;
  sim::OffscreenRenderer r(f.m.get(), 64, 48);
  EXPECT_THROW(r.render(f.d.get(), "no_such_camera"), InputError);
  try {
    r.render(f.d.get(), "no_such_camera");
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("overview"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("no_such_camera"), std::string::npos) << e.what();
  }
}

TEST(Renderer, SizeBeyondOffscreenBufferThrowsArgumentError) {
  Fixture f;
  EXPECT_THROW(sim::OffscreenRenderer(f.m.get(), 801, 600), ArgumentError);
  EXPECT_THROW(sim::OffscreenRenderer(f.m.get(), 800, 601), ArgumentError);
  EXPECT_THROW(sim::OffscreenRenderer(f.m.get(), 0, 100), ArgumentError);
  try {
    sim::OffscreenRenderer(f.m.get(), 1920, 1080);
    ADD_FAILURE() << "expected ArgumentError";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("1920x1080"), std::string::npos) << e.what();
    EXPECT_NE(std::string(e.what()).find("800x600"), std::string::npos) << e.what();
  }
  // The full buffer is allowed.
  sim::OffscreenRenderer r(f.m.get(), 800, 600);
  EXPECT_EQ(r.render(f.d.get(), "overview").width(), 800);
}

TEST(Renderer, SameStateRendersIdentically) {
  Fixture f;
  sim::OffscreenRenderer r(f.m.get(), 640, 480);
  const Image a = r.render(f.d.get(), "overview");
  const Image b = r.render(f.d.get(), "overview");
  EXPECT_EQ(a.pixels(), b.pixels());
}

TEST(Renderer, TwoRenderersInOneThreadTakeTurns) {
  // Each render re-binds its renderer's own OSMesa context.
  Fixture f;
  sim::OffscreenRenderer r1(f.m.get(), 320, 240);
  sim::OffscreenRenderer r2(f.m.get(), 320, 240);
  const Image a1 = r1.render(f.d.get(), "overview");
  const Image a2 = r2.render(f.d.get(), "overview");
  const Image b1 = r1.render(f.d.get(), "overview");
  EXPECT_EQ(a1.pixels(), a2.pixels());
  EXPECT_EQ(a1.pixels(), b1.pixels());
}
