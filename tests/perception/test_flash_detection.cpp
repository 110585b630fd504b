// Flash detection on synthetic parts: boxes with box-shaped fins, sampled as a scanner looking
// from above would see them (upward and sideways faces), with Gaussian noise along the normal.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>

#include <algorithm>
#include <cmath>
#include <utility>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/flash_detection.hpp"

using namespace flashtwin;
using namespace flashtwin::perception;

namespace {


struct Part {
  std::vector<Eigen::AlignedBox3d> body, fins;
  TriangleMesh cad() const {
    TriangleMesh m;
    for (const auto& b : body) m.append(box_mesh(b.min(), b.max()));
    return m;
  }
};

bool inside_any(const std::vector<Eigen::AlignedBox3d>& boxes, const Vec3& p, double eps = 1e-9) {
  for (const auto& b : boxes)
    if ((p.array() > b.min().array() + eps).all() && (p.array() < b.max().array() - eps).all()) return true;
  return false;
}

// Points every `step` on the faces of every box whose normal does not point down, except
// where they are inside another solid; noise sigma along the face normal.
PointCloud sample(const Part& part, double step, double sigma, std::uint64_t seed,
                  std::vector<std::uint8_t>* truth = nullptr) {
  Rng rng(seed);
  PointCloud c;
  auto faces = [&](const Eigen::AlignedBox3d& b, bool is_fin) {
    for (int axis = 0; axis < 3; ++axis)
      for (int side = 0; side < 2; ++side) {
        if (axis == 2 && side == 0) continue;  // the underside is not seen
        const int u = (axis + 1) % 3, v = (axis + 2) % 3;
        Vec3 n = Vec3::Zero();
        n[axis] = side ? 1 : -1;
        for (double a = b.min()[u] + step / 2; a < b.max()[u]; a += step)
          for (double bb = b.min()[v] + step / 2; bb < b.max()[v]; bb += step) {
            Vec3 p;
            p[axis] = side ? b.max()[axis] : b.min()[axis];
            p[u] = a;
            p[v] = bb;
            const Vec3 probe = p + 1e-6 * n;
            if (inside_any(part.body, probe) || inside_any(part.fins, probe)) continue;
            c.points.push_back((p + rng.normal() * sigma * n).cast<float>());
            if (truth) truth->push_back(is_fin ? 1 : 0);
          }
      }
  };
  for (const auto& b : part.body) faces(b, false);
  for (const auto& f : part.fins) faces(f, true);
  return c;
}

// A 100 x 60 x 30 mm block with a fin 0.8 mm thick, 5 mm out along its +y wall at z = 15 mm.
Part straight_fin_part(double x0 = -0.04, double x1 = 0.04) {
  Part p;
  p.body.emplace_back(Vec3(-0.05, -0.03, 0), Vec3(0.05, 0.03, 0.03));
  p.fins.emplace_back(Vec3(x0, 0.03, 0.0146), Vec3(x1, 0.035, 0.0154));
  return p;
}

// The scanner 0.5 m above the part looking down; the scan handed over in its frame {M}.
const Pose kX_CM = pose_from_xyz_rpy(Vec3(0.0, 0.0, 0.5), Vec3(M_PI, 0.0, 0.0));
PointCloud to_scanner(const PointCloud& scan_C) {
  PointCloud out;
  for (const auto& p : scan_C.points) out.points.push_back((kX_CM.inverse() * p.cast<double>()).cast<float>());
  return out;
}

double distance_to_segment(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = b - a;
  const double t = std::clamp((p - a).dot(ab) / ab.squaredNorm(), 0.0, 1.0);
  return (a + t * ab - p).norm();
}

// Total length of the grinding lines lying wholly within `tol` of the root segment a–b.
double length_along(const DetectionResult& r, const Vec3& a, const Vec3& b, double tol) {
  double len = 0;
  for (const auto& path : r.paths) {
    bool on = true;
    for (const auto& p : path.points_C) on = on && distance_to_segment(p, a, b) < tol;
    if (on) len += path.length();
  }
  return len;
}

}  // namespace

TEST(FlashDetection, StraightFinPathWithinFiftyMicrons) {
  const Part part = straight_fin_part();
  std::vector<std::uint8_t> truth;
  // The scan arrives in the scanner frame: put it somewhere else and hand over the pose.
  // Faces sampled every 0.1 mm (the fin edge, 0.8 mm tall, gets 8 rows).
  const PointCloud scan_C = sample(part, 0.0001, 0.03e-3, 7, &truth);
  const Pose X_CM = pose_from_xyz_rpy(Vec3(0.1, -0.2, 0.5), Vec3(M_PI, 0.1, 0.3));
  PointCloud scan_M;
  for (const auto& p : scan_C.points) scan_M.points.push_back((X_CM.inverse() * p.cast<double>()).cast<float>());
  const MeshBvh cad(part.cad());
  const auto r = detect_flash(scan_M, cad, X_CM);
  ASSERT_TRUE(r.ran);
  ASSERT_EQ(r.regions.size(), 1u);
  ASSERT_EQ(r.paths.size(), 1u);
  const auto& path = r.paths[0];
  EXPECT_FALSE(path.closed);
  // The true root: the fin's mid-line on the wall.
  const Vec3 a(-0.04, 0.03, 0.015), b(0.04, 0.03, 0.015);
  double worst = 0;
  double worst_z = 0;
  for (const auto& p : path.points_C) {
    worst = std::max(worst, distance_to_segment(p, a, b));
    worst_z = std::max(worst_z, std::abs(p.z() - 0.015));
  }
  EXPECT_LT(worst_z, 0.05e-3);
  EXPECT_LT(worst, 0.05e-3);
  // It spans the fin: its ends within 0.3 mm of the fin's (the moving average's one-sided
  // window at an open line's ends had pulled them 0.45 mm in).
  double lo = 1, hi = -1;
  for (const auto& p : path.points_C) {
    lo = std::min(lo, p.x());
    hi = std::max(hi, p.x());
  }
  EXPECT_LT(lo, -0.04 + 0.3e-3);
  EXPECT_GT(hi, 0.04 - 0.3e-3);
  // Fin normal points up (the scanner side), labels agree with the truth.
  EXPECT_GT(r.regions[0].normal_C.z(), 0.99);
  std::size_t tp = 0, fp = 0, fn = 0;
  for (std::size_t i = 0; i < truth.size(); ++i) {
    tp += truth[i] == 1 && r.labels[i] == kDetectFlash;
    fp += truth[i] == 0 && r.labels[i] == kDetectFlash;
    fn += truth[i] == 1 && r.labels[i] != kDetectFlash;
  }
  EXPECT_GT(static_cast<double>(tp) / (tp + fp), 0.98);
  EXPECT_GT(static_cast<double>(tp) / (tp + fn), 0.95);
  // Walking direction: fin normal x surface normal (+z x +y = -x).
  EXPECT_LT((path.points_C.back() - path.points_C.front()).x(), 0);
}

