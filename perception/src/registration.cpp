// The project's registration: PCA principal-axis alignment + 4PCS + normal-constrained ICP.
#include "flashtwin/perception/registration.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <chrono>
#include <cstdint>
#include <deque>
#include <mutex>
#include <limits>
#include <cmath>
#include <numeric>
#include <unordered_map>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "kdtree.hpp"

#include <omp.h>

#include <spdlog/spdlog.h>

namespace flashtwin::perception {

using detail::KdTree;
using Vec3f = Eigen::Vector3f;

// ------------------------------------------------------------------ the target model

struct ModelTarget::Impl {
  PointCloud dense, coarse;
  std::unique_ptr<KdTree> dense_tree, coarse_tree;
  double diag = 0;
  Vec3 centroid = Vec3::Zero();
  Mat3 axes = Mat3::Identity();  // principal axes, columns by decreasing variance
  // 4PCS: a subset of the coarse points and all their pairs sorted by distance.
  std::vector<Vec3f> fpcs_points;
  struct Pair {
    float d;
    std::uint32_t a, b;
  };
  std::vector<Pair> pairs;
  // Nearest-sample lookup in a narrow band around the surface: cell → index of the dense
  // sample nearest the cell centre. O(1) correspondences for the final ICP polish.
  double cell = 0;
  // Open-addressing hash table (linear probing): key+1 (0 = empty) and the sample index.
  std::vector<std::uint64_t> band_keys;
  std::vector<std::uint32_t> band_vals;
  std::uint64_t band_mask = 0;
  std::uint64_t cell_key(const Vec3f& p) const {
    const auto f = [&](float v) {
      return static_cast<std::uint64_t>(static_cast<std::int64_t>(std::floor(v / cell)) & 0x1fffff);
    };
    return (f(p.x()) << 42) | (f(p.y()) << 21) | f(p.z());
  }
  static std::uint64_t mix(std::uint64_t k) {
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return k;
  }
  bool nearest_in_band(const Vec3f& p, std::uint32_t& j) const {
    if (band_keys.empty()) return false;
    const std::uint64_t key = cell_key(p) + 1;
    for (std::uint64_t h = mix(key) & band_mask;; h = (h + 1) & band_mask) {
      if (band_keys[h] == key) {
        j = band_vals[h];
        return true;
      }
      if (band_keys[h] == 0) return false;
    }
  }
};

namespace {

double bbox_diagonal(const std::vector<Vec3f>& pts) {
  Eigen::AlignedBox3f box;
  for (const auto& p : pts) box.extend(p);
  return box.isEmpty() ? 0.0 : static_cast<double>(box.diagonal().norm());
}

// Principal axes (columns by decreasing variance) and centroid of a point set.
void principal_axes(const std::vector<Vec3f>& pts, Vec3& centroid, Mat3& axes) {
  centroid.setZero();
  for (const auto& p : pts) centroid += p.cast<double>();
  centroid /= static_cast<double>(pts.size());
  Mat3 C = Mat3::Zero();
  for (const auto& p : pts) {
    const Vec3 d = p.cast<double>() - centroid;
    C += d * d.transpose();
  }
  Eigen::SelfAdjointEigenSolver<Mat3> es(C);
  // Eigen sorts ascending: reverse to decreasing variance.
  axes.col(0) = es.eigenvectors().col(2);
  axes.col(1) = es.eigenvectors().col(1);
  axes.col(2) = es.eigenvectors().col(0);
}

// Every cell within r cells of a dense sample, with the sample nearest the cell's centre (ties:
// the lower index). A dense array over the samples' cell box (at the default fine_voxel at most
// ~(250·0.58 + 2r)^3 cells, ~30 MB: the box of a given diagonal is largest as a cube), else a
// hash map; both give the same cells and samples.
std::vector<std::pair<std::uint64_t, std::uint32_t>> nearest_sample_per_cell(
    const ModelTarget::Impl& t, int r) {
  const float cell = static_cast<float>(t.cell);
  // Each candidate: the cell centre around sample i's own cell c0 and its squared distance.
  auto visit = [&](auto&& offer) {
    for (std::uint32_t i = 0; i < t.dense.size(); ++i) {
      const Vec3f& q = t.dense.points[i];
      const Eigen::Vector3f c0 = (q / cell).array().floor();
      for (int dx = -r; dx <= r; ++dx)
        for (int dy = -r; dy <= r; ++dy)
          for (int dz = -r; dz <= r; ++dz) {
            const Vec3f centre = (c0 + Vec3f(dx + 0.5f, dy + 0.5f, dz + 0.5f)) * cell;
            offer(centre, (centre - q).squaredNorm(), i);
          }
    }
  };
  auto cell_of = [&](float v) { return static_cast<std::int64_t>(std::floor(v / t.cell)); };
  std::array<std::int64_t, 3> lo{INT64_MAX, INT64_MAX, INT64_MAX}, hi{INT64_MIN, INT64_MIN, INT64_MIN};
  for (const Vec3f& q : t.dense.points)
    for (int k = 0; k < 3; ++k) {
      // r + 2: the float cell of a centre may round one cell either way.
      lo[k] = std::min(lo[k], cell_of(q[k]) - r - 2);
      hi[k] = std::max(hi[k], cell_of(q[k]) + r + 2);
    }
  const std::array<std::int64_t, 3> n{hi[0] - lo[0] + 1, hi[1] - lo[1] + 1, hi[2] - lo[2] + 1};
  std::vector<std::pair<std::uint64_t, std::uint32_t>> out;
  constexpr std::int64_t kMaxDenseCells = 64LL << 20;
  if (!t.dense.points.empty() &&
      static_cast<double>(n[0]) * static_cast<double>(n[1]) * static_cast<double>(n[2]) <=
          static_cast<double>(kMaxDenseCells)) {
    constexpr std::uint32_t kNone = UINT32_MAX;
    std::vector<float> d2_of(static_cast<std::size_t>(n[0] * n[1] * n[2]),
                             std::numeric_limits<float>::infinity());
    std::vector<std::uint32_t> sample_of(d2_of.size(), kNone);
    visit([&](const Vec3f& centre, float d2, std::uint32_t i) {
      const std::int64_t x = cell_of(centre.x()) - lo[0], y = cell_of(centre.y()) - lo[1],
                         z = cell_of(centre.z()) - lo[2];
      FT_ASSERT(x >= 0 && x < n[0] && y >= 0 && y < n[1] && z >= 0 && z < n[2]);
      const std::size_t idx = static_cast<std::size_t>((z * n[1] + y) * n[0] + x);
      if (sample_of[idx] == kNone || d2 < d2_of[idx]) {
        d2_of[idx] = d2;
        sample_of[idx] = i;
      }
    });
    for (std::size_t idx = 0; idx < sample_of.size(); ++idx) {
      if (sample_of[idx] == kNone) continue;
      const auto i = static_cast<std::int64_t>(idx);
      const std::int64_t x = i % n[0] + lo[0], y = (i / n[0]) % n[1] + lo[1], z = i / (n[0] * n[1]) + lo[2];
      const auto bits = [](std::int64_t v) { return static_cast<std::uint64_t>(v & 0x1fffff); };
      out.emplace_back((bits(x) << 42) | (bits(y) << 21) | bits(z), sample_of[idx]);
    }
    return out;
  }
  std::unordered_map<std::uint64_t, std::pair<float, std::uint32_t>> best;
  best.reserve(t.dense.size() * 30);
  visit([&](const Vec3f& centre, float d2, std::uint32_t i) {
    auto [it, fresh] = best.emplace(t.cell_key(centre), std::make_pair(d2, i));
    if (!fresh && d2 < it->second.first) it->second = {d2, i};
  });
  for (const auto& [key, v] : best) out.emplace_back(key, v.second);
  return out;
}

void finish_target(ModelTarget::Impl& t, const TargetParams& p) {
  t.diag = bbox_diagonal(t.dense.points);
  t.dense_tree = std::make_unique<KdTree>(t.dense.points);
  t.coarse = voxel_downsample(t.dense, t.diag * p.coarse_voxel);
  t.coarse_tree = std::make_unique<KdTree>(t.coarse.points);
  principal_axes(t.dense.points, t.centroid, t.axes);
  // 4PCS works on at most ~600 evenly spread target points.
  const std::size_t stride = std::max<std::size_t>(1, t.coarse.size() / 600);
  for (std::size_t i = 0; i < t.coarse.size(); i += stride) t.fpcs_points.push_back(t.coarse.points[i]);
  const auto n = static_cast<std::uint32_t>(t.fpcs_points.size());
  t.pairs.reserve(static_cast<std::size_t>(n) * (n - 1) / 2);
  for (std::uint32_t a = 0; a < n; ++a)
    for (std::uint32_t b = a + 1; b < n; ++b)
      t.pairs.push_back({(t.fpcs_points[a] - t.fpcs_points[b]).norm(), a, b});
  std::sort(t.pairs.begin(), t.pairs.end(), [](const auto& x, const auto& y) { return x.d < y.d; });
  // The band: cells within 3 cells of any sample, each with the sample nearest its centre.
  t.cell = t.diag * p.fine_voxel;
  const std::vector<std::pair<std::uint64_t, std::uint32_t>> best = nearest_sample_per_cell(t, 3);
  std::uint64_t cap = 16;
  while (cap < 2 * best.size()) cap <<= 1;
  t.band_keys.assign(cap, 0);
  t.band_vals.assign(cap, 0);
  t.band_mask = cap - 1;
  for (const auto& [key, sample] : best) {
    std::uint64_t h = ModelTarget::Impl::mix(key + 1) & t.band_mask;
    while (t.band_keys[h] != 0) h = (h + 1) & t.band_mask;
    t.band_keys[h] = key + 1;
    t.band_vals[h] = sample;
  }
}

}  // namespace

ModelTarget::ModelTarget(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}
ModelTarget::~ModelTarget() = default;
double ModelTarget::diagonal() const { return impl_->diag; }
const PointCloud& ModelTarget::dense() const { return impl_->dense; }
const PointCloud& ModelTarget::coarse() const { return impl_->coarse; }

std::shared_ptr<const ModelTarget> ModelTarget::from_mesh(const TriangleMesh& mesh,
                                                          const TargetParams& params) {
  if (mesh.triangles.empty()) throw ArgumentError("target mesh: expected triangles, got none");
  std::vector<double> cum(mesh.triangles.size());
  double total = 0;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& f = mesh.triangles[t];
    total += 0.5 * (mesh.vertices[f[1]] - mesh.vertices[f[0]])
                       .cross(mesh.vertices[f[2]] - mesh.vertices[f[0]])
                       .norm();
    cum[t] = total;
  }
  if (!(total > 0) || !std::isfinite(total))
    throw ArgumentError("target mesh: expected a positive, finite surface area");
  auto impl = std::make_unique<Impl>();
  Rng rng(params.seed);
  const int n = std::max(100, params.mesh_samples);
  for (int i = 0; i < n; ++i) {
    // Area-uniform: triangle by cumulative area, point by the square-root barycentric trick.
    const double u = rng.uniform() * total;
    const std::size_t t = std::min<std::size_t>(
        std::lower_bound(cum.begin(), cum.end(), u) - cum.begin(), cum.size() - 1);
    const auto& f = mesh.triangles[t];
    const double r1 = std::sqrt(rng.uniform()), r2 = rng.uniform();
    const Vec3 p = (1 - r1) * mesh.vertices[f[0]] + r1 * (1 - r2) * mesh.vertices[f[1]] +
                   r1 * r2 * mesh.vertices[f[2]];
    impl->dense.points.push_back(p.cast<float>());
    impl->dense.normals.push_back(mesh.triangle_normal(t).cast<float>());
  }
  finish_target(*impl, params);
  return std::shared_ptr<const ModelTarget>(new ModelTarget(std::move(impl)));
}

