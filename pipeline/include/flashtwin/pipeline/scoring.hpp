#pragma once
// Scoring against the simulator's ground truth (the only place that reads it).
#include <cstdint>
#include <vector>

#include "flashtwin/core/transform.hpp"

namespace flashtwin::pipeline {

/// Flash point labels vs the scanner's truth labels. Scored points: truth body, flash or
/// background (outliers and mixed points have no true class and are left out). Positive =
/// flash.
struct SegmentationScore {
  double precision = 0, recall = 0;  ///< 1 when there is nothing to find / nothing found
  std::size_t true_positive = 0, false_positive = 0, false_negative = 0, scored = 0;
};
/// @pre detected (perception::DetectLabel) and truth (sim::TruthLabel) have one entry per point.
SegmentationScore score_segmentation(const std::vector<std::uint8_t>& detected,
                                     const std::vector<std::uint8_t>& truth);

/// A polyline; closed joins the last point to the first.
struct Curve {
  std::vector<Vec3> points;
  bool closed = false;
};

/// Extracted path vs the true flash root curves (thesis §4.5): evaluation points sampled every
/// `spacing` along the true roots; each one's distance to the nearest point of the extracted
/// polylines gives mean, RMSE and max; coverage is the share within `cover_tolerance`.
/// `spurious_max` is the other direction: the farthest extracted path vertex from any true root.
struct PathScore {
  double mean = 0, rmse = 0, max = 0;  ///< [m]
  double coverage = 0;                 ///< [0, 1]; 1 when there is no true root
  double spurious_max = 0;             ///< [m]
  std::size_t eval_points = 0;
  double true_length = 0, path_length = 0;  ///< [m]
};
PathScore score_path(const std::vector<Curve>& extracted, const std::vector<Curve>& truth,
                     double spacing = 1e-4, double cover_tolerance = 5e-4);

/// Share of the true roots (sampled every `spacing`) with no seen point within `radius`:
/// what no scanner view saw (`scan.unseen_parting_fraction`). `seen_C` holds the scan points
/// that truly lie on a flash, at their true place in {C}. 0 when there is no root.
double unseen_root_fraction(const std::vector<Curve>& roots, const std::vector<Vec3>& seen_C,
                            double radius = 1.5e-3, double spacing = 1e-3);

/// Distance from p to the nearest segment of a set of polylines (helper of score_path, kept
/// public for tests). Returns +inf when there is no segment or point.
class CurveDistance {
 public:
  explicit CurveDistance(const std::vector<Curve>& curves, double cell = 2e-3);
  double operator()(const Vec3& p) const;

 private:
  struct Seg {
    Vec3 a, b;
  };
  std::vector<Seg> segs_;
  double cell_;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> grid_;  // sorted (cell key, segment)
  std::uint64_t key(long x, long y, long z) const;
};

}  // namespace flashtwin::pipeline
