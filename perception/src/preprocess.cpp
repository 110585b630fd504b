#include "flashtwin/perception/preprocess.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <array>
#include <cstdint>
#include <cmath>
#include <limits>
#include <numeric>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "kdtree.hpp"

namespace flashtwin::perception {

using detail::KdTree;
using Vec3f = Eigen::Vector3f;

std::string validate_cloud(const PointCloud& cloud, std::size_t min_points) {
  if (cloud.empty()) return "expected a point cloud, got an empty one";
  if (cloud.size() < min_points)
    return "expected at least " + std::to_string(min_points) + " points, got " +
           std::to_string(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (!cloud.points[i].allFinite())
      return "point " + std::to_string(i) + ": expected finite coordinates, got NaN or inf";
  if (!cloud.normals.empty() && cloud.normals.size() != cloud.size())
    return "expected one normal per point, got " + std::to_string(cloud.normals.size()) +
           " normals for " + std::to_string(cloud.size()) + " points";
  return "";
}

namespace {

// Sorts (key, index) pairs that are in index order by key, ties by index: the order of
// std::sort on the pairs. LSD radix sort, 8 bits per pass, stable; a pass is skipped when every
// key has the same byte there (3 to 4 of 8 passes on a scan's voxel keys). A scan of ~2 M points
// sorts ~6× faster than with std::sort.
void sort_by_key(std::vector<std::pair<std::uint64_t, std::uint32_t>>& keyed) {
  std::vector<std::pair<std::uint64_t, std::uint32_t>> tmp(keyed.size());
  for (int shift = 0; shift < 64; shift += 8) {
    std::array<std::size_t, 257> count{};
    for (const auto& e : keyed) ++count[((e.first >> shift) & 0xFF) + 1];
    if (std::any_of(count.begin() + 1, count.end(), [&](std::size_t c) { return c == keyed.size(); }))
      continue;
    for (int b = 0; b < 256; ++b) count[b + 1] += count[b];
    for (const auto& e : keyed) tmp[count[(e.first >> shift) & 0xFF]++] = e;
    keyed.swap(tmp);
  }
}

// Calls f(indices of one voxel's points) for every occupied voxel, in voxel-key order: points
// are sorted by key (ties by index), so each voxel is a run. Faster than hashing, deterministic.
template <typename F>
void for_each_voxel(const PointCloud& cloud, double voxel, F&& f) {
  const double inv = 1.0 / voxel;
  std::vector<std::pair<std::uint64_t, std::uint32_t>> keyed(cloud.size());
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const Vec3f& p = cloud.points[i];
    const auto cx = static_cast<std::int64_t>(std::floor(p.x() * inv));
    const auto cy = static_cast<std::int64_t>(std::floor(p.y() * inv));
    const auto cz = static_cast<std::int64_t>(std::floor(p.z() * inv));
    keyed[i] = {(static_cast<std::uint64_t>(cx & 0x1fffff) << 42) |
                    (static_cast<std::uint64_t>(cy & 0x1fffff) << 21) |
                    static_cast<std::uint64_t>(cz & 0x1fffff),
                static_cast<std::uint32_t>(i)};
  }
  sort_by_key(keyed);
  std::vector<std::uint32_t> run;
  for (std::size_t a = 0; a < keyed.size();) {
    run.clear();
    std::size_t b = a;
    for (; b < keyed.size() && keyed[b].first == keyed[a].first; ++b) run.push_back(keyed[b].second);
    f(run);
    a = b;
  }
}

Eigen::Vector3d centroid_of(const PointCloud& cloud, const std::vector<std::uint32_t>& run) {
  Eigen::Vector3d c = Eigen::Vector3d::Zero();
  for (std::uint32_t i : run) c += cloud.points[i].cast<double>();
  return c / static_cast<double>(run.size());
}

}  // namespace

PointCloud voxel_downsample(const PointCloud& cloud, double voxel) {
  FT_ASSERT(voxel > 0);
  const bool has_n = cloud.normals.size() == cloud.size() && !cloud.empty();
  PointCloud out;
  for_each_voxel(cloud, voxel, [&](const std::vector<std::uint32_t>& run) {
    out.points.push_back(centroid_of(cloud, run).cast<float>());
    if (!has_n) return;
    // Average normals up to sign, relative to the first one of the voxel.
    Eigen::Vector3d n = Eigen::Vector3d::Zero();
    for (std::uint32_t i : run) {
      const Eigen::Vector3d ni = cloud.normals[i].cast<double>();
      n += n.dot(ni) < 0 ? -ni : ni;
    }
    const double len = n.norm();
    out.normals.push_back(len > 0 ? Vec3f((n / len).cast<float>()) : Vec3f::UnitZ());
  });
  return out;
}

PointCloud voxel_downsample_nearest(const PointCloud& cloud, double voxel) {
  FT_ASSERT(voxel > 0);
  const bool has_n = cloud.normals.size() == cloud.size() && !cloud.empty();
  PointCloud out;
  for_each_voxel(cloud, voxel, [&](const std::vector<std::uint32_t>& run) {
    // The voxel's points are at hand: a linear scan finds the one nearest the centroid.
    const Eigen::Vector3d c = centroid_of(cloud, run);
    std::uint32_t best = run.front();
    double best_d2 = std::numeric_limits<double>::infinity();
    for (std::uint32_t i : run) {
      const double d2 = (cloud.points[i].cast<double>() - c).squaredNorm();
      if (d2 < best_d2) {
        best_d2 = d2;
        best = i;
      }
    }
    out.points.push_back(cloud.points[best]);
    if (has_n) out.normals.push_back(cloud.normals[best]);
  });
  return out;
}

PointCloud remove_statistical_outliers(const PointCloud& cloud, int k, double std_mult) {
  if (cloud.size() <= static_cast<std::size_t>(k) + 1) return cloud;
  const KdTree tree(cloud.points);
  std::vector<double> mean_d(cloud.size());
  std::vector<std::uint32_t> idx(k + 1);
  std::vector<float> d2(k + 1);
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    const std::size_t n = tree.knn(cloud.points[i], k + 1, idx.data(), d2.data());
    double s = 0;
    for (std::size_t j = 1; j < n; ++j) s += std::sqrt(d2[j]);  // skip the point itself
    mean_d[i] = n > 1 ? s / static_cast<double>(n - 1) : 0;
  }
  const double mu = std::accumulate(mean_d.begin(), mean_d.end(), 0.0) / mean_d.size();
  double var = 0;
  for (double d : mean_d) var += (d - mu) * (d - mu);
  const double limit = mu + std_mult * std::sqrt(var / mean_d.size());
  PointCloud out;
  const bool has_n = cloud.normals.size() == cloud.size();
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (mean_d[i] <= limit) {
      out.points.push_back(cloud.points[i]);
      if (has_n) out.normals.push_back(cloud.normals[i]);
    }
  return out;
}

