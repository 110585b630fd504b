#include <gtest/gtest.h>

#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/casting.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

double point_triangle_distance(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  // Project onto the plane; if outside the triangle, the nearest edge decides.
  const Vec3 n = (b - a).cross(c - a).normalized();
  const Vec3 q = p - n * (p - a).dot(n);
  const bool inside = (b - a).cross(q - a).dot(n) >= 0 && (c - b).cross(q - b).dot(n) >= 0 &&
                      (a - c).cross(q - c).dot(n) >= 0;
  if (inside) return std::abs((p - a).dot(n));
  auto seg = [&](const Vec3& u, const Vec3& v) {
    const double t = std::clamp((p - u).dot(v - u) / (v - u).squaredNorm(), 0.0, 1.0);
    return (p - (u + t * (v - u))).norm();
  };
  return std::min({seg(a, b), seg(b, c), seg(c, a)});
}

double mesh_distance(const TriangleMesh& m, const Vec3& p) {
  double d = 1e9;
  for (const auto& t : m.triangles)
    d = std::min(d, point_triangle_distance(p, m.vertices[t[0]], m.vertices[t[1]], m.vertices[t[2]]));
  return d;
}

// Ray parity along a skewed direction (avoids edges and axis-aligned walls).
bool inside(const TriangleMesh& m, const Vec3& p) {
  const Vec3 d = Vec3(0.5773, 0.3371, 0.7436).normalized();
  int hits = 0;
  for (const auto& t : m.triangles) {
    const Vec3 &a = m.vertices[t[0]], &b = m.vertices[t[1]], &c = m.vertices[t[2]];
    const Vec3 e1 = b - a, e2 = c - a, h = d.cross(e2);
    const double det = e1.dot(h);
    if (std::abs(det) < 1e-18) continue;
    const Vec3 s = p - a;
    const double u = s.dot(h) / det;
    if (u < 0 || u > 1) continue;
    const Vec3 q = s.cross(e1);
    const double v = d.dot(q) / det;
    if (v < 0 || u + v > 1) continue;
    if (e2.dot(q) / det > 0) ++hits;
  }
  return hits % 2 == 1;
}

CastingParams params_for(CastingFamily f, std::uint64_t seed) {
  CastingParams p;
  p.family = f;
  p.seed = seed;
  return p;
}

const CastingFamily kFamilies[] = {CastingFamily::kFlangedPlate, CastingFamily::kRoundFlange,
                                   CastingFamily::kHousing, CastingFamily::kCover};

}  // namespace

TEST(Casting, FamiliesAreWatertightOrientedAndMatchTheirAnalyticVolume) {
  for (auto fam : kFamilies)
    for (std::uint64_t seed = 1; seed <= 4; ++seed) {
      const Casting c = make_casting(params_for(fam, seed));
      SCOPED_TRACE(c.description);
      const MeshCheck chk = check_mesh(c.nominal);
      EXPECT_TRUE(chk.watertight()) << chk.boundary_edges << " boundary, " << chk.nonmanifold_edges
                                    << " non-manifold";
      EXPECT_TRUE(chk.consistently_oriented()) << chk.inconsistent_edges;
      EXPECT_EQ(chk.degenerate_triangles, 0u);
      ASSERT_GT(c.analytic_volume, 0);
      EXPECT_NEAR(c.nominal.volume() / c.analytic_volume, 1.0, 0.005);
      EXPECT_GE(c.size.head<2>().maxCoeff(), 0.1);
      EXPECT_LE(c.size.head<2>().maxCoeff(), 0.4);
    }
}

TEST(Casting, ArcsRespectTheChordalError) {
  // Round flange rim: vertices on the circle, edge midpoints within 0.05 mm of it.
  const Casting c = make_casting(params_for(CastingFamily::kRoundFlange, 3));
  double R = 0;  // the rim radius: the largest vertex radius
  for (const auto& v : c.nominal.vertices) R = std::max(R, v.head<2>().norm());
  double worst = 0;
  for (std::size_t ti = 0; ti < c.nominal.triangles.size(); ++ti) {
    // Wall triangles only: their horizontal edges join neighbouring rim vertices.
    if (std::abs(c.nominal.triangle_normal(ti).z()) > 1e-9) continue;
    const auto& t = c.nominal.triangles[ti];
    for (int k = 0; k < 3; ++k) {
      const Vec3 &a = c.nominal.vertices[t[k]], &b = c.nominal.vertices[t[(k + 1) % 3]];
      if (std::abs(a.head<2>().norm() - R) > 1e-9 || std::abs(b.head<2>().norm() - R) > 1e-9) continue;
      if (std::abs(a.z() - b.z()) > 1e-12) continue;
      if ((a - b).norm() > 0.2 * R) continue;  // the flat on the rim is a chord by design
      worst = std::max(worst, R - (0.5 * (a + b)).head<2>().norm());
    }
  }
  EXPECT_GT(worst, 0);
  EXPECT_LE(worst, 5e-5);
}

