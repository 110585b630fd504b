// Raster plotting to PNG: an RGB8 image with clipped primitives, a built-in 5x7 bitmap font,
// and line/scatter plot panels with "nice" ticks. Everything clips against the image, so no
// input (NaN, huge values, tiny images) can write out of bounds.
#include "flashtwin/core/plot.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <limits>
#include <utility>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

#include <zlib.h>

// zlib deflates the PNG data: stb's own deflate took most of the time of writing a plot.
namespace {
unsigned char* zlib_deflate(unsigned char* data, int size, int* out_size, int /*quality*/) {
  uLongf n = compressBound(static_cast<uLong>(size));
  auto* out = static_cast<unsigned char*>(std::malloc(n));  // freed by stb with free()
  if (out && compress2(out, &n, data, static_cast<uLong>(size), Z_DEFAULT_COMPRESSION) != Z_OK) {
    std::free(out);
    out = nullptr;
  }
  *out_size = out ? static_cast<int>(n) : 0;
  return out;
}
}  // namespace
#define STBIW_ZLIB_COMPRESS zlib_deflate

// Header-only library: this is the one translation unit that instantiates it. STATIC keeps
// its symbols private so another component embedding stb cannot clash at link time.
#define STB_IMAGE_WRITE_IMPLEMENTATION
#define STB_IMAGE_WRITE_STATIC
#pragma GCC diagnostic push
#pragma GCC diagnostic ignored "-Wmissing-field-initializers"
#pragma GCC diagnostic ignored "-Wunused-function"
#include <stb/stb_image_write.h>
#pragma GCC diagnostic pop

