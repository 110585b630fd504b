#pragma once
// Minimal raster plotting to PNG (no external plotting library): scatter and line plots
// with axes, ticks, labels and a title, drawn with a built-in 5x7 bitmap font.
#include <array>
#include <cstdint>
#include <string>
#include <vector>

namespace flashtwin {

/// RGB colour, 8 bits per channel.
struct Rgb {
  std::uint8_t r = 0, g = 0, b = 0;
};

/// An RGB8 image, row-major, origin at the top-left pixel.
class Image {
 public:
  Image() = default;
  /// @pre width > 0, height > 0
  Image(int width, int height, Rgb fill = {255, 255, 255});
  int width() const { return width_; }
  int height() const { return height_; }
  /// Sets a pixel; coordinates outside the image are ignored.
  void set(int x, int y, Rgb c);
  /// Alpha-blends a pixel (alpha in [0,1]); outside the image is ignored.
  void blend(int x, int y, Rgb c, double alpha);
  Rgb get(int x, int y) const;
  void fill_rect(int x0, int y0, int x1, int y1, Rgb c);
  /// Bresenham line, `thickness` pixels wide.
  void line(int x0, int y0, int x1, int y1, Rgb c, int thickness = 1);
  /// Text with the built-in 5x7 font (ASCII 32..126), scaled by an integer `scale`;
  /// (x, y) is the top-left corner. Returns the width drawn in pixels.
  int text(int x, int y, const std::string& s, Rgb c, int scale = 1);
  /// Width in pixels that `text` would use.
  static int text_width(const std::string& s, int scale = 1);
  /// Pastes `other` with its top-left corner at (x, y).
  void paste(const Image& other, int x, int y);
  const std::vector<std::uint8_t>& pixels() const { return data_; }
  std::vector<std::uint8_t>& pixels() { return data_; }

 private:
  int width_ = 0, height_ = 0;
  std::vector<std::uint8_t> data_;  // width*height*3
};

/// Writes `img` as PNG. @throws IoError when the file cannot be written.
void write_png(const std::string& path, const Image& img);

/// One data series of a plot.
struct Series {
  std::vector<double> x, y;  ///< same length
  Rgb color{31, 119, 180};
  std::string label;          ///< shown in the legend when non-empty
  bool points = false;        ///< true: scatter dots; false: polyline
  int size = 1;               ///< dot radius or line thickness [px]
  double alpha = 1.0;         ///< dot opacity (dense scatter plots)
};

/// A 2-D plot panel: axes with "nice" ticks, labels, title, legend.
struct PlotSpec {
  std::string title, xlabel, ylabel;
  std::vector<Series> series;
  bool equal_aspect = false;  ///< same data units per pixel on both axes
  /// Optional fixed ranges; used when min < max.
  double xmin = 0, xmax = 0, ymin = 0, ymax = 0;
  /// Optional horizontal reference lines (e.g. a limit), drawn dashed.
  std::vector<std::pair<double, Rgb>> hlines;
};

/// Renders one panel into a width x height image.
Image render_plot(const PlotSpec& spec, int width, int height);

/// Stacks panels in a grid of `cols` columns, each panel w x h pixels.
Image render_grid(const std::vector<PlotSpec>& panels, int cols, int w, int h);

}  // namespace flashtwin