namespace {

// The finalists' decision from the evidence points: a finalist has strong evidence over a rival
// where it explains a point (expl 1) that lies far from the rival's model (expl 0). Points near
// both models (edges, noise, mixed pixels) say nothing, so a small datum feature (a flat on a
// round flange, a hole) decides even when most of the part is symmetric and the rival explains
// nearly as many points. Starting from the finalist that explains the most, a rival with more
// strong evidence against it takes its place until none has; the ambiguity is the strongest
// rival's evidence over the winner's against it (+5 each: a handful of points decides nothing).
struct EvidenceVerdict {
  std::size_t winner = 0;
  double for_winner = 0, for_rival = 0;
  double ambiguity = 0;
};

EvidenceVerdict decide_by_evidence(const std::vector<std::vector<char>>& expl, std::size_t start) {
  const auto strong = [&](std::size_t a, std::size_t b) {
    double n = 0;
    for (std::size_t i = 0; i < expl[a].size(); ++i) n += expl[a][i] == 1 && expl[b][i] == 0;
    return n;
  };
  EvidenceVerdict v;
  v.winner = start;
  // At most one change of winner per finalist: a cycle (a over b over c over a) ends ambiguous.
  for (std::size_t round = 0; round < expl.size(); ++round) {
    bool changed = false;
    for (std::size_t k = 0; k < expl.size(); ++k)
      if (k != v.winner && strong(k, v.winner) > strong(v.winner, k)) {
        v.winner = k;
        changed = true;
      }
    if (!changed) break;
  }
  for (std::size_t k = 0; k < expl.size(); ++k) {
    if (k == v.winner) continue;
    const double w = strong(v.winner, k), r = strong(k, v.winner);
    const double a = std::min(1.0, (r + 5) / (w + 5));
    if (a >= v.ambiguity) {
      v.ambiguity = a;
      v.for_winner = w;
      v.for_rival = r;
    }
  }
  return v;
}

struct CachedTarget {
  std::uint64_t hash = 0;
  TriangleMesh mesh;
  TargetParams params;
  std::shared_ptr<const ModelTarget> target;
};

// FNV-1a over the mesh's bytes and the parameters.
std::uint64_t target_hash(const TriangleMesh& mesh, const TargetParams& p) {
  std::uint64_t h = 1469598103934665603ULL;
  auto add = [&](const void* data, std::size_t n) {
    const auto* b = static_cast<const unsigned char*>(data);
    for (std::size_t i = 0; i < n; ++i) h = (h ^ b[i]) * 1099511628211ULL;
  };
  add(mesh.vertices.data(), mesh.vertices.size() * sizeof(mesh.vertices[0]));
  add(mesh.triangles.data(), mesh.triangles.size() * sizeof(mesh.triangles[0]));
  add(&p.mesh_samples, sizeof p.mesh_samples);
  add(&p.coarse_voxel, sizeof p.coarse_voxel);
  add(&p.fine_voxel, sizeof p.fine_voxel);
  add(&p.normal_k, sizeof p.normal_k);
  add(&p.seed, sizeof p.seed);
  return h;
}

bool same_target(const CachedTarget& c, std::uint64_t hash, const TriangleMesh& mesh,
                 const TargetParams& p) {
  return c.hash == hash && c.params.mesh_samples == p.mesh_samples &&
         c.params.coarse_voxel == p.coarse_voxel && c.params.fine_voxel == p.fine_voxel &&
         c.params.normal_k == p.normal_k && c.params.seed == p.seed &&
         c.mesh.vertices == mesh.vertices && c.mesh.triangles == mesh.triangles;
}

}  // namespace

std::shared_ptr<const ModelTarget> ModelTarget::from_mesh_cached(const TriangleMesh& mesh,
                                                                 const TargetParams& params) {
  static std::mutex mutex;
  static std::deque<CachedTarget> cache;  // most recent first
  const std::uint64_t hash = target_hash(mesh, params);
  {
    const std::lock_guard<std::mutex> lock(mutex);
    for (auto it = cache.begin(); it != cache.end(); ++it)
      if (same_target(*it, hash, mesh, params)) {
        CachedTarget hit = std::move(*it);
        cache.erase(it);
        cache.push_front(std::move(hit));
        return cache.front().target;
      }
  }
  // Built outside the lock (two threads may build the same target once each: same result).
  auto target = from_mesh(mesh, params);
  const std::lock_guard<std::mutex> lock(mutex);
  cache.push_front({hash, mesh, params, target});
  if (cache.size() > 4) cache.pop_back();
  return target;
}

std::shared_ptr<const ModelTarget> ModelTarget::from_cloud(const PointCloud& cloud,
                                                           const TargetParams& params) {
  const std::string why = validate_cloud(cloud, 10);
  if (!why.empty()) throw ArgumentError("target cloud: " + why);
  auto impl = std::make_unique<Impl>();
  impl->dense.points = cloud.points;
  if (cloud.normals.size() == cloud.size()) impl->dense.normals = cloud.normals;
  else estimate_normals(impl->dense, params.normal_k);
  finish_target(*impl, params);
  return std::shared_ptr<const ModelTarget>(new ModelTarget(std::move(impl)));
}

// ------------------------------------------------------------------ ICP