void estimate_normals(PointCloud& cloud, int k, const Vec3& viewpoint) {
  const std::size_t n = cloud.size();
  cloud.normals.assign(n, Vec3f::UnitZ());
  if (n < 3) return;
  const KdTree tree(cloud.points);
  const std::size_t kk = std::min<std::size_t>(static_cast<std::size_t>(k), n);
  std::vector<std::uint32_t> idx(kk);
  std::vector<float> d2(kk);
  std::vector<std::vector<std::uint32_t>> graph(viewpoint.allFinite() ? 0 : n);
#pragma omp parallel for schedule(static) firstprivate(idx, d2) if (n >= 8192)
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t m = tree.knn(cloud.points[i], kk, idx.data(), d2.data());
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (std::size_t j = 0; j < m; ++j) c += cloud.points[idx[j]].cast<double>();
    c /= static_cast<double>(m);
    Eigen::Matrix3d C = Eigen::Matrix3d::Zero();
    for (std::size_t j = 0; j < m; ++j) {
      const Eigen::Vector3d d = cloud.points[idx[j]].cast<double>() - c;
      C += d * d.transpose();
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> es(C);
    cloud.normals[i] = es.eigenvectors().col(0).cast<float>();  // smallest eigenvalue
    if (!graph.empty()) graph[i].assign(idx.begin(), idx.begin() + static_cast<long>(m));
  }
  if (viewpoint.allFinite()) {
    const Vec3f vp = viewpoint.cast<float>();
    for (std::size_t i = 0; i < n; ++i)
      if (cloud.normals[i].dot(vp - cloud.points[i]) < 0) cloud.normals[i] = -cloud.normals[i];
    return;
  }
  // No viewpoint: away from the centroid, then consistent over the neighbour graph (BFS from
  // the farthest point, whose outward direction is the most reliable).
  Vec3f centroid = Vec3f::Zero();
  for (const auto& p : cloud.points) centroid += p;
  centroid /= static_cast<float>(n);
  std::size_t far = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (cloud.normals[i].dot(cloud.points[i] - centroid) < 0) cloud.normals[i] = -cloud.normals[i];
    if ((cloud.points[i] - centroid).squaredNorm() > (cloud.points[far] - centroid).squaredNorm()) far = i;
  }
  std::vector<char> seen(n, 0);
  std::vector<std::size_t> queue;
  auto flood = [&](std::size_t start) {
    if (seen[start]) return;
    queue.assign(1, start);
    seen[start] = 1;
    for (std::size_t q = 0; q < queue.size(); ++q) {
      const std::size_t i = queue[q];
      for (std::uint32_t j : graph[i]) {
        if (seen[j]) continue;
        seen[j] = 1;
        if (cloud.normals[j].dot(cloud.normals[i]) < 0) cloud.normals[j] = -cloud.normals[j];
        queue.push_back(j);
      }
    }
  };
  // Other components keep their centroid-based orientation as their seed.
  flood(far);
  for (std::size_t i = 0; i < n; ++i) flood(i);
}