TEST(FlashDetection, HiddenRootStretchIsBridgedByTheFinEdgeNearestTheWall) {
  // The straight fin, but over x in [-10, 10] mm no point within 1.5 mm of the wall comes back
  // (a wall above the fin hid the root from the triangulation camera there).
  const Part part = straight_fin_part();
  const PointCloud full = sample(part, 0.0001, 0.03e-3, 11);
  PointCloud scan_C;
  for (const auto& p : full.points)
    if (!(std::abs(p.x()) < 0.01f && p.y() > 0.03f && p.y() < 0.0315f)) scan_C.points.push_back(p);
  const MeshBvh cad(part.cad());
  const Vec3 a(-0.04, 0.03, 0.015), b(0.04, 0.03, 0.015);
  // How much of the root, sampled every 0.5 mm, has a path point within 0.5 mm.
  const auto covered = [&](const DetectionResult& r) {
    int hit = 0, n = 0;
    for (double x = -0.038; x <= 0.038; x += 0.0005, ++n) {
      const Vec3 q(x, 0.03, 0.015);
      bool near = false;
      for (const auto& path : r.paths)
        for (const auto& p : path.points_C) near = near || (p - q).norm() < 0.5e-3;
      hit += near;
    }
    return static_cast<double>(hit) / n;
  };
  DetectionParams off;
  off.hidden_root_band = 0;
  const auto r_off = detect_flash(to_scanner(scan_C), cad, kX_CM, off);
  const auto r_on = detect_flash(to_scanner(scan_C), cad, kX_CM);
  ASSERT_TRUE(r_on.ran);
  // Without the fallback the 20 mm stretch is missing; with it the root is covered through.
  EXPECT_LT(covered(r_off), 0.8);
  EXPECT_GT(covered(r_on), 0.95);
  // The bridged points are snapped onto the wall: still on the root line.
  double worst = 0;
  for (const auto& path : r_on.paths)
    for (const auto& p : path.points_C) worst = std::max(worst, distance_to_segment(p, a, b));
  EXPECT_LT(worst, 0.2e-3);
}

// A block whose +y wall is one flat face sloping 45° (it faces up and out), with a fin 0.8 mm
// thick at z = 15 mm standing 2 mm out from it over x < 0 and 5 mm over x > 5 mm, thinning to a
// quarter of that over its last 3 mm at each end, as generated fins do. Seen from above: the
// block's top, the wall except under the fin, the fin's top face, outer edge and ends.
// - Such a fin is too low to pass the "spreads 100 times more over its plane than across it"
//   test, and its heights had been taken along the wall: the whole line lay 3.4 mm down the
//   slope. A flat wall's fin takes its top face's normal: every path point now on the root.
// - Where the fin is low its outer edge comes within the hidden-root band of the wall and,
//   snapped onto the slope, lands 1-2 mm down it beside the root: no path may come back along
//   itself (a hairpin turning short of the fin's end), and the root is covered to within
//   1.5 mm of both ends.
TEST(FlashDetection, LowFinOnAFlatSlopedWallIsRootedOnItInOneRow) {
  TriangleMesh cad = box_mesh(Vec3(-0.05, -0.03, 0), Vec3(0.05, 0.03, 0.03));
  for (auto& v : cad.vertices)
    if (v.y() > 0.029 && v.z() < 0.001) v.y() = 0.06;
  const auto wall_y = [](double z) { return 0.06 - z; };
  const double zc = 0.015, t = 0.8e-3, x0 = -0.04, x1 = 0.04, step = 0.1e-3, sigma = 0.03e-3;
  const auto height = [&](double x) {
    const double e = std::min(x - x0, x1 - x) / 0.003;
    const double h = x < 0 ? 2e-3 : (x > 0.005 ? 5e-3 : 2e-3 + 3e-3 * x / 0.005);
    return h * (e < 1 ? 0.25 + 0.75 * e : 1.0);
  };
  const auto tip_y = [&](double x) { return wall_y(zc) + height(x); };
  Rng rng(5);
  PointCloud scan_C;
  const auto add = [&](const Vec3& p, const Vec3& n) {
    scan_C.points.push_back((p + rng.normal() * sigma * n).cast<float>());
  };
  const auto in_fin_x = [&](double x) { return x >= x0 && x <= x1; };
  for (double x = -0.05 + step / 2; x < 0.05; x += step) {
    for (double y = -0.03 + step / 2; y < 0.03; y += step) add(Vec3(x, y, 0.03), Vec3::UnitZ());
    // The wall, a sample every `step` along its slope; none inside the fin or under it.
    for (double z = step / 2; z < 0.03; z += step / std::sqrt(2.0)) {
      if (in_fin_x(x) && std::abs(z - zc) <= t / 2) continue;
      if (in_fin_x(x) && z < zc && wall_y(z) < tip_y(x)) continue;
      add(Vec3(x, wall_y(z), z), Vec3(0, 1, 1).normalized());
    }
    if (!in_fin_x(x)) continue;
    for (double y = wall_y(zc + t / 2) + step / 2; y < tip_y(x); y += step)
      add(Vec3(x, y, zc + t / 2), Vec3::UnitZ());
    for (double z = zc - t / 2 + step / 2; z < zc + t / 2; z += step) add(Vec3(x, tip_y(x), z), Vec3::UnitY());
  }
  for (const double xe : {x0, x1})
    for (double z = zc - t / 2 + step / 2; z < zc + t / 2; z += step)
      for (double y = wall_y(z) + step / 2; y < tip_y(xe); y += step)
        add(Vec3(xe, y, z), Vec3(xe < 0 ? -1 : 1, 0, 0));
  const MeshBvh bvh(cad);
  const auto r = detect_flash(to_scanner(scan_C), bvh, kX_CM);
  ASSERT_TRUE(r.ran);
  ASSERT_FALSE(r.paths.empty());
  const Vec3 a(x0, wall_y(zc), zc), b(x1, wall_y(zc), zc);
  double lo = 1, hi = -1;
  for (const auto& path : r.paths) {
    std::vector<double> s(path.points_C.size(), 0.0);
    for (std::size_t i = 1; i < s.size(); ++i) s[i] = s[i - 1] + (path.points_C[i] - path.points_C[i - 1]).norm();
    for (std::size_t i = 0; i < s.size(); ++i) {
      const Vec3& p = path.points_C[i];
      EXPECT_LT(distance_to_segment(p, a, b), 0.3e-3) << "path point " << p.transpose() << " off the root";
      lo = std::min(lo, p.x());
      hi = std::max(hi, p.x());
      for (std::size_t j = i + 1; j < s.size(); ++j)
        ASSERT_FALSE(s[j] - s[i] > 5e-3 && (path.points_C[j] - p).norm() < 1e-3)
            << "the path comes back along itself at " << p.transpose();
    }
  }
  EXPECT_LT(lo, x0 + 1.5e-3);
  EXPECT_GT(hi, x1 - 1.5e-3);
}