namespace {

struct IcpOptions {
  bool point_to_plane = true;
  bool reciprocal = true;
  double cos_normal = -1;   // reject pairs with n_s·n_t below this (−1: no normal test)
  bool signed_normals = false;  // source normals reliably outward (known viewpoint): compare
                                // with sign, so a top face never matches a bottom face
  double max_dist = 0.01;   // [m] initial correspondence distance
  double min_dist = 0.001;  // [m] floor of the shrinking distance
  int iterations = 30;
  double converge = 1e-7;
};

struct IcpResult {
  Pose T = Pose::Identity();
  double rmse = 0;
  std::size_t pairs = 0;
  int iterations = 0;
};

Mat3 skew_exp(const Vec3& w) {
  const double a = w.norm();
  if (a < 1e-15) return Mat3::Identity();
  return Eigen::AngleAxisd(a, w / a).toRotationMatrix();
}

// Target level an ICP matches against: the dense samples or the coarse voxel centroids.
struct TargetLevel {
  const std::vector<Vec3f>* points;
  const std::vector<Vec3f>* normals;
  const KdTree* tree;
  const ModelTarget::Impl* band = nullptr;  ///< O(1) lookup near the surface (dense level)
  /// Nearest target point: the band table near the surface, the k-d tree elsewhere.
  bool nearest(const Vec3f& q, std::uint32_t& j, float& d2) const {
    if (band && band->nearest_in_band(q, j)) {
      d2 = ((*points)[j] - q).squaredNorm();
      return true;
    }
    return tree->nearest(q, j, d2);
  }
};

TargetLevel dense_level(const ModelTarget::Impl& t) {
  return {&t.dense.points, &t.dense.normals, t.dense_tree.get(), &t};
}
TargetLevel coarse_level(const ModelTarget::Impl& t) {
  return {&t.coarse.points, &t.coarse.normals, t.coarse_tree.get(), nullptr};
}

IcpResult icp(const std::vector<Vec3f>& src, const std::vector<Vec3f>& src_normals,
              const KdTree& src_tree, const TargetLevel& tgt, double diag, const Pose& T0,
              const IcpOptions& o) {
  IcpResult r;
  r.T = T0;
  double thr = o.max_dist, prev = std::numeric_limits<double>::infinity();
  const bool use_normals = o.cos_normal > -1 && src_normals.size() == src.size();
  const auto n = static_cast<long>(src.size());
  // Per-point match (index or −1) and squared distance: filled in parallel, read in order, so
  // the result does not depend on the thread count.
  std::vector<std::int64_t> match(src.size());
  std::vector<float> dist2(src.size());
  std::vector<std::pair<std::uint32_t, std::uint32_t>> pairs;
  pairs.reserve(src.size());
  for (int it = 0; it < o.iterations; ++it) {
    const Eigen::Matrix3f R = r.T.linear().cast<float>();
    const Vec3f t = r.T.translation().cast<float>();
    const Pose Tinv = r.T.inverse();
    const Eigen::Matrix3f Ri = Tinv.linear().cast<float>();
    const Vec3f ti = Tinv.translation().cast<float>();
    const float thr2 = static_cast<float>(thr * thr);
    const float cosn = static_cast<float>(o.cos_normal);
    // Threads only pay off for large sets (and spin badly when the other core is busy).
#pragma omp parallel for schedule(static) if (n >= 8192)
    for (long i = 0; i < n; ++i) {
      match[i] = -1;
      const Vec3f p = R * src[i] + t;
      std::uint32_t j;
      float d2;
      if (!tgt.nearest(p, j, d2) || d2 > thr2) continue;
      if (use_normals) {
        const float c = (R * src_normals[i]).dot((*tgt.normals)[j]);
        if ((o.signed_normals ? c : std::abs(c)) < cosn) continue;
      }
      if (o.reciprocal) {
        std::uint32_t back;
        float bd2;
        src_tree.nearest(Ri * (*tgt.points)[j] + ti, back, bd2);
        if (back != static_cast<std::uint32_t>(i)) continue;
      }
      match[i] = j;
      dist2[i] = d2;
    }
    pairs.clear();
    double sum2 = 0;
    for (long i = 0; i < n; ++i)
      if (match[i] >= 0) {
        pairs.emplace_back(static_cast<std::uint32_t>(i), static_cast<std::uint32_t>(match[i]));
        sum2 += dist2[i];
      }
    r.pairs = pairs.size();
    r.iterations = it + 1;
    if (pairs.size() < 6) break;
    r.rmse = std::sqrt(sum2 / static_cast<double>(pairs.size()));
    Pose dT = Pose::Identity();
    if (o.point_to_plane) {
      // Linearised point-to-plane: rows [ (p × n)ᵀ  nᵀ ] x = (q − p)·n, x = [ω; v].
      Eigen::Matrix<double, 6, 6> AtA = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> Atb = Eigen::Matrix<double, 6, 1>::Zero();
      for (const auto& [i, j] : pairs) {
        const Vec3 p = r.T * src[i].cast<double>();
        const Vec3 q = (*tgt.points)[j].cast<double>();
        const Vec3 nq = (*tgt.normals)[j].cast<double>();
        Eigen::Matrix<double, 6, 1> a;
        a << p.cross(nq), nq;
        AtA += a * a.transpose();
        Atb += a * (q - p).dot(nq);
      }
      const Eigen::Matrix<double, 6, 1> x = AtA.ldlt().solve(Atb);
      if (!x.allFinite()) break;
      dT.linear() = skew_exp(x.head<3>());
      dT.translation() = x.tail<3>();
    } else {
      Eigen::Matrix<double, 3, Eigen::Dynamic> A(3, pairs.size()), B(3, pairs.size());
      for (std::size_t k = 0; k < pairs.size(); ++k) {
        A.col(static_cast<long>(k)) = r.T * src[pairs[k].first].cast<double>();
        B.col(static_cast<long>(k)) = (*tgt.points)[pairs[k].second].cast<double>();
      }
      dT.matrix() = Eigen::umeyama(A, B, false);
    }
    r.T = dT * r.T;
    const double step = Eigen::AngleAxisd(dT.linear()).angle() * diag + dT.translation().norm();
    // Coarse to fine: the correspondence distance follows the residual down to its floor.
    thr = std::max(o.min_dist, std::min(thr, 4.0 * r.rmse));
    // Converged when the pose stops moving or the error stops changing.
    if (step < 1e-7 * diag ||
        (std::isfinite(prev) && std::abs(prev - r.rmse) <= o.converge * std::max(prev, 1e-12)))
      break;
    prev = r.rmse;
  }
  return r;
}

// ------------------------------------------------------------------ 4PCS

struct Hypothesis {
  Pose T;
  double score = 0;
  std::string stage;
};

// Closest points of lines a0 + s(a1 − a0) and b0 + t(b1 − b0): returns s, t.
bool line_params(const Vec3& a0, const Vec3& a1, const Vec3& b0, const Vec3& b1, double& s, double& t) {
  const Vec3 u = a1 - a0, v = b1 - b0, w = a0 - b0;
  const double a = u.dot(u), b = u.dot(v), c = v.dot(v), d = u.dot(w), e = v.dot(w);
  const double den = a * c - b * b;
  if (den < 1e-12 * a * c) return false;  // parallel
  s = (b * e - c * d) / den;
  t = (a * e - b * d) / den;
  return true;
}

// Points in a uniform grid of cells of edge `cell` over a box (counting sort into cells): radius
// queries return indices in increasing order. Rebuilt per 4PCS base (a k-d tree build per base
// was a third of the time of registering a partial view).
class CellIndex {
 public:
  CellIndex(const Eigen::AlignedBox3f& box, float cell) : lo_(box.min()), inv_(1 / cell) {
    for (int k = 0; k < 3; ++k)
      n_[k] = std::max(1, static_cast<int>(std::ceil((box.max()[k] - box.min()[k]) * inv_)) + 1);
  }
  void build(const std::vector<Vec3f>& pts) {
    const std::size_t cells = static_cast<std::size_t>(n_[0]) * n_[1] * n_[2];
    start_.assign(cells + 1, 0);
    cell_of_.resize(pts.size());
    for (std::size_t i = 0; i < pts.size(); ++i) {
      cell_of_[i] = cell(pts[i]);
      ++start_[cell_of_[i] + 1];
    }
    for (std::size_t c = 0; c < cells; ++c) start_[c + 1] += start_[c];
    order_.resize(pts.size());
    std::vector<std::uint32_t> fill(start_.begin(), start_.end() - 1);
    for (std::size_t i = 0; i < pts.size(); ++i)
      order_[fill[cell_of_[i]]++] = static_cast<std::uint32_t>(i);
  }
  // Indices of pts within distance r of q (r ≤ the cell edge), in increasing order.
  void within(const std::vector<Vec3f>& pts, const Vec3f& q, float r,
              std::vector<std::uint32_t>& out) const {
    out.clear();
    const Vec3f u = (q - lo_) * inv_;
    const int c[3] = {static_cast<int>(std::floor(u.x())), static_cast<int>(std::floor(u.y())),
                      static_cast<int>(std::floor(u.z()))};
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          const int x = c[0] + dx, y = c[1] + dy, z = c[2] + dz;
          if (x < 0 || y < 0 || z < 0 || x >= n_[0] || y >= n_[1] || z >= n_[2]) continue;
          const std::size_t id = (static_cast<std::size_t>(z) * n_[1] + y) * n_[0] + x;
          for (std::uint32_t k = start_[id]; k < start_[id + 1]; ++k)
            if ((pts[order_[k]] - q).squaredNorm() <= r * r) out.push_back(order_[k]);
        }
    std::sort(out.begin(), out.end());
  }

 private:
  std::size_t cell(const Vec3f& p) const {
    int c[3];
    for (int k = 0; k < 3; ++k)
      c[k] = std::clamp(static_cast<int>(std::floor((p[k] - lo_[k]) * inv_)), 0, n_[k] - 1);
    return (static_cast<std::size_t>(c[2]) * n_[1] + c[1]) * n_[0] + c[0];
  }
  Vec3f lo_;
  float inv_;
  int n_[3];
  std::vector<std::uint32_t> start_, cell_of_, order_;
};

