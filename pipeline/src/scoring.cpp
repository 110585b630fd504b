#include "flashtwin/pipeline/scoring.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::pipeline {

SegmentationScore score_segmentation(const std::vector<std::uint8_t>& detected,
                                     const std::vector<std::uint8_t>& truth) {
  FT_ASSERT(detected.size() == truth.size());
  // Truth: 0 body, 1 flash, 2 background, 3 outlier, 4 mixed. Detected: 1 flash.
  SegmentationScore s;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    if (truth[i] > 2) continue;
    ++s.scored;
    const bool t = truth[i] == 1, d = detected[i] == 1;
    s.true_positive += t && d;
    s.false_positive += !t && d;
    s.false_negative += t && !d;
  }
  const double tp = static_cast<double>(s.true_positive);
  s.precision = s.true_positive + s.false_positive ? tp / (tp + s.false_positive) : 1.0;
  s.recall = s.true_positive + s.false_negative ? tp / (tp + s.false_negative) : 1.0;
  return s;
}

namespace {
double segment_distance(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double L2 = ab.squaredNorm();
  const double t = L2 > 0 ? std::clamp((p - a).dot(ab) / L2, 0.0, 1.0) : 0.0;
  return (a + t * ab - p).norm();
}
}  // namespace

std::uint64_t CurveDistance::key(long x, long y, long z) const {
  const auto u = [](long v) { return static_cast<std::uint64_t>(v + (1L << 20)) & 0x1FFFFF; };
  return (u(x) << 42) | (u(y) << 21) | u(z);
}

CurveDistance::CurveDistance(const std::vector<Curve>& curves, double cell) : cell_(cell) {
  for (const auto& c : curves) {
    const std::size_t n = c.points.size();
    if (n == 1) segs_.push_back({c.points[0], c.points[0]});
    for (std::size_t i = 0; i + 1 < n; ++i) segs_.push_back({c.points[i], c.points[i + 1]});
    if (c.closed && n > 2) segs_.push_back({c.points[n - 1], c.points[0]});
  }
  // Each segment goes into every grid cell its bounding box overlaps.
  for (std::size_t s = 0; s < segs_.size(); ++s) {
    const Vec3 lo = segs_[s].a.cwiseMin(segs_[s].b) / cell_;
    const Vec3 hi = segs_[s].a.cwiseMax(segs_[s].b) / cell_;
    for (long x = std::lround(std::floor(lo.x())); x <= std::lround(std::floor(hi.x())); ++x)
      for (long y = std::lround(std::floor(lo.y())); y <= std::lround(std::floor(hi.y())); ++y)
        for (long z = std::lround(std::floor(lo.z())); z <= std::lround(std::floor(hi.z())); ++z)
          grid_.emplace_back(key(x, y, z), static_cast<std::uint32_t>(s));
  }
  std::sort(grid_.begin(), grid_.end());
}

double CurveDistance::operator()(const Vec3& p) const {
  double best = std::numeric_limits<double>::infinity();
  const long cx = std::lround(std::floor(p.x() / cell_)), cy = std::lround(std::floor(p.y() / cell_)),
             cz = std::lround(std::floor(p.z() / cell_));
  for (long x = cx - 1; x <= cx + 1; ++x)
    for (long y = cy - 1; y <= cy + 1; ++y)
      for (long z = cz - 1; z <= cz + 1; ++z) {
        const auto k = key(x, y, z);
        auto it = std::lower_bound(grid_.begin(), grid_.end(), std::make_pair(k, 0u));
        for (; it != grid_.end() && it->first == k; ++it)
          best = std::min(best, segment_distance(p, segs_[it->second].a, segs_[it->second].b));
      }
  // Any segment nearer than one cell lies in the 27 cells searched; otherwise look everywhere.
  if (best <= cell_) return best;
  for (const auto& s : segs_) best = std::min(best, segment_distance(p, s.a, s.b));
  return best;
}

