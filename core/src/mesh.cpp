#include "flashtwin/core/mesh.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <map>
#include <numeric>
#include <unordered_map>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

namespace flashtwin {

TriangleMesh box_mesh(const Vec3& lo, const Vec3& hi) {
  TriangleMesh mesh;
  for (int i = 0; i < 8; ++i)
    mesh.vertices.emplace_back((i & 1) ? hi.x() : lo.x(), (i & 2) ? hi.y() : lo.y(),
                               (i & 4) ? hi.z() : lo.z());
  // Vertex i has bits (x, y, z); each face as two counter-clockwise triangles seen from outside.
  const int faces[6][4] = {{0, 2, 3, 1}, {4, 5, 7, 6}, {0, 1, 5, 4},
                           {2, 6, 7, 3}, {0, 4, 6, 2}, {1, 3, 7, 5}};
  for (const auto& f : faces) {
    mesh.triangles.emplace_back(f[0], f[1], f[2]);
    mesh.triangles.emplace_back(f[0], f[2], f[3]);
  }
  return mesh;
}

double TriangleMesh::volume() const {
  double v = 0;
  for (const auto& t : triangles)
    v += vertices[t[0]].dot(vertices[t[1]].cross(vertices[t[2]]));
  return v / 6.0;
}

double TriangleMesh::area() const {
  double a = 0;
  for (const auto& t : triangles)
    a += (vertices[t[1]] - vertices[t[0]]).cross(vertices[t[2]] - vertices[t[0]]).norm();
  return a / 2.0;
}

void TriangleMesh::bounds(Vec3& lo, Vec3& hi) const {
  if (vertices.empty()) {
    lo = hi = Vec3::Zero();
    return;
  }
  lo = hi = vertices[0];
  for (const auto& v : vertices) {
    lo = lo.cwiseMin(v);
    hi = hi.cwiseMax(v);
  }
}

Vec3 TriangleMesh::triangle_normal(std::size_t t) const {
  const auto& f = triangles[t];
  const Vec3 n = (vertices[f[1]] - vertices[f[0]]).cross(vertices[f[2]] - vertices[f[0]]);
  const double len = n.norm();
  return len > 0 ? Vec3(n / len) : Vec3::Zero();
}

void TriangleMesh::append(const TriangleMesh& other) {
  const int off = static_cast<int>(vertices.size());
  vertices.insert(vertices.end(), other.vertices.begin(), other.vertices.end());
  for (const auto& t : other.triangles) triangles.emplace_back(t[0] + off, t[1] + off, t[2] + off);
}

TriangleMesh TriangleMesh::transformed(const Pose& X) const {
  TriangleMesh m;
  m.triangles = triangles;
  m.vertices.reserve(vertices.size());
  for (const auto& v : vertices) m.vertices.push_back(X * v);
  return m;
}

namespace {

std::uint64_t edge_key(int a, int b) {
  return (static_cast<std::uint64_t>(static_cast<std::uint32_t>(a)) << 32) |
         static_cast<std::uint32_t>(b);
}

}  // namespace

MeshCheck check_mesh(const TriangleMesh& mesh) {
  MeshCheck c;
  // Directed edge counts: a closed, consistently oriented surface uses every directed edge
  // exactly once and its reverse exactly once.
  std::unordered_map<std::uint64_t, int> directed;
  directed.reserve(mesh.triangles.size() * 3);
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& f = mesh.triangles[t];
    if (f[0] == f[1] || f[1] == f[2] || f[0] == f[2] || mesh.triangle_normal(t).isZero()) {
      ++c.degenerate_triangles;
    }
    for (int k = 0; k < 3; ++k) ++directed[edge_key(f[k], f[(k + 1) % 3])];
  }
  for (const auto& [key, n] : directed) {
    const int a = static_cast<int>(key >> 32), b = static_cast<int>(key & 0xffffffffu);
    const auto it = directed.find(edge_key(b, a));
    const int rev = it == directed.end() ? 0 : it->second;
    // Count each undirected edge once (from its smaller endpoint, or alone if no reverse).
    if (rev > 0 && a > b) continue;
    const int total = n + rev;
    if (total == 1) ++c.boundary_edges;
    else if (total > 2) ++c.nonmanifold_edges;
    else if (n == 2 || rev == 2) ++c.inconsistent_edges;
  }
  return c;
}

