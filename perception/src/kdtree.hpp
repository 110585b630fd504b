#pragma once
// k-d tree over float points (nanoflann), perception-internal.
#include <nanoflann.hpp>

#include "flashtwin/core/errors.hpp"

#include <Eigen/Core>
#include <cmath>
#include <cstdint>
#include <limits>
#include <memory>
#include <vector>

namespace flashtwin::perception::detail {

class KdTree {
 public:
  /// Indexes `points` (kept by reference: they must outlive the tree).
  explicit KdTree(const std::vector<Eigen::Vector3f>& points)
      : adaptor_{&points}, index_(3, adaptor_, nanoflann::KDTreeSingleIndexAdaptorParams(12)) {
    if (!points.empty()) index_.buildIndex();
  }
  std::size_t size() const { return adaptor_.pts->size(); }
  /// Nearest neighbour: index and squared distance; false when the tree is empty.
  bool nearest(const Eigen::Vector3f& q, std::uint32_t& idx, float& d2) const {
    if (size() == 0) return false;
    return index_.knnSearch(q.data(), 1, &idx, &d2) == 1;
  }
  /// True when some point lies within squared distance d2_max (inclusive) of q: the same
  /// answer as nearest() and d2 ≤ d2_max, but the search is bounded by d2_max from the start
  /// and stops at the first point found (far queries end after a few nodes).
  bool any_within(const Eigen::Vector3f& q, float d2_max) const {
    if (size() == 0) return false;
    // nanoflann accepts a point when its distance is strictly below worstDist().
    AnyWithin rs{std::nextafter(d2_max, std::numeric_limits<float>::infinity())};
    index_.findNeighbors(rs, q.data(), nanoflann::SearchParams());
    return rs.found;
  }
  /// k nearest neighbours (sorted by distance); returns how many were found.
  std::size_t knn(const Eigen::Vector3f& q, std::size_t k, std::uint32_t* idx, float* d2) const {
    if (size() == 0) return 0;
    return index_.knnSearch(q.data(), k, idx, d2);
  }
  /// Indices within `radius` (not squared).
  void radius(const Eigen::Vector3f& q, float radius,
              std::vector<std::pair<std::uint32_t, float>>& out) const {
    out.clear();
    if (size() == 0) return;
    nanoflann::SearchParams sp;
    sp.sorted = false;
    index_.radiusSearch(q.data(), radius * radius, out, sp);
  }

 private:
  // nanoflann result set: a fixed search radius; the first point inside ends the search.
  struct AnyWithin {
    float bound;
    bool found = false;
    std::size_t size() const { return found ? 1 : 0; }
    bool full() const { return found; }
    bool addPoint(float, std::uint32_t) {
      found = true;
      return false;  // stop searching
    }
    float worstDist() const { return bound; }
  };
  struct Adaptor {
    const std::vector<Eigen::Vector3f>* pts;
    std::size_t kdtree_get_point_count() const { return pts->size(); }
    float kdtree_get_pt(std::size_t i, std::size_t d) const { return (*pts)[i][static_cast<int>(d)]; }
    template <class B>
    bool kdtree_get_bbox(B&) const {
      return false;
    }
  };
  using Index = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<float, Adaptor>,
                                                    Adaptor, 3, std::uint32_t>;
  Adaptor adaptor_;
  Index index_;
};

/// Euclidean clusters: region growing over the neighbours within `tol` of `points` (indexed by
/// `tree`). Each cluster lists its points in the order it reached them, from its first point;
/// the clusters come in the order of their first points.
inline std::vector<std::vector<std::uint32_t>> euclidean_clusters(
    const std::vector<Eigen::Vector3f>& points, const KdTree& tree, float tol) {
  FT_ASSERT(tree.size() == points.size());
  std::vector<char> taken(points.size(), 0);
  std::vector<std::vector<std::uint32_t>> clusters;
  std::vector<std::pair<std::uint32_t, float>> nb;
  for (std::size_t s = 0; s < points.size(); ++s) {
    if (taken[s]) continue;
    std::vector<std::uint32_t> cl{static_cast<std::uint32_t>(s)};
    taken[s] = 1;
    for (std::size_t q = 0; q < cl.size(); ++q) {
      tree.radius(points[cl[q]], tol, nb);
      for (const auto& [j, d2] : nb)
        if (!taken[j]) {
          taken[j] = 1;
          cl.push_back(j);
        }
    }
    clusters.push_back(std::move(cl));
  }
  return clusters;
}

}  // namespace flashtwin::perception::detail