TEST(FlashDetection, HoleFlashIsOneClosedLoop) {
  // A plate with a 20 x 20 mm square hole; a 1 mm ring fin sticks 2 mm into the hole.
  Part part;
  part.body.emplace_back(Vec3(-0.04, -0.04, 0), Vec3(-0.01, 0.04, 0.02));
  part.body.emplace_back(Vec3(0.01, -0.04, 0), Vec3(0.04, 0.04, 0.02));
  part.body.emplace_back(Vec3(-0.01, -0.04, 0), Vec3(0.01, -0.01, 0.02));
  part.body.emplace_back(Vec3(-0.01, 0.01, 0), Vec3(0.01, 0.04, 0.02));
  const double z0 = 0.0095, z1 = 0.0105;
  part.fins.emplace_back(Vec3(-0.01, -0.01, z0), Vec3(-0.008, 0.01, z1));
  part.fins.emplace_back(Vec3(0.008, -0.01, z0), Vec3(0.01, 0.01, z1));
  part.fins.emplace_back(Vec3(-0.008, -0.01, z0), Vec3(0.008, -0.008, z1));
  part.fins.emplace_back(Vec3(-0.008, 0.008, z0), Vec3(0.008, 0.01, z1));
  const PointCloud scan = to_scanner(sample(part, 0.0001, 0.03e-3, 3));
  const MeshBvh cad(part.cad());
  const auto r = detect_flash(scan, cad, kX_CM);
  ASSERT_TRUE(r.ran);
  ASSERT_EQ(r.paths.size(), 1u) << r.message;
  EXPECT_TRUE(r.paths[0].closed);
  // Around the hole: 80 mm of wall at the fin's mid height.
  EXPECT_NEAR(r.paths[0].length(), 0.08, 0.004);
  for (const auto& p : r.paths[0].points_C) {
    EXPECT_NEAR(p.z(), 0.01, 0.1e-3);
    EXPECT_NEAR(std::max(std::abs(p.x()), std::abs(p.y())), 0.01, 0.05e-3);
  }
}

namespace {

// A round wall of radius R (z from 0 to 20 mm, 96 facets) with a 1 mm ring fin 2 mm wide at
// z = 10 mm on its open side: inside a hole (`hole`, normals towards the axis) or around a
// boss (normals away from it). Fin points over the azimuth intervals `hide` [deg] are not seen.
struct RoundCase {
  TriangleMesh cad;
  PointCloud scan_C;
};

RoundCase round_wall_with_ring(double R, bool hole, const std::vector<std::pair<double, double>>& hide) {
  RoundCase rc;
  const int n = 96;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    rc.cad.vertices.emplace_back(R * std::cos(a), R * std::sin(a), 0.0);
    rc.cad.vertices.emplace_back(R * std::cos(a), R * std::sin(a), 0.02);
  }
  for (int i = 0; i < n; ++i) {
    const int a0 = 2 * i, a1 = 2 * i + 1, b0 = 2 * ((i + 1) % n), b1 = b0 + 1;
    // Counter-clockwise seen from outside the solid: the solid is outside the hole's wall.
    if (hole) {
      rc.cad.triangles.emplace_back(a0, a1, b0);
      rc.cad.triangles.emplace_back(b0, a1, b1);
    } else {
      rc.cad.triangles.emplace_back(a0, b0, a1);
      rc.cad.triangles.emplace_back(b0, b1, a1);
    }
  }
  Rng rng(17);
  const double s = 0.03e-3, side = hole ? -1 : 1;  // the fin grows away from the solid
  auto hidden = [&](double a) {
    const double deg = std::fmod(a * 180 / M_PI + 360, 360);
    for (const auto& [from, to] : hide)
      if (deg > from && deg < to) return true;
    return false;
  };
  const double apothem = R * std::cos(M_PI / n);
  for (double a = 0; a < 2 * M_PI; a += 0.1e-3 / R) {
    const Vec3 e(std::cos(a), std::sin(a), 0);
    // The wall above and below the fin (on the facet polygon: radius between apothem and R).
    for (double z = 0.0005; z < 0.02; z += 0.0002) {
      if (std::abs(z - 0.01) < 0.0006) continue;
      rc.scan_C.points.push_back(((apothem + rng.normal() * s) * e + Vec3(0, 0, z)).cast<float>());
    }
    if (hidden(a)) continue;
    // Fin top and its edge face.
    for (double d = 0.0001; d < 0.002; d += 0.0001)
      rc.scan_C.points.push_back(((apothem + side * d) * e + Vec3(0, 0, 0.0105 + rng.normal() * s)).cast<float>());
    for (double z = 0.0096; z < 0.0105; z += 0.0001)
      rc.scan_C.points.push_back(((apothem + side * 0.002 + rng.normal() * s) * e + Vec3(0, 0, z)).cast<float>());
  }
  return rc;
}