void weld_vertices(TriangleMesh& mesh, double tol) {
  // Hash vertices on a grid of cell size tol; compare against the 27 neighbouring cells.
  // Cells are 64-bit: a millimetre CAD at scale 1 has coordinates of several hundred units,
  // i.e. cell indices far beyond 32 bits at tol = 1e-9. The clamp keeps a huge or non-finite
  // coordinate's conversion defined; such cells only share a bucket, and the distance test
  // below decides.
  using Cell = Eigen::Matrix<std::int64_t, 3, 1>;
  const double inv = 1.0 / std::max(tol, 1e-15);
  auto index = [&](double x) {
    const double f = std::floor(x * inv);
    constexpr double kMax = 4.0e18;  // < 2^63, and f ± 1 stays exact in int64
    return static_cast<std::int64_t>(f >= -kMax && f <= kMax ? f : (f > 0 ? kMax : -kMax));
  };
  auto cell = [&](const Vec3& v) { return Cell(index(v.x()), index(v.y()), index(v.z())); };
  auto key = [](const Cell& c) {
    // 21 bits per axis; distant cells may share a key, which costs time, never correctness.
    return (static_cast<std::uint64_t>(c.x()) & 0x1fffff) << 42 |
           (static_cast<std::uint64_t>(c.y()) & 0x1fffff) << 21 |
           (static_cast<std::uint64_t>(c.z()) & 0x1fffff);
  };
  std::unordered_map<std::uint64_t, std::vector<int>> grid;
  std::vector<int> remap(mesh.vertices.size());
  std::vector<Vec3> out;
  for (std::size_t i = 0; i < mesh.vertices.size(); ++i) {
    const Vec3& v = mesh.vertices[i];
    const Cell c = cell(v);
    int found = -1;
    for (int dx = -1; dx <= 1 && found < 0; ++dx)
      for (int dy = -1; dy <= 1 && found < 0; ++dy)
        for (int dz = -1; dz <= 1 && found < 0; ++dz) {
          const auto it = grid.find(key(c + Cell(dx, dy, dz)));
          if (it == grid.end()) continue;
          for (int j : it->second)
            if ((out[j] - v).norm() <= tol) {
              found = j;
              break;
            }
        }
    if (found < 0) {
      found = static_cast<int>(out.size());
      out.push_back(v);
      grid[key(c)].push_back(found);
    }
    remap[i] = found;
  }
  std::vector<Eigen::Vector3i> tris;
  tris.reserve(mesh.triangles.size());
  for (const auto& t : mesh.triangles) {
    const Eigen::Vector3i r(remap[t[0]], remap[t[1]], remap[t[2]]);
    if (r[0] != r[1] && r[1] != r[2] && r[0] != r[2]) tris.push_back(r);
  }
  mesh.vertices = std::move(out);
  mesh.triangles = std::move(tris);
}

bool orient_consistently(TriangleMesh& mesh) {
  const std::size_t nt = mesh.triangles.size();
  // Undirected edge → triangles using it.
  std::unordered_map<std::uint64_t, std::vector<int>> edges;
  for (std::size_t t = 0; t < nt; ++t)
    for (int k = 0; k < 3; ++k) {
      int a = mesh.triangles[t][k], b = mesh.triangles[t][(k + 1) % 3];
      edges[edge_key(std::min(a, b), std::max(a, b))].push_back(static_cast<int>(t));
    }
  for (const auto& [k, ts] : edges)
    if (ts.size() > 2) return false;
  auto has_directed = [&](int t, int a, int b) {
    const auto& f = mesh.triangles[t];
    for (int k = 0; k < 3; ++k)
      if (f[k] == a && f[(k + 1) % 3] == b) return true;
    return false;
  };
  std::vector<int> comp(nt, -1);
  int ncomp = 0;
  bool ok = true;
  for (std::size_t seed = 0; seed < nt; ++seed) {
    if (comp[seed] >= 0) continue;
    // Breadth-first flood: a neighbour must traverse the shared edge the other way.
    std::vector<int> queue{static_cast<int>(seed)};
    comp[seed] = ncomp;
    std::vector<int> members;
    for (std::size_t qi = 0; qi < queue.size(); ++qi) {
      const int t = queue[qi];
      members.push_back(t);
      for (int k = 0; k < 3; ++k) {
        const int a = mesh.triangles[t][k], b = mesh.triangles[t][(k + 1) % 3];
        for (int u : edges[edge_key(std::min(a, b), std::max(a, b))]) {
          if (u == t) continue;
          if (comp[u] < 0) {
            if (has_directed(u, a, b)) std::swap(mesh.triangles[u][1], mesh.triangles[u][2]);
            comp[u] = ncomp;
            queue.push_back(u);
          } else if (has_directed(u, a, b)) {
            ok = false;  // Möbius-like: cannot be oriented
          }
        }
      }
    }
    // Outward: the component must enclose positive volume.
    double v = 0;
    for (int t : members) {
      const auto& f = mesh.triangles[t];
      v += mesh.vertices[f[0]].dot(mesh.vertices[f[1]].cross(mesh.vertices[f[2]]));
    }
    if (v < 0)
      for (int t : members) std::swap(mesh.triangles[t][1], mesh.triangles[t][2]);
    ++ncomp;
  }
  return ok;
}

}  // namespace flashtwin