TEST(Casting, FinsAreClosedOutsideTheBodyAndRootedOnItsSurface) {
  for (auto fam : kFamilies) {
    CastingParams p = params_for(fam, 2);
    p.flash.root_spacing = 0.002;  // coarser roots keep the brute-force checks quick
    const Casting c = make_casting(p);
    SCOPED_TRACE(c.description);
    ASSERT_FALSE(c.fins.empty());
    double worst_root = 0;
    for (const auto& f : c.fins) {
      const MeshCheck chk = check_mesh(f.mesh);
      EXPECT_TRUE(chk.watertight());
      EXPECT_TRUE(chk.consistently_oriented());
      EXPECT_GT(f.volume, 0);
      EXPECT_NEAR(f.volume, f.mesh.volume(), 1e-15);
      EXPECT_GE(f.thickness, 0.3e-3);
      EXPECT_LE(f.thickness, 1.5e-3);
      EXPECT_LE(f.max_height, 8e-3 + 1e-12);
      for (std::size_t i = 0; i < f.root.size(); i += 7)
        worst_root = std::max(worst_root, mesh_distance(c.nominal, f.root[i]));
      // Every fin vertex off the root face lies outside the nominal body.
      for (std::size_t v = 2; v < f.mesh.vertices.size(); v += 4 * 9) {
        const Vec3& pt = f.mesh.vertices[v];  // a tip vertex
        EXPECT_FALSE(inside(c.nominal, pt)) << pt.transpose();
      }
    }
    EXPECT_LT(worst_root, 1e-5);  // within 0.01 mm of the nominal surface
  }
}

TEST(Casting, FlashLayoutFollowsTheParameters) {
  CastingParams p = params_for(CastingFamily::kRoundFlange, 5);
  p.flash.gaps = 3;
  const Casting c = make_casting(p);
  int parting = 0, holes = 0;
  for (const auto& f : c.fins) {
    if (f.kind == "parting_line") {
      ++parting;
      EXPECT_FALSE(f.closed);
    } else {
      ++holes;
      EXPECT_TRUE(f.closed);
    }
  }
  EXPECT_EQ(parting, 3);
  // Bolt holes plus the bore.
  EXPECT_GE(holes, 5);

  p.flash.gaps = 0;
  p.flash.holes = false;
  const Casting ring = make_casting(p);
  ASSERT_EQ(ring.fins.size(), 1u);
  EXPECT_TRUE(ring.fins[0].closed);
}

TEST(Casting, DeterministicBySeed) {
  const Casting a = make_casting(params_for(CastingFamily::kHousing, 7));
  const Casting b = make_casting(params_for(CastingFamily::kHousing, 7));
  const Casting c = make_casting(params_for(CastingFamily::kHousing, 8));
  ASSERT_EQ(a.nominal.vertices.size(), b.nominal.vertices.size());
  for (std::size_t i = 0; i < a.nominal.vertices.size(); ++i)
    ASSERT_EQ(a.nominal.vertices[i], b.nominal.vertices[i]);
  ASSERT_EQ(a.fins.size(), b.fins.size());
  EXPECT_EQ(a.flash_volume(), b.flash_volume());
  EXPECT_NE(a.description, c.description);
}

TEST(Casting, UserMeshRoundTripAndRejections) {
  const std::string dir = ftest::temp_dir("casting_mesh");
  const Casting gen = make_casting(params_for(CastingFamily::kFlangedPlate, 1));
  save_mesh(dir + "/part.stl", gen.nominal.transformed(Pose(Eigen::Scaling(1000.0))));
  // Scale: the STL is in millimetres.
  CastingParams p;
  p.family = CastingFamily::kMesh;
  p.mesh_path = dir + "/part.stl";
  p.mesh_scale = 0.001;
  const Casting user = make_casting(p);
  EXPECT_TRUE(check_mesh(user.nominal).watertight());
  EXPECT_NEAR(user.nominal.volume(), gen.nominal.volume(), 1e-6 * gen.nominal.volume());
  EXPECT_FALSE(user.fins.empty());

  // A mesh with a hole is rejected, naming the file.
  TriangleMesh holed = gen.nominal;
  holed.triangles.pop_back();
  save_mesh(dir + "/holed.obj", holed);
  p.mesh_path = dir + "/holed.obj";
  p.mesh_scale = 1.0;
  try {
    make_casting(p);
    FAIL();
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("holed.obj: expected a closed surface"), std::string::npos)
        << e.what();
  }
  // Wrong units: a millimetre file read as metres is rejected by its size.
  p.mesh_path = dir + "/part.stl";
  EXPECT_THROW(make_casting(p), InputError);
  p.mesh_path = dir + "/missing.stl";
  EXPECT_THROW(make_casting(p), IoError);
  EXPECT_THROW(family_from_string("teapot"), ArgumentError);
  CastingParams bad = params_for(CastingFamily::kHousing, 1);
  bad.flash.thickness_min = -1;
  EXPECT_THROW(make_casting(bad), ArgumentError);
}

TEST(Casting, LabelerSeparatesFlashFromBody) {
  const Casting c = make_casting(params_for(CastingFamily::kFlangedPlate, 4));
  const FlashLabeler label(c);
  int flash_ok = 0, flash_total = 0;
  for (const auto& f : c.fins)
    for (std::size_t v = 2; v < f.mesh.vertices.size(); v += 4 * 25) {  // tip vertices
      ++flash_total;
      flash_ok += label.is_flash(f.mesh.vertices[v]);
    }
  EXPECT_EQ(flash_ok, flash_total);
  // Points on the top face (far from the parting plane) are body.
  int body_ok = 0, body_total = 0;
  for (std::size_t t = 0; t < c.nominal.triangles.size(); t += 3) {
    const auto& tri = c.nominal.triangles[t];
    const Vec3 p = (c.nominal.vertices[tri[0]] + c.nominal.vertices[tri[1]] + c.nominal.vertices[tri[2]]) / 3;
    if (std::abs(p.z() - c.parting_height) < 0.004) continue;
    ++body_total;
    body_ok += !label.is_flash(p);
    EXPECT_LT(label.distance_to_nominal(p), 1e-10);
  }
  EXPECT_EQ(body_ok, body_total);
  EXPECT_GT(body_total, 20);
}
