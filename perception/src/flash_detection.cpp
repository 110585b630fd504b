#include "flashtwin/perception/flash_detection.hpp"

#include <Eigen/Eigenvalues>
#include <algorithm>
#include <chrono>
#include <deque>
#include <cmath>
#include <limits>
#include <map>
#include <optional>
#include <numeric>
#include <set>
#include <queue>
#include <sstream>

#include <spdlog/spdlog.h>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "kdtree.hpp"

namespace flashtwin::perception {

double FlashPath::length() const {
  double L = 0;
  for (std::size_t i = 1; i < points_C.size(); ++i) L += (points_C[i] - points_C[i - 1]).norm();
  if (closed && points_C.size() > 2) L += (points_C.front() - points_C.back()).norm();
  return L;
}

namespace {

using Clock = std::chrono::steady_clock;

double percentile(std::vector<double> v, double q) {
  if (v.empty()) return 0;
  const auto k = static_cast<std::size_t>(std::clamp(q, 0.0, 1.0) * (v.size() - 1));
  std::nth_element(v.begin(), v.begin() + static_cast<std::ptrdiff_t>(k), v.end());
  return v[k];
}

void check_params(const DetectionParams& p) {
  auto bad = [](const char* field, const char* expected, double got) {
    std::ostringstream os;
    os << "detection parameter '" << field << "': expected " << expected << ", got " << got;
    throw ArgumentError(os.str());
  };
  if (!(p.crop_margin >= 0 && p.crop_margin < 1)) bad("crop_margin", "[0, 1) m", p.crop_margin);
  if (!(p.noise_sigma < 0.01) || std::isnan(p.noise_sigma))
    bad("noise_sigma", "< 0.01 m (negative: estimate)", p.noise_sigma);
  if (!(p.threshold_sigmas > 0)) bad("threshold_sigmas", "> 0", p.threshold_sigmas);
  if (!(p.min_threshold > 0 && p.max_threshold >= p.min_threshold))
    bad("min_threshold/max_threshold", "0 < min <= max", p.min_threshold);
  if (!(p.cluster_tolerance >= 0)) bad("cluster_tolerance", ">= 0 m", p.cluster_tolerance);
  if (p.min_region_points < 3) bad("min_region_points", ">= 3", p.min_region_points);
  if (!(p.fragment_merge >= 0 && p.fragment_merge <= 20))
    bad("fragment_merge", "0..20 (<= 1: off)", p.fragment_merge);
  if (!(p.support_distance > 0)) bad("support_distance", "> 0 m", p.support_distance);
  if (!(p.alpha >= 0)) bad("alpha", ">= 0 m", p.alpha);
  if (!(p.inner_band >= 0)) bad("inner_band", ">= 0 m", p.inner_band);
  if (!(p.hidden_root_band >= 0) || !std::isfinite(p.hidden_root_band))
    bad("hidden_root_band", ">= 0 m", p.hidden_root_band);
  if (!(p.path_voxel > 0)) bad("path_voxel", "> 0 m", p.path_voxel);
  if (!(p.gap >= 0)) bad("gap", ">= 0 m", p.gap);
  if (p.smoothing < 0) bad("smoothing", ">= 0", p.smoothing);
}

// A plane through c with unit normal n; after a fit, axes holds the principal directions
// (columns by increasing spread: normal, minor, major).
struct Plane {
  Vec3 c = Vec3::Zero();
  Vec3 n = Vec3::UnitZ();
  Mat3 axes = Mat3::Identity();
  Vec3 spread = Vec3::Zero();  ///< eigenvalues of the scatter matrix, by the axes' order
  double dist(const Vec3& p) const { return n.dot(p - c); }
};

// Least-squares plane (PCA) of a point set: normal = smallest eigenvector.
Plane fit_plane(const std::vector<Vec3>& pts) {
  Plane pl;
  for (const auto& p : pts) pl.c += p;
  pl.c /= static_cast<double>(std::max<std::size_t>(1, pts.size()));
  Mat3 C = Mat3::Zero();
  for (const auto& p : pts) C += (p - pl.c) * (p - pl.c).transpose();
  Eigen::SelfAdjointEigenSolver<Mat3> es(C);
  pl.axes = es.eigenvectors();
  pl.spread = es.eigenvalues();
  pl.n = pl.axes.col(0).normalized();
  return pl;
}

// The plane of a fin region: the plane through three of its points that most points lie
// within `band` of, among those holding at least half the points that touch the casting
// (`touch`: a fin grows out of the casting along its root, a fixture's top beside it does
// not; a plane through a fixture's top and a few root points does not count), by RANSAC
// (256 draws from a fixed seed over about 4000 of the points), refitted by least squares to
// those within the band. A region whose points reach a fixture standing beside its fin
// (round_flange 6115: a clamp block's face and top, up to 17 mm above the fin) tilted the plain
// fit by 15°; the mid-plane then climbed 9 mm off the root along a 230 mm rim. The plain fit
// stands when it also holds half the touching points and as many points (`consensus` false).
Plane fit_fin_plane(const std::vector<Vec3>& pts, const std::vector<bool>& touch, double band,
                    bool* consensus) {
  FT_ASSERT(touch.size() == pts.size());
  if (consensus) *consensus = false;
  const Plane plain = fit_plane(pts);
  if (pts.size() < 10) return plain;
  const auto count = [&](const Plane& pl, std::size_t* touching) {
    std::size_t k = 0, t = 0;
    for (std::size_t i = 0; i < pts.size(); ++i) {
      const bool in = std::abs(pl.dist(pts[i])) <= band;
      k += in;
      t += in && touch[i];
    }
    if (touching) *touching = t;
    return k;
  };
  std::vector<std::size_t> sub, sub_touch;
  const std::size_t stride = std::max<std::size_t>(1, (pts.size() + 3999) / 4000);
  for (std::size_t i = 0; i < pts.size(); i += stride) sub.push_back(i);
  for (std::size_t i = 0; i < pts.size(); ++i)
    if (touch[i]) sub_touch.push_back(i);
  if (sub_touch.size() < 3) return plain;  // (all the touching points: a few thousand at most)
  Rng rng(0x5eed);
  Plane best;
  std::size_t best_k = 0;
  for (int it = 0; it < 256; ++it) {
    const auto pick = [&] { return sub[static_cast<std::size_t>(rng.uniform() * sub.size()) % sub.size()]; };
    const Vec3 &a = pts[pick()], &b = pts[pick()], &c = pts[pick()];
    const Vec3 n = (b - a).cross(c - a);
    if (n.norm() < 1e-9) continue;
    Plane cand;
    cand.c = a;
    cand.n = n.normalized();
    std::size_t k = 0, t = 0;
    for (std::size_t i : sub) k += std::abs(cand.dist(pts[i])) <= band;
    if (k <= best_k) continue;
    for (std::size_t i : sub_touch) t += std::abs(cand.dist(pts[i])) <= band;
    if (2 * t < sub_touch.size()) continue;
    best_k = k;
    best = cand;
  }
  if (best_k == 0) return plain;
  std::vector<Vec3> in;
  for (const auto& p : pts)
    if (std::abs(best.dist(p)) <= band) in.push_back(p);
  if (in.size() < 3) return plain;
  const Plane refit = fit_plane(in);
  std::size_t refit_touch = 0, plain_touch = 0;
  const std::size_t refit_k = count(refit, &refit_touch), plain_k = count(plain, &plain_touch);
  if (2 * refit_touch < sub_touch.size()) return plain;
  // The plain fit stands when it holds the root too and at least as many points.
  if (2 * plain_touch >= sub_touch.size() && plain_k >= refit_k) return plain;
  if (consensus) *consensus = true;
  return refit;
}

// Support planes (table, fixture faces): RANSAC planes through many candidates with the whole
// CAD model on one side; a fin's plane cuts through the part, so it is never taken for one.
// A support removes its own points and the candidates behind it, but only over its footprint:
// the 2 mm cells of the plane (and two cells round them) where its inliers lie on a surface along
// the plane (neighbourhood normal within 45° of it: under 5× scanner noise a 30° test left holes
// in a fixture's footprint whose points became false flash). A fixture's face is a few centimetres wide; behind its plane beyond its edges
// stand fins of the casting (past the outer face of a clamp block beside the part), and a fin
// crossing the plane leaves inliers on a strip across it whose neighbourhood is no surface
// along the plane. Returns the candidates still alive.
std::vector<bool> support_plane_mask(const std::vector<Vec3>& pc,
                                     const std::vector<std::uint32_t>& cand,
                                     const detail::KdTree& cand_tree,
                                     const std::vector<Eigen::Vector3f>& cf,
                                     const std::vector<double>& dist, const TriangleMesh& cad,
                                     const DetectionParams& P, std::size_t& support_points) {
  constexpr double kCell = 2e-3;  // [m] footprint cells, and the neighbourhood of a cell's fit
  std::vector<bool> alive(cand.size(), true);
  Rng rng(12345);
  std::vector<bool> excluded(cand.size(), false);
  std::vector<std::pair<std::uint32_t, float>> nb;
  for (int plane_no = 0; plane_no < 6; ++plane_no) {
    std::vector<std::uint32_t> pool;
    for (std::size_t c = 0; c < cand.size(); ++c)
      if (alive[c] && !excluded[c]) pool.push_back(static_cast<std::uint32_t>(c));
    if (pool.size() < static_cast<std::size_t>(P.min_region_points)) break;
    const std::size_t probe_step = std::max<std::size_t>(1, pool.size() / 4000);
    Plane best;
    std::size_t best_count = 0;
    for (int it = 0; it < 300; ++it) {
      const Vec3 a = pc[cand[pool[static_cast<std::size_t>(rng.uniform() * pool.size())]]];
      const Vec3 b = pc[cand[pool[static_cast<std::size_t>(rng.uniform() * pool.size())]]];
      const Vec3 c = pc[cand[pool[static_cast<std::size_t>(rng.uniform() * pool.size())]]];
      Vec3 nn = (b - a).cross(c - a);
      if (nn.norm() < 1e-12) continue;
      Plane pl;
      pl.n = nn.normalized();
      pl.c = a;
      std::size_t count = 0;
      for (std::size_t q = 0; q < pool.size(); q += probe_step)
        count += std::abs(pl.dist(pc[cand[pool[q]]])) < P.support_distance;
      if (count > best_count) {
        best_count = count;
        best = pl;
      }
    }
    std::vector<std::uint32_t> inl;
    for (auto q : pool)
      if (std::abs(best.dist(pc[cand[q]])) < P.support_distance) inl.push_back(q);
    if (inl.size() < static_cast<std::size_t>(P.min_region_points)) break;
    std::vector<Vec3> ip;
    for (auto q : inl) ip.push_back(pc[cand[q]]);
    best = fit_plane(ip);
    double smin = 1e300, smax = -1e300;
    for (const auto& v : cad.vertices) {
      const double sv = best.dist(v);
      smin = std::min(smin, sv);
      smax = std::max(smax, sv);
    }
    // A plane along one of the CAD's own faces, through the noisy tail of that face's points
    // (an obliquely seen face is noisier than the threshold assumes), also has the whole CAD
    // on one side, yet it is no support: behind it stand the fins that grow out of that face.
    // Many of its inliers hug the CAD (a fifth: fins standing on the face add inliers off
    // it); a table's or fixture's points lie off it.
    std::size_t hugging = 0;
    for (auto q : inl) hugging += dist[cand[q]] < P.support_distance;
    const bool cad_face = 5 * hugging >= inl.size();
    const bool support =
        !cad_face && (smin > -P.support_side_tolerance || smax < P.support_side_tolerance);
    if (!support) {
      for (auto q : inl) excluded[q] = true;
      spdlog::debug("detect: plane {} n=({:.3f},{:.3f},{:.3f}) offset {:.4f}: {} inliers ({} on "
                    "the CAD), CAD side [{:.4f}, {:.4f}] -> {}",
                    plane_no, best.n.x(), best.n.y(), best.n.z(), best.n.dot(best.c), inl.size(),
                    hugging, smin, smax, cad_face ? "kept (a CAD face)" : "kept");
      continue;
    }
    // Footprint: cells whose inliers (off the CAD) have a neighbourhood lying along the plane,
    // or too thin to tell (one scan line); one fit per cell.
    const Vec3 eu = best.axes.col(2), ev = best.axes.col(1);
    const auto cell_of = [&](const Vec3& x) {
      const auto iu = static_cast<std::int64_t>(std::floor(eu.dot(x - best.c) / kCell));
      const auto iv = static_cast<std::int64_t>(std::floor(ev.dot(x - best.c) / kCell));
      return std::pair<std::int64_t, std::int64_t>(iu, iv);
    };
    std::map<std::pair<std::int64_t, std::int64_t>, Vec3> cell_sum;
    std::map<std::pair<std::int64_t, std::int64_t>, int> cell_count;
    for (auto q : inl) {
      if (dist[cand[q]] < P.support_distance) continue;
      const auto key = cell_of(pc[cand[q]]);
      auto [it, fresh] = cell_sum.try_emplace(key, Vec3::Zero());
      it->second += pc[cand[q]];
      ++cell_count[key];
    }
    std::set<std::pair<std::int64_t, std::int64_t>> footprint;
    for (const auto& [key, sum] : cell_sum) {
      const Vec3 centre = sum / cell_count[key];
      cand_tree.radius(centre.cast<float>(), static_cast<float>(kCell), nb);
      std::vector<Vec3> local;
      for (const auto& [j, d2] : nb) local.push_back(cf[j].cast<double>());
      const Plane lp = fit_plane(local);
      const bool thin = local.size() < 5 || lp.spread(1) < 0.05 * lp.spread(2);
      if (thin || std::abs(lp.n.dot(best.n)) > std::cos(M_PI / 4)) footprint.insert(key);
    }
    const double side = smin > -P.support_side_tolerance ? 1.0 : -1.0;
    std::size_t dropped = 0;
    for (std::size_t c = 0; c < cand.size(); ++c) {
      if (!alive[c] || side * best.dist(pc[cand[c]]) >= P.support_distance) continue;
      const auto [iu, iv] = cell_of(pc[cand[c]]);
      bool on = false;
      for (std::int64_t du = -2; du <= 2 && !on; ++du)
        for (std::int64_t dv = -2; dv <= 2 && !on; ++dv) on = footprint.count({iu + du, iv + dv}) > 0;
      if (!on) continue;
      alive[c] = false;
      ++dropped;
    }
    support_points += dropped;
    // Inliers off the footprint are not this plane's: never tried again as a support's.
    for (auto q : inl)
      if (alive[q]) excluded[q] = true;
    spdlog::debug("detect: plane {} n=({:.3f},{:.3f},{:.3f}) offset {:.4f}: {} inliers ({} on the "
                  "CAD), CAD side [{:.4f}, {:.4f}] -> support over {} cells: {} points dropped",
                  plane_no, best.n.x(), best.n.y(), best.n.z(), best.n.dot(best.c), inl.size(),
                  hugging, smin, smax, footprint.size(), dropped);
  }
  return alive;
}

}  // namespace

// Direction: with the fin normal up, walk so that tangent · (n_fin × n_surface) > 0.
void orient_path(FlashPath& path) {
  double dir = 0;
  for (std::size_t i = 1; i < path.points_C.size(); ++i)
    dir += (path.points_C[i] - path.points_C[i - 1]).dot(path.fin_normal_C.cross(path.normals_C[i]));
  if (dir < 0) {
    std::reverse(path.points_C.begin(), path.points_C.end());
    std::reverse(path.normals_C.begin(), path.normals_C.end());
  }
}

// Shortest arc of a hole's ring that is closed into the whole ring [rad] (the planner treats an
// open arc of 45° or more on an inward-facing wall as a hole too).
constexpr double kMinHoleArc = M_PI / 4;

int close_hole_arc(FlashPath& path, const MeshBvh& cad_C, const Vec3& w, double step,
                   double fit_tol, double min_swept = M_PI);

// The CAD's section by the plane w·x = h within a box: the segments where its triangles cross
// the plane, each with its triangle's normal. A fin's root is where its mid-plane meets the
// wall, so the root lies on this section whatever the wall's slope or curvature.
struct PlaneSection {
  std::vector<std::pair<Vec3, Vec3>> segments;
  std::vector<Vec3> normals;

