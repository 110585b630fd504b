// The project's registration: PCA principal-axis alignment + 4PCS + normal-constrained ICP.
#include "flashtwin/perception/registration.hpp"

#include <Eigen/Eigenvalues>
#include <Eigen/Geometry>
#include <algorithm>
#include <chrono>
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
  const int r = 3;
  std::unordered_map<std::uint64_t, std::pair<float, std::uint32_t>> best;
  best.reserve(t.dense.size() * 30);
  for (std::uint32_t i = 0; i < t.dense.size(); ++i) {
    const Vec3f& q = t.dense.points[i];
    const Eigen::Vector3f c0 = (q / static_cast<float>(t.cell)).array().floor();
    for (int dx = -r; dx <= r; ++dx)
      for (int dy = -r; dy <= r; ++dy)
        for (int dz = -r; dz <= r; ++dz) {
          const Vec3f centre = (c0 + Vec3f(dx + 0.5f, dy + 0.5f, dz + 0.5f)) * static_cast<float>(t.cell);
          const float d2 = (centre - q).squaredNorm();
          auto [it, fresh] = best.emplace(t.cell_key(centre), std::make_pair(d2, i));
          if (!fresh && d2 < it->second.first) it->second = {d2, i};
        }
  }
  std::uint64_t cap = 16;
  while (cap < 2 * best.size()) cap <<= 1;
  t.band_keys.assign(cap, 0);
  t.band_vals.assign(cap, 0);
  t.band_mask = cap - 1;
  for (const auto& [key, v] : best) {
    std::uint64_t h = ModelTarget::Impl::mix(key + 1) & t.band_mask;
    while (t.band_keys[h] != 0) h = (h + 1) & t.band_mask;
    t.band_keys[h] = key + 1;
    t.band_vals[h] = v.second;
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
  std::vector<std::pair<std::uint32_t, float>> nb;
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
    const KdTree e1_tree(e1);
    int candidates = 0;
    for (auto it = lo2; it != hi2 && candidates < 400; ++it)
      for (int o = 0; o < 2 && candidates < 400; ++o) {
        const std::uint32_t c = o ? it->b : it->a, d = o ? it->a : it->b;
        const Vec3f e2 = tgt.fpcs_points[c] + static_cast<float>(r2) * (tgt.fpcs_points[d] - tgt.fpcs_points[c]);
        e1_tree.radius(e2, static_cast<float>(delta), nb);
        for (const auto& [k, dist] : nb) {
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
            std::uint32_t j;
            float dd;
            ++seen;
            if (tgt.dense_tree->nearest(R * v + t, j, dd) && dd <= v2) ++in;
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
  const double pca_best =
      hyps.empty() ? 0.0 : std::max_element(hyps.begin(), hyps.end(), [](const auto& a, const auto& b) {
                             return a.score < b.score;
                           })->score;
  if (p.use_4pcs && pca_best < p.pca_accept_fitness) {
    for (const auto& h : four_pcs(global.points, tgt, p, rng)) refine_and_score(h.T, "4pcs");
  }
  if (hyps.empty()) {
    res.message = "no global alignment hypothesis (PCA and 4PCS disabled or failed)";
    return finish();
  }
  auto by_score = [](const auto& a, const auto& b) { return a.score > b.score; };
  std::sort(hyps.begin(), hyps.end(), by_score);
  auto second_distinct = [&](const std::vector<Hypothesis>& h) {
    for (std::size_t k = 1; k < h.size(); ++k)
      if (distinct(h[k].T, h[0].T, diag)) return h[k].score;
    return 0.0;
  };
  // Symmetry sweep: unless the coarse ranking is decisive (near-symmetric or partially seen
  // parts), also try the best pose turned about each principal axis of the model in 30° steps.
  // Skipped only when the coarse level is already clear: a near-complete fit and no close rival.
  const bool clear = hyps[0].score > 0.95 && second_distinct(hyps) < 0.8 * hyps[0].score;
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
  // explained by a pose when its point-to-plane residual is within `tight`. The winner
  // explains the most; the runner-up decides the ambiguity from the points the two disagree
  // on (D1: only the winner explains them, D2: only the runner-up), so that a small datum
  // feature (a flat, a hole) decides even when most of the part is symmetric.
  std::vector<Hypothesis> finalists;
  std::vector<std::vector<char>> expl;
  // Explained = close to the model (point-to-plane within `tight`) with a compatible normal:
  // the normal test keeps flash fins, which stick out flat from walls, from "explaining" a
  // wrongly placed wall.
  const float cos_tau = static_cast<float>(std::cos(p.normal_angle));
  const bool signed_n = p.viewpoint.allFinite();
  // Evidence points: the ICP subset when the coarse level is clear, otherwise up to 20,000
  // fine points with their own normals (small datum features need many points to be seen).
  PointCloud evidence_cloud;
  if (!clear) {
    const std::size_t stride = std::max<std::size_t>(1, fine.size() / 20000);
    for (std::size_t i = 0; i < fine.size(); i += stride) evidence_cloud.points.push_back(fine.points[i]);
    estimate_normals(evidence_cloud, p.normal_k, p.viewpoint);
  }
  const PointCloud& evidence = clear ? sub : evidence_cloud;
  auto explained = [&](const Pose& T) {
    std::vector<char> e(evidence.size(), 0);
    const Eigen::Matrix3f R = T.linear().cast<float>();
    const Vec3f t = T.translation().cast<float>();
    const auto n = static_cast<long>(evidence.size());
#pragma omp parallel for schedule(static) if (n >= 8192)
    for (long i = 0; i < n; ++i) {
      std::uint32_t j;
      const Vec3f q = R * evidence.points[i] + t;
      if (!tgt.nearest_in_band(q, j)) continue;
      if (std::abs((tgt.dense.points[j] - q).dot(tgt.dense.normals[j])) > static_cast<float>(tight)) continue;
      const float c = (R * evidence.normals[i]).dot(tgt.dense.normals[j]);
      e[i] = (signed_n ? c : std::abs(c)) >= cos_tau;
    }
    return e;
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
      const double count = static_cast<double>(std::count(expl.back().begin(), expl.back().end(), 1));
      finalists.push_back({r.T, count, h.stage});
      if (finalists.size() >= 16 || alone) break;
    }
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
  std::size_t win = 0, runner = 0;
  for (std::size_t k = 1; k < finalists.size(); ++k)
    if (finalists[k].score > finalists[win].score) win = k;
  // With a single finalist, the coarse level decides: unexplained share of the best over that
  // of the best distinct alternative.
  const double s2 = second_distinct(hyps);
  res.ambiguity = s2 > 0 ? std::min(1.0, (1 - hyps[0].score + 1e-3) / (1 - s2 + 1e-3)) : 0.0;
  if (finalists.size() > 1) {
    runner = win == 0 ? 1 : 0;
    for (std::size_t k = 0; k < finalists.size(); ++k)
      if (k != win && finalists[k].score > finalists[runner].score) runner = k;
    double d1 = 0, d2 = 0;
    for (std::size_t i = 0; i < evidence.size(); ++i) {
      d1 += expl[win][i] && !expl[runner][i];
      d2 += expl[runner][i] && !expl[win][i];
    }
    // A handful of disagreeing points decides nothing: the +5 keeps small counts ambiguous.
    res.ambiguity = std::min(1.0, (d2 + 5) / (d1 + 5));
  }
  // Local search around the winner: small turns about the model's principal axes (the sweep's
  // 30° grid and short ICP runs can leave a near-symmetric part a few degrees off).
  if (!clear) {
    auto count = [](const std::vector<char>& e) { return static_cast<double>(std::count(e.begin(), e.end(), 1)); };
    Pose centre = finalists[win].T;
    double best_count = finalists[win].score;
    for (double step : {8.0, 4.0, 2.0, 1.0}) {
      bool improved = true;
      while (improved) {
        improved = false;
        for (int axis = 0; axis < 3; ++axis)
          for (double sign : {-1.0, 1.0}) {
            Pose turn = Pose::Identity();
            turn.linear() = Eigen::AngleAxisd(sign * step * M_PI / 180, tgt.axes.col(axis)).toRotationMatrix();
            turn.translation() = tgt.centroid - turn.linear() * tgt.centroid;
            const Pose cand = turn * centre;
            const double c = count(explained(cand));
            if (c > best_count * 1.002) {
              best_count = c;
              centre = cand;
              improved = true;
            }
          }
      }
    }
    if (best_count > finalists[win].score) {
      IcpOptions quick = fine_icp;
      quick.iterations = 8;
      finalists[win].T = icp(sub.points, sub.normals, sub_tree, dense_t, diag, centre, quick).T;
    }
  }
  hyps[0] = finalists[win];

  IcpResult best = icp(sub.points, sub.normals, sub_tree, dense_t, diag, hyps[0].T, fine_icp);
  // Polish: every fine point, robust point-to-plane against the O(1) band lookup (the
  // noise-limited accuracy grows with the number of points).
  if (p.point_to_plane) {
    const auto n = static_cast<long>(fine.size());
    std::vector<float> resid(fine.size());
    std::vector<std::uint32_t> match(fine.size());
    for (int it = 0; it < p.polish_iterations; ++it) {
      const Eigen::Matrix3f R = best.T.linear().cast<float>();
      const Vec3f t = best.T.translation().cast<float>();
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
        const Vec3 pp = best.T * fine.points[i].cast<double>();
        const Vec3 nq = tgt.dense.normals[match[i]].cast<double>();
        Eigen::Matrix<double, 6, 1> a;
        a << pp.cross(nq), nq;
        const double u = e / scale, w = 1.0 / ((1 + u * u) * (1 + u * u));
        AtA += w * a * a.transpose();
        Atb += w * a * e;
      }
      const Eigen::Matrix<double, 6, 1> x = AtA.ldlt().solve(Atb);
      if (!x.allFinite()) break;
      Pose dT = Pose::Identity();
      dT.linear() = skew_exp(x.head<3>());
      dT.translation() = x.tail<3>();
      best.T = dT * best.T;
      if (scale <= 3.5 * sigma * 1.0001 && x.norm() < 1e-8) break;
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
  res.confident = fit_ok && rmse_ok && unique;
  if (!fit_ok)
    res.message = "low inlier fraction " + std::to_string(res.fitness) + " (need " +
                  std::to_string(p.min_fitness) + ")";
  else if (!rmse_ok)
    res.message = "inlier RMSE " + std::to_string(res.rmse * 1000) + " mm too high";
  else if (!unique)
    res.message = "ambiguous: a distinct pose fits almost as well (symmetric part?), ambiguity " +
                  std::to_string(res.ambiguity);
  else
    res.message = "ok";
  return finish();
}

}  // namespace flashtwin::perception