// A closed loop on the round wall of radius R at the fin's mid height (z = 10 mm), no gap
// between neighbours longer than 1 mm.
void expect_loop_on_wall(const FlashPath& loop, double R) {
  for (std::size_t i = 0; i < loop.points_C.size(); ++i) {
    const Vec3& p = loop.points_C[i];
    EXPECT_NEAR(std::hypot(p.x(), p.y()), R, 0.05e-3);
    EXPECT_NEAR(p.z(), 0.01, 0.1e-3);
    EXPECT_LT((loop.points_C[(i + 1) % loop.points_C.size()] - p).norm(), 1e-3);
  }
}

}  // namespace

TEST(FlashDetection, PartlySeenHoleRingIsClosedAlongItsCircle) {
  // A 12 mm hole whose ring fin is not seen over 110 degrees: without the hole step the path
  // is an open 250-degree arc; with it, one closed loop on the wall all the way round.
  const double R = 0.006;
  const RoundCase rc = round_wall_with_ring(R, true, {{100, 210}});
  const MeshBvh cad(rc.cad);
  DetectionParams off;
  off.close_holes = false;
  const auto r_off = detect_flash(to_scanner(rc.scan_C), cad, kX_CM, off);
  const auto r_on = detect_flash(to_scanner(rc.scan_C), cad, kX_CM);
  ASSERT_TRUE(r_on.ran) << r_on.message;
  ASSERT_EQ(r_off.paths.size(), 1u) << r_off.message;
  EXPECT_FALSE(r_off.paths[0].closed);
  EXPECT_LT(r_off.paths[0].length(), 0.75 * 2 * M_PI * R);
  ASSERT_EQ(r_on.paths.size(), 1u) << r_on.message;
  const auto& loop = r_on.paths[0];
  EXPECT_TRUE(loop.closed);
  EXPECT_NEAR(loop.length(), 2 * M_PI * R, 0.03 * 2 * M_PI * R);
  // Every point on the wall at the fin's mid height, the added arc included; no gap between
  // neighbours longer than 1 mm.
  expect_loop_on_wall(loop, R);
}

TEST(FlashDetection, HoleRingSeenOverAQuarterIsClosedOnTheWall) {
  // Only 90 degrees of the ring seen (one view looking into the hole): the short arc's circle,
  // refined on the CAD wall, closes the loop on the wall all the way round.
  const double R = 0.006;
  const RoundCase rc = round_wall_with_ring(R, true, {{90, 360}});
  const MeshBvh cad(rc.cad);
  DetectionParams off;
  off.close_holes = false;
  const auto r_off = detect_flash(to_scanner(rc.scan_C), cad, kX_CM, off);
  ASSERT_EQ(r_off.paths.size(), 1u) << r_off.message;
  EXPECT_LT(r_off.paths[0].length(), 0.3 * 2 * M_PI * R);
  const auto r_on = detect_flash(to_scanner(rc.scan_C), cad, kX_CM);
  ASSERT_EQ(r_on.paths.size(), 1u) << r_on.message;
  EXPECT_TRUE(r_on.paths[0].closed);
  EXPECT_NEAR(r_on.paths[0].length(), 2 * M_PI * R, 0.03 * 2 * M_PI * R);
  expect_loop_on_wall(r_on.paths[0], R);
}

TEST(FlashDetection, HoleRingSeenInTwoArcsIsOneLoopOnItsCircle) {
  // The ring seen in two arcs (as two views see a hole from either side), unseen over 60-120
  // and 200-260 degrees: two open paths without the hole step, one closed loop on the circle
  // with it, the gaps filled along the wall.
  const double R = 0.006;
  const RoundCase rc = round_wall_with_ring(R, true, {{60, 120}, {200, 260}});
  const MeshBvh cad(rc.cad);
  DetectionParams off;
  off.close_holes = false;
  const auto r_off = detect_flash(to_scanner(rc.scan_C), cad, kX_CM, off);
  ASSERT_TRUE(r_off.ran) << r_off.message;
  EXPECT_EQ(r_off.paths.size(), 2u) << r_off.message;
  const auto r_on = detect_flash(to_scanner(rc.scan_C), cad, kX_CM);
  ASSERT_TRUE(r_on.ran) << r_on.message;
  ASSERT_EQ(r_on.paths.size(), 1u) << r_on.message;
  const auto& loop = r_on.paths[0];
  EXPECT_TRUE(loop.closed);
  EXPECT_NEAR(loop.length(), 2 * M_PI * R, 0.03 * 2 * M_PI * R);
  expect_loop_on_wall(loop, R);
}