  PlaneSection(const TriangleMesh& cad, const Vec3& w, double h, const Vec3& lo, const Vec3& hi) {
    for (std::size_t t = 0; t < cad.triangles.size(); ++t) {
      const auto& tri = cad.triangles[t];
      Vec3 v[3];
      double d[3];
      for (int k = 0; k < 3; ++k) {
        v[k] = cad.vertices[static_cast<std::size_t>(tri[k])];
        d[k] = w.dot(v[k]) - h;
      }
      // The triangle's bounding box meets the box (a wall's triangles can span its whole height
      // with no vertex near the fin).
      const Vec3 t_lo = v[0].cwiseMin(v[1]).cwiseMin(v[2]), t_hi = v[0].cwiseMax(v[1]).cwiseMax(v[2]);
      if ((t_hi.array() < lo.array()).any() || (t_lo.array() > hi.array()).any()) continue;
      std::vector<Vec3> cut;  // where the edges cross the plane
      for (int k = 0; k < 3; ++k) {
        const int j = (k + 1) % 3;
        if ((d[k] < 0) != (d[j] < 0)) cut.push_back(v[k] + (d[k] / (d[k] - d[j])) * (v[j] - v[k]));
      }
      if (cut.size() != 2) continue;
      segments.emplace_back(cut[0], cut[1]);
      normals.push_back(cad.triangle_normal(t));
    }
  }