std::vector<Hypothesis> four_pcs(const std::vector<Vec3f>& src, const ModelTarget::Impl& tgt,
                                 const RegistrationParams& p, Rng& rng) {
  std::vector<Hypothesis> out;
  const std::size_t n = src.size();
  if (n < 8 || tgt.fpcs_points.size() < 8) return out;
  const double delta = tgt.diag * p.fpcs_delta;
  const double src_diam = bbox_diagonal(src);
  const double width = p.fpcs_overlap * std::min(src_diam, tgt.diag);
  // Points to verify candidates on (a fixed random subset).
  std::vector<Vec3f> verify;
  for (int k = 0; k < 300; ++k) verify.push_back(src[rng.next() % n]);
  const float v2 = static_cast<float>(delta * delta);
  double best_score = 0;
  std::vector<std::uint32_t> nb;
  // Midpoints lie in the target's bounding box (convex combinations of its points).
  Eigen::AlignedBox3f box;
  for (const auto& q : tgt.fpcs_points) box.extend(q);
  CellIndex e1_grid(box, static_cast<float>(delta));
  for (int base = 0; base < p.fpcs_bases; ++base) {
    // Wide coplanar base: p1 random, p2 and p3 far from it, p4 near their plane and far.
    const Vec3 b1 = src[rng.next() % n].cast<double>();
    Vec3 b2, b3, b4;
    bool ok = false;
    for (int tries = 0; tries < 60 && !ok; ++tries) {
      b2 = src[rng.next() % n].cast<double>();
      const double d12 = (b2 - b1).norm();
      ok = d12 > 0.5 * width && d12 < 1.2 * width;
    }
    if (!ok) continue;
    ok = false;
    for (int tries = 0; tries < 60 && !ok; ++tries) {
      b3 = src[rng.next() % n].cast<double>();
      const double h = (b3 - b1).cross(b2 - b1).norm() / (b2 - b1).norm();
      ok = h > 0.25 * width && (b3 - b1).norm() < 1.2 * width && (b3 - b2).norm() < 1.2 * width;
    }
    if (!ok) continue;
    const Vec3 nrm = (b2 - b1).cross(b3 - b1).normalized();
    double best_spread = -1;
    for (int tries = 0; tries < 200; ++tries) {
      const Vec3 c = src[rng.next() % n].cast<double>();
      if (std::abs(nrm.dot(c - b1)) > 0.5 * delta) continue;
      const double spread = std::min({(c - b1).norm(), (c - b2).norm(), (c - b3).norm()});
      if (spread > best_spread && (c - b1).norm() < 1.2 * width) {
        best_spread = spread;
        b4 = c;
      }
    }
    if (best_spread < 0.2 * width) continue;
    // Pair the four points so that the two segments cross: invariants r1, r2 in (0, 1).
    const Vec3 pts[4] = {b1, b2, b3, b4};
    const int pairings[3][4] = {{0, 1, 2, 3}, {0, 2, 1, 3}, {0, 3, 1, 2}};
    int pa = -1;
    double r1 = 0, r2 = 0;
    for (int k = 0; k < 3 && pa < 0; ++k) {
      double s, t;
      const auto& q = pairings[k];
      if (line_params(pts[q[0]], pts[q[1]], pts[q[2]], pts[q[3]], s, t) && s > 0.05 && s < 0.95 &&
          t > 0.05 && t < 0.95) {
        pa = k;
        r1 = s;
        r2 = t;
      }
    }
    if (pa < 0) continue;
    const auto& q = pairings[pa];
    const Vec3 B[4] = {pts[q[0]], pts[q[1]], pts[q[2]], pts[q[3]]};
    const double d1 = (B[1] - B[0]).norm(), d2 = (B[3] - B[2]).norm();
    const double cos_base = (B[1] - B[0]).normalized().dot((B[3] - B[2]).normalized());
    // Target pairs of matching lengths (both orders) and their intermediate points.
    auto band = [&](double d) {
      const auto lo = std::lower_bound(tgt.pairs.begin(), tgt.pairs.end(), static_cast<float>(d - delta),
                                       [](const auto& x, float v) { return x.d < v; });
      const auto hi = std::upper_bound(tgt.pairs.begin(), tgt.pairs.end(), static_cast<float>(d + delta),
                                       [](float v, const auto& x) { return v < x.d; });
      return std::make_pair(lo, hi);
    };
    const auto [lo1, hi1] = band(d1);
    const auto [lo2, hi2] = band(d2);
    std::vector<Vec3f> e1;
    std::vector<std::pair<std::uint32_t, std::uint32_t>> e1_pairs;
    for (auto it = lo1; it != hi1; ++it)
      for (int o = 0; o < 2; ++o) {
        const std::uint32_t a = o ? it->b : it->a, b = o ? it->a : it->b;
        e1.push_back(tgt.fpcs_points[a] + static_cast<float>(r1) * (tgt.fpcs_points[b] - tgt.fpcs_points[a]));
        e1_pairs.emplace_back(a, b);
      }
    if (e1.empty()) continue;
    e1_grid.build(e1);
    int candidates = 0;
    for (auto it = lo2; it != hi2 && candidates < 400; ++it)
      for (int o = 0; o < 2 && candidates < 400; ++o) {
        const std::uint32_t c = o ? it->b : it->a, d = o ? it->a : it->b;
        const Vec3f e2 = tgt.fpcs_points[c] + static_cast<float>(r2) * (tgt.fpcs_points[d] - tgt.fpcs_points[c]);
        e1_grid.within(e1, e2, static_cast<float>(delta), nb);
        for (const std::uint32_t k : nb) {
          const auto [a, b] = e1_pairs[k];
          const Vec3 Q[4] = {tgt.fpcs_points[a].cast<double>(), tgt.fpcs_points[b].cast<double>(),
                             tgt.fpcs_points[c].cast<double>(), tgt.fpcs_points[d].cast<double>()};
          // The angle between the two segments must match the base's.
          if (std::abs((Q[1] - Q[0]).normalized().dot((Q[3] - Q[2]).normalized()) - cos_base) > 0.1)
            continue;
          ++candidates;
          Eigen::Matrix<double, 3, 4> S, D;
          for (int m = 0; m < 4; ++m) {
            S.col(m) = B[m];
            D.col(m) = Q[m];
          }
          Pose T;
          T.matrix() = Eigen::umeyama(S, D, false);
          // Largest common point set with early exit when it cannot beat half the best.
          const Eigen::Matrix3f R = T.linear().cast<float>();
          const Vec3f t = T.translation().cast<float>();
          std::size_t in = 0, seen = 0;
          for (const auto& v : verify) {
            ++seen;
            if (tgt.dense_tree->any_within(R * v + t, v2)) ++in;
            if (seen == 60 && static_cast<double>(in) / 60 < 0.5 * best_score) break;
          }
          const double score = static_cast<double>(in) / static_cast<double>(verify.size());
          if (seen == verify.size() && score > 0.3) {
            out.push_back({T, score, "4pcs"});
            best_score = std::max(best_score, score);
          }
        }
      }
    // Early exit: a convincing alignment, or a good one and no progress for a while.
    if (best_score > 0.85 || (base >= 40 && best_score > 0.6)) break;
  }
  std::sort(out.begin(), out.end(), [](const auto& a, const auto& b) { return a.score > b.score; });
  if (out.size() > 12) out.resize(12);
  return out;
}

bool distinct(const Pose& a, const Pose& b, double diag) {
  return rotation_distance(a.linear(), b.linear()) > 10 * M_PI / 180 ||
         (a.translation() - b.translation()).norm() > diag / 20;
}

// Which scan points a pose explains: the evidence that decides between finalists and moves
// them. A point is explained when it lies within `tight` of the model (point-to-plane) with a
// compatible normal: the normal test keeps flash fins, which stick out flat from walls, from
// "explaining" a wrongly placed wall.
class EvidenceScore {
 public:
  EvidenceScore(const PointCloud& evidence, const ModelTarget::Impl& tgt, double tight, double cos_tau,
                bool signed_normals)
      : ev_(evidence), tgt_(tgt), tight_(tight), cos_tau_(static_cast<float>(cos_tau)), signed_(signed_normals) {}

  double tight() const { return tight_; }

  // Per evidence point: 1 explained; 2 near the model but not explained (residual up to 4 ×
  // tight, or a normal that disagrees): noise, edges and mixed pixels; 0 far from the model.
  std::vector<char> explained(const Pose& T) const {
    std::vector<char> e(ev_.size(), 0);
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Vec3f t = T.translation().cast<float>();
    const auto n = static_cast<long>(ev_.size());
#pragma omp parallel for schedule(static) if (n >= 8192)
    for (long i = 0; i < n; ++i) {
      std::uint32_t j;
      const Vec3f q = R * ev_.points[i] + t;
      if (!tgt_.nearest_in_band(q, j)) continue;
      const float r = std::abs((tgt_.dense.points[j] - q).dot(tgt_.dense.normals[j]));
      if (r > static_cast<float>(4 * tight_)) continue;
      const float c = (R * ev_.normals[i]).dot(tgt_.dense.normals[j]);
      e[i] = r <= static_cast<float>(tight_) && (signed_ ? c : std::abs(c)) >= cos_tau_ ? 1 : 2;
    }
    return e;
  }
  static double count(const std::vector<char>& e) { return static_cast<double>(std::count(e.begin(), e.end(), 1)); }
  double count(const Pose& T) const { return count(explained(T)); }