TEST(FlashDetection, PartlySeenRingAroundABossStaysOpen) {
  // The same ring outside a round boss: an outer contour may have real gaps, so it is not
  // closed (the wall normals point away from the circle's centre).
  const RoundCase rc = round_wall_with_ring(0.02, false, {{100, 210}});
  const MeshBvh cad(rc.cad);
  const auto r = detect_flash(to_scanner(rc.scan_C), cad, kX_CM);
  ASSERT_TRUE(r.ran) << r.message;
  ASSERT_EQ(r.paths.size(), 1u) << r.message;
  EXPECT_FALSE(r.paths[0].closed);
  EXPECT_LT(r.paths[0].length(), 0.75 * 2 * M_PI * 0.02);
}

TEST(FlashDetection, FinSeenInSparseScanLinesIsOneRegion) {
  // Two fins: one seen densely (+y wall), the other (−y wall) only in scan lines 0.8 mm apart,
  // as from an oblique view. Clustered at 3 × the dense spacing, every line of the sparse fin
  // is a cluster of its own and no grinding line comes out of it; re-clustering the small
  // clusters at 2.5 × that tolerance joins them into one region with one path along the root.
  Part part = straight_fin_part();
  part.fins.emplace_back(Vec3(-0.04, -0.035, 0.0146), Vec3(0.04, -0.03, 0.0154));
  const PointCloud dense = sample(part, 0.0001, 0.03e-3, 5);
  PointCloud scan_C;
  for (const auto& p : dense.points) {
    const double line = std::remainder(static_cast<double>(p.x()), 0.0008);
    const bool on_fin = p.y() < -0.030001f && p.z() > 0.0145f && p.z() < 0.0156f;
    if (on_fin && std::abs(line) > 0.00006) continue;
    scan_C.points.push_back(p);
  }
  const MeshBvh cad(part.cad());
  const Vec3 a(-0.04, -0.03, 0.015), b(0.04, -0.03, 0.015);
  // Length of the grinding lines lying along the sparse fin's root (within 0.2 mm of it).
  const auto along_root = [&](const DetectionResult& r) { return length_along(r, a, b, 0.2e-3); };
  DetectionParams off;
  off.fragment_merge = 0;
  const auto r_off = detect_flash(to_scanner(scan_C), cad, kX_CM, off);
  const auto r_on = detect_flash(to_scanner(scan_C), cad, kX_CM);
  ASSERT_TRUE(r_off.ran && r_on.ran) << r_on.message;
  // One region per scan line without the merge (about 100), a handful with it.
  EXPECT_GT(r_off.regions.size(), 50u);
  EXPECT_LE(r_on.regions.size(), 4u);
  EXPECT_LT(along_root(r_off), 0.02);
  EXPECT_GT(along_root(r_on), 0.07);
}

TEST(FlashDetection, ScanLinesAcrossAFinWhoseRootIsHiddenJoinItsRegion) {
  // Over 20 mm of a 5 mm fin the root strip (2 mm) is hidden and the rest seen only in scan
  // lines 0.6 mm apart, each too small to be a region and not reaching the casting, as where
  // a wall hid a rounded corner from every view. Joined to the fin's region through each
  // other, their inner ends stand for the hidden root and the grinding line runs on.
  const Part part = straight_fin_part();
  const PointCloud dense = sample(part, 0.0001, 0.03e-3, 7);
  PointCloud scan_C;
  for (const auto& p : dense.points) {
    const bool on_fin = p.y() > 0.030001f && p.z() > 0.0145f && p.z() < 0.0156f;
    const bool stretch = std::abs(p.x()) < 0.01f;
    const double line = std::remainder(static_cast<double>(p.x()), 0.0006);
    if (on_fin && stretch && (p.y() < 0.032f || std::abs(line) > 0.00006)) continue;
    scan_C.points.push_back(p);
  }
  const MeshBvh cad(part.cad());
  const Vec3 a(-0.04, 0.03, 0.015), b(0.04, 0.03, 0.015);
  const auto along_root = [&](const DetectionResult& r) { return length_along(r, a, b, 0.3e-3); };
  DetectionParams off;
  off.fragment_merge = 0;
  const auto r_off = detect_flash(to_scanner(scan_C), cad, kX_CM, off);
  const auto r_on = detect_flash(to_scanner(scan_C), cad, kX_CM);
  ASSERT_TRUE(r_off.ran && r_on.ran) << r_on.message;
  EXPECT_LT(along_root(r_off), 0.065);
  EXPECT_GT(along_root(r_on), 0.075);
}

TEST(FlashDetection, FinPastTheOuterFaceOfAFixtureBesideItStaysFlash) {
  // A clamp block stands 3 mm off the part's +y wall with its outer face 0.5 mm past the part's
  // -x end (the largest face in the crop: the first support found); a fin 5 mm out of that end
  // lies behind the face's plane (away from the part). The plane is a support (the whole CAD
  // on one side), but the fin is beyond the block's edges: it must stay flash (before the
  // footprint it was dropped with everything behind the plane), and the clamp must not.
  Part part;
  part.body.emplace_back(Vec3(-0.05, -0.03, 0), Vec3(0.05, 0.03, 0.03));
  part.fins.emplace_back(Vec3(-0.055, -0.02, 0.0146), Vec3(-0.05, 0.02, 0.0154));
  Part scene = part;
  const Eigen::AlignedBox3d clamp(Vec3(-0.0505, 0.033, 0), Vec3(-0.045, 0.09, 0.06));
  scene.body.push_back(clamp);
  const PointCloud scan_C = sample(scene, 0.0002, 0.03e-3, 17);
  const MeshBvh cad(part.cad());
  const auto r = detect_flash(to_scanner(scan_C), cad, kX_CM);
  ASSERT_TRUE(r.ran) << r.message;
  EXPECT_GT(r.support_points, 1000u) << "the clamp's faces are supports";
  const Vec3 a(-0.05, -0.02, 0.015), b(-0.05, 0.02, 0.015);
  EXPECT_GT(length_along(r, a, b, 0.3e-3), 0.035);
  // No grinding line on the clamp.
  for (const auto& path : r.paths)
    for (const auto& p : path.points_C) EXPECT_FALSE(clamp.contains(p)) << p.transpose();
}