  // The section point nearest p within max_d, and its wall normal; false when there is none.
  bool closest(const Vec3& p, double max_d, Vec3& q, Vec3& n) const {
    double best = max_d * max_d;
    bool found = false;
    for (std::size_t i = 0; i < segments.size(); ++i) {
      const auto& [a, b] = segments[i];
      const Vec3 ab = b - a;
      const double u = std::clamp(ab.dot(p - a) / std::max(ab.squaredNorm(), 1e-30), 0.0, 1.0);
      const Vec3 c = a + u * ab;
      const double d2 = (c - p).squaredNorm();
      if (d2 < best) {
        best = d2;
        q = c;
        n = normals[i];
        found = true;
      }
    }
    return found;
  }
};

// A closed hole loop onto its fitted circle: each point keeps its angle, its radius becomes the
// circle's and its height along `w` a moving average over ±3 points. The burr's centre runs on
// a circle only a few millimetres across, where a tenth of a millimetre of scatter in the root
// points becomes a zig-zag that plunges the burr in and out of the fin. Then each point goes
// onto the CAD wall itself (its closest point, when within `fit_tol`), with that face's
// normal: a fitted circle off by a tenth somewhere is a tenth of gouge there.
void snap_to_circle(FlashPath& path, const Vec3& w, const MeshBvh& cad_C, double fit_tol) {
  auto& P = path.points_C;
  const int n = static_cast<int>(P.size());
  if (!path.closed || n < 8) return;
  const ArcFit arc = fit_arc(P, w, path.normals_C);
  if (!arc.ok) return;
  std::vector<Vec3> out(P.size());
  for (int i = 0; i < n; ++i) {
    double h = 0;
    for (int k = -3; k <= 3; ++k) h += arc.w.dot(P[static_cast<std::size_t>(((i + k) % n + n) % n)]);
    out[static_cast<std::size_t>(i)] = arc.point(arc.angle[static_cast<std::size_t>(i)], h / 7);
    const auto cp = cad_C.closest(out[static_cast<std::size_t>(i)], fit_tol);
    if (cp.triangle >= 0) {
      out[static_cast<std::size_t>(i)] = cp.point;
      path.normals_C[static_cast<std::size_t>(i)] =
          cad_C.mesh().triangle_normal(static_cast<std::size_t>(cp.triangle));
    }
  }
  P = std::move(out);
}

// The direction an open path leaves at one end (front: towards its first point), from its
// points within `span` of that end; zero when they do not reach that far.
static Vec3 path_end_direction(const FlashPath& p, bool front, double span) {
  const auto& q = p.points_C;
  const Vec3& end = front ? q.front() : q.back();
  for (std::size_t k = 1; k < q.size(); ++k) {
    const Vec3& inner = front ? q[k] : q[q.size() - 1 - k];
    if ((inner - end).norm() >= span) return (end - inner).normalized();
  }
  return Vec3::Zero();
}

// One fin's root split between regions (a region boundary where two views' points meet, a
// stretch seen by one view only) comes out as open paths that continue each other; ground
// apart, each end has its own approach and retract, and the finishing pass of the first runs
// its end into the next one's fin still standing at full height (housing 7015: 95 N at the
// end, the arm pushed 0.13 mm into the wall). Open paths whose ends lie within `reach` of each
// other, both leaving within 30° of the same line and with fin planes within 20°, become one:
// the second's leading points up to the first one past the junction (overlapping ends) are
// dropped, and the second's end must lie within span/2 of the first's end line. Returns how
// many paths were joined into others.
int join_continuing_paths(std::vector<FlashPath>& paths, double reach, double span) {
  const double cos30 = std::cos(M_PI / 6), cos20 = std::cos(M_PI / 9);
  int joined = 0;
  for (bool again = true; again;) {
    again = false;
    for (std::size_t i = 0; i < paths.size() && !again; ++i) {
      for (std::size_t j = 0; j < paths.size() && !again; ++j) {
        FlashPath& a = paths[i];
        FlashPath& b = paths[j];
        if (i == j || a.closed || b.closed || a.points_C.size() < 2 || b.points_C.size() < 2) continue;
        if (std::abs(a.fin_normal_C.dot(b.fin_normal_C)) < cos20) continue;
        // a's back end meets b's front end (the other pairings by reversing either).
        for (int flip = 0; flip < 4 && !again; ++flip) {
          const bool a_front = flip & 1, b_back = flip & 2;
          const Vec3 ea = a_front ? a.points_C.front() : a.points_C.back();
          const Vec3 eb = b_back ? b.points_C.back() : b.points_C.front();
          if ((ea - eb).norm() > reach) continue;
          const Vec3 ta = path_end_direction(a, a_front, span);   // leaving a
          const Vec3 tb = path_end_direction(b, !b_back, span);   // leaving b, towards a
          if (ta.isZero() || tb.isZero() || ta.dot(-tb) < cos30) continue;
          // On one line: b's end no more than span/2 to the side of a's end line (two parallel
          // fins' ends can lie within reach).
          const Vec3 d = eb - ea;
          if ((d - d.dot(ta) * ta).norm() > 0.5 * span) continue;
          FlashPath m = a;
          if (a_front) {
            std::reverse(m.points_C.begin(), m.points_C.end());
            std::reverse(m.normals_C.begin(), m.normals_C.end());
          }
          std::vector<Vec3> bp = b.points_C, bn = b.normals_C;
          if (b_back) {
            std::reverse(bp.begin(), bp.end());
            std::reverse(bn.begin(), bn.end());
          }
          // b's leading points up to the first one past the junction overlap a's end.
          const Vec3 junction = m.points_C.back();
          std::size_t k0 = 0;
          while (k0 < bp.size() && (bp[k0] - junction).dot(ta) <= 0.25 * span) ++k0;
          m.points_C.insert(m.points_C.end(), bp.begin() + static_cast<std::ptrdiff_t>(k0), bp.end());
          m.normals_C.insert(m.normals_C.end(), bn.begin() + static_cast<std::ptrdiff_t>(k0), bn.end());
          m.fin_height = std::max(a.fin_height, b.fin_height);
          orient_path(m);
          a = std::move(m);
          paths.erase(paths.begin() + static_cast<std::ptrdiff_t>(j));
          ++joined;
          again = true;
        }
      }
    }
  }
  return joined;
}

// A fin cannot stand on a face parallel to it. Where the root runs along an edge (a parting
// line just under a top face) the CAD triangle nearest a root point can be that face: such a
// point takes the wall normal of the nearest point along the path that has a wall's normal
// (round_flange 6115: the normals turned to +z halfway along a rim's flat, every IK branch then
// had to swing the wrist by 1.8 rad at the switch, and the fin stayed whole).
int repair_fin_parallel_normals(FlashPath& path, const Vec3& fin_normal_C) {
  const double lim = std::cos(M_PI / 12);  // within 15°: as the region's root snaps (on_wall)
  const std::size_t n = path.normals_C.size();
  std::vector<std::size_t> walls;
  for (std::size_t i = 0; i < n; ++i)
    if (std::abs(path.normals_C[i].dot(fin_normal_C)) <= lim) walls.push_back(i);
  if (walls.empty() || walls.size() == n) return 0;
  const std::vector<Vec3> before = path.normals_C;
  int repaired = 0;
  for (std::size_t i = 0; i < n; ++i) {
    if (std::abs(before[i].dot(fin_normal_C)) <= lim) continue;
    std::size_t best = walls.front(), best_d = n;
    for (std::size_t j : walls) {
      std::size_t d = i > j ? i - j : j - i;
      if (path.closed) d = std::min(d, n - d);
      if (d < best_d) {
        best_d = d;
        best = j;
      }
    }
    path.normals_C[i] = before[best];
    ++repaired;
  }
  return repaired;
}

// Arcs of one hole's ring seen by different views come out as separate open paths, the parts
// between them unseen. Open paths that lie on one circle (a joint fit within `fit_tol`, CAD
// normals facing its centre: a hole wall, fin normals within 10°) become one path: the points
// ordered by angle about the circle from the widest gap on, the other gaps filled along the
// circle at steps of at most `step` where the CAD wall is (every added point within `fit_tol`
// of the surface); close_hole_arc then closes the widest gap when the arcs span over half the
// ring. Then an open path on the circle of a closed ring is dropped (the ring grinds it), and
// one of at least kMinHoleArc on a hole wall is closed. Returns how many paths were joined
// into others or dropped.
int merge_hole_arcs(std::vector<FlashPath>& paths, const MeshBvh& cad_C, double step, double fit_tol) {
  // The points and normals of several paths, back to back.
  const auto gather = [&](const std::vector<std::size_t>& ids, std::vector<Vec3>& pts, std::vector<Vec3>& nrm) {
    pts.clear();
    nrm.clear();
    for (auto k : ids) {
      pts.insert(pts.end(), paths[k].points_C.begin(), paths[k].points_C.end());
      nrm.insert(nrm.end(), paths[k].normals_C.begin(), paths[k].normals_C.end());
    }
  };
  const auto joint_fit = [&](const std::vector<std::size_t>& ids) {
    std::vector<Vec3> pts, nrm;
    gather(ids, pts, nrm);
    return fit_arc(pts, paths[ids.front()].fin_normal_C, nrm);
  };
  const auto on_hole = [&](const ArcFit& a) {
    return a.ok && a.radius >= 1e-3 && a.radius <= 0.1 && a.rms <= fit_tol && a.facing >= 0.8;
  };
  // Groups grow greedily: a path joins the first group whose joint fit stays a hole circle.
  std::vector<std::vector<std::size_t>> groups;
  for (std::size_t k = 0; k < paths.size(); ++k) {
    if (paths[k].closed || paths[k].points_C.size() < 3) continue;
    bool placed = false;
    for (auto& g : groups) {
      if (std::abs(paths[g.front()].fin_normal_C.dot(paths[k].fin_normal_C)) < std::cos(M_PI / 18)) continue;
      std::vector<std::size_t> trial = g;
      trial.push_back(k);
      if (!on_hole(joint_fit(trial))) continue;
      g = std::move(trial);
      placed = true;
      break;
    }
    if (!placed) groups.push_back({k});
  }
  int joined = 0;
  std::vector<char> drop(paths.size(), 0);
  for (const auto& g : groups) {
    if (g.size() < 2) continue;
    std::vector<Vec3> pts, nrm;
    gather(g, pts, nrm);
    const ArcFit arc = fit_arc(pts, paths[g.front()].fin_normal_C, nrm);
    std::vector<std::size_t> order(pts.size());
    std::iota(order.begin(), order.end(), std::size_t{0});
    std::sort(order.begin(), order.end(), [&](std::size_t a, std::size_t b) { return arc.angle[a] < arc.angle[b]; });
    // Start after the widest gap (cyclically).
    std::size_t start = 0;
    double widest = -1;
    for (std::size_t i = 0; i < order.size(); ++i) {
      const double a0 = arc.angle[order[i]];
      const double a1 = i + 1 < order.size() ? arc.angle[order[i + 1]] : arc.angle[order[0]] + 2 * M_PI;
      if (a1 - a0 > widest) {
        widest = a1 - a0;
        start = (i + 1) % order.size();
      }
    }
    FlashPath merged;
    merged.region = paths[g.front()].region;
    merged.fin_normal_C = paths[g.front()].fin_normal_C;
    for (const std::size_t k : g) merged.fin_height = std::max(merged.fin_height, paths[k].fin_height);
    bool ok = true;
    for (std::size_t i = 0; i < order.size() && ok; ++i) {
      const std::size_t a = order[(start + i) % order.size()];
      if (i > 0) {
        // Fill a gap to the previous point along the circle.
        const std::size_t b = order[(start + i - 1) % order.size()];
        const double gap = std::remainder(arc.angle[a] - arc.angle[b], 2 * M_PI);
        const int k = static_cast<int>(std::floor(std::abs(gap) * arc.radius / step));
        const double hb = arc.w.dot(pts[b]), ha = arc.w.dot(pts[a]);
        for (int j = 1; j < k && ok; ++j) {
          const double f = static_cast<double>(j) / k;
          const Vec3 q = arc.point(arc.angle[b] + gap * f, hb + f * (ha - hb));
          const auto cp = cad_C.closest(q, 4 * fit_tol);
          ok = cp.triangle >= 0 && cp.distance <= fit_tol;
          if (!ok) break;
          merged.points_C.push_back(q);
          merged.normals_C.push_back(cad_C.mesh().triangle_normal(static_cast<std::size_t>(cp.triangle)));
        }
      }
      merged.points_C.push_back(pts[a]);
      merged.normals_C.push_back(nrm[a]);
    }
    if (!ok) continue;  // the circle leaves the wall somewhere: not one hole after all
    orient_path(merged);
    close_hole_arc(merged, cad_C, merged.fin_normal_C, step, fit_tol);
    for (std::size_t i = 1; i < g.size(); ++i) drop[g[i]] = 1;
    paths[g.front()] = std::move(merged);
    joined += static_cast<int>(g.size()) - 1;
  }
  // The open arcs left: one on the circle of a hole whose ring is already closed (another
  // view's region saw the whole ring, or an arc closed before it) is ground with that ring (a
  // second path over the same wall only adds a pass whose ends dwell against the finished
  // wall); any other arc of at least kMinHoleArc on a hole wall is closed into its ring.
  const auto on_a_ring = [&](std::size_t k) {
    for (std::size_t c = 0; c < paths.size(); ++c) {
      if (drop[c] || !paths[c].closed || paths[c].points_C.size() < 8) continue;
      if (std::abs(paths[c].fin_normal_C.dot(paths[k].fin_normal_C)) < std::cos(M_PI / 18)) continue;
      if (!on_hole(fit_arc(paths[c].points_C, paths[c].fin_normal_C, paths[c].normals_C)) ||
          !on_hole(joint_fit({c, k})))
        continue;
      paths[c].fin_height = std::max(paths[c].fin_height, paths[k].fin_height);
      return true;
    }
    return false;
  };
  for (std::size_t k = 0; k < paths.size(); ++k) {
    if (drop[k] || paths[k].closed || paths[k].points_C.size() < 3) continue;
    if (on_a_ring(k)) {
      drop[k] = 1;
      ++joined;
    } else {
      close_hole_arc(paths[k], cad_C, paths[k].fin_normal_C, step, fit_tol, kMinHoleArc);
    }
  }
  std::size_t out = 0;
  for (std::size_t k = 0; k < paths.size(); ++k)
    if (!drop[k]) {
      if (out != k) paths[out] = std::move(paths[k]);
      ++out;
    }
  paths.resize(out);
  return joined;
}

// A hole's flash is a ring, so its root is a closed loop even where part of it was not seen.
// An open path that runs at least `min_swept` round a circle (in the plane across the fin
// normal `w`, fitted within `fit_tol`) whose CAD normals point at the circle's centre (a hole
// wall, not an outer contour) is closed along that circle (refined on the CAD wall), at steps
// of `step`, where the CAD wall is there (every added point within `fit_tol` of the surface,
// then moved onto it). Returns the points added.
int close_hole_arc(FlashPath& path, const MeshBvh& cad_C, const Vec3& w, double step,
                   double fit_tol, double min_swept) {
  const auto& P = path.points_C;
  const std::size_t n = P.size();
  if (n < 8) return 0;
  const ArcFit arc = fit_arc(P, w, path.normals_C);
  if (!arc.ok || arc.radius < 1e-3 || arc.radius > 0.1) return 0;
  if (path.closed) {  // a ring seen whole: only onto its circle
    if (arc.rms <= fit_tol && arc.facing >= 0.8) snap_to_circle(path, w, cad_C, fit_tol);
    return 0;
  }
  if (arc.rms > fit_tol || arc.facing < 0.8 || std::abs(arc.swept) < min_swept ||
      std::abs(arc.swept) > 2 * M_PI)
    return 0;
  // A short arc's circle is uncertain: refine it on the CAD wall. Points all round it are
  // projected onto the CAD (within 1 mm) and the circle refitted on them and the seen points,
  // twice; a hole wall holds them all, anything else (a pocket's fillet) fails the checks below.
  ArcFit c = arc;
  {
    double hm = 0;
    for (const auto& q : P) hm += w.dot(q);
    hm /= static_cast<double>(n);
    for (int it = 0; it < 2; ++it) {
      std::vector<Vec3> pts = P, nrm = path.normals_C;
      for (int j = 0; j < 36; ++j) {
        const auto cp = cad_C.closest(c.point(2 * M_PI * j / 36, hm), 1e-3);
        if (cp.triangle < 0) return 0;
        pts.push_back(cp.point);
        nrm.push_back(cad_C.mesh().triangle_normal(static_cast<std::size_t>(cp.triangle)));
      }
      c = fit_arc(pts, w, nrm);
      if (!c.ok || c.facing < 0.8 || c.rms > fit_tol) return 0;
    }
  }
  const auto angle_of = [&](const Vec3& q) {
    return std::atan2(c.v.dot(q) - c.cv, c.u.dot(q) - c.cu);
  };
  const double h0 = w.dot(P.front()), h1 = w.dot(P.back());
  const double missing = 2 * M_PI - std::abs(arc.swept);
  // Added points as far apart as the seen ones (at most `step`): an even density keeps the
  // loop's centroid at the hole's centre.
  double seen = 0;
  for (std::size_t i = 1; i < n; ++i) seen += (P[i] - P[i - 1]).norm();
  const double pitch = std::max(1e-5, std::min(step, seen / static_cast<double>(n - 1)));
  const int k = static_cast<int>(std::floor(missing * c.radius / pitch));
  if (k < 2) return 0;
  const double dir = arc.swept > 0 ? 1 : -1;
  std::vector<Vec3> add_p, add_n;
  for (int j = 1; j < k; ++j) {
    const double f = static_cast<double>(j) / k;
    const Vec3 q = c.point(angle_of(P.back()) + dir * missing * f, h1 + f * (h0 - h1));
    const auto cp = cad_C.closest(q, 4 * fit_tol);
    if (cp.triangle < 0 || cp.distance > fit_tol) return 0;
    add_p.push_back(cp.point);  // on the wall itself
    add_n.push_back(cad_C.mesh().triangle_normal(static_cast<std::size_t>(cp.triangle)));
  }
  path.points_C.insert(path.points_C.end(), add_p.begin(), add_p.end());
  path.normals_C.insert(path.normals_C.end(), add_n.begin(), add_n.end());
  path.closed = true;
  snap_to_circle(path, w, cad_C, fit_tol);
  return static_cast<int>(add_p.size());
}

namespace {

// How many of the points `uv` (indexed by `tree`, z = 0) lie in the corridor leaving p along
// the unit direction d: from `from` to `to` along it, at most `half` to either side.
int points_in_corridor(const std::vector<Eigen::Vector2d>& uv, const detail::KdTree& tree,
                       const Eigen::Vector2d& p, const Eigen::Vector2d& d, double from, double to,
                       double half) {
  const Eigen::Vector2d c = p + 0.5 * (from + to) * d;
  std::vector<std::pair<std::uint32_t, float>> nb;
  tree.radius(Eigen::Vector3f(static_cast<float>(c.x()), static_cast<float>(c.y()), 0.0f),
              static_cast<float>(std::hypot(0.5 * (to - from), half)), nb);
  int n = 0;
  for (const auto& e : nb) {
    const Eigen::Vector2d q = uv[e.first] - p;
    const double along = q.dot(d);
    n += along >= from && along <= to && std::abs(q.x() * d.y() - q.y() * d.x()) <= half;
  }
  return n;
}

}  // namespace

std::vector<bool> alpha_boundary(const std::vector<Eigen::Vector2d>& uv, double alpha,
                                 const std::vector<bool>& test_only) {
  FT_ASSERT(alpha > 0);
  std::vector<bool> boundary(uv.size(), false);
  if (uv.size() < 3) {
    std::fill(boundary.begin(), boundary.end(), true);
    return boundary;
  }
  std::vector<Eigen::Vector3f> pts(uv.size());
  for (std::size_t i = 0; i < uv.size(); ++i)
    pts[i] = Eigen::Vector3f(static_cast<float>(uv[i].x()), static_cast<float>(uv[i].y()), 0.f);
  detail::KdTree tree(pts);
  const double a2 = alpha * alpha;
  const double inside2 = a2 * (1 - 1e-6);
  std::vector<std::pair<std::uint32_t, float>> nb;
  for (std::size_t i = 0; i < uv.size(); ++i) {
    if (!test_only.empty() && !test_only[i]) continue;
    tree.radius(pts[i], static_cast<float>(2 * alpha), nb);
    if (nb.size() <= 1) {
      boundary[i] = true;  // isolated: its own boundary
      continue;
    }
    const Eigen::Vector2d p = uv[i];
    // Rolling circle: a circle of radius alpha through p and a neighbour q with no other
    // point inside means p lies on the alpha shape's boundary.
    for (const auto& [j, d2] : nb) {
      if (j == i) continue;
      const Eigen::Vector2d q = uv[j];
      const Eigen::Vector2d m = 0.5 * (p + q);
      const Eigen::Vector2d pq = q - p;
      const double half2 = 0.25 * pq.squaredNorm();
      if (half2 <= 0 || half2 > a2) continue;
      const double h = std::sqrt(a2 - half2);
      const Eigen::Vector2d perp = Eigen::Vector2d(-pq.y(), pq.x()).normalized();
      for (int side = -1; side <= 1 && !boundary[i]; side += 2) {
        const Eigen::Vector2d c = m + side * h * perp;
        bool empty = true;
        for (const auto& [k, dk] : nb) {
          if (k == i || k == j) continue;
          if ((uv[k] - c).squaredNorm() < inside2) {
            empty = false;
            break;
          }
        }
        if (empty) boundary[i] = true;
      }
      if (boundary[i]) break;
    }
  }
  return boundary;
}

namespace {

// The unit direction in which a piece of curve (point indices) leaves through its front or back
// end, from its point `span` inside; zero for a piece shorter than a tenth of the span.
Vec3 leaving_direction(const std::vector<int>& piece, const std::vector<Vec3>& points, bool front,
                       double span) {
  const auto at = [&](std::size_t k) {
    return points[static_cast<std::size_t>(piece[front ? k : piece.size() - 1 - k])];
  };
  const Vec3 end = at(0);
  Vec3 inside = end;
  for (std::size_t k = 1; k < piece.size(); ++k) {
    inside = at(k);
    if ((inside - end).norm() >= span) break;
  }
  const Vec3 d = end - inside;
  return d.norm() < 0.1 * span ? Vec3::Zero() : Vec3(d.normalized());
}

// Pieces of one curve split where a few of its points are missing (a stretch of root hidden for
// a millimetre or two) are joined end to end, nearest ends first: ends within `reach` whose
// link continues the direction in which each piece leaves there (within 30°). A piece too short
// to have a direction joins nothing: a few points of a neighbouring hole's ring in the same
// region would otherwise be stepping stones that carry a line across a corner through the
// steel (housing 7026). Side-by-side pieces (two walls' roots, the two sides of a slot) do not
// continue into each other and stay apart.
void chain_pieces(std::vector<std::vector<int>>& pieces, const std::vector<Vec3>& points, double reach) {
  const double span = reach / 2, aligned = std::cos(M_PI / 6);
  for (;;) {
    double best = reach;
    int bi = -1, bj = -1;
    bool bi_front = false, bj_front = false;
    for (std::size_t i = 0; i < pieces.size(); ++i)
      for (std::size_t j = i + 1; j < pieces.size(); ++j)
        for (int ends = 0; ends < 4; ++ends) {
          const bool fi = ends & 1, fj = ends & 2;
          const Vec3& a = points[static_cast<std::size_t>(fi ? pieces[i].front() : pieces[i].back())];
          const Vec3& b = points[static_cast<std::size_t>(fj ? pieces[j].front() : pieces[j].back())];
          const double d = (b - a).norm();
          if (d >= best || d <= 0) continue;
          const Vec3 link = (b - a) / d;
          const Vec3 ti = leaving_direction(pieces[i], points, fi, span);
          const Vec3 tj = leaving_direction(pieces[j], points, fj, span);
          if (ti.isZero() || tj.isZero() || ti.dot(link) < aligned || tj.dot(-link) < aligned)
            continue;
          best = d;
          bi = static_cast<int>(i);
          bj = static_cast<int>(j);
          bi_front = fi;
          bj_front = fj;
        }
    if (bi < 0) return;
    auto& p = pieces[static_cast<std::size_t>(bi)];
    auto q = std::move(pieces[static_cast<std::size_t>(bj)]);
    pieces.erase(pieces.begin() + bj);
    // p's joined end last, then q from its joined end on.
    if (bi_front) std::reverse(p.begin(), p.end());
    if (!bj_front) std::reverse(q.begin(), q.end());
    p.insert(p.end(), q.begin(), q.end());
  }
}

}  // namespace

std::vector<Polyline> order_polylines(const std::vector<Vec3>& points, double gap) {
  FT_ASSERT(gap > 0);
  const std::size_t n = points.size();
  std::vector<Polyline> out;
  if (n == 0) return out;
  std::vector<Eigen::Vector3f> pf(n);
  for (std::size_t i = 0; i < n; ++i) pf[i] = points[i].cast<float>();
  detail::KdTree tree(pf);
  // Candidate edges: up to 10 nearest neighbours within a reach of 4 × gap; Kruskal builds the
  // Euclidean minimum spanning forest (ties broken by index: deterministic).
  struct Edge {
    float w;
    std::uint32_t a, b;
  };
  const double reach = 4 * gap;
  std::vector<Edge> edges;
  const std::size_t K = std::min<std::size_t>(11, n);
  std::vector<std::uint32_t> idx(K);
  std::vector<float> d2(K);
  for (std::size_t i = 0; i < n; ++i) {
    const std::size_t k = tree.knn(pf[i], K, idx.data(), d2.data());
    for (std::size_t t = 0; t < k; ++t)
      if (idx[t] > i && d2[t] <= reach * reach) edges.push_back({d2[t], static_cast<std::uint32_t>(i), idx[t]});
  }
  std::sort(edges.begin(), edges.end(), [](const Edge& x, const Edge& y) {
    return x.w != y.w ? x.w < y.w : (x.a != y.a ? x.a < y.a : x.b < y.b);
  });
  std::vector<std::uint32_t> parent(n);
  std::iota(parent.begin(), parent.end(), 0u);
  auto find = [&](std::uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  };
  std::vector<Edge> tree_edges;
  for (const auto& e : edges) {
    const auto ra = find(e.a), rb = find(e.b);
    if (ra == rb) continue;
    parent[ra] = rb;
    tree_edges.push_back(e);
  }
  // A link longer than `gap` is kept where the root is sampled that sparsely round it: scan
  // lines crossing a root a couple of millimetres apart give a group of points each, and the
  // links between groups are all about the line spacing. It is kept when at least two other
  // long links (over gap / 1.5) lie within three of its lengths and it is at most 1.5 × their
  // median: a stretch where lines are missing, not the sampling, is still cut.
  std::vector<double> link_length(tree_edges.size());
  std::vector<Vec3> link_mid(tree_edges.size());
  std::vector<std::size_t> long_links;
  for (std::size_t i = 0; i < tree_edges.size(); ++i) {
    link_length[i] = std::sqrt(static_cast<double>(tree_edges[i].w));
    link_mid[i] = 0.5 * (points[tree_edges[i].a] + points[tree_edges[i].b]);
    if (link_length[i] > gap / 1.5) long_links.push_back(i);
  }
  const auto sampled_that_sparsely = [&](std::size_t e) {
    const double L = link_length[e];
    std::vector<double> near;
    for (auto j : long_links)
      if (j != e && (link_mid[j] - link_mid[e]).norm() <= 3 * L) near.push_back(link_length[j]);
    return near.size() >= 2 && L <= 1.5 * percentile(near, 0.5);
  };
  std::vector<std::vector<std::uint32_t>> adj(n);
  for (std::size_t i = 0; i < tree_edges.size(); ++i) {
    const auto& e = tree_edges[i];
    if (link_length[i] > gap && !sampled_that_sparsely(i)) continue;
    adj[e.a].push_back(e.b);
    adj[e.b].push_back(e.a);
  }
  // Farthest node (by path length along the tree) from a start node.
  std::vector<double> dist(n, -1);
  std::vector<std::int64_t> from(n, -1);
  auto farthest = [&](std::uint32_t s, std::vector<std::uint32_t>& comp) {
    comp.clear();
    std::vector<std::uint32_t> stack{s};
    dist[s] = 0;
    from[s] = -1;
    std::uint32_t best = s;
    while (!stack.empty()) {
      const auto u = stack.back();
      stack.pop_back();
      comp.push_back(u);
      if (dist[u] > dist[best]) best = u;
      for (auto v : adj[u])
        if (dist[v] < 0) {
          dist[v] = dist[u] + (points[u] - points[v]).norm();
          from[v] = u;
          stack.push_back(v);
        }
    }
    return best;
  };
  std::vector<bool> done(n, false);
  std::vector<std::uint32_t> comp;
  std::vector<std::vector<int>> pieces;
  for (std::size_t s = 0; s < n; ++s) {
    if (done[s]) continue;
    const auto a = farthest(static_cast<std::uint32_t>(s), comp);
    for (auto u : comp) {
      done[u] = true;
      dist[u] = -1;
    }
    const auto b = farthest(a, comp);
    std::vector<int> piece;
    for (std::int64_t u = b; u >= 0; u = from[u]) piece.push_back(static_cast<int>(u));
    for (auto u : comp) dist[u] = -1;
    pieces.push_back(std::move(piece));
  }
  chain_pieces(pieces, points, 3 * gap);
  for (auto& piece : pieces) {
    Polyline pl;
    pl.source = std::move(piece);
    for (auto u : pl.source) pl.points.push_back(points[static_cast<std::size_t>(u)]);
    double len = 0, link = gap;  // length; the longest link along the curve, if over gap
    for (std::size_t i = 1; i < pl.points.size(); ++i) {
      len += (pl.points[i] - pl.points[i - 1]).norm();
      link = std::max(link, (pl.points[i] - pl.points[i - 1]).norm());
    }
    // Closed: the ends meet, or the curve turns a full circle (about its best-fit plane's
    // normal) and its ends are close compared with its length and within 4 × gap (a loop seen
    // with a gap, e.g. a hole flash partly hidden from the scanner; a wider gap in a hole's
    // ring is closed along its circle by close_hole_arc, and a parting line round a whole
    // casting that stops 20 mm short of its start is not a loop: its chord cut a corner).
    const double ends = (pl.points.front() - pl.points.back()).norm();
    double turn = 0;
    if (pl.points.size() > 3) {
      const Vec3 nrm = fit_plane(pl.points).n;
      for (std::size_t i = 2; i < pl.points.size(); ++i) {
        const Vec3 u = pl.points[i - 1] - pl.points[i - 2], v = pl.points[i] - pl.points[i - 1];
        turn += std::atan2(nrm.dot(u.cross(v)), u.dot(v));
      }
    }
    pl.closed = pl.points.size() > 3 && len > 4 * gap &&
                (ends <= link || (std::abs(turn) > 1.5 * M_PI && ends < 0.25 * len && ends <= 4 * gap));
    out.push_back(std::move(pl));
  }
  return out;
}

FinPlane fin_plane(const std::vector<Vec3>& pts, const std::vector<bool>& touch, double band) {
  FinPlane out;
  const Plane pl = fit_fin_plane(pts, touch, band, &out.consensus);
  out.n = pl.n;
  out.c = pl.c;
  return out;
}

namespace {

// ---------------------------------------------------------------------------------------------
// detect_flash's stages, in the order it runs them.

// Bad input is refused before any work: an empty or non-finite scan, a pose that is not rigid,
// a CAD model without triangles.
void check_inputs(const PointCloud& scan_M, const TriangleMesh& cad, const Pose& X_CM) {
  if (scan_M.empty()) throw ArgumentError("scan: expected at least one point, got an empty cloud");
  for (std::size_t i = 0; i < scan_M.size(); ++i)
    if (!scan_M.points[i].allFinite())
      throw ArgumentError("scan: expected finite coordinates, got NaN/inf at point " +
                          std::to_string(i));
  const Mat3 R = X_CM.linear();
  if (!X_CM.matrix().allFinite() || (R.transpose() * R - Mat3::Identity()).norm() > 1e-6 ||
      std::abs(R.determinant() - 1) > 1e-6)
    throw ArgumentError("pose X_CM: expected a rigid transform (orthonormal rotation, det +1)");
  if (cad.triangles.empty()) throw ArgumentError("CAD model: expected triangles, got none");
}

// The scan in {C}, cropped to the CAD model's box grown by `margin` (drops most of the table
// and fixture).
struct CroppedScan {
  std::vector<std::uint32_t> index;  // the scan point of each kept point
  std::vector<Vec3> points_C;
};

// A scan whose extent is 50 times larger or smaller than the model's, or with fewer than ten
// points near it, is another part or in other units: refused (ArgumentError).
CroppedScan crop_to_cad(const PointCloud& scan_M, const TriangleMesh& cad, const Pose& X_CM,
                        double margin) {
  Vec3 lo, hi;
  cad.bounds(lo, hi);
  const double cad_diag = (hi - lo).norm();
  const Eigen::AlignedBox3d box(lo - Vec3::Constant(margin), hi + Vec3::Constant(margin));
  CroppedScan out;
  Eigen::AlignedBox3d scan_box;
  for (std::size_t i = 0; i < scan_M.size(); ++i) {
    const Vec3 p = X_CM * scan_M.points[i].cast<double>();
    scan_box.extend(p);
    if (box.contains(p)) {
      out.index.push_back(static_cast<std::uint32_t>(i));
      out.points_C.push_back(p);
    }
  }
  const double scan_diag = scan_box.diagonal().norm();
  if (scan_diag > 50 * cad_diag || scan_diag < cad_diag / 50 || out.index.size() < 10) {
    std::ostringstream os;
    os << "scan and CAD model do not match: the scan spans " << scan_diag << " m, the CAD model "
       << cad_diag << " m, and " << out.index.size()
       << " scan points lie near the CAD model (expected both in metres and the pose mapping the "
          "scan onto the model)";
    throw ArgumentError(os.str());
  }
  return out;
}

// Distance of every point to the CAD surface (true point-to-triangle distance, BVH), searched
// only within `far`: beyond it a point gets `far` whatever its exact distance.
std::vector<double> distances_to_cad(const std::vector<Vec3>& pc, const MeshBvh& cad_C, double far) {
  const std::size_t m = pc.size();
  std::vector<double> dist(m);
  // In chunks of consecutive points (neighbours along a scan line), each query hinted with the
  // previous answer: the search starts bounded, with the same result.
  const std::ptrdiff_t chunk = 4096, chunks = (static_cast<std::ptrdiff_t>(m) + chunk - 1) / chunk;
#pragma omp parallel for schedule(dynamic, 1) if (m >= 8192)
  for (std::ptrdiff_t c = 0; c < chunks; ++c) {
    int hint = -1;
    const auto end = std::min<std::size_t>(m, static_cast<std::size_t>((c + 1) * chunk));
    for (auto k = static_cast<std::size_t>(c * chunk); k < end; ++k) {
      const auto cp = cad_C.closest(pc[k], far, hint);
      dist[k] = cp.triangle < 0 ? far : cp.distance;
      if (cp.triangle >= 0) hint = cp.triangle;
    }
  }
  return dist;
}

// The scanner's noise σ: the given one, else estimated from the points on the surface, whose
// distances are ~ |N(0, σ)|: σ ≈ median / 0.6745 over the points within `max_threshold`
// (flash points are a minority and sit far off).
double scanner_noise(const std::vector<double>& dist, const DetectionParams& P) {
  if (P.noise_sigma > 0) return P.noise_sigma;
  std::vector<double> near;
  near.reserve(dist.size());
  for (const double d : dist)
    if (d < P.max_threshold) near.push_back(d);
  return near.empty() ? P.min_threshold : percentile(near, 0.5) / 0.6745;
}

// Median spacing of the candidates (sets the clustering, alpha and gap scales): the nearest
// neighbour's, and across scan lines. Line scanners sample densely along a profile and
// sparsely across profiles: besides the nearest-neighbour spacing, the spacing across (nearest
// neighbour off the line through the nearest one) sets the scales that must bridge profiles.
void candidate_spacing(const std::vector<Eigen::Vector3f>& cf, const detail::KdTree& tree,
                       DetectionResult& res) {
  std::vector<double> sp, sp_cross;
  const std::size_t step = std::max<std::size_t>(1, cf.size() / 2000);
  constexpr std::size_t K = 32;
  std::uint32_t id[K];
  float d2[K];
  for (std::size_t c = 0; c < cf.size(); c += step) {
    const std::size_t k = tree.knn(cf[c], K, id, d2);
    if (k < 2) continue;
    sp.push_back(std::sqrt(static_cast<double>(d2[1])));
    const Eigen::Vector3f d1 = (cf[id[1]] - cf[c]).normalized();
    for (std::size_t t = 2; t < k; ++t) {
      const Eigen::Vector3f dq = cf[id[t]] - cf[c];
      if (std::abs(dq.normalized().dot(d1)) < 0.7071f) {
        sp_cross.push_back(std::sqrt(static_cast<double>(d2[t])));
        break;
      }
    }
  }
  res.spacing = std::max(1e-5, percentile(sp, 0.5));
  res.spacing_across = std::max(res.spacing, percentile(sp_cross, 0.5));
}

// The candidates left after the support planes, which the stages after them work on.
struct Live {
  std::vector<std::uint32_t> k;     // index into the cropped scan of each
  std::vector<Eigen::Vector3f> pf;  // its position in {C} (float, for the k-d trees)
};

// The scales of one detection, set by the parameters or else by the scan's spacing and
// threshold [m].
struct Scales {
  double spacing = 0;       // across scan lines
  double tol = 0;           // Euclidean clustering tolerance
  double far = 0;           // distances to the CAD searched up to here
  double alpha = 0;         // alpha-shape radius
  double gap = 0;           // a longer gap splits a grinding line
  double inner_limit = 0;   // a boundary point this close to the CAD is a root point
  double hidden_limit = 0;  // up to here it stands for a hidden stretch of root
  double hidden_cover = 0;  // a snapped edge point this close to a seen root point adds nothing
};

// Where a view saw a fin only obliquely its scan lines lie farther apart than `tol`, and
// each line became a cluster of its own. Small clusters are re-clustered among themselves
// at a larger tolerance (big ones are left as they are).
// Only fragments that reach the casting take part (a scan line across a fin runs from its
// root to its edge; stray points and clutter mostly do not), and rise clearly off it (`rise`:
// noise tails and mixed pixels just past the threshold, scattered over a face, would otherwise
// join up).
void recluster_fragments(std::vector<std::vector<std::uint32_t>>& clusters, const Live& live,
                         const std::vector<double>& dist, double reach, double rise, double tol,
                         const DetectionParams& P) {
  const std::size_t small = 5 * static_cast<std::size_t>(P.min_region_points);
  std::vector<std::uint32_t> frag;  // indices into live
  std::vector<std::vector<std::uint32_t>> kept;
  // A fragment: a small cluster (≥ 5 points) that reaches the casting and rises off it.
  const auto fragment = [&](const std::vector<std::uint32_t>& cl) {
    bool touches = false, rises = false;
    if (cl.size() < small && cl.size() >= 5)
      for (auto v : cl) {
        const double dv = dist[live.k[v]];
        touches = touches || dv < reach;
        rises = rises || dv > rise;
      }
    return touches && rises;
  };
  for (auto& cl : clusters) {
    if (fragment(cl)) frag.insert(frag.end(), cl.begin(), cl.end());
    else kept.push_back(std::move(cl));
  }
  if (!frag.empty()) {
    std::vector<Eigen::Vector3f> ff(frag.size());
    for (std::size_t i = 0; i < frag.size(); ++i) ff[i] = live.pf[frag[i]];
    const detail::KdTree ftree(ff);
    std::size_t merged = 0;
    for (auto& cl : detail::euclidean_clusters(ff, ftree, static_cast<float>(P.fragment_merge * tol))) {
      for (auto& v : cl) v = frag[v];
      merged += cl.size() >= small;
      kept.push_back(std::move(cl));
    }
    spdlog::debug("detect: {} points in small clusters re-clustered at {:.3f} mm: {} region(s) "
                  "of at least {} points",
                  frag.size(), P.fragment_merge * tol * 1e3, merged, small);
  }
  clusters = std::move(kept);
}

// Small clusters that rise off the casting (single scan lines along a fin's root, or across
// its outer part where a wall hid the rest from every view) join the region they reach
// through each other within fragment_merge × tol: without them the root there has no
// boundary points and the grinding line breaks off. A breadth-first search from the
// regions (≥ 5 × min_region_points) hands each reached cluster to the region it was reached
// from. Only clusters in the region's fin plane join it (within the thickest flash, 1.5 mm):
// clutter off the part (a fixture's edge) does not.
void join_rising_clusters(std::vector<std::vector<std::uint32_t>>& clusters, const Live& live,
                          const std::vector<double>& dist, const std::vector<Vec3>& pc,
                          double rise, double tol, const DetectionParams& P) {
  const std::size_t small = 5 * static_cast<std::size_t>(P.min_region_points);
  std::vector<char> cand_cl(clusters.size(), 0);
  std::vector<std::uint32_t> cp;  // points of the candidate clusters (indices into live)
  std::vector<std::size_t> ck;    // their cluster
  for (std::size_t k = 0; k < clusters.size(); ++k) {
    const auto& cl = clusters[k];
    if (cl.size() >= small || cl.size() < 5) continue;
    bool rises = false;
    for (auto v : cl) rises = rises || dist[live.k[v]] > rise;
    if (!rises) continue;
    cand_cl[k] = 1;
    for (auto v : cl) {
      cp.push_back(v);
      ck.push_back(k);
    }
  }
  if (cp.empty()) return;
  std::vector<Eigen::Vector3f> cfp(cp.size());
  for (std::size_t i = 0; i < cp.size(); ++i) cfp[i] = live.pf[cp[i]];
  const detail::KdTree ctree(cfp);
  std::vector<std::pair<std::uint32_t, float>> nb;
  std::vector<std::size_t> owner(clusters.size(), clusters.size());
  std::vector<Plane> plane(clusters.size());
  std::deque<std::size_t> queue;
  for (std::size_t k = 0; k < clusters.size(); ++k)
    if (clusters[k].size() >= small) {
      owner[k] = k;
      queue.push_back(k);
      std::vector<Vec3> pts;
      for (auto v : clusters[k]) pts.push_back(pc[live.k[v]]);
      plane[k] = fit_plane(pts);
    }
  const auto in_plane = [&](std::size_t c, const Plane& pl) {
    for (auto v : clusters[c])
      if (std::abs(pl.dist(pc[live.k[v]])) > 1.5e-3) return false;
    return true;
  };
  while (!queue.empty()) {
    const std::size_t k = queue.front();
    queue.pop_front();
    const Plane& pl = plane[owner[k]];
    for (auto v : clusters[k]) {
      ctree.radius(live.pf[v], static_cast<float>(P.fragment_merge * tol), nb);
      for (const auto& [j, d2] : nb) {
        const std::size_t c = ck[j];
        if (owner[c] < clusters.size() || !in_plane(c, pl)) continue;
        owner[c] = owner[k];
        queue.push_back(c);
      }
    }
  }
  std::size_t joined = 0;
  for (std::size_t k = 0; k < clusters.size(); ++k) {
    if (!cand_cl[k] || owner[k] >= clusters.size()) continue;
    auto& to = clusters[owner[k]];
    to.insert(to.end(), clusters[k].begin(), clusters[k].end());
    joined += clusters[k].size();
    clusters[k].clear();
  }
  if (joined > 0)
    spdlog::debug("detect: {} points of small clusters joined the regions they reach", joined);
}

// One flash region's points and what the passes after the region stage keep of it.
struct RegionWork {
  std::vector<Vec3> inner, inner_n;  // snapped inner-boundary points and CAD normals
  Vec3 w = Vec3::UnitZ();            // height direction along the wall
  double top = 0;                    // height of the visible face at the root
  double mid = 0;                    // height of the mid-plane
  bool resolved = false;             // mid-plane seen at the fin's edge
  bool shift = false;                // the root goes to the mid-plane
  Vec3 at_mid(Vec3 p) const {
    if (shift) p += (mid - w.dot(p)) * w;
    return p;
  }
};

// A cluster's points in {C} and their heights over the CAD surface.
struct ClusterPoints {
  std::vector<Vec3> pts;
  std::vector<double> height;
  std::vector<bool> touch;  // within inner_limit of the CAD
  double hmax = 0;
  std::size_t touching = 0;
  /// The points of the region's outer half (higher than half its highest): the fin's top face
  /// and outer edge, away from the root.
  std::vector<Vec3> outer_half() const {
    std::vector<Vec3> out;
    for (std::size_t i = 0; i < pts.size(); ++i)
      if (height[i] > 0.5 * hmax) out.push_back(pts[i]);
    return out;
  }
};

// The points and how many touch the casting; their heights only when at least three do (the
// distances were searched only up to `far`; a flash region's own points get their full
// distance to the CAD: fins stand up to centimetres off the surface).
ClusterPoints cluster_points(const std::vector<std::uint32_t>& cl, const Live& live,
                             const std::vector<Vec3>& pc, const std::vector<double>& dist,
                             const MeshBvh& cad_C, const Scales& s) {
  ClusterPoints c;
  c.pts.reserve(cl.size());
  c.touch.resize(cl.size());
  for (std::size_t i = 0; i < cl.size(); ++i) {
    const auto k = live.k[cl[i]];
    c.pts.push_back(pc[k]);
    c.touch[i] = dist[k] < s.inner_limit;
    c.touching += c.touch[i];
  }
  if (c.touching < 3) return c;
  c.height.resize(cl.size());
  for (std::size_t i = 0; i < cl.size(); ++i) {
    const auto k = live.k[cl[i]];
    c.height[i] = dist[k] < s.far ? dist[k] : cad_C.closest(pc[k]).distance;
    c.hmax = std::max(c.hmax, c.height[i]);
  }
  return c;
}

// Where the consensus plane won, the points off it by more than the band and the scanner's
// noise are not the fin: a fixture's top (taken for the fin's outer edge, it put 6115's
// mid-plane 7 mm above the root) or the face of a clamp beside the fin's tip, 2 mm under
// its plane (taken for the fin's lower edge, it put default 5013's 1 mm below).
void drop_points_off_fin_plane(std::vector<std::uint32_t>& cl, ClusterPoints& c, const Plane& fin,
                               double off) {
  std::size_t k = 0;
  c.hmax = 0;
  c.touching = 0;
  for (std::size_t i = 0; i < cl.size(); ++i) {
    if (std::abs(fin.dist(c.pts[i])) > off) continue;
    cl[k] = cl[i];
    c.pts[k] = c.pts[i];
    c.height[k] = c.height[i];
    c.hmax = std::max(c.hmax, c.height[k]);
    c.touching += c.touch[i];
    c.touch[k] = c.touch[i];
    ++k;
  }
  if (k < cl.size())
    spdlog::debug("detect: {} of a region's {} points lie off its fin plane: dropped", cl.size() - k, cl.size());
  cl.resize(k);
  c.pts.resize(k);
  c.height.resize(k);
  c.touch.resize(k);
}

// The region's points in the fin plane's coordinates (u along the major axis, v along the
// minor) and its extents.
std::vector<Eigen::Vector2d> fin_plane_coordinates(const std::vector<Vec3>& pts, const Plane& fin,
                                                   FlashRegion& reg) {
  const Vec3 e1 = fin.axes.col(2), e2 = fin.axes.col(1);
  double u0 = 1e300, u1 = -1e300, v0 = 1e300, v1 = -1e300;
  std::vector<Eigen::Vector2d> uv(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) {
    uv[i] = Eigen::Vector2d(e1.dot(pts[i] - reg.centroid_C), e2.dot(pts[i] - reg.centroid_C));
    u0 = std::min(u0, uv[i].x());
    u1 = std::max(u1, uv[i].x());
    v0 = std::min(v0, uv[i].y());
    v1 = std::max(v1, uv[i].y());
  }
  reg.extent_major = u1 - u0;
  reg.extent_minor = v1 - v0;
  return uv;
}

// The root: the region's inner boundary snapped onto the walls it stands out of.
struct RootPoints {
  std::vector<Vec3> points, normals;  // on the CAD surface, with its normals there
};

// Alpha-shape boundary. Only the points near the casting can be on the inner boundary,
// so the rolling circle is tried there (the outer boundary is not needed for the path).
// Points up to hidden_limit off the CAD are tried too: where the root itself is hidden
// from every view (a wall above the fin blocks the triangulation camera), the fin's edge
// nearest to the casting stands for it.
RootPoints root_points(const ClusterPoints& c, const std::vector<Eigen::Vector2d>& uv,
                       const Plane& fin, const MeshBvh& cad_C, const Scales& s, FlashRegion& reg) {
  const TriangleMesh& cad = cad_C.mesh();
  const Vec3 e1 = fin.axes.col(2), e2 = fin.axes.col(1);
  const auto& pts = c.pts;
  std::vector<bool> test(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i) test[i] = c.height[i] < s.hidden_limit;
  const auto bnd = alpha_boundary(uv, s.alpha, test);
  RootPoints root;
  std::vector<std::size_t> hidden;  // boundary points beyond the inner band
  // A root lies on a wall the fin stands out of: a snap onto a face parallel to the fin
  // (within 15°) is the face the fin lies on or runs along, not its root (30° had dropped every
  // root point of a fin high on a flat dome, its wall 25-30° off the fin plane: cover 9141).
  const auto on_wall = [&](int t) {
    return std::abs(cad.triangle_normal(static_cast<std::size_t>(t)).dot(reg.normal_C)) <
           std::cos(M_PI / 12);
  };
  // A root has no fin between it and the casting: a boundary point with region points
  // further towards the wall (within the fin plane, along the wall normal's part in it) is
  // the fin's outer edge or its end face, low enough to pass for the root where the fin
  // tapers. Snapped onto a sloped wall such points land down the slope beside the root
  // (cover 9003, 9012: a second row 1-2 mm off the root along a tapering end; the grinding
  // line ran out along one row and back along the other and turned 2-5 mm short of the end).
  std::vector<Eigen::Vector3f> uvf(pts.size());
  for (std::size_t i = 0; i < pts.size(); ++i)
    uvf[i] = Eigen::Vector3f(static_cast<float>(uv[i].x()), static_cast<float>(uv[i].y()), 0.0f);
  const detail::KdTree uv_tree(uvf);
  const auto fin_toward_wall = [&](std::size_t i, int t) {
    const Vec3 nt = cad.triangle_normal(static_cast<std::size_t>(t));
    const Vec3 in = -(nt - nt.dot(reg.normal_C) * reg.normal_C);
    Eigen::Vector2d d(e1.dot(in), e2.dot(in));
    if (d.norm() < 0.1) return false;
    // A corridor from alpha to hidden_limit towards the wall, alpha to either side.
    return points_in_corridor(uv, uv_tree, uv[i], d.normalized(), s.alpha,
                              std::max(2 * s.alpha, s.hidden_limit), s.alpha) >= 3;
  };
  const auto add = [&](const auto& cp) {
    ++reg.inner_points;
    root.points.push_back(cp.point);
    root.normals.push_back(cad.triangle_normal(static_cast<std::size_t>(cp.triangle)));
  };
  for (std::size_t i = 0; i < pts.size(); ++i) {
    if (!bnd[i]) continue;
    ++reg.boundary_points;
    if (c.height[i] >= s.inner_limit) {
      hidden.push_back(i);
      continue;
    }
    // Snap onto the CAD surface: the path must not carry the scanner noise.
    const auto cp = cad_C.closest(pts[i], s.inner_limit * 1.5);
    if (cp.triangle < 0 || !on_wall(cp.triangle) || fin_toward_wall(i, cp.triangle)) continue;
    add(cp);
  }
  // Hidden stretches of root: boundary points of the wider band whose snap lands away from
  // every root point seen (so they fill gaps and never compete with the seen root).
  const std::size_t seen = root.points.size();
  const double r2 = s.hidden_cover * s.hidden_cover;
  for (std::size_t i : hidden) {
    const auto cp = cad_C.closest(pts[i], s.hidden_limit * 1.5);
    if (cp.triangle < 0 || !on_wall(cp.triangle) || fin_toward_wall(i, cp.triangle)) continue;
    bool covered = false;
    for (std::size_t j = 0; j < seen && !covered; ++j)
      covered = (root.points[j] - cp.point).squaredNorm() < r2;
    if (!covered) add(cp);
  }
  return root;
}

// The fin's fitted normal on a flat wall sloping towards the fin, from the fin's top face alone.
// Where every root point's wall normal lies within 2° of their mean the wall is one plane, not
// a hole's arc, so a plane fitted to the fin is no narrow band's guess; but a low fin (under
// about ten times its thickness) spreads too little over its plane to pass the spread test,
// and its heights would go along the wall (on a 45° wall a 5 mm fin's root came 3.4 mm down the
// slope). The whole fin's least-squares plane leans by a few degrees: the scanner sees its top
// face and outer edge, not its underside (a 5 mm fin 0.8 mm thick: 2.8°, 0.2 mm at the root).
// The top face's plane (RANSAC over the outer half's points with a band of three times the
// scanner noise, at least 30 µm) does not; it must lie within 10° of the fin's fitted normal.
// Empty when the wall is not flat or no top face stands out. Oriented like `fin_n`.
std::optional<Vec3> flat_sloped_wall_normal(const std::vector<Vec3>& wall_n,
                                            const std::vector<Vec3>& outer_half, const Vec3& fin_n,
                                            double noise_sigma) {
  if (wall_n.empty() || outer_half.size() < 20) return std::nullopt;
  Vec3 mean = Vec3::Zero();
  for (const auto& v : wall_n) mean += v;
  if (mean.norm() < 1e-9) return std::nullopt;
  mean.normalize();
  for (const auto& v : wall_n)
    if (v.dot(mean) < std::cos(2 * M_PI / 180)) return std::nullopt;
  const std::vector<bool> all(outer_half.size(), true);
  const Plane top = fit_fin_plane(outer_half, all, std::max(30e-6, 3 * noise_sigma), nullptr);
  Vec3 n = top.n;
  if (n.dot(fin_n) < 0) n = -n;
  if (n.dot(fin_n) < std::cos(10 * M_PI / 180)) return std::nullopt;
  return n;
}

// The direction heights are measured along (RegionWork::w). Height direction: the fin normal
// made perpendicular to the mean wall normal (walls around a loop average out: then the fin
// normal itself). On walls sloping towards the fin (a dome: more than 10° on average) "along
// the wall" is no one direction: heights go along the fin normal, and the root onto the CAD's
// section by the mid-plane (trace_region). Only when the fitted normal can be trusted: the fin
// spreads over its plane ten times more than across it (a narrow band, a few millimetres of a
// hole's ring, can fit a plane tilted by tens of degrees, and the walls then look sloped), or
// the wall is flat (flat_sloped_wall_normal).
Vec3 height_direction(const ClusterPoints& c, const RootPoints& root, const Plane& fin,
                      const Vec3& fin_n, double noise_sigma) {
  Vec3 nw = Vec3::Zero();
  double slope = 0;  // mean |sin| of the walls' slope towards the fin normal
  for (const auto& v : root.normals) {
    nw += v;
    slope += std::abs(v.dot(fin_n)) / static_cast<double>(root.normals.size());
  }
  const bool tilted_to_fin = slope >= std::sin(10 * M_PI / 180);
  if (tilted_to_fin && fin.spread(1) > 100 * fin.spread(0)) return fin_n;
  if (tilted_to_fin)
    if (const auto n_top = flat_sloped_wall_normal(root.normals, c.outer_half(), fin_n, noise_sigma))
      return *n_top;
  if (nw.norm() > 0.5 * static_cast<double>(root.normals.size())) {
    nw.normalize();
    const Vec3 w = fin_n - fin_n.dot(nw) * nw;
    if (w.norm() > 0.5) return w.normalized();
  }
  return fin_n;
}

// The scanner sees the fin's upper face; the root lies on its mid-plane. Where the fin's
// edge (its outer half) shows its thickness, the mid-height there, measured along the
// height direction, is the fin's mid-plane (a symmetric fin, the parting plane across the wall).
void measure_mid_plane(const ClusterPoints& c, double noise_sigma, RegionWork& wk, FlashRegion& reg) {
  std::vector<double> h_outer, h_inner;
  for (const auto& p : c.outer_half()) h_outer.push_back(wk.w.dot(p));
  for (const auto& p : wk.inner) h_inner.push_back(wk.w.dot(p));
  wk.top = percentile(h_inner, 0.5);
  if (h_outer.size() < 20) return;
  // The top face is the bulk (its median is its height); the lowest edge points mark the
  // fin's bottom.
  const double top = percentile(h_outer, 0.5);
  const double bottom = percentile(h_outer, 0.01);
  reg.thickness = std::max(0.0, top - bottom);
  if (reg.thickness > 3 * noise_sigma) {
    wk.resolved = true;
    wk.mid = 0.5 * (top + bottom);
  }
}

// One cluster made a flash region: its fin plane, root and mid-plane. Labels its points flash
// when it stands off the casting and touches it; no region when it never comes near the
// surface (fixture, robot, stray points) or its root lies on no wall seen (labelled flash, no
// grinding line).
std::optional<std::pair<FlashRegion, RegionWork>> analyse_region(
    std::vector<std::uint32_t>& cl, const Live& live, const CroppedScan& crop,
    const std::vector<double>& dist, const MeshBvh& cad_C, const Pose& X_CM, const Scales& s,
    DetectionResult& res) {
  std::sort(cl.begin(), cl.end());
  ClusterPoints c = cluster_points(cl, live, crop.points_C, dist, cad_C, s);
  // A flash grows out of the casting: a cluster that never comes near the surface is
  // something else (fixture, robot, stray points).
  if (c.touching < 3) {
    spdlog::debug("detect: cluster of {} points never near the CAD: dropped", cl.size());
    return std::nullopt;
  }
  // Fins are at most 1.5 mm thick: a fin's points lie within 1.5 mm of its plane.
  bool consensus = false;
  const Plane fin = fit_fin_plane(c.pts, c.touch, 1.5e-3, &consensus);
  if (consensus) drop_points_off_fin_plane(cl, c, fin, 1.5e-3 + 3 * res.noise_sigma);
  FlashRegion reg;
  reg.points.reserve(cl.size());
  for (auto v : cl) reg.points.push_back(crop.index[live.k[v]]);
  reg.centroid_C = fin.c;
  // The fin normal faces the scanner (the origin of {M}).
  reg.normal_C = fin.n;
  if (reg.normal_C.dot(X_CM.translation() - reg.centroid_C) < 0) reg.normal_C = -reg.normal_C;
  const auto uv = fin_plane_coordinates(c.pts, fin, reg);
  reg.max_height = c.hmax;
  RootPoints root = root_points(c, uv, fin, cad_C, s, reg);
  spdlog::debug("detect: region of {} points, {} near the CAD, {} boundary, {} inner, fin normal ({:.3f}, {:.3f}, {:.3f})",
                cl.size(), c.touching, reg.boundary_points, root.points.size(), reg.normal_C.x(),
                reg.normal_C.y(), reg.normal_C.z());
  for (auto idx : reg.points) res.labels[idx] = kDetectFlash;
  // Flash (it stands off the casting and touches it) whose root is nowhere on a wall seen:
  // labelled, but it gives no grinding line.
  if (root.points.size() < 3) return std::nullopt;
  RegionWork wk;
  wk.w = height_direction(c, root, fin, reg.normal_C, res.noise_sigma);
  wk.inner = std::move(root.points);
  wk.inner_n = std::move(root.normals);
  measure_mid_plane(c, res.noise_sigma, wk, reg);
  return std::make_pair(std::move(reg), std::move(wk));
}

// One parting plane: a fin whose edge is too thin to resolve takes the mid-plane of the
// resolved fins parallel to it and within 2 mm of its face (castings part along one plane).
void share_parting_plane(std::vector<RegionWork>& work, std::vector<FlashRegion>& regions,
                         bool mid_plane) {
  for (std::size_t r = 0; r < work.size(); ++r) {
    auto& wk = work[r];
    if (!mid_plane) {
      wk.shift = false;
      continue;
    }
    if (wk.resolved) {
      wk.shift = true;
      continue;
    }
    std::vector<double> mids;
    for (std::size_t q = 0; q < work.size(); ++q) {
      if (!work[q].resolved || work[q].w.dot(wk.w) < std::cos(5 * M_PI / 180)) continue;
      // The other fin's mid height measured along this fin's direction at its own centroid.
      const double m_other = work[q].mid;
      if (std::abs(m_other - wk.top) < 2e-3) mids.push_back(m_other);
    }
    if (!mids.empty()) {
      wk.mid = percentile(mids, 0.5);
      wk.shift = wk.mid < wk.top;  // never above the visible face
      regions[r].thickness = 2 * (wk.top - wk.mid);
    }
  }
}

// The root points at the mid-plane's height, thinned by the (improved) voxel grid: one
// original point per voxel, the one nearest its centroid; then the band a few points wide is
// pulled onto the line fitted to each point's neighbours (twice) so it becomes one curve before
// it is ordered, and thinned again.
std::vector<Vec3> thin_root_band(const RegionWork& wk, const DetectionParams& P, double spacing,
                                 DetectionResult& res) {
  PointCloud ic;
  for (std::size_t i = 0; i < wk.inner.size(); ++i) {
    ic.points.push_back(wk.at_mid(wk.inner[i]).cast<float>());
    ic.normals.push_back(wk.inner_n[i].cast<float>());
  }
  const auto tv = Clock::now();
  const PointCloud thin = P.path_voxel_nearest ? voxel_downsample_nearest(ic, P.path_voxel)
                                               : voxel_downsample(ic, P.path_voxel);
  res.path_voxel_time_s += std::chrono::duration<double>(Clock::now() - tv).count();
  res.path_points_before += ic.size();
  res.path_points_after += thin.size();
  std::vector<Vec3> tp(thin.size());
  for (std::size_t i = 0; i < thin.size(); ++i) tp[i] = thin.points[i].cast<double>();
  const double reach = std::max(2 * P.path_voxel, 2 * spacing);
  for (int pass = 0; pass < 2 && tp.size() > 3; ++pass) {
    std::vector<Eigen::Vector3f> tf(tp.size());
    for (std::size_t i = 0; i < tp.size(); ++i) tf[i] = tp[i].cast<float>();
    const detail::KdTree tt(tf);
    std::vector<Vec3> moved(tp.size());
    std::vector<std::pair<std::uint32_t, float>> nb;
    for (std::size_t i = 0; i < tp.size(); ++i) {
      tt.radius(tf[i], static_cast<float>(reach), nb);
      if (nb.size() < 3) {
        moved[i] = tp[i];
        continue;
      }
      std::vector<Vec3> loc;
      for (const auto& e : nb) loc.push_back(tp[e.first]);
      const Plane local = fit_plane(loc);
      const Vec3 dir = local.axes.col(2);
      moved[i] = local.c + dir.dot(tp[i] - local.c) * dir;
    }
    tp = std::move(moved);
  }
  PointCloud again;
  for (const auto& q : tp) again.points.push_back(q.cast<float>());
  const PointCloud t2 = P.path_voxel_nearest ? voxel_downsample_nearest(again, P.path_voxel)
                                             : voxel_downsample(again, P.path_voxel);
  tp.resize(t2.size());
  for (std::size_t i = 0; i < t2.size(); ++i) tp[i] = t2.points[i].cast<double>();
  return tp;
}

// A fin stands out of its wall, so its normal is square to the wall normals along the
// root: where the wall curves (the normals span a plane: a hole, a rounded corner) it is
// that plane's normal, else the fitted fin normal less its part along the wall normal. A
// plane fitted to a few points of a partly seen ring can be tens of degrees off. Not on a
// wall sloping round the fin normal (a dome, a cone: the normals lie on a cone whose axis
// is the fin normal, and the fin leaves the wall at its slope): where the fitted plane is
// within 5° of the axis the normals turn about, it stands (cover 9015: the dome's parting
// plane, fitted within 0.03°, had been turned 57° off, and the burr's shank with it; a
// 2 mm fragment on a vertical wall, fitted 20° off, is still squared: housing 7016).
void square_fin_normal_to_wall(FlashPath& path, const Vec3& fitted_n) {
  Mat3 M = Mat3::Zero();
  Vec3 mean = Vec3::Zero();
  for (const auto& nrm : path.normals_C) {
    M += nrm * nrm.transpose();
    mean += nrm;
  }
  M /= static_cast<double>(path.normals_C.size());
  mean /= static_cast<double>(path.normals_C.size());
  const Eigen::SelfAdjointEigenSolver<Mat3> es(M);  // ascending eigenvalues
  const Vec3 along_wall = fitted_n - fitted_n.dot(es.eigenvectors().col(2)) * es.eigenvectors().col(2);
  // Curved wall: normals spread in a plane (second eigenvalue), none out of it (smallest),
  // and that plane's normal within 45° of the fitted fin normal; else the straight case.
  const Vec3 e0 = es.eigenvectors().col(0);
  const bool curved = es.eigenvalues()(1) > 0.05 && es.eigenvalues()(0) < 0.02 &&
                      std::abs(e0.dot(fitted_n)) > std::cos(M_PI / 4);
  // The axis the wall normals turn about: the direction in which they do not vary (their
  // covariance, M less the mean's outer product).
  const Eigen::SelfAdjointEigenSolver<Mat3> ec(Mat3(M - mean * mean.transpose()));
  const bool sloped = std::abs(fitted_n.dot(es.eigenvectors().col(2))) > std::sin(M_PI / 18) &&
                      ec.eigenvalues()(1) > 2e-4 &&
                      std::abs(ec.eigenvectors().col(0).dot(fitted_n)) > std::cos(M_PI / 36);
  Vec3 fn = curved ? e0 : (sloped ? fitted_n : along_wall);
  if (fn.norm() > 1e-6) {
    fn.normalize();
    if (fn.dot(fitted_n) < 0) fn = -fn;
    path.fin_normal_C = fn;
  }
}

// A region's grinding lines: its thinned root ordered into polylines, each smoothed by a
// moving average along the curve (wrapping for loops), put back onto the surface and the
// mid-plane, with the fin normal squared to its walls.
void trace_region(int r, const RegionWork& wk, const FlashRegion& reg, const MeshBvh& cad_C,
                  const DetectionParams& P, const Scales& s, DetectionResult& res) {
  const TriangleMesh& cad = cad_C.mesh();
  // With the mid-plane known, the root goes onto the CAD's section by it: moving a wall point
  // along the height direction keeps it on the wall only where the wall is parallel to that
  // direction; on a sloped or domed wall it would stand off the steel or in it.
  const double section_reach = 3e-3;
  std::optional<PlaneSection> section;
  if (wk.shift && !wk.inner.empty()) {
    Vec3 box_lo = wk.inner.front(), box_hi = box_lo;
    for (const auto& q : wk.inner) {
      box_lo = box_lo.cwiseMin(q);
      box_hi = box_hi.cwiseMax(q);
    }
    const Vec3 margin = Vec3::Constant(2 * section_reach);
    section.emplace(cad, wk.w, wk.mid, box_lo - margin, box_hi + margin);
  }
  const std::vector<Vec3> tp = thin_root_band(wk, P, s.spacing, res);
  for (auto& pl : order_polylines(tp, s.gap)) {
    double len = 0;
    for (std::size_t i = 1; i < pl.points.size(); ++i) len += (pl.points[i] - pl.points[i - 1]).norm();
    if (pl.points.size() < 3 || len < P.min_path_length) continue;
    FlashPath path;
    path.region = r;
    path.closed = pl.closed;
    path.fin_normal_C = reg.normal_C;
    path.fin_height = reg.max_height;
    const int N = static_cast<int>(pl.points.size());
    for (int i = 0; i < N; ++i) {
      // An open line's window narrows towards its ends, so they stay where the root ends (a
      // one-sided window pulled them 1-2 mm back along the line: flash left at fin ends).
      const int half = path.closed ? P.smoothing : std::min({P.smoothing, i, N - 1 - i});
      Vec3 acc = Vec3::Zero();
      int cnt = 0;
      for (int k = -half; k <= half; ++k) {
        int j = i + k;
        if (path.closed) j = (j % N + N) % N;
        else if (j < 0 || j >= N) continue;
        acc += pl.points[static_cast<std::size_t>(j)];
        ++cnt;
      }
      const auto cp = cad_C.closest(acc / cnt);
      Vec3 root = wk.at_mid(cp.point), normal = cad.triangle_normal(static_cast<std::size_t>(std::max(0, cp.triangle)));
      Vec3 q, nq;
      if (section && section->closest(root, section_reach, q, nq)) {
        root = q;
        normal = nq;
      }
      path.points_C.push_back(root);
      path.normals_C.push_back(normal);
    }
    if (const int k = repair_fin_parallel_normals(path, reg.normal_C); k > 0)
      spdlog::debug("detect: region {}: {} root normal(s) lay on a face parallel to the fin", r, k);
    square_fin_normal_to_wall(path, reg.normal_C);
    orient_path(path);
    // Extent, not travel: a short zig-zag of boundary points is not a grinding line.
    double extent = 0;
    for (const auto& q : path.points_C) extent = std::max(extent, (q - path.points_C.front()).norm());
    if (extent < P.min_path_length) continue;
    if (P.close_holes) {
      const int added = close_hole_arc(path, cad_C, path.fin_normal_C, std::max(P.path_voxel, s.spacing),
                                       std::max(0.15e-3, 3 * res.noise_sigma));
      if (added > 0)
        spdlog::debug("detect: region {}: hole arc closed along its circle ({} points added)", r,
                      added);
    }
    res.paths.push_back(std::move(path));
  }
}

}  // namespace

DetectionResult detect_flash(const PointCloud& scan_M, const MeshBvh& cad_C, const Pose& X_CM,
                             const DetectionParams& params) {
  const auto t0 = Clock::now();
  const auto& P = params;
  check_params(P);
  const TriangleMesh& cad = cad_C.mesh();
  check_inputs(scan_M, cad, X_CM);
  DetectionResult res;
  res.labels.assign(scan_M.size(), kDetectIgnored);
  const auto done = [&](std::string message) {
    res.ran = true;
    res.message = std::move(message);
    res.time_s = std::chrono::duration<double>(Clock::now() - t0).count();
    return std::move(res);  // (each call is a return of detect_flash)
  };

  // Points off the CAD surface by more than the noise threshold are flash candidates.
  const CroppedScan crop = crop_to_cad(scan_M, cad, X_CM, P.crop_margin);
  res.cropped_points = crop.index.size();
  const std::vector<Vec3>& pc = crop.points_C;
  Scales s;
  s.far = 2 * P.max_threshold;
  const std::vector<double> dist = distances_to_cad(pc, cad_C, s.far);
  res.noise_sigma = scanner_noise(dist, P);
  res.threshold = std::clamp(P.threshold_sigmas * res.noise_sigma, P.min_threshold, P.max_threshold);
  std::vector<std::uint32_t> cand;  // indices into crop
  for (std::size_t k = 0; k < dist.size(); ++k) {
    if (dist[k] > res.threshold) cand.push_back(static_cast<std::uint32_t>(k));
    else res.labels[crop.index[k]] = kDetectBody;
  }
  res.candidate_points = cand.size();
  if (cand.size() < static_cast<std::size_t>(P.min_region_points))
    return done("nothing to grind: no point lies off the CAD surface");

  // Scales from the candidates' spacing; support planes (table, fixture faces) removed.
  std::vector<Eigen::Vector3f> cf(cand.size());
  for (std::size_t c = 0; c < cand.size(); ++c) cf[c] = pc[cand[c]].cast<float>();
  const detail::KdTree cand_tree(cf);
  candidate_spacing(cf, cand_tree, res);
  s.spacing = res.spacing_across;
  const std::vector<bool> alive =
      support_plane_mask(pc, cand, cand_tree, cf, dist, cad, P, res.support_points);
  spdlog::debug("detect: {} cropped, {} candidates, threshold {:.4f} mm, spacing {:.3f}/{:.3f} mm, {} on supports",
                pc.size(), cand.size(), res.threshold * 1e3, res.spacing * 1e3, s.spacing * 1e3,
                res.support_points);
  const double band = P.inner_band > 0 ? P.inner_band : 1.5 * s.spacing;
  s.tol = P.cluster_tolerance > 0 ? P.cluster_tolerance : 3 * s.spacing;
  s.alpha = P.alpha > 0 ? P.alpha : 1.5 * s.spacing;
  s.gap = P.gap > 0 ? P.gap : std::max(4 * P.path_voxel, 4 * s.spacing);
  s.inner_limit = res.threshold + band;
  s.hidden_limit = std::max(s.inner_limit, res.threshold + P.hidden_root_band);
  // (At most half the gap that splits a line: a gap between seen root points, wide enough to
  // split the line, has a hidden point in its middle. At 1 mm a fin's tapering end, its root
  // seen every 1-2 mm, lost its last 2 mm.)
  s.hidden_cover = std::min(std::max(1e-3, 3 * s.spacing), 0.5 * s.gap);

  // Regions: Euclidean clusters of the surviving candidates, with the fragments of fins seen
  // obliquely gathered.
  Live live;
  for (std::size_t c = 0; c < cand.size(); ++c)
    if (alive[c]) {
      live.k.push_back(cand[c]);
      live.pf.push_back(cf[c]);
    }
  const detail::KdTree ltree(live.pf);
  auto clusters = detail::euclidean_clusters(live.pf, ltree, static_cast<float>(s.tol));
  if (P.fragment_merge > 1) {
    const double reach = res.threshold + band;
    const double rise = std::max(0.5e-3, 4 * res.threshold);
    recluster_fragments(clusters, live, dist, reach, rise, s.tol, P);
    join_rising_clusters(clusters, live, dist, pc, rise, s.tol, P);
  }

  // Each region's fin plane, root and mid-plane; one parting plane across them.
  std::vector<RegionWork> work;
  for (auto& cl : clusters) {
    if (cl.size() < static_cast<std::size_t>(P.min_region_points)) continue;
    auto region = analyse_region(cl, live, crop, dist, cad_C, X_CM, s, res);
    if (!region) continue;
    res.regions.push_back(std::move(region->first));
    work.push_back(std::move(region->second));
  }
  share_parting_plane(work, res.regions, P.mid_plane);

  // Grinding lines, then the pieces of one ring or line joined.
  for (std::size_t r = 0; r < work.size(); ++r)
    trace_region(static_cast<int>(r), work[r], res.regions[r], cad_C, P, s, res);
  if (P.close_holes) {
    const int joined = merge_hole_arcs(res.paths, cad_C, std::max(P.path_voxel, res.spacing),
                                       std::max(0.15e-3, 3 * res.noise_sigma));
    if (joined > 0) spdlog::debug("detect: {} arc(s) of hole rings joined to others", joined);
  }
  {
    const double step = std::max(P.path_voxel, res.spacing);
    const int joined = join_continuing_paths(res.paths, std::max(2e-3, 3 * step), 4 * step);
    if (joined > 0) spdlog::debug("detect: {} path(s) joined to the paths they continue", joined);
  }
  if (res.paths.empty()) return done("nothing to grind: no flash region found");
  std::ostringstream os;
  os << res.regions.size() << " flash region(s), " << res.paths.size() << " path(s)";
  return done(os.str());
}

}  // namespace flashtwin::perception