namespace {
/// Evaluation points every `spacing` along each curve (segment ends included); adds the
/// curves' length to `length`.
std::vector<Vec3> sample_curves(const std::vector<Curve>& curves, double spacing, double& length) {
  std::vector<Vec3> out;
  for (const auto& c : curves) {
    const std::size_t n = c.points.size();
    const std::size_t segs = c.closed && n > 2 ? n : (n ? n - 1 : 0);
    if (n == 1) out.push_back(c.points[0]);
    for (std::size_t i = 0; i < segs; ++i) {
      const Vec3& a = c.points[i];
      const Vec3& b = c.points[(i + 1) % n];
      const double L = (b - a).norm();
      length += L;
      const int k = std::max(1, static_cast<int>(std::ceil(L / spacing)));
      for (int j = 0; j < k; ++j) out.push_back(a + (b - a) * (static_cast<double>(j) / k));
      if (!c.closed && i + 1 == segs) out.push_back(b);
    }
  }
  return out;
}
}  // namespace

PathScore score_path(const std::vector<Curve>& extracted, const std::vector<Curve>& truth,
                     double spacing, double cover_tolerance) {
  FT_ASSERT(spacing > 0 && cover_tolerance > 0);
  PathScore s;
  const CurveDistance to_path(extracted);
  const CurveDistance to_truth(truth);
  // Evaluation points every `spacing` along each true root (segment ends included).
  std::vector<double> d;
  for (const auto& q : sample_curves(truth, spacing, s.true_length)) d.push_back(to_path(q));
  for (const auto& c : extracted) {
    const std::size_t n = c.points.size();
    for (std::size_t i = 0; i < n; ++i) {
      if (i + 1 < n) s.path_length += (c.points[i + 1] - c.points[i]).norm();
      if (!truth.empty()) s.spurious_max = std::max(s.spurious_max, to_truth(c.points[i]));
    }
    if (c.closed && n > 2) s.path_length += (c.points.front() - c.points.back()).norm();
  }
  if (truth.empty() && extracted.empty()) {
    s.coverage = 1;
    return s;
  }
  if (truth.empty()) {
    s.coverage = 1;
    s.spurious_max = std::numeric_limits<double>::infinity();
    return s;
  }
  s.eval_points = d.size();
  double sum = 0, sum2 = 0;
  std::size_t covered = 0;
  for (double v : d) {
    sum += v;
    sum2 += v * v;
    s.max = std::max(s.max, v);
    covered += v <= cover_tolerance;
  }
  s.mean = sum / d.size();
  s.rmse = std::sqrt(sum2 / d.size());
  s.coverage = static_cast<double>(covered) / d.size();
  return s;
}

double unseen_root_fraction(const std::vector<Curve>& roots, const std::vector<Vec3>& seen_C,
                            double radius, double spacing) {
  FT_ASSERT(radius > 0 && spacing > 0);
  double length = 0;
  const std::vector<Vec3> samples = sample_curves(roots, spacing, length);
  if (samples.empty()) return 0;
  // Seen points in a grid of `radius` cells: a point within `radius` of a sample lies in one of
  // the 27 cells around it.
  const auto cell_of = [radius](const Vec3& p) {
    return Eigen::Vector3i(static_cast<int>(std::floor(p.x() / radius)), static_cast<int>(std::floor(p.y() / radius)),
                           static_cast<int>(std::floor(p.z() / radius)));
  };
  const auto key = [](const Eigen::Vector3i& c) {
    const auto u = [](int v) { return static_cast<std::uint64_t>(v + (1 << 20)) & 0x1FFFFF; };
    return (u(c.x()) << 42) | (u(c.y()) << 21) | u(c.z());
  };
  std::vector<std::pair<std::uint64_t, std::uint32_t>> grid;
  grid.reserve(seen_C.size());
  for (std::size_t i = 0; i < seen_C.size(); ++i)
    grid.emplace_back(key(cell_of(seen_C[i])), static_cast<std::uint32_t>(i));
  std::sort(grid.begin(), grid.end());
  std::size_t unseen = 0;
  for (const auto& q : samples) {
    const Eigen::Vector3i c = cell_of(q);
    bool seen = false;
    for (int dx = -1; dx <= 1 && !seen; ++dx)
      for (int dy = -1; dy <= 1 && !seen; ++dy)
        for (int dz = -1; dz <= 1 && !seen; ++dz) {
          const auto k = key(c + Eigen::Vector3i(dx, dy, dz));
          for (auto it = std::lower_bound(grid.begin(), grid.end(), std::make_pair(k, 0u));
               it != grid.end() && it->first == k && !seen; ++it)
            seen = (seen_C[it->second] - q).squaredNorm() <= radius * radius;
        }
    unseen += !seen;
  }
  return static_cast<double>(unseen) / static_cast<double>(samples.size());
}

}  // namespace flashtwin::pipeline