TEST(FlashDetection, NoFlashNothingToGrind) {
  Part part = straight_fin_part();
  part.fins.clear();
  const PointCloud scan = to_scanner(sample(part, 0.0005, 0.03e-3, 5));
  const MeshBvh cad(part.cad());
  const auto r = detect_flash(scan, cad, kX_CM);
  ASSERT_TRUE(r.ran);
  EXPECT_TRUE(r.paths.empty());
  EXPECT_TRUE(r.regions.empty());
  EXPECT_NE(r.message.find("nothing to grind"), std::string::npos);
}

TEST(FlashDetection, SeveralRegionsWithGaps) {
  // Two fins on the +y wall with a 15 mm gap, one on the -x wall: three regions, three paths.
  Part part;
  part.body.emplace_back(Vec3(-0.05, -0.03, 0), Vec3(0.05, 0.03, 0.03));
  part.fins.emplace_back(Vec3(-0.045, 0.03, 0.0146), Vec3(-0.01, 0.034, 0.0154));
  part.fins.emplace_back(Vec3(0.005, 0.03, 0.0146), Vec3(0.045, 0.036, 0.0154));
  part.fins.emplace_back(Vec3(-0.054, -0.02, 0.0146), Vec3(-0.05, 0.02, 0.0154));
  const PointCloud scan = to_scanner(sample(part, 0.0004, 0.03e-3, 11));
  const MeshBvh cad(part.cad());
  const auto r = detect_flash(scan, cad, kX_CM);
  ASSERT_TRUE(r.ran);
  EXPECT_EQ(r.regions.size(), 3u);
  ASSERT_EQ(r.paths.size(), 3u);
  std::vector<double> lengths;
  for (const auto& p : r.paths) {
    EXPECT_FALSE(p.closed);
    lengths.push_back(p.length());
  }
  std::sort(lengths.begin(), lengths.end());
  EXPECT_NEAR(lengths[0], 0.035, 0.004);
  EXPECT_NEAR(lengths[1], 0.040, 0.004);
  EXPECT_NEAR(lengths[2], 0.040, 0.004);
}

TEST(FlashDetection, BadInputIsRejected) {
  const Part part = straight_fin_part();
  const MeshBvh cad(part.cad());
  const PointCloud scan = sample(part, 0.001, 0.03e-3, 1);
  // Empty scan.
  EXPECT_THROW(detect_flash(PointCloud{}, cad, Pose::Identity()), ArgumentError);
  // NaN point.
  PointCloud bad = scan;
  bad.points[3].x() = std::nanf("");
  EXPECT_THROW(detect_flash(bad, cad, Pose::Identity()), ArgumentError);
  // Scan in millimetres against a CAD model in metres.
  PointCloud mm = scan;
  for (auto& p : mm.points) p *= 1000.f;
  try {
    detect_flash(mm, cad, Pose::Identity());
    FAIL() << "units mismatch not detected";
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find("metres"), std::string::npos) << e.what();
  }
  // A pose that is not rigid (scaled).
  Pose scaled = Pose::Identity();
  scaled.linear() *= 1.01;
  EXPECT_THROW(detect_flash(scan, cad, scaled), ArgumentError);
  // Impossible parameter.
  DetectionParams p;
  p.path_voxel = -1;
  EXPECT_THROW(detect_flash(scan, cad, Pose::Identity(), p), ArgumentError);
}

// A root seen by scan lines 1.8 mm apart: each line gives a group of three points 0.2 mm
// apart, the groups farther apart than the gap. The groups are one line (the sampling, not a
// missing stretch, spaces them); a stretch with four lines missing (9 mm) still splits it.
TEST(FlashDetection, OrderPolylinesJoinsScanLineGroupsButNotAMissingStretch) {
  std::vector<Vec3> pts;
  for (int g = 0; g < 30; ++g) {
    if (g >= 14 && g < 18) continue;  // lines 14-17 missing
    for (int k = 0; k < 3; ++k) pts.emplace_back(0.0018 * g + 0.0002 * k, 0.0001 * k, 0);
  }
  const auto lines = order_polylines(pts, 0.0016);
  ASSERT_EQ(lines.size(), 2u);
  for (const auto& l : lines) {
    EXPECT_FALSE(l.closed);
    EXPECT_GE(l.points.size(), 36u);
  }
  // One point per line: the same; a 5 mm break between lines 1.8 mm apart splits them.
  std::vector<Vec3> sparse;
  for (int g = 0; g < 20; ++g) sparse.emplace_back(0.0018 * g + (g >= 10 ? 0.0032 : 0.0), 0, 0);
  const auto two = order_polylines(sparse, 0.0016);
  ASSERT_EQ(two.size(), 2u);
  EXPECT_EQ(two[0].points.size(), 10u);
}

// Pieces of a root with a few points missing (a 1.8 mm hole in 0.4 mm sampling) are joined end
// to end; a piece beside another (a root 2 mm off, parallel) or past 3 × gap is not.
TEST(FlashDetection, OrderPolylinesJoinsPiecesThatContinueEachOther) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 30; ++i) pts.emplace_back(0.0004 * i, 0, 0);          // 0 - 11.6 mm
  for (int i = 0; i < 30; ++i) pts.emplace_back(0.0134 + 0.0004 * i, 0, 0);  // 1.8 mm on
  for (int i = 0; i < 30; ++i) pts.emplace_back(0.0004 * i, 0.002, 0);       // beside, 2 mm off
  for (int i = 0; i < 30; ++i) pts.emplace_back(0.0300 + 0.0004 * i, 0, 0);  // 4.9 mm past the end
  const auto lines = order_polylines(pts, 0.0016);
  ASSERT_EQ(lines.size(), 3u);
  std::size_t longest = 0;
  for (const auto& l : lines) longest = std::max(longest, l.points.size());
  EXPECT_EQ(longest, 60u);
}