std::vector<float> normal_variation(const PointCloud& cloud, int k) {
  FT_ASSERT(cloud.normals.size() == cloud.size());
  const std::size_t n = cloud.size();
  std::vector<float> gamma(n, 0.f);
  if (n < 2) return gamma;
  const KdTree tree(cloud.points);
  const std::size_t kk = std::min<std::size_t>(static_cast<std::size_t>(k) + 1, n);
  std::vector<std::uint32_t> idx(kk);
  std::vector<float> d2(kk);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t m = tree.knn(cloud.points[i], kk, idx.data(), d2.data());
    double s = 0;
    int c = 0;
    for (std::size_t j = 0; j < m; ++j) {
      if (idx[j] == i) continue;
      const float dot = std::min(1.f, std::abs(cloud.normals[i].dot(cloud.normals[idx[j]])));
      s += std::acos(dot);
      ++c;
    }
    gamma[i] = c ? static_cast<float>(s / c) : 0.f;
  }
  return gamma;
}

std::vector<int> feature_points(const std::vector<float>& gamma, double fraction) {
  std::vector<int> order(gamma.size());
  std::iota(order.begin(), order.end(), 0);
  const std::size_t keep = std::min(gamma.size(),
                                    std::max<std::size_t>(4, static_cast<std::size_t>(fraction * gamma.size())));
  std::partial_sort(order.begin(), order.begin() + static_cast<long>(keep), order.end(),
                    [&](int a, int b) { return gamma[a] > gamma[b] || (gamma[a] == gamma[b] && a < b); });
  order.resize(keep);
  std::sort(order.begin(), order.end());
  return order;
}

namespace {
/// Share of the off-plane points a support plane may have on its far side (noise, outliers,
/// mixed points, a few rays under a table edge).
constexpr double kSupportOtherSide = 0.05;
}  // namespace

PointCloud remove_support_plane(const PointCloud& cloud, double distance, double cluster_tolerance,
                                double min_share, std::uint64_t seed) {
  const std::size_t n = cloud.size();
  if (n < 10) return cloud;
  Rng rng(seed);
  // RANSAC on a subsample for the plane hypothesis, counted on the whole cloud at the end.
  const std::size_t step = std::max<std::size_t>(1, n / 20000);
  Vec3 best_n = Vec3::UnitZ();
  double best_d = 0;
  std::size_t best_count = 0;
  for (int it = 0; it < 300; ++it) {
    const Vec3 a = cloud.points[rng.next() % n].cast<double>();
    const Vec3 b = cloud.points[rng.next() % n].cast<double>();
    const Vec3 c = cloud.points[rng.next() % n].cast<double>();
    Vec3 nrm = (b - a).cross(c - a);
    if (nrm.norm() < 1e-12) continue;
    nrm.normalize();
    const double d = -nrm.dot(a);
    std::size_t count = 0, pos = 0, neg = 0;
    for (std::size_t i = 0; i < n; i += step) {
      const double sd = nrm.dot(cloud.points[i].cast<double>()) + d;
      if (std::abs(sd) < distance) ++count;
      else if (sd > 0) ++pos;
      else ++neg;
    }
    // The part stands on its support: (nearly) everything off the plane lies on one side. A
    // big face of the part itself (a plate's top, seen from many views) has the rest of the
    // part and the table on its other side.
    if (std::min(pos, neg) > kSupportOtherSide * static_cast<double>(pos + neg)) continue;
    if (count > best_count) {
      best_count = count;
      best_n = nrm;
      best_d = d;
    }
  }
  std::size_t on_plane = 0, above = 0, below = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const double s = best_n.dot(cloud.points[i].cast<double>()) + best_d;
    if (std::abs(s) < distance) ++on_plane;
    else if (s > 0) ++above;
    else ++below;
  }
  if (static_cast<double>(on_plane) < min_share * static_cast<double>(n)) return cloud;
  // Keep the side with more off-plane points (the part sits on the table).
  const double side = above >= below ? 1.0 : -1.0;
  PointCloud kept;
  const bool has_n = cloud.normals.size() == n;
  for (std::size_t i = 0; i < n; ++i) {
    const double s = side * (best_n.dot(cloud.points[i].cast<double>()) + best_d);
    if (s >= distance) {
      kept.points.push_back(cloud.points[i]);
      if (has_n) kept.normals.push_back(cloud.normals[i]);
    }
  }
  if (kept.size() < 10) return kept;
  // Largest Euclidean cluster (region growing over radius neighbours).
  const KdTree tree(kept.points);
  const auto clusters = detail::euclidean_clusters(kept.points, tree, static_cast<float>(cluster_tolerance));
  const auto biggest = std::max_element(clusters.begin(), clusters.end(), [](const auto& a, const auto& b) {
    return a.size() < b.size();
  });
  std::vector<char> in_biggest(kept.size(), 0);
  for (const auto j : *biggest) in_biggest[j] = 1;
  PointCloud out;
  for (std::size_t i = 0; i < kept.size(); ++i)
    if (in_biggest[i]) {
      out.points.push_back(kept.points[i]);
      if (has_n) out.normals.push_back(kept.normals[i]);
    }
  return out;
}

}  // namespace flashtwin::perception
