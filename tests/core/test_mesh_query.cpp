#include <gtest/gtest.h>

#include <cmath>

#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/random.hpp"

using namespace flashtwin;

namespace {

// A closed mesh with many triangles, shared edges and ties: a finely split box plus a sphere.
TriangleMesh test_mesh() {
  TriangleMesh m = box_mesh(Vec3(-0.1, -0.05, 0), Vec3(0.1, 0.05, 0.03));
  const int n = 24;
  for (int i = 0; i < n; ++i)
    for (int j = 0; j < 2 * n; ++j) {
      auto at = [&](int a, int b) {
        const double th = M_PI * a / n, ph = M_PI * b / n;
        return Vec3(0.05 + 0.02 * std::sin(th) * std::cos(ph), 0.02 * std::sin(th) * std::sin(ph),
                    0.06 + 0.02 * std::cos(th));
      };
      const int base = static_cast<int>(m.vertices.size());
      m.vertices.push_back(at(i, j));
      m.vertices.push_back(at(i + 1, j));
      m.vertices.push_back(at(i + 1, j + 1));
      m.vertices.push_back(at(i, j + 1));
      m.triangles.emplace_back(base, base + 1, base + 2);
      m.triangles.emplace_back(base, base + 2, base + 3);
    }
  return m;
}

}  // namespace

// A hint only bounds the search: the same distance, point and triangle with any hint (near,
// far, invalid), also under a max_distance, including points on shared edges and vertices.
TEST(MeshBvh, HintedQueryGivesTheUnhintedResult) {
  const TriangleMesh mesh = test_mesh();
  const MeshBvh bvh(mesh);
  Rng rng(7);
  const int n_tri = static_cast<int>(mesh.triangles.size());
  for (int k = 0; k < 4000; ++k) {
    Vec3 p(rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), rng.uniform(-0.05, 0.1));
    if (k % 4 == 0) p = mesh.vertices[static_cast<std::size_t>(k % mesh.vertices.size())];
    const double max_d = k % 3 == 0 ? 0.01 : 1e300;
    const ClosestPoint ref = bvh.closest(p, max_d);
    for (int hint : {-1, ref.triangle, (k * 37) % n_tri, n_tri + 5}) {
      const ClosestPoint h = bvh.closest(p, max_d, hint);
      ASSERT_EQ(h.triangle, ref.triangle) << "query " << k << " hint " << hint;
      ASSERT_EQ(h.distance, ref.distance);
      ASSERT_EQ(h.point, ref.point);
    }
  }
}