  // How well the points pose T explains (e) pin each translation direction: the spectrum of
  // Σ n nᵀ over their normals in the model frame. The weakest direction, and its eigenvalue
  // over the strongest one.
  struct WeakDirection {
    Vec3 dir = Vec3::UnitX();
    double ratio = 1;
  };
  WeakDirection weak_translation(const Pose& T, const std::vector<char>& e) const {
    Mat3 N = Mat3::Zero();
    for (std::size_t i = 0; i < e.size(); ++i)
      if (e[i] == 1) {
        const Vec3 nm = T.linear() * ev_.normals[i].cast<double>();
        N += nm * nm.transpose();
      }
    const Eigen::SelfAdjointEigenSolver<Mat3> es(N);
    WeakDirection w;
    w.dir = es.eigenvectors().col(0);
    w.ratio = es.eigenvalues()[2] > 0 ? es.eigenvalues()[0] / es.eigenvalues()[2] : 1.0;
    return w;
  }

 private:
  const PointCloud& ev_;
  const ModelTarget::Impl& tgt_;
  double tight_;
  float cos_tau_;
  bool signed_;
};

// A finalist moved to the pose nearby that explains the most points. The sweep's 30° grid and
// short ICP runs leave a near-symmetric part's finalists a few degrees off (a round flange's
// 10° off its bolt-hole grid) or millimetres off along a weak direction (a housing's along its
// flange), and the few points that tell finalists apart (a flat, a hole, an end wall) only
// speak once each stands where it fits best.
// 1. Along a weakly constrained direction (eigenvalue ratio below `weak_ratio`) the peak is as
//    narrow as `tight` and can stand several millimetres off between dips: a profile over
//    ±diag/15 in steps of `tight` (at most 81) finds it where single steps would not.
// 2. Coordinate moves about and along the model's principal axes, turns of 8° down to 1° and
//    shifts of 8 down to 1 × tight, each taken when it explains 2 per mille more points.
// The profile and the two coarser levels count on `sparse` (a subset of the evidence: every
// 4th point), the finer levels on all of `ev`: the score returned is `ev`'s.
Hypothesis settle_finalist(const EvidenceScore& sparse, const EvidenceScore& ev, const ModelTarget::Impl& tgt,
                           const Hypothesis& f, double diag, double weak_ratio) {
  const double tight = ev.tight();
  Hypothesis h = f;
  const EvidenceScore* scorer = &sparse;
  const std::vector<char> start_expl = sparse.explained(f.T);
  h.score = EvidenceScore::count(start_expl);
  const auto take_if_better = [&](const Pose& cand) {
    const double c = scorer->count(cand);
    if (c <= h.score * 1.002) return false;
    h.score = c;
    h.T = cand;
    return true;
  };
  const auto weak = sparse.weak_translation(f.T, start_expl);
  if (weak.ratio < weak_ratio) {
    const Pose start = h.T;
    const double reach = diag / 15, step = std::max(tight, reach / 40);  // at most 81 poses
    for (double d = -reach; d <= reach + 1e-12; d += step) {
      Pose S = Pose::Identity();
      S.translation() = d * weak.dir;
      take_if_better(S * start);
    }
  }
  for (double level : {8.0, 4.0, 2.0, 1.0}) {
    if (level == 2.0) {
      scorer = &ev;
      h.score = ev.count(h.T);
    }
    bool improved = true;
    while (improved) {
      improved = false;
      for (int move = 0; move < 6; ++move)
        for (double sign : {-1.0, 1.0}) {
          const Vec3 axis = tgt.axes.col(move % 3);
          Pose step = Pose::Identity();
          if (move < 3) {
            step.linear() = Eigen::AngleAxisd(sign * level * M_PI / 180, axis).toRotationMatrix();
            step.translation() = tgt.centroid - step.linear() * tgt.centroid;
          } else {
            step.translation() = sign * level * tight * axis;
          }
          improved = take_if_better(step * h.T) || improved;
        }
    }
  }
  spdlog::debug("register: finalist moved from {:.0f} to {:.0f} explained points ({:.2f} deg, {:.2f} mm)", f.score,
                h.score, Eigen::AngleAxisd(h.T.linear() * f.T.linear().transpose()).angle() * 180 / M_PI,
                (h.T.translation() - f.T.translation()).norm() * 1e3);
  return h;
}

}  // namespace

// ------------------------------------------------------------------ the pipeline