namespace flashtwin {
namespace {

// ---- Font ---------------------------------------------------------------------------------

using Glyph = std::array<std::uint8_t, 7>;  // 7 rows, 5 bits each, bit 4 = leftmost column

// ASCII 32..126. Lowercase g, p, q and y are drawn one row lower (into the spacing row of the
// 8-px cell) so their bowls sit on the baseline and they don't read as 9, P, 9 and 4.
constexpr std::array<Glyph, 95> kFont = {{
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x00},  // ' '
    {0x04, 0x04, 0x04, 0x04, 0x04, 0x00, 0x04},  // !
    {0x0A, 0x0A, 0x0A, 0x00, 0x00, 0x00, 0x00},  // "
    {0x0A, 0x0A, 0x1F, 0x0A, 0x1F, 0x0A, 0x0A},  // #
    {0x04, 0x0F, 0x14, 0x0E, 0x05, 0x1E, 0x04},  // $
    {0x18, 0x19, 0x02, 0x04, 0x08, 0x13, 0x03},  // %
    {0x0C, 0x12, 0x14, 0x08, 0x15, 0x12, 0x0D},  // &
    {0x04, 0x04, 0x08, 0x00, 0x00, 0x00, 0x00},  // '
    {0x02, 0x04, 0x08, 0x08, 0x08, 0x04, 0x02},  // (
    {0x08, 0x04, 0x02, 0x02, 0x02, 0x04, 0x08},  // )
    {0x00, 0x04, 0x15, 0x0E, 0x15, 0x04, 0x00},  // *
    {0x00, 0x04, 0x04, 0x1F, 0x04, 0x04, 0x00},  // +
    {0x00, 0x00, 0x00, 0x00, 0x0C, 0x04, 0x08},  // ,
    {0x00, 0x00, 0x00, 0x1F, 0x00, 0x00, 0x00},  // -
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x0C, 0x0C},  // .
    {0x01, 0x01, 0x02, 0x04, 0x08, 0x10, 0x10},  // /
    {0x0E, 0x11, 0x13, 0x15, 0x19, 0x11, 0x0E},  // 0
    {0x04, 0x0C, 0x04, 0x04, 0x04, 0x04, 0x0E},  // 1
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x08, 0x1F},  // 2
    {0x1F, 0x02, 0x04, 0x02, 0x01, 0x11, 0x0E},  // 3
    {0x02, 0x06, 0x0A, 0x12, 0x1F, 0x02, 0x02},  // 4
    {0x1F, 0x10, 0x1E, 0x01, 0x01, 0x11, 0x0E},  // 5
    {0x06, 0x08, 0x10, 0x1E, 0x11, 0x11, 0x0E},  // 6
    {0x1F, 0x01, 0x02, 0x04, 0x08, 0x08, 0x08},  // 7
    {0x0E, 0x11, 0x11, 0x0E, 0x11, 0x11, 0x0E},  // 8
    {0x0E, 0x11, 0x11, 0x0F, 0x01, 0x02, 0x0C},  // 9
    {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x0C, 0x00},  // :
    {0x00, 0x0C, 0x0C, 0x00, 0x0C, 0x04, 0x08},  // ;
    {0x02, 0x04, 0x08, 0x10, 0x08, 0x04, 0x02},  // <
    {0x00, 0x00, 0x1F, 0x00, 0x1F, 0x00, 0x00},  // =
    {0x08, 0x04, 0x02, 0x01, 0x02, 0x04, 0x08},  // >
    {0x0E, 0x11, 0x01, 0x02, 0x04, 0x00, 0x04},  // ?
    {0x0E, 0x11, 0x01, 0x0D, 0x15, 0x15, 0x0E},  // @
    {0x0E, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11},  // A
    {0x1E, 0x11, 0x11, 0x1E, 0x11, 0x11, 0x1E},  // B
    {0x0E, 0x11, 0x10, 0x10, 0x10, 0x11, 0x0E},  // C
    {0x1C, 0x12, 0x11, 0x11, 0x11, 0x12, 0x1C},  // D
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x1F},  // E
    {0x1F, 0x10, 0x10, 0x1E, 0x10, 0x10, 0x10},  // F
    {0x0E, 0x11, 0x10, 0x17, 0x11, 0x11, 0x0F},  // G
    {0x11, 0x11, 0x11, 0x1F, 0x11, 0x11, 0x11},  // H
    {0x0E, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},  // I
    {0x07, 0x02, 0x02, 0x02, 0x02, 0x12, 0x0C},  // J
    {0x11, 0x12, 0x14, 0x18, 0x14, 0x12, 0x11},  // K
    {0x10, 0x10, 0x10, 0x10, 0x10, 0x10, 0x1F},  // L
    {0x11, 0x1B, 0x15, 0x15, 0x11, 0x11, 0x11},  // M
    {0x11, 0x11, 0x19, 0x15, 0x13, 0x11, 0x11},  // N
    {0x0E, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},  // O
    {0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10, 0x10},  // P
    {0x0E, 0x11, 0x11, 0x11, 0x15, 0x12, 0x0D},  // Q
    {0x1E, 0x11, 0x11, 0x1E, 0x14, 0x12, 0x11},  // R
    {0x0F, 0x10, 0x10, 0x0E, 0x01, 0x01, 0x1E},  // S
    {0x1F, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},  // T
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x11, 0x0E},  // U
    {0x11, 0x11, 0x11, 0x11, 0x11, 0x0A, 0x04},  // V
    {0x11, 0x11, 0x11, 0x15, 0x15, 0x15, 0x0A},  // W
    {0x11, 0x11, 0x0A, 0x04, 0x0A, 0x11, 0x11},  // X
    {0x11, 0x11, 0x11, 0x0A, 0x04, 0x04, 0x04},  // Y
    {0x1F, 0x01, 0x02, 0x04, 0x08, 0x10, 0x1F},  // Z
    {0x0E, 0x08, 0x08, 0x08, 0x08, 0x08, 0x0E},  // [
    {0x10, 0x10, 0x08, 0x04, 0x02, 0x01, 0x01},  // backslash
    {0x0E, 0x02, 0x02, 0x02, 0x02, 0x02, 0x0E},  // ]
    {0x04, 0x0A, 0x11, 0x00, 0x00, 0x00, 0x00},  // ^
    {0x00, 0x00, 0x00, 0x00, 0x00, 0x00, 0x1F},  // _
    {0x08, 0x04, 0x02, 0x00, 0x00, 0x00, 0x00},  // `
    {0x00, 0x00, 0x0E, 0x01, 0x0F, 0x11, 0x0F},  // a
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x1E},  // b
    {0x00, 0x00, 0x0E, 0x10, 0x10, 0x11, 0x0E},  // c
    {0x01, 0x01, 0x0D, 0x13, 0x11, 0x11, 0x0F},  // d
    {0x00, 0x00, 0x0E, 0x11, 0x1F, 0x10, 0x0E},  // e
    {0x06, 0x09, 0x08, 0x1C, 0x08, 0x08, 0x08},  // f
    {0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x0E},  // g (descender: drawn one row lower)
    {0x10, 0x10, 0x16, 0x19, 0x11, 0x11, 0x11},  // h
    {0x04, 0x00, 0x0C, 0x04, 0x04, 0x04, 0x0E},  // i
    {0x02, 0x00, 0x06, 0x02, 0x02, 0x12, 0x0C},  // j
    {0x10, 0x10, 0x12, 0x14, 0x18, 0x14, 0x12},  // k
    {0x0C, 0x04, 0x04, 0x04, 0x04, 0x04, 0x0E},  // l
    {0x00, 0x00, 0x1A, 0x15, 0x15, 0x11, 0x11},  // m
    {0x00, 0x00, 0x16, 0x19, 0x11, 0x11, 0x11},  // n
    {0x00, 0x00, 0x0E, 0x11, 0x11, 0x11, 0x0E},  // o
    {0x00, 0x1E, 0x11, 0x11, 0x1E, 0x10, 0x10},  // p (descender)
    {0x00, 0x0F, 0x11, 0x11, 0x0F, 0x01, 0x01},  // q (descender)
    {0x00, 0x00, 0x16, 0x19, 0x10, 0x10, 0x10},  // r
    {0x00, 0x00, 0x0E, 0x10, 0x0E, 0x01, 0x1E},  // s
    {0x08, 0x08, 0x1C, 0x08, 0x08, 0x09, 0x06},  // t
    {0x00, 0x00, 0x11, 0x11, 0x11, 0x13, 0x0D},  // u
    {0x00, 0x00, 0x11, 0x11, 0x11, 0x0A, 0x04},  // v
    {0x00, 0x00, 0x11, 0x11, 0x15, 0x15, 0x0A},  // w
    {0x00, 0x00, 0x11, 0x0A, 0x04, 0x0A, 0x11},  // x
    {0x00, 0x11, 0x11, 0x11, 0x0F, 0x01, 0x0E},  // y (descender)
    {0x00, 0x00, 0x1F, 0x02, 0x04, 0x08, 0x1F},  // z
    {0x02, 0x04, 0x04, 0x08, 0x04, 0x04, 0x02},  // {
    {0x04, 0x04, 0x04, 0x04, 0x04, 0x04, 0x04},  // |
    {0x08, 0x04, 0x04, 0x02, 0x04, 0x04, 0x08},  // }
    {0x00, 0x00, 0x08, 0x15, 0x02, 0x00, 0x00},  // ~
}};
constexpr Glyph kDegree = {0x0C, 0x12, 0x12, 0x0C, 0x00, 0x00, 0x00};
constexpr int kCellW = 6, kCellH = 8;  // glyph plus one pixel of spacing

