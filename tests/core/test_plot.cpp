#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/plot.hpp"
#include "test_util.hpp"

using namespace flashtwin;

TEST(Plot, RendersSeriesIntoTheRequestedSizeAndWritesPng) {
  PlotSpec spec;
  spec.title = "sine";
  Series s;
  for (int i = 0; i < 100; ++i) {
    s.x.push_back(i * 0.1);
    s.y.push_back(std::sin(i * 0.1));
  }
  s.color = Rgb{255, 0, 0};
  spec.series.push_back(s);
  const Image img = render_plot(spec, 400, 300);
  ASSERT_EQ(img.width(), 400);
  ASSERT_EQ(img.height(), 300);
  // The red curve must actually be drawn.
  int red = 0;
  for (int y = 0; y < img.height(); ++y)
    for (int x = 0; x < img.width(); ++x) {
      const Rgb c = img.get(x, y);
      red += c.r > 200 && c.g < 60 && c.b < 60;
    }
  EXPECT_GT(red, 200);
  const std::string dir = ftest::temp_dir("plot");
  const std::string path = dir + "/p.png";
  write_png(path, img);
  EXPECT_GT(std::filesystem::file_size(path), 1000u);
  EXPECT_THROW(write_png("/nonexistent_dir/x.png", img), IoError);
}