RegistrationResult register_scan(const PointCloud& source, const ModelTarget& target,
                                 const RegistrationParams& p) {
  const auto t0 = std::chrono::steady_clock::now();
  RegistrationResult res;
  auto finish = [&] {
    res.time_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    return res;
  };
  const std::string why = validate_cloud(source, 10);
  if (!why.empty()) {
    res.message = "source: " + why;
    return finish();
  }
  const ModelTarget::Impl& tgt = target.impl();
  const double diag = tgt.diag;

  // Preprocessing: fine voxel grid, optional table removal, coarse voxel grid + outlier removal.
  // The fine level keeps original points (nearest the voxel centroid): no averaging bias at
  // the casting's edges and corners.
  PointCloud fine = voxel_downsample_nearest(PointCloud{source.points, {}, {}}, diag * p.fine_voxel);
  if (p.remove_support_plane)
    fine = remove_support_plane(fine, diag / 150, diag / 60, 0.2, 7);
  if (fine.size() < 10) {
    res.message = "source: fewer than 10 points left after preprocessing";
    return finish();
  }
  const auto t_fine = std::chrono::steady_clock::now();
  PointCloud coarse = voxel_downsample(fine, diag * p.coarse_voxel);
  if (coarse.size() > static_cast<std::size_t>(p.sor_k) + 1)
    coarse = remove_statistical_outliers(coarse, p.sor_k, p.sor_std);
  if (coarse.size() < 10) {
    res.message = "source: fewer than 10 points at the coarse level";
    return finish();
  }
  const auto t_coarse = std::chrono::steady_clock::now();
  estimate_normals(coarse, p.normal_k, p.viewpoint);
  const auto t_cn = std::chrono::steady_clock::now();
  // The global stage works on at most ~600 evenly spread coarse points.
  PointCloud global;
  {
    const std::size_t stride = std::max<std::size_t>(1, coarse.size() / 600);
    for (std::size_t i = 0; i < coarse.size(); i += stride) {
      global.points.push_back(coarse.points[i]);
      global.normals.push_back(coarse.normals[i]);
    }
  }
  const KdTree global_tree(global.points);

  // Fine ICP subset (at most 2000 points, evenly spread) with normals from its own
  // neighbourhoods (enough for the normal-angle test).
  PointCloud sub;
  {
    const std::size_t stride = std::max<std::size_t>(1, fine.size() / 2000);
    for (std::size_t i = 0; i < fine.size(); i += stride) sub.points.push_back(fine.points[i]);
    estimate_normals(sub, p.normal_k, p.viewpoint);
  }
  const KdTree sub_tree(sub.points);
  const auto t_pre = std::chrono::steady_clock::now();

  IcpOptions coarse_icp;
  coarse_icp.point_to_plane = false;
  coarse_icp.reciprocal = p.reciprocal;
  coarse_icp.cos_normal = std::cos(p.normal_angle);
  coarse_icp.signed_normals = p.viewpoint.allFinite();
  coarse_icp.max_dist = diag / 8;
  // The floor stays wide enough to see end walls and other features that stop sliding.
  coarse_icp.min_dist = 2.5 * diag * p.coarse_voxel;
  coarse_icp.iterations = 15;
  coarse_icp.converge = 1e-3;

  Rng rng(12345);
  std::vector<Hypothesis> hyps;
  const TargetLevel coarse_t = coarse_level(tgt), dense_t = dense_level(tgt);
  // Hypotheses are scored by the share of the source's fine points (a fixed subset) whose
  // point-to-plane residual to the model is within two fine voxels: sharper than the coarse
  // voxel distance, still cheap through the band lookup.
  std::vector<Vec3f> probe;
  {
    const std::size_t stride = std::max<std::size_t>(1, fine.size() / 1500);
    for (std::size_t i = 0; i < fine.size(); i += stride) probe.push_back(fine.points[i]);
  }
  auto band_score = [&](const Pose& T, double delta) {
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Vec3f t = T.translation().cast<float>();
    std::size_t in = 0;
    for (const auto& q0 : probe) {
      std::uint32_t j;
      const Vec3f q = R * q0 + t;
      in += tgt.nearest_in_band(q, j) &&
            std::abs((tgt.dense.points[j] - q).dot(tgt.dense.normals[j])) <= static_cast<float>(delta);
    }
    return static_cast<double>(in) / static_cast<double>(probe.size());
  };
  auto refine_and_score = [&](const Pose& T, const std::string& stage) {
    const IcpResult r = icp(global.points, global.normals, global_tree, coarse_t, diag, T, coarse_icp);
    hyps.push_back({r.T, band_score(r.T, 2 * diag * p.fine_voxel), stage});
  };
  if (p.use_pca) {
    Vec3 cs;
    Mat3 As;
    principal_axes(global.points, cs, As);
    for (int k = 0; k < 8; ++k) {
      const Vec3 s(k & 1 ? -1 : 1, k & 2 ? -1 : 1, k & 4 ? -1 : 1);
      const Mat3 R = tgt.axes * s.asDiagonal() * As.transpose();
      if (R.determinant() < 0) continue;  // the 4 reflections are not rigid motions
      Pose T = Pose::Identity();
      T.linear() = R;
      T.translation() = tgt.centroid - R * cs;
      refine_and_score(T, "pca");
    }
  }
  auto by_score = [](const auto& a, const auto& b) { return a.score > b.score; };
  auto second_distinct = [&](const std::vector<Hypothesis>& h) {
    for (std::size_t k = 1; k < h.size(); ++k)
      if (distinct(h[k].T, h[0].T, diag)) return h[k].score;
    return 0.0;
  };
  // A near-complete fit and no close rival: the coarse level is clear.
  const auto is_clear = [&](const std::vector<Hypothesis>& h) {
    return !h.empty() && h[0].score > 0.95 && second_distinct(h) < 0.8 * h[0].score;
  };
  std::sort(hyps.begin(), hyps.end(), by_score);
  // 4PCS when PCA's best is poor, or when its ranking is not clear: on a part that is nearly
  // symmetric about a turn (a housing whose walls sit off-centre on its flange), PCA's axes
  // offer the turned pose that fits the walls, and the true pose lies too far from any PCA or
  // sweep candidate for ICP to reach it.
  if (p.use_4pcs && (hyps.empty() || hyps[0].score < p.pca_accept_fitness || !is_clear(hyps))) {
    for (const auto& h : four_pcs(global.points, tgt, p, rng)) refine_and_score(h.T, "4pcs");
  }
  if (hyps.empty()) {
    res.message = "no global alignment hypothesis (PCA and 4PCS disabled or failed)";
    return finish();
  }
  std::sort(hyps.begin(), hyps.end(), by_score);
  // Symmetry sweep: unless the coarse ranking is decisive (near-symmetric or partially seen
  // parts), also try the best pose turned about each principal axis of the model in 30° steps.
  // Skipped only when the coarse level is already clear: a near-complete fit and no close rival.
  const bool clear = is_clear(hyps);
  {
    const Pose T_best = hyps[0].T;
    for (int axis = 0; axis < 3; ++axis)
      for (int k = 1; k < 12; ++k) {
        // Only when the coarse level is not clear (near-symmetric or partially seen parts).
        if (clear) continue;  // the PCA candidates already hold the half turns
        Pose turn = Pose::Identity();
        turn.linear() = Eigen::AngleAxisd(k * M_PI / 6, tgt.axes.col(axis)).toRotationMatrix();
        turn.translation() = tgt.centroid - turn.linear() * tgt.centroid;
        refine_and_score(turn * T_best, hyps[0].stage + "+sweep");
      }
    std::sort(hyps.begin(), hyps.end(), by_score);
  }

  // Fine ICP: point-to-plane (or point-to-point), reciprocal, normal-constrained.
  IcpOptions fine_icp;
  fine_icp.point_to_plane = p.point_to_plane;
  fine_icp.reciprocal = p.reciprocal;
  fine_icp.cos_normal = std::cos(p.normal_angle);
  fine_icp.signed_normals = p.viewpoint.allFinite();
  fine_icp.max_dist = diag * p.coarse_voxel;
  fine_icp.min_dist = diag * p.fine_voxel;
  fine_icp.iterations = p.icp_iterations;
  fine_icp.converge = p.icp_converge;
  const double inlier = diag * p.fine_voxel;
  const double tight = 0.5 * inlier;

  const auto t_global = std::chrono::steady_clock::now();
  // The top distinct hypotheses compete at the fine level on every fine point: a point is
  // explained by a pose when its point-to-plane residual is within `tight`. The finalists are
  // then decided by the points one explains that lie far from another's model
  // (decide_by_evidence).
  std::vector<Hypothesis> finalists;
  std::vector<std::vector<char>> expl;
  // Evidence points: the ICP subset when the coarse level is clear, otherwise up to 20,000
  // fine points with their own normals (small datum features need many points to be seen).
  PointCloud evidence_cloud;
  if (!clear) {
    const std::size_t stride = std::max<std::size_t>(1, (fine.size() + 19999) / 20000);
    for (std::size_t i = 0; i < fine.size(); i += stride) evidence_cloud.points.push_back(fine.points[i]);
    estimate_normals(evidence_cloud, p.normal_k, p.viewpoint);
  }
  const PointCloud& evidence = clear ? sub : evidence_cloud;
  const EvidenceScore score(evidence, tgt, tight, std::cos(p.normal_angle), p.viewpoint.allFinite());
  PointCloud sparse_evidence;  // every 4th evidence point: the coarse moves of settle_finalist
  if (!clear)
    for (std::size_t i = 0; i < evidence.size(); i += 4) {
      sparse_evidence.points.push_back(evidence.points[i]);
      sparse_evidence.normals.push_back(evidence.normals[i]);
    }
  const EvidenceScore sparse_score(sparse_evidence, tgt, tight, std::cos(p.normal_angle), p.viewpoint.allFinite());
  const auto explained = [&](const Pose& T) { return score.explained(T); };
  const auto count = [](const std::vector<char>& e) { return EvidenceScore::count(e); };
  // The ICP minimises the plain point-to-plane error of the ICP subset; on a near-symmetric part
  // the few points that fix the turn about its axis can lose to a bias of the many others (a
  // round flange turned 8° off the pose the local turns had found, 0.002° from the true one).
  // After the decision, a run is taken only when its pose explains no fewer points than its
  // start (2 per mille for noise); otherwise the polish starts from the start.
  const auto icp_no_worse = [&](const Pose& start, const IcpOptions& o) {
    IcpResult r = icp(sub.points, sub.normals, sub_tree, dense_t, diag, start, o);
    const double before = count(explained(start)), after = count(explained(r.T));
    if (after < 0.998 * before) {
      spdlog::debug("register: ICP run not taken: it explains {:.0f} points, its start {:.0f}", after, before);
      r.T = start;
    }
    return r;
  };
  {
    IcpOptions quick = fine_icp;
    quick.iterations = 8;
    for (const auto& h : hyps) {
      // Only hypotheses close to the best at the coarse level compete (each costs an ICP run),
      // but the best distinct rival always does unless the coarse level is clear.
      if (h.score < 0.8 * hyps[0].score && (clear || finalists.size() >= 2)) break;
      bool dup = false;
      for (const auto& f : finalists) dup = dup || !distinct(f.T, h.T, diag);
      if (dup) continue;
      // A lone clear winner needs no quick run: the fine ICP below starts from it.
      const bool alone = clear;
      const IcpResult r = alone ? IcpResult{h.T, 0, 0, 0}
                                : icp(sub.points, sub.normals, sub_tree, dense_t, diag, h.T, quick);
      bool dup_after = false;
      for (const auto& f : finalists) dup_after = dup_after || !distinct(f.T, r.T, diag);
      if (dup_after) continue;
      expl.push_back(explained(r.T));
      finalists.push_back({r.T, count(expl.back()), h.stage});
      if (finalists.size() >= 16 || alone) break;
    }
  }
  // Each finalist first moves to where it explains the most points (settle_finalist); those
  // that move onto each other merge. Only when the coarse level is not clear.
  bool rivals_merged = false;  // every rival moved onto the winner
  if (!clear) {
    const auto t_settle = std::chrono::steady_clock::now();
    std::vector<Hypothesis> settled;
    std::vector<std::vector<char>> settled_expl;
    for (const auto& f : finalists) {
      const Hypothesis h = settle_finalist(sparse_score, score, tgt, f, diag, p.weak_direction_ratio);
      std::size_t same = settled.size();
      for (std::size_t k = 0; k < settled.size() && same == settled.size(); ++k)
        if (!distinct(settled[k].T, h.T, diag)) same = k;
      if (same == settled.size()) {
        settled.push_back(h);
        settled_expl.push_back(explained(h.T));
      } else if (h.score > settled[same].score) {
        settled[same] = h;
        settled_expl[same] = explained(h.T);
      }
    }
    spdlog::debug("register: {} finalists settled in {:.0f} ms ({} evidence points)", finalists.size(),
                  std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - t_settle).count(),
                  evidence.size());
    rivals_merged = finalists.size() > 1 && settled.size() == 1;
    finalists = std::move(settled);
    expl = std::move(settled_expl);
  }
  for (const auto& h : hyps) {
    const Eigen::AngleAxisd aa(h.T.linear());
    spdlog::trace("hypothesis {} score {:.4f} rot {:.2f} deg about [{:.3f} {:.3f} {:.3f}] t [{:.4f} {:.4f} {:.4f}]",
                  h.stage, h.score, aa.angle() * 180 / M_PI, aa.axis().x(), aa.axis().y(), aa.axis().z(),
                  h.T.translation().x(), h.T.translation().y(), h.T.translation().z());
  }
  for (const auto& f : finalists) {
    const Eigen::AngleAxisd aa(f.T.linear());
    spdlog::trace("finalist {} explains {:.0f} rot {:.2f} deg about [{:.3f} {:.3f} {:.3f}] t [{:.4f} {:.4f} {:.4f}]",
                  f.stage, f.score, aa.angle() * 180 / M_PI, aa.axis().x(), aa.axis().y(), aa.axis().z(),
                  f.T.translation().x(), f.T.translation().y(), f.T.translation().z());
  }
  std::size_t win = 0;
  for (std::size_t k = 1; k < finalists.size(); ++k)
    if (finalists[k].score > finalists[win].score) win = k;
  // With a single finalist, the coarse level decides: unexplained share of the best over that
  // of the best distinct alternative.
  const double s2 = second_distinct(hyps);
  res.ambiguity = s2 > 0 ? std::min(1.0, (1 - hyps[0].score + 1e-3) / (1 - s2 + 1e-3)) : 0.0;
  // The best distinct rival of the coarse level is always a finalist when that level is not
  // clear: when it moved onto the winner, the two were one pose seen from two starts.
  if (rivals_merged) {
    spdlog::debug("register: every rival moved onto the winner: not ambiguous");
    res.ambiguity = 0;
  }
  if (finalists.size() > 1) {
    const EvidenceVerdict v = decide_by_evidence(expl, win);
    spdlog::debug("register: {} finalists; most explained by {} ({:.0f} points), decided for {} "
                  "(strong evidence {:.0f} against the strongest rival's {:.0f})",
                  finalists.size(), win, finalists[win].score, v.winner, v.for_winner, v.for_rival);
    win = v.winner;
    res.ambiguity = v.ambiguity;
  }
  if (!clear) {
    IcpOptions quick = fine_icp;
    quick.iterations = 8;
    finalists[win].T = icp_no_worse(finalists[win].T, quick).T;
  }
  hyps[0] = finalists[win];

  IcpResult best = icp_no_worse(hyps[0].T, fine_icp);
  // Polish: every fine point, robust point-to-plane against the O(1) band lookup (the
  // noise-limited accuracy grows with the number of points). Returns the most weakly
  // constrained translation direction (target frame) and its eigenvalue ratio.
  struct Weak {
    Vec3 dir = Vec3::UnitX();
    double ratio = 1;
    double sigma = 0;  // [m] robust residual scale of the last pass
    // The most weakly constrained turn (the translation free to follow): its axis direction
    // and a point on it (target frame), and its stiffness at half the diagonal over the
    // strongest translation's.
    Vec3 turn_axis = Vec3::UnitZ(), turn_point = Vec3::Zero();
    double turn_ratio = 1;
  };
  auto polish = [&](Pose& T) {
    Weak weak;
    const auto n = static_cast<long>(fine.size());
    std::vector<float> resid(fine.size());
    std::vector<std::uint32_t> match(fine.size());
    for (int it = 0; it < p.polish_iterations; ++it) {
      const Eigen::Matrix3f R = T.linear().cast<float>();
      const Vec3f t = T.translation().cast<float>();
#pragma omp parallel for schedule(static) if (n >= 8192)
      for (long i = 0; i < n; ++i) {
        std::uint32_t j;
        const Vec3f q = R * fine.points[i] + t;
        resid[i] = -1.f;
        if (tgt.nearest_in_band(q, j)) {
          match[i] = j;
          resid[i] = (tgt.dense.points[j] - q).dot(tgt.dense.normals[j]);
        }
      }
      // Robust scale: the median absolute residual of the points in the band.
      std::vector<float> valid;
      valid.reserve(resid.size());
      for (float v : resid)
        if (v != -1.f) valid.push_back(std::abs(v));
      if (valid.size() < 10) break;
      std::nth_element(valid.begin(), valid.begin() + static_cast<long>(valid.size() / 2), valid.end());
      const double sigma = 1.4826 * valid[valid.size() / 2];
      weak.sigma = sigma;
      // Graduated robust weights (Geman-McClure): the scale starts at the fine voxel, so
      // features a millimetre or two off still steer the pose, and halves each pass down to
      // 3.5 σ̂, where flashes and mixed points no longer count.
      const double scale = std::max(3.5 * sigma, diag * p.fine_voxel * std::pow(0.5, it));
      Eigen::Matrix<double, 6, 6> AtA = Eigen::Matrix<double, 6, 6>::Zero();
      Eigen::Matrix<double, 6, 1> Atb = Eigen::Matrix<double, 6, 1>::Zero();
      // Sequential accumulation in index order: the result does not depend on threads.
      for (long i = 0; i < n; ++i) {
        if (resid[i] == -1.f) continue;
        const double e = resid[i];
        if (std::abs(e) > 10 * scale) continue;
        const Vec3 pp = T * fine.points[i].cast<double>();
        const Vec3 nq = tgt.dense.normals[match[i]].cast<double>();
        Eigen::Matrix<double, 6, 1> a;
        a << pp.cross(nq), nq;
        const double u = e / scale, w = 1.0 / ((1 + u * u) * (1 + u * u));
        AtA += w * a * a.transpose();
        Atb += w * a * e;
      }
      const Eigen::Matrix<double, 6, 1> x = AtA.ldlt().solve(Atb);
      if (!x.allFinite()) break;
      {
        // How well the points pin each translation direction: the spectrum of the
        // translational block of the normal equations.
        const Eigen::SelfAdjointEigenSolver<Mat3> es(AtA.bottomRightCorner<3, 3>());
        const Vec3 ev = es.eigenvalues();
        weak.dir = es.eigenvectors().col(0);
        weak.ratio = ev[2] > 0 ? ev[0] / ev[2] : 1.0;
        spdlog::debug("register: polish {} translation constraint eigenvalues {:.3g} {:.3g} {:.3g} "
                      "(weakest along [{:.3f} {:.3f} {:.3f}] in the target frame)",
                      it, ev[0], ev[1], ev[2], weak.dir.x(), weak.dir.y(), weak.dir.z());
        // Turns with the translation re-fitted: the Schur complement of the translational
        // block. A turn ω about the origin moves the fit's translation by −K_tt⁻¹ K_tr ω, which
        // is a turn about the axis through a = ω̂ × t per unit turn.
        const Mat3 Ktt = AtA.bottomRightCorner<3, 3>(), Krt = AtA.topRightCorner<3, 3>();
        const Eigen::LDLT<Mat3> Ktt_inv = Ktt.ldlt();
        const Mat3 S = AtA.topLeftCorner<3, 3>() - Krt * Ktt_inv.solve(Mat3(Krt.transpose()));
        const Eigen::SelfAdjointEigenSolver<Mat3> er(S);
        weak.turn_axis = er.eigenvectors().col(0);
        const Vec3 t_per_turn = -Ktt_inv.solve(Vec3(Krt.transpose() * weak.turn_axis));
        weak.turn_point = weak.turn_axis.cross(t_per_turn);
        const double r = 0.5 * diag;
        weak.turn_ratio = ev[2] > 0 ? er.eigenvalues()[0] / (r * r) / ev[2] : 1.0;
        spdlog::debug("register: polish {} weakest turn about [{:.3f} {:.3f} {:.3f}] through "
                      "[{:.4f} {:.4f} {:.4f}], stiffness ratio {:.3g}",
                      it, weak.turn_axis.x(), weak.turn_axis.y(), weak.turn_axis.z(), weak.turn_point.x(),
                      weak.turn_point.y(), weak.turn_point.z(), weak.turn_ratio);
      }
      Pose dT = Pose::Identity();
      dT.linear() = skew_exp(x.head<3>());
      dT.translation() = x.tail<3>();
      T = dT * T;
      if (scale <= 3.5 * sigma * 1.0001 && x.norm() < 1e-8) break;
    }
    return weak;
  };
  // Along a weakly constrained direction the robust polish can stop with the few surfaces that
  // face it a few tenths of a millimetre off: its weights treat them as outliers by then, and
  // the rest of the part does not care. The profile of those surfaces' sharp inliers (residual
  // within 3 σ̂, at least 0.05 mm) over offsets along the direction shows where they agree;
  // the pose moves to its peak. The peak must stand out of the profile (the highest count
  // more than 3 bands away, over the peak's): otherwise the scan does not fix the pose along
  // that direction, and the verdict says so.
  struct WeakProfile {
    double offset = 0;      // [m] taken
    double peak_ratio = 1;  // peak count over the highest count away from it
  };
  bool determined = true;
  auto settle_along = [&](Pose& T, const Vec3& dir, double sigma) {
    const double band = std::max(0.05e-3, 3 * sigma), step = band / 4, reach = 8 * band;
    const auto sharp_count = [&](double d) {
      const Eigen::Matrix3f R = T.linear().cast<float>();
      const Vec3f t = (T.translation() + d * dir).cast<float>();
      const Vec3f w = dir.cast<float>();
      const auto n = static_cast<long>(fine.size());
      std::vector<char> hit(fine.size(), 0);
#pragma omp parallel for schedule(static) if (n >= 8192)
      for (long i = 0; i < n; ++i) {
        std::uint32_t j;
        const Vec3f q = R * fine.points[i] + t;
        if (!tgt.nearest_in_band(q, j) || std::abs(tgt.dense.normals[j].dot(w)) < 0.5f) continue;
        hit[i] = std::abs((tgt.dense.points[j] - q).dot(tgt.dense.normals[j])) < static_cast<float>(band);
      }
      return static_cast<double>(std::count(hit.begin(), hit.end(), 1));
    };
    const auto m = static_cast<int>(std::lround(reach / step));
    std::vector<double> prof(static_cast<std::size_t>(2 * m + 1));
    for (int k = -m; k <= m; ++k) prof[static_cast<std::size_t>(k + m)] = sharp_count(k * step);
    const auto top = static_cast<int>(std::max_element(prof.begin(), prof.end()) - prof.begin()) - m;
    double away = 0;
    for (int k = -m; k <= m; ++k)
      if (std::abs(k - top) * step > 3 * band) away = std::max(away, prof[static_cast<std::size_t>(k + m)]);
    WeakProfile wp;
    const double peak = prof[static_cast<std::size_t>(top + m)];
    wp.peak_ratio = (peak + 5) / (away + 5);
    // Move only when the peak clearly beats where the polish stopped.
    if (top != 0 && peak > 1.2 * prof[static_cast<std::size_t>(m)]) {
      wp.offset = top * step;
      T.translation() += wp.offset * dir;
    }
    spdlog::debug("register: along [{:.3f} {:.3f} {:.3f}] sharp inliers (band {:.3f} mm) peak {:.0f} "
                  "at {:.3f} mm (polish {:.0f}), highest away {:.0f}: moved {:.3f} mm, peak ratio {:.2f}",
                  dir.x(), dir.y(), dir.z(), band * 1e3, peak, top * step * 1e3, prof[static_cast<std::size_t>(m)],
                  away, wp.offset * 1e3, wp.peak_ratio);
    return wp;
  };
  // Along a one-parameter family of moves (move(v) for v in [-reach, reach], `step` apart), the
  // one whose pose explains the most points, and that count; (0, base) when none beats `base`.
  const auto most_explained = [&](const auto& move, double reach, double step, double base) {
    std::pair<double, double> best_v{0.0, base};
    for (double v = -reach; v <= reach + 1e-12; v += step) {
      const double c = count(explained(move(v) * best.T));
      if (c > best_v.second) best_v = {v, c};
    }
    return best_v;
  };
  if (p.point_to_plane) {
    const Weak weak = polish(best.T);
    Weak latest = weak;  // the last polish's
    // A plate's long axis can rest on a few features (ends behind fixture blocks, holes): the
    // robust polish then stops in a local minimum a rib or hole spacing away. Along a weak
    // direction, try offsets up to diag/15 and keep the one whose pose explains the most
    // points, then polish again from it.
    if (weak.ratio < p.weak_direction_ratio) {
      const double step = 0.25 * diag * p.fine_voxel, reach = diag / 15;
      const double base_count = count(explained(best.T));
      const auto [best_offset, best_count] = most_explained(
          [&](double d) {
            Pose S = Pose::Identity();
            S.translation() = d * weak.dir;
            return S;
          },
          reach, step, base_count);
      spdlog::debug("register: weak direction [{:.3f} {:.3f} {:.3f}] (eigenvalue ratio {:.3g}): "
                    "best offset {:.2f} mm explains {:.0f} vs {:.0f}",
                    weak.dir.x(), weak.dir.y(), weak.dir.z(), weak.ratio, best_offset * 1e3,
                    best_count, base_count);
      Weak last = weak;
      if (best_count > base_count * (1 + p.weak_direction_gain)) {
        Pose S = Pose::Identity();
        S.translation() = best_offset * weak.dir;
        best.T = S * best.T;
        last = polish(best.T);
      }
      const WeakProfile wp = settle_along(best.T, weak.dir, last.sigma);
      res.weak_direction_peak = wp.peak_ratio;
      determined = wp.peak_ratio >= p.weak_direction_peak;
      latest = last;
    }
    // A part nearly round about an axis (a domed cover, a round flange) has its turn about it
    // fixed by a few features (bolt holes, a flange's corners); where the polish stopped turned
    // off them, the robust weights dropped those features and the turn is left to the round
    // surfaces, which do not care (cover 9011: 5.3° off, confident, the burr ground the flange's
    // side). As along a weak translation: turns up to (diag/15)/(diag/2) about the weakest
    // axis, a quarter fine voxel at half the diagonal apart; the one explaining the most points
    // is taken when it explains weak_direction_gain more, and polished.
    if (latest.turn_ratio < p.weak_turn_ratio) {
      const double r = 0.5 * diag, step = 0.25 * diag * p.fine_voxel / r, reach = (diag / 15) / r;
      const double base_count = count(explained(best.T));
      const auto turned = [&](double a) {
        Pose S = Pose::Identity();
        S.linear() = Eigen::AngleAxisd(a, latest.turn_axis).toRotationMatrix();
        S.translation() = latest.turn_point - S.linear() * latest.turn_point;
        return S;
      };
      const auto [best_angle, best_count] = most_explained(turned, reach, step, base_count);
      spdlog::debug("register: weak turn about [{:.3f} {:.3f} {:.3f}] (stiffness ratio {:.3g}): best "
                    "turn {:.3f} deg explains {:.0f} vs {:.0f}",
                    latest.turn_axis.x(), latest.turn_axis.y(), latest.turn_axis.z(), latest.turn_ratio,
                    best_angle * 180 / M_PI, best_count, base_count);
      if (best_count > base_count * (1 + p.weak_direction_gain)) {
        best.T = turned(best_angle) * best.T;
        polish(best.T);
      }
    }
  }
  const auto t_icp = std::chrono::steady_clock::now();

  // Verdict: inliers among all fine points by their point-to-plane residual to the model
  // (distances to the nearest model sample would add the sample spacing), and their RMSE.
  {
    const Eigen::Matrix3f R = best.T.linear().cast<float>();
    const Vec3f t = best.T.translation().cast<float>();
    const auto n = static_cast<long>(fine.size());
    // Squared residual per point (-1: not an inlier), summed in point order afterwards: a
    // parallel reduction would add in an order that depends on the thread count, and the
    // verdict must not.
    std::vector<double> e2(fine.size(), -1.0);
#pragma omp parallel for schedule(static) if (n >= 8192)
    for (long i = 0; i < n; ++i) {
      std::uint32_t j;
      const Vec3f q = R * fine.points[i] + t;
      if (!tgt.nearest_in_band(q, j)) continue;
      const double e = (tgt.dense.points[j] - q).dot(tgt.dense.normals[j]);
      if (std::abs(e) <= inlier) e2[i] = e * e;
    }
    long in = 0;
    double sum2 = 0;
    for (const double v : e2)
      if (v >= 0) {
        ++in;
        sum2 += v;
      }
    res.fitness = static_cast<double>(in) / static_cast<double>(fine.size());
    res.rmse = in ? std::sqrt(sum2 / static_cast<double>(in)) : 0;
  }
  const auto ms = [](auto a, auto b) { return std::chrono::duration<double, std::milli>(b - a).count(); };
  spdlog::debug("register: preprocess = fine voxel {:.1f} + coarse/SOR {:.1f} + normals {:.1f} + subset {:.1f} ms",
                ms(t0, t_fine), ms(t_fine, t_coarse), ms(t_coarse, t_cn), ms(t_cn, t_pre));
  spdlog::debug("register: {} fine / {} coarse / {} ICP points; preprocess {:.1f} ms, global ({} "
                "hypotheses) {:.1f} ms, fine ICP {:.1f} ms ({} iterations), verdict {:.1f} ms",
                fine.size(), coarse.size(), sub.size(), ms(t0, t_pre), hyps.size(), ms(t_pre, t_global),
                ms(t_global, t_icp), best.iterations, ms(t_icp, std::chrono::steady_clock::now()));
  res.T_target_source = best.T;
  res.stage = hyps[0].stage;
  res.ran = true;
  const bool fit_ok = res.fitness >= p.min_fitness;
  const bool rmse_ok = res.rmse <= diag * p.max_rmse;
  const bool unique = res.ambiguity <= p.max_ambiguity;
  res.confident = fit_ok && rmse_ok && unique && determined;
  if (!fit_ok)
    res.message = "low inlier fraction " + std::to_string(res.fitness) + " (need " +
                  std::to_string(p.min_fitness) + ")";
  else if (!rmse_ok)
    res.message = "inlier RMSE " + std::to_string(res.rmse * 1000) + " mm too high";
  else if (!unique)
    res.message = "ambiguous: a distinct pose fits almost as well (symmetric part?), ambiguity " +
                  std::to_string(res.ambiguity);
  else if (!determined)
    res.message = "weakly constrained: the surfaces facing the weakest translation direction do "
                  "not agree on one position along it (peak ratio " +
                  std::to_string(res.weak_direction_peak) + ")";
  else
    res.message = "ok";
  return finish();
}

}  // namespace flashtwin::perception