// A parting line round a whole casting (a 100 mm circle here) that stops 20 mm short of its
// start turns a full circle with its ends far closer than a quarter of its length, but it is
// not a loop: closing it would grind a chord across the gap (through a corner of the part). A
// hole's ring of radius 6 mm seen with a 3 mm gap is one.
TEST(FlashDetection, OrderPolylinesClosesAHiddenGapOfARingNotOfAWholePartingLine) {
  const auto arc = [](double radius, double gap_length, double step) {
    std::vector<Vec3> pts;
    const double span = 2 * M_PI - gap_length / radius;
    const int n = static_cast<int>(span * radius / step);
    for (int i = 0; i <= n; ++i) {
      const double a = span * i / n;
      pts.emplace_back(radius * std::cos(a), radius * std::sin(a), 0);
    }
    return pts;
  };
  const auto long_line = order_polylines(arc(0.05, 0.02, 0.0004), 0.0016);
  ASSERT_EQ(long_line.size(), 1u);
  EXPECT_FALSE(long_line[0].closed);
  const auto ring = order_polylines(arc(0.006, 0.003, 0.0004), 0.0016);
  ASSERT_EQ(ring.size(), 1u);
  EXPECT_TRUE(ring[0].closed);
}

TEST(FlashDetection, OrderPolylinesSplitsAtGapsAndClosesLoops) {
  std::vector<Vec3> pts;
  for (int i = 0; i < 100; ++i) {  // a circle of radius 10 mm, shuffled order
    const double a = 2 * M_PI * ((i * 37) % 100) / 100.0;
    pts.emplace_back(0.01 * std::cos(a), 0.01 * std::sin(a), 0);
  }
  for (int i = 0; i < 20; ++i) pts.emplace_back(0.05 + 0.0005 * i, 0, 0);  // a line
  for (int i = 0; i < 20; ++i) pts.emplace_back(0.07 + 0.0005 * i, 0, 0);  // after a 10 mm gap
  const auto lines = order_polylines(pts, 0.002);
  ASSERT_EQ(lines.size(), 3u);
  int closed = 0;
  for (const auto& l : lines) {
    closed += l.closed;
    for (std::size_t i = 1; i < l.points.size(); ++i)
      EXPECT_LT((l.points[i] - l.points[i - 1]).norm(), 0.002);
  }
  EXPECT_EQ(closed, 1);
}

namespace {
// An open path along x on the wall y = 0 (outward normal -y), fin plane z = 7 mm.
FlashPath line_path(double x0, double x1, double step) {
  FlashPath p;
  p.fin_normal_C = Vec3::UnitZ();
  const int n = static_cast<int>(std::round(std::abs(x1 - x0) / step));
  for (int i = 0; i <= n; ++i) {
    p.points_C.emplace_back(x0 + (x1 - x0) * i / n, 0.0, 0.007);
    p.normals_C.emplace_back(0.0, -1.0, 0.0);
  }
  return p;
}
}  // namespace

TEST(FlashDetection, PathsThatContinueEachOtherBecomeOne) {
  // Housing 7015: one straight root split between regions as paths ending 0.7 mm apart, the
  // second running back over the first's end; ground apart, the first's finishing pass ran
  // into the second's standing fin and pushed the arm into the wall (gouge 0.12 mm).
  std::vector<FlashPath> paths = {line_path(0.0, 0.05, 4e-4), line_path(0.0493, 0.08, 4e-4)};
  std::reverse(paths[1].points_C.begin(), paths[1].points_C.end());  // either direction
  paths[1].fin_height = 0.004;
  // A parallel path 5 mm off (another fin), a path at right angles at the end and a closed
  // loop nearby are left alone.
  FlashPath parallel = line_path(0.051, 0.07, 4e-4);
  for (auto& q : parallel.points_C) q.y() = 0.005;
  FlashPath corner = line_path(0.0, 0.02, 4e-4);
  for (auto& q : corner.points_C) q = Vec3(0.0806, q.x(), q.z());
  // A parallel fin 1 mm to the side whose end overlaps the first's end (within reach).
  FlashPath beside = line_path(0.0495, 0.065, 4e-4);
  for (auto& q : beside.points_C) q.y() = -0.001;
  FlashPath loop = line_path(0.0494, 0.052, 4e-4);  // its ends by the junction, but closed
  loop.closed = true;
  for (auto& q : loop.points_C) q.y() = 0.001;
  paths.push_back(parallel);
  paths.push_back(corner);
  paths.push_back(loop);
  paths.push_back(beside);
  EXPECT_EQ(join_continuing_paths(paths, 2e-3, 1.6e-3), 1);
  ASSERT_EQ(paths.size(), 5u);
  const FlashPath& m = paths[0];
  EXPECT_FALSE(m.closed);
  EXPECT_EQ(m.fin_height, 0.004);
  // One line from 0 to 80 mm, monotonic (the overlap dropped), normals kept with their points.
  double lo = 1, hi = -1;
  for (std::size_t k = 0; k < m.points_C.size(); ++k) {
    lo = std::min(lo, m.points_C[k].x());
    hi = std::max(hi, m.points_C[k].x());
    EXPECT_NEAR(m.normals_C[k].y(), -1.0, 1e-12);
    if (k > 0) {
      const double dx = m.points_C[k].x() - m.points_C[k - 1].x();
      EXPECT_GT(std::abs(dx), 1e-5) << k;
      EXPECT_EQ(dx > 0, m.points_C[1].x() > m.points_C[0].x()) << k;
    }
  }
  EXPECT_NEAR(lo, 0.0, 1e-9);
  EXPECT_NEAR(hi, 0.08, 1e-9);
}