// Decodes `s` into glyphs: ASCII 32..126 as is, the degree sign (UTF-8 C2 B0, or a lone Latin-1
// B0) as a small ring, and every other code point or control byte as '?'. One glyph per code
// point keeps text_width() consistent with what text() draws.
std::vector<const Glyph*> glyphs(const std::string& s) {
  std::vector<const Glyph*> out;
  const Glyph* unknown = &kFont['?' - 32];
  for (std::size_t i = 0; i < s.size(); ++i) {
    const auto b = static_cast<unsigned char>(s[i]);
    if (b < 0x80) {
      out.push_back(b >= 32 && b <= 126 ? &kFont[b - 32] : unknown);
    } else if (b == 0xC2 && i + 1 < s.size() && static_cast<unsigned char>(s[i + 1]) == 0xB0) {
      out.push_back(&kDegree);
      ++i;
    } else if (b >= 0xC0) {  // UTF-8 lead byte: swallow its continuation bytes
      while (i + 1 < s.size() && (static_cast<unsigned char>(s[i + 1]) & 0xC0) == 0x80) ++i;
      out.push_back(unknown);
    } else {
      out.push_back(b == 0xB0 ? &kDegree : unknown);
    }
  }
  return out;
}

// Row offset of a glyph: descenders start one row lower (see kFont).
int glyph_drop(const Glyph* g) {
  for (char ch : {'g', 'p', 'q', 'y'}) {
    if (g == &kFont[ch - 32]) return 1;
  }
  return 0;
}

// Text rotated 90 degrees counter-clockwise (reads bottom to top, as y-axis labels do);
// (x, y) is the bottom-left corner of the rotated string.
void text_vertical(Image& img, int x, int y, const std::string& s, Rgb c) {
  int u = 0;  // position along the text, growing upwards on screen
  for (const Glyph* g : glyphs(s)) {
    const int drop = glyph_drop(g);
    for (int row = 0; row < 7; ++row) {
      for (int col = 0; col < 5; ++col) {
        if (((*g)[row] >> (4 - col)) & 1) img.set(x + row + drop, y - (u + col), c);
      }
    }
    u += kCellW;
  }
}

// ---- Geometry -----------------------------------------------------------------------------

// Liang-Barsky clipping of a segment to a rectangle; false when nothing remains. Keeps the
// integer rasteriser from walking millions of off-image pixels for far-away endpoints.
bool clip_segment(double& x0, double& y0, double& x1, double& y1, double xmin, double ymin,
                  double xmax, double ymax) {
  const double dx = x1 - x0, dy = y1 - y0;
  const double p[4] = {-dx, dx, -dy, dy};
  const double q[4] = {x0 - xmin, xmax - x0, y0 - ymin, ymax - y0};
  double t0 = 0.0, t1 = 1.0;
  for (int i = 0; i < 4; ++i) {
    if (p[i] == 0.0) {
      if (q[i] < 0.0) return false;  // parallel to and outside this edge
      continue;
    }
    const double t = q[i] / p[i];
    if (p[i] < 0.0) {
      if (t > t1) return false;
      t0 = std::max(t0, t);
    } else {
      if (t < t0) return false;
      t1 = std::min(t1, t);
    }
  }
  const double ax = x0, ay = y0;
  x0 = ax + t0 * dx;
  y0 = ay + t0 * dy;
  x1 = ax + t1 * dx;
  y1 = ay + t1 * dy;
  return true;
}

// Filled disc of radius r centred at (cx, cy), alpha-blended pixel by pixel.
void disc(Image& img, double cx, double cy, int r, Rgb c, double alpha) {
  r = std::clamp(r, 0, 64);
  if (!(cx > -r - 1 && cy > -r - 1 && cx < img.width() + r && cy < img.height() + r)) return;
  const int ix = static_cast<int>(std::lround(cx)), iy = static_cast<int>(std::lround(cy));
  for (int dy = -r; dy <= r; ++dy) {
    for (int dx = -r; dx <= r; ++dx) {
      if (dx * dx + dy * dy <= r * r + r) img.blend(ix + dx, iy + dy, c, alpha);
    }
  }
}

// ---- Axes ---------------------------------------------------------------------------------

struct Range {
  double lo = 0, hi = 1;
  double span() const { return hi - lo; }
};

// Makes [lo, hi] usable for division and tick generation: finite span, and non-degenerate
// (constant data is widened by +-|v|*0.1, or +-1 around zero).
Range sanitize(double lo, double hi) {
  constexpr double kBig = 1e307;  // keeps hi - lo (and padding) finite
  lo = std::clamp(lo, -kBig, kBig);
  hi = std::clamp(hi, -kBig, kBig);
  const double mid = 0.5 * lo + 0.5 * hi;
  if (hi - lo <= std::abs(mid) * 1e-12) {
    const double d = mid == 0.0 ? 1.0 : std::abs(mid) * 0.1;
    lo = mid - d;
    hi = mid + d;
  }
  return {lo, hi};
}