TEST(FlashDetection, RootNormalsOnAFaceParallelToTheFinTakeTheWallsNormal) {
  // Round flange 6115: a rim's root just under the top face; halfway along, the nearest CAD
  // triangle was the top face (+z, the fin's own normal) and the wrist had to swing 1.8 rad.
  FlashPath p = line_path(0.0, 0.03, 1e-3);
  for (std::size_t i = 12; i < p.normals_C.size(); ++i) p.normals_C[i] = Vec3::UnitZ();
  p.normals_C[3] = Vec3(0.0, -std::cos(0.9), std::sin(0.9)).normalized();  // sloped 52°: a wall
  const Vec3 sloped = p.normals_C[3];
  EXPECT_EQ(repair_fin_parallel_normals(p, Vec3::UnitZ()), static_cast<int>(p.normals_C.size()) - 12);
  for (std::size_t i = 0; i < p.normals_C.size(); ++i) {
    if (i == 3) EXPECT_EQ(p.normals_C[i], sloped);
    else EXPECT_NEAR(p.normals_C[i].y(), -1.0, 1e-12) << i;
  }
  // The nearest wall's normal, around the loop's seam too: walls -y at 0..4, +x at 10..14,
  // parallel elsewhere (20 points, closed).
  FlashPath ring = line_path(0.0, 0.019, 1e-3);
  ring.closed = true;
  for (std::size_t i = 0; i < ring.normals_C.size(); ++i)
    ring.normals_C[i] = i < 5 ? Vec3(0, -1, 0) : (i >= 10 && i < 15 ? Vec3(1, 0, 0) : Vec3(0, 0, 1));
  EXPECT_EQ(repair_fin_parallel_normals(ring, Vec3::UnitZ()), 10);
  EXPECT_EQ(ring.normals_C[6], Vec3(0, -1, 0));   // 2 from the -y wall, 4 from the +x wall
  EXPECT_EQ(ring.normals_C[8], Vec3(1, 0, 0));    // 4 from -y, 2 from +x
  EXPECT_EQ(ring.normals_C[16], Vec3(1, 0, 0));   // 2 from +x, 4 across the seam from -y
  EXPECT_EQ(ring.normals_C[18], Vec3(0, -1, 0));  // 4 from +x, 2 across the seam from -y
  // Nothing to take from: every normal parallel to the fin is left as it is.
  FlashPath flat = line_path(0.0, 0.01, 1e-3);
  for (auto& n : flat.normals_C) n = Vec3::UnitZ();
  EXPECT_EQ(repair_fin_parallel_normals(flat, Vec3::UnitZ()), 0);
  EXPECT_EQ(flat.normals_C.back(), Vec3::UnitZ());
}

TEST(FlashDetection, FinPlaneIsNotTiltedByAFixtureClusteredWithTheFin) {
  // Round flange 6115: a clamp block's top (not in the CAD, 10–17 mm above the fin) clustered
  // with a rim's fin and tilted the least-squares plane by 15°; the root then came out 7 mm
  // above the parting line. Here an arc of fin 0.8 mm thick (z 14.6–15.4 mm) and a block top
  // beside one end, 10 mm above it, with a fifth of the points.
  std::vector<Vec3> pts;
  Rng rng(5);
  for (int i = 0; i < 4000; ++i) {
    const double a = rng.uniform(-1.2, 1.2), r = rng.uniform(0.116, 0.124);
    pts.emplace_back(r * std::cos(a), r * std::sin(a), rng.uniform(0.0146, 0.0154));
  }
  for (int i = 0; i < 1000; ++i)
    pts.emplace_back(rng.uniform(0.125, 0.145), rng.uniform(0.05, 0.07), 0.025);
  // The fin's points next to the wall touch the casting; the block's do not.
  std::vector<bool> touch(pts.size(), false);
  for (std::size_t i = 0; i < 4000; ++i) touch[i] = pts[i].head<2>().norm() < 0.117;
  const FinPlane plane = fin_plane(pts, touch, 1.5e-3);
  EXPECT_TRUE(plane.consensus);
  EXPECT_GT(std::abs(plane.n.z()), std::cos(0.2 * M_PI / 180));
  EXPECT_NEAR(plane.c.z(), 0.015, 0.2e-3);
  // A block with more points than the fin: still the fin's plane, the only one touching.
  std::vector<Vec3> more = pts;
  for (int i = 0; i < 6000; ++i) more.emplace_back(rng.uniform(0.125, 0.145), rng.uniform(0.05, 0.07), 0.025);
  std::vector<bool> more_touch = touch;
  more_touch.resize(more.size(), false);
  const FinPlane crowded = fin_plane(more, more_touch, 1.5e-3);
  EXPECT_GT(std::abs(crowded.n.z()), std::cos(0.2 * M_PI / 180));
  EXPECT_NEAR(crowded.c.z(), 0.015, 0.2e-3);
  // The least-squares plane of the same points is tilted by more than a degree.
  Vec3 c = Vec3::Zero();
  for (const auto& p : pts) c += p;
  c /= static_cast<double>(pts.size());
  Mat3 M = Mat3::Zero();
  for (const auto& p : pts) M += (p - c) * (p - c).transpose();
  const Eigen::SelfAdjointEigenSolver<Mat3> es(M);
  EXPECT_LT(std::abs(es.eigenvectors().col(0).z()), std::cos(M_PI / 180));
  // A clean fin: the same plane as least squares.
  pts.resize(4000);
  touch.resize(4000);
  const FinPlane clean = fin_plane(pts, touch, 1.5e-3);
  EXPECT_FALSE(clean.consensus);
  EXPECT_GT(std::abs(clean.n.z()), std::cos(0.2 * M_PI / 180));
}