// Fixed range when the spec gives a valid one, else data extent plus 5% padding; [0, 1] when
// there is no finite data at all. hlines count as y data so reference lines stay visible.
Range axis_range(const PlotSpec& spec, bool x_axis) {
  const double fmin = x_axis ? spec.xmin : spec.ymin, fmax = x_axis ? spec.xmax : spec.ymax;
  if (std::isfinite(fmin) && std::isfinite(fmax) && fmin < fmax) return sanitize(fmin, fmax);
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const Series& s : spec.series) {
    const std::size_t n = std::min(s.x.size(), s.y.size());
    for (std::size_t i = 0; i < n; ++i) {
      if (!std::isfinite(s.x[i]) || !std::isfinite(s.y[i])) continue;
      const double v = x_axis ? s.x[i] : s.y[i];
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  if (!x_axis) {
    for (const auto& [v, c] : spec.hlines) {
      if (!std::isfinite(v)) continue;
      lo = std::min(lo, v);
      hi = std::max(hi, v);
    }
  }
  if (lo > hi) return {0.0, 1.0};
  const Range r = sanitize(lo, hi);
  const double pad = 0.05 * r.span();
  return {r.lo - pad, r.hi + pad};
}

// Smallest 1/2/5 x 10^k that is >= raw (raw > 0).
double nice_step(double raw) {
  const double mag = std::pow(10.0, std::floor(std::log10(raw)));
  const double f = raw / mag;
  const double m = f <= 1.0 + 1e-9 ? 1.0 : f <= 2.0 + 1e-9 ? 2.0 : f <= 5.0 + 1e-9 ? 5.0 : 10.0;
  return m * mag;
}

std::string fmt(const char* spec, int prec, double v) {
  char buf[400];  // %f of 1e307 needs ~330 characters
  std::snprintf(buf, sizeof buf, spec, prec, v);
  return buf;
}

// Labels as short as possible: fixed notation with just enough decimals for the step, or
// exponent notation ("1e+03", "2.5e-05") only when that is clearly shorter.
std::vector<std::string> tick_labels(const std::vector<double>& ticks, double step) {
  const int e = static_cast<int>(std::floor(std::log10(step) + 1e-9));
  double maxabs = 0.0;
  for (double t : ticks) maxabs = std::max(maxabs, std::abs(t));
  const int mant = maxabs > 0.0 ? static_cast<int>(std::floor(std::log10(maxabs))) - e : 0;
  std::vector<std::string> fixed, expo;
  std::size_t fixed_len = 0, expo_len = 0;
  for (double t : ticks) {
    fixed.push_back(fmt("%.*f", std::clamp(-e, 0, 20), t));
    std::string s = fmt("%.*e", std::clamp(mant, 0, 15), t);
    const std::size_t epos = s.find('e');
    if (epos != std::string::npos && s.find('.') < epos) {  // "1.500e+03" -> "1.5e+03"
      std::size_t cut = epos;
      while (s[cut - 1] == '0') --cut;
      if (s[cut - 1] == '.') --cut;
      s.erase(cut, epos - cut);
    }
    if (t == 0.0) s = "0";
    expo.push_back(s);
    fixed_len = std::max(fixed_len, fixed.back().size());
    expo_len = std::max(expo_len, s.size());
  }
  return fixed_len <= 6 || fixed_len <= expo_len ? fixed : expo;
}

struct Axis {
  std::vector<double> ticks;
  std::vector<std::string> labels;
  int label_w = 0;  // widest label [px]
};

// Ticks at multiples of a nice step, aiming at one tick per ~80 px (x) or ~45 px (y), then
// coarsened until neighbouring labels no longer collide.
Axis make_axis(Range r, int length_px, bool horizontal) {
  Axis a;
  const double len = std::max(1, length_px);
  double step = nice_step(r.span() / std::max(1.0, len / (horizontal ? 80.0 : 45.0)));
  for (int iter = 0; iter < 10; ++iter) {
    a = Axis{};
    const double first = std::ceil(r.lo / step - 1e-9), last = std::floor(r.hi / step + 1e-9);
    if (!(last - first < 200.0)) {  // float resolution exhausted (or NaN): try coarser
      step = nice_step(step * 1.5);
      continue;
    }
    for (double k = first; k <= last; ++k) {
      const double v = k * step;
      a.ticks.push_back(std::abs(v) < step * 1e-9 ? 0.0 : v);  // avoid "-0" and 1e-17
    }
    a.labels = tick_labels(a.ticks, step);
    for (const auto& s : a.labels) a.label_w = std::max(a.label_w, Image::text_width(s));
    const double spacing = step / r.span() * len;
    const double need = horizontal ? a.label_w + 10.0 : kCellH + 6.0;
    if (spacing >= need || a.ticks.size() <= 2) break;
    step = nice_step(step * 1.5);  // next 1/2/5 value
  }
  return a;
}

// Grows the range with fewer data units per pixel so both axes share one scale.
void equalize(Range& xr, Range& yr, int pw, int ph) {
  const double wx = std::max(1, pw - 1), wy = std::max(1, ph - 1);
  const double upp = std::max(xr.span() / wx, yr.span() / wy);
  const double cx = 0.5 * (xr.lo + xr.hi), cy = 0.5 * (yr.lo + yr.hi);
  xr = {cx - 0.5 * upp * wx, cx + 0.5 * upp * wx};
  yr = {cy - 0.5 * upp * wy, cy + 0.5 * upp * wy};
}

constexpr Rgb kText{20, 20, 20}, kFrame{60, 60, 60}, kGrid{225, 225, 225};
constexpr Rgb kWhite{255, 255, 255};
constexpr int kTick = 4;  // tick mark length [px]

}  // namespace

// ---- Image --------------------------------------------------------------------------------

Image::Image(int width, int height, Rgb fill) : width_(width), height_(height) {
  FT_ASSERT(width > 0 && height > 0);
  data_.resize(static_cast<std::size_t>(width) * static_cast<std::size_t>(height) * 3);
  for (std::size_t i = 0; i < data_.size(); i += 3) {
    data_[i] = fill.r;
    data_[i + 1] = fill.g;
    data_[i + 2] = fill.b;
  }
}

void Image::set(int x, int y, Rgb c) {
  if (x < 0 || y < 0 || x >= width_ || y >= height_) return;
  const std::size_t i = (static_cast<std::size_t>(y) * width_ + x) * 3;
  data_[i] = c.r;
  data_[i + 1] = c.g;
  data_[i + 2] = c.b;
}

void Image::blend(int x, int y, Rgb c, double alpha) {
  if (x < 0 || y < 0 || x >= width_ || y >= height_ || !(alpha > 0.0)) return;
  alpha = std::min(alpha, 1.0);
  const std::size_t i = (static_cast<std::size_t>(y) * width_ + x) * 3;
  const auto mix = [alpha](std::uint8_t old, std::uint8_t v) {
    return static_cast<std::uint8_t>(std::lround(v * alpha + old * (1.0 - alpha)));
  };
  data_[i] = mix(data_[i], c.r);
  data_[i + 1] = mix(data_[i + 1], c.g);
  data_[i + 2] = mix(data_[i + 2], c.b);
}

// Outside the image reads as black rather than failing.
Rgb Image::get(int x, int y) const {
  if (x < 0 || y < 0 || x >= width_ || y >= height_) return {};
  const std::size_t i = (static_cast<std::size_t>(y) * width_ + x) * 3;
  return {data_[i], data_[i + 1], data_[i + 2]};
}

// Corners are inclusive and may come in any order.
void Image::fill_rect(int x0, int y0, int x1, int y1, Rgb c) {
  if (x0 > x1) std::swap(x0, x1);
  if (y0 > y1) std::swap(y0, y1);
  x0 = std::max(x0, 0);
  y0 = std::max(y0, 0);
  x1 = std::min(x1, width_ - 1);
  y1 = std::min(y1, height_ - 1);
  for (int y = y0; y <= y1; ++y) {
    for (int x = x0; x <= x1; ++x) set(x, y, c);
  }
}

void Image::line(int x0, int y0, int x1, int y1, Rgb c, int thickness) {
  thickness = std::clamp(thickness, 1, 64);
  double ax = x0, ay = y0, bx = x1, by = y1;  // doubles: x1 - x0 may overflow int
  const double m = thickness;
  if (!clip_segment(ax, ay, bx, by, -m, -m, width_ - 1 + m, height_ - 1 + m)) return;
  int x = static_cast<int>(std::lround(ax)), y = static_cast<int>(std::lround(ay));
  const int xe = static_cast<int>(std::lround(bx)), ye = static_cast<int>(std::lround(by));
  const int dx = std::abs(xe - x), dy = -std::abs(ye - y);
  const int sx = x < xe ? 1 : -1, sy = y < ye ? 1 : -1;
  const int lo = (thickness - 1) / 2, hi = thickness / 2;  // square pen, `thickness` wide
  int err = dx + dy;
  for (;;) {
    if (thickness == 1) {
      set(x, y, c);
    } else {
      fill_rect(x - lo, y - lo, x + hi, y + hi, c);
    }
    if (x == xe && y == ye) break;
    const int e2 = 2 * err;
    if (e2 >= dy) {
      err += dy;
      x += sx;
    }
    if (e2 <= dx) {
      err += dx;
      y += sy;
    }
  }
}

int Image::text(int x, int y, const std::string& s, Rgb c, int scale) {
  scale = std::clamp(scale, 1, 64);
  int cx = x;
  for (const Glyph* g : glyphs(s)) {
    const int drop = glyph_drop(g);
    for (int row = 0; row < 7; ++row) {
      for (int col = 0; col < 5; ++col) {
        if (!(((*g)[row] >> (4 - col)) & 1)) continue;
        const int px = cx + col * scale, py = y + (row + drop) * scale;
        fill_rect(px, py, px + scale - 1, py + scale - 1, c);
      }
    }
    cx += kCellW * scale;
  }
  return cx - x;
}

int Image::text_width(const std::string& s, int scale) {
  return static_cast<int>(glyphs(s).size()) * kCellW * std::clamp(scale, 1, 64);
}

void Image::paste(const Image& other, int x, int y) {
  for (int sy = 0; sy < other.height_; ++sy) {
    const int ty = y + sy;
    if (ty < 0 || ty >= height_) continue;
    for (int sx = 0; sx < other.width_; ++sx) set(x + sx, ty, other.get(sx, sy));
  }
}

void write_png(const std::string& path, const Image& img) {
  if (img.width() <= 0 || img.height() <= 0) {
    throw IoError(path + ": cannot write PNG of an empty image");
  }
  int size = 0;
  unsigned char* png = stbi_write_png_to_mem(img.pixels().data(), img.width() * 3, img.width(),
                                             img.height(), 3, &size);
  if (!png) throw IoError(path + ": cannot encode the PNG (out of memory)");
  const std::string bytes(reinterpret_cast<const char*>(png), static_cast<std::size_t>(size));
  std::free(png);
  write_text_file(path, bytes);  // atomic: never a half-written image
}

// ---- Plots --------------------------------------------------------------------------------

Image render_plot(const PlotSpec& spec, int width, int height) {
  width = std::max(width, 1);
  height = std::max(height, 1);
  Image img(width, height);

  // Vertical layout is fixed by text heights; the left margin depends on the y tick labels,
  // which depend (with equal_aspect) on the plot width, so iterate a few times to settle.
  const int title_scale = Image::text_width(spec.title, 2) <= width - 8 ? 2 : 1;
  const int top = spec.title.empty() ? 10 : kCellH * title_scale + 12;
  const int bottom = kTick + 4 + kCellH + (spec.xlabel.empty() ? 0 : kCellH + 6) + 6;
  const int right = 16;
  const Range base_x = axis_range(spec, true), base_y = axis_range(spec, false);
  const int ph = std::max(1, height - top - bottom);
  Range xr = base_x, yr = base_y;
  Axis ay;
  int left = 50, pw = 1;
  for (int pass = 0; pass < 3; ++pass) {
    pw = std::max(1, width - left - right);
    xr = base_x;
    yr = base_y;
    if (spec.equal_aspect) equalize(xr, yr, pw, ph);
    ay = make_axis(yr, ph, false);
    const int want = 6 + (spec.ylabel.empty() ? 0 : kCellH + 6) + ay.label_w + kTick + 4;
    left = std::min(want, width / 2);  // tiny images keep some room for the data
  }
  pw = std::max(1, width - left - right);
  const Axis ax = make_axis(xr, pw, true);

  // Data to plot-area pixels; far-off values are clamped so clipping stays in float range.
  const auto frac = [](double v, const Range& r) {
    const double d = v - r.lo;  // may overflow for values near DBL_MAX: divide first then
    return std::isfinite(d) ? d / r.span() : v / r.span() - r.lo / r.span();
  };
  const auto to_px = [&](double x, double y, double& px, double& py) {
    if (!std::isfinite(x) || !std::isfinite(y)) return false;
    px = frac(x, xr) * (pw - 1);
    py = (ph - 1) - frac(y, yr) * (ph - 1);
    if (!std::isfinite(px) || !std::isfinite(py)) return false;
    px = std::clamp(px, -1e9, 1e9);
    py = std::clamp(py, -1e9, 1e9);
    return true;
  };

  // The plot area is drawn into its own image, so data is clipped to it for free.
  Image area(pw, ph);
  std::vector<int> xt_px, yt_px;
  for (double t : ax.ticks) {
    double px = 0, py = 0;
    to_px(t, yr.lo, px, py);
    xt_px.push_back(static_cast<int>(std::lround(px)));
    area.line(xt_px.back(), 0, xt_px.back(), ph - 1, kGrid);
  }
  for (double t : ay.ticks) {
    double px = 0, py = 0;
    to_px(xr.lo, t, px, py);
    yt_px.push_back(static_cast<int>(std::lround(py)));
    area.line(0, yt_px.back(), pw - 1, yt_px.back(), kGrid);
  }
  for (const auto& [v, c] : spec.hlines) {
    double px = 0, py = 0;
    if (!to_px(xr.lo, v, px, py) || py < -0.5 || py > ph - 0.5) continue;
    const int y = static_cast<int>(std::lround(py));
    for (int x = 0; x < pw; ++x) {
      if (x % 10 < 6) area.set(x, y, c);  // 6 px dash, 4 px gap
    }
  }
  for (const Series& s : spec.series) {
    const std::size_t n = std::min(s.x.size(), s.y.size());
    const int size = std::clamp(s.size, 0, 64);
    const auto ok = [&](std::size_t i) {
      return i < n && std::isfinite(s.x[i]) && std::isfinite(s.y[i]);
    };
    bool have_prev = false;
    double qx = 0, qy = 0;  // previous point of the current polyline run
    for (std::size_t i = 0; i < n; ++i) {
      double px = 0, py = 0;
      if (!to_px(s.x[i], s.y[i], px, py)) {
        have_prev = false;  // a NaN breaks the polyline
        continue;
      }
      if (s.points) {
        disc(area, px, py, size, s.color, s.alpha);
        continue;
      }
      const int t = std::max(size, 1);
      if (have_prev || !ok(i + 1)) {  // isolated points still show up as a dot
        double ax0 = have_prev ? qx : px, ay0 = have_prev ? qy : py, bx = px, by = py;
        const double m = t + 1.0;
        if (clip_segment(ax0, ay0, bx, by, -m, -m, pw - 1 + m, ph - 1 + m)) {
          area.line(static_cast<int>(std::lround(ax0)), static_cast<int>(std::lround(ay0)),
                    static_cast<int>(std::lround(bx)), static_cast<int>(std::lround(by)),
                    s.color, t);
        }
      }
      have_prev = true;
      qx = px;
      qy = py;
    }
  }
  img.paste(area, left, top);

  // Frame just outside the plot area so it never hides data at the edges.
  const int fx0 = left - 1, fy0 = top - 1, fx1 = left + pw, fy1 = top + ph;
  img.line(fx0, fy0, fx1, fy0, kFrame);
  img.line(fx0, fy1, fx1, fy1, kFrame);
  img.line(fx0, fy0, fx0, fy1, kFrame);
  img.line(fx1, fy0, fx1, fy1, kFrame);

  // Tick marks and labels, kept inside the image horizontally.
  for (std::size_t i = 0; i < xt_px.size(); ++i) {
    const int x = left + xt_px[i];
    img.line(x, fy1 + 1, x, fy1 + kTick, kFrame);
    const int w = Image::text_width(ax.labels[i]);
    const int tx = std::clamp(x - w / 2, 0, std::max(0, width - w));
    img.text(tx, fy1 + kTick + 3, ax.labels[i], kText);
  }
  for (std::size_t i = 0; i < yt_px.size(); ++i) {
    const int y = top + yt_px[i];
    img.line(fx0 - kTick, y, fx0 - 1, y, kFrame);
    const int w = Image::text_width(ay.labels[i]);
    img.text(std::max(0, fx0 - kTick - 3 - w), y - 3, ay.labels[i], kText);
  }

  // Title centred on the whole image (left-aligned when too long to centre).
  if (!spec.title.empty()) {
    const int w = Image::text_width(spec.title, title_scale);
    img.text(std::max(2, (width - w) / 2), 5, spec.title, kText, title_scale);
  }
  if (!spec.xlabel.empty()) {
    const int w = Image::text_width(spec.xlabel);
    const int tx = std::clamp(left + (pw - w) / 2, 0, std::max(0, width - w));
    img.text(tx, fy1 + kTick + 3 + kCellH + 6, spec.xlabel, kText);
  }
  if (!spec.ylabel.empty()) {
    const int w = Image::text_width(spec.ylabel);
    const int by = std::min(height - 1, top + (ph + w) / 2);  // baseline end, reads upwards
    text_vertical(img, 6, by, spec.ylabel, kText);
  }

  // Legend: top-right corner of the plot area, translucent so data stays faintly visible.
  std::vector<const Series*> entries;
  for (const Series& s : spec.series) {
    if (!s.label.empty()) entries.push_back(&s);
  }
  if (!entries.empty()) {
    int tw = 0;
    for (const Series* s : entries) tw = std::max(tw, Image::text_width(s->label));
    constexpr int kRow = 12, kSwatch = 18;
    const int bw = 6 + kSwatch + 5 + tw + 4, bh = 5 + kRow * static_cast<int>(entries.size());
    const int bx1 = left + pw - 7, by0 = top + 6;
    const int bx0 = std::max(left + 1, bx1 - bw + 1), by1 = by0 + bh - 1;
    for (int y = by0; y <= by1; ++y) {
      for (int x = bx0; x <= bx1; ++x) img.blend(x, y, kWhite, 0.85);
    }
    img.line(bx0, by0, bx1, by0, kFrame);
    img.line(bx0, by1, bx1, by1, kFrame);
    img.line(bx0, by0, bx0, by1, kFrame);
    img.line(bx1, by0, bx1, by1, kFrame);
    for (std::size_t k = 0; k < entries.size(); ++k) {
      const Series& s = *entries[k];
      const int cy = by0 + 3 + kRow * static_cast<int>(k) + kRow / 2;
      const int sx0 = bx0 + 6, sx1 = sx0 + kSwatch - 1;
      if (s.points) {
        disc(img, 0.5 * (sx0 + sx1), cy, std::clamp(s.size, 2, 4), s.color, 1.0);
      } else {
        img.line(sx0, cy, sx1, cy, s.color, std::clamp(s.size, 1, 3));
      }
      img.text(sx1 + 6, cy - 3, s.label, kText);
    }
  }
  return img;
}

Image render_grid(const std::vector<PlotSpec>& panels, int cols, int w, int h) {
  w = std::max(w, 1);
  h = std::max(h, 1);
  if (panels.empty()) return Image(w, h);
  const int n = static_cast<int>(panels.size());
  cols = std::clamp(cols, 1, n);
  const int rows = (n + cols - 1) / cols;
  Image out(cols * w, rows * h);
  for (int i = 0; i < n; ++i) {
    out.paste(render_plot(panels[static_cast<std::size_t>(i)], w, h), (i % cols) * w,
              (i / cols) * h);
  }
  return out;
}

}  // namespace flashtwin
