#include "flashtwin/sim/mujoco_scene.hpp"

#include <cmath>
#include <string>
#include <utility>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {

namespace {

constexpr double kInfinitePlaneHalfSize = 3.0;  // [m] stand-in for MuJoCo's infinite plane

/// Surface of revolution about z of a profile (r_i, z_i) running from the bottom pole
/// (r_0 = 0) to the top pole (r_m = 0); `n` segments around. Poles are single vertices, so the
/// surface is closed; triangles face outwards.
TriangleMesh lathe(const std::vector<std::pair<double, double>>& profile, int n) {
  TriangleMesh mesh;
  const int m = static_cast<int>(profile.size()) - 1;
  mesh.vertices.emplace_back(0.0, 0.0, profile.front().second);
  for (int i = 1; i < m; ++i)
    for (int k = 0; k < n; ++k) {
      const double a = 2.0 * M_PI * k / n;
      mesh.vertices.emplace_back(profile[i].first * std::cos(a), profile[i].first * std::sin(a),
                                 profile[i].second);
    }
  mesh.vertices.emplace_back(0.0, 0.0, profile.back().second);
  const int bottom = 0, top = static_cast<int>(mesh.vertices.size()) - 1;
  auto ring = [n](int i, int k) { return 1 + (i - 1) * n + k % n; };
  for (int k = 0; k < n; ++k) mesh.triangles.emplace_back(bottom, ring(1, k + 1), ring(1, k));
  for (int i = 1; i + 1 < m; ++i)
    for (int k = 0; k < n; ++k) {
      mesh.triangles.emplace_back(ring(i, k), ring(i, k + 1), ring(i + 1, k + 1));
      mesh.triangles.emplace_back(ring(i, k), ring(i + 1, k + 1), ring(i + 1, k));
    }
  for (int k = 0; k < n; ++k) mesh.triangles.emplace_back(top, ring(m - 1, k), ring(m - 1, k + 1));
  return mesh;
}

/// Half-circle profile of radius r from angle -π/2 to π/2 in `rings` steps; the lower half
/// shifted by -h and the upper half by +h (h = 0: a sphere; h > 0: a capsule).
std::vector<std::pair<double, double>> round_profile(double r, double h, int rings) {
  std::vector<std::pair<double, double>> p;
  for (int i = 0; i <= rings; ++i) {
    const double th = -0.5 * M_PI + M_PI * i / rings;
    const double rr = (i == 0 || i == rings) ? 0.0 : r * std::cos(th);
    const double z = r * std::sin(th);
    if (2 * i < rings) {
      p.emplace_back(rr, z - h);
    } else if (2 * i > rings) {
      p.emplace_back(rr, z + h);
    } else {  // equator: once per hemisphere
      p.emplace_back(rr, -h);
      if (h > 0) p.emplace_back(rr, h);
    }
  }
  return p;
}


std::string geom_label(const mjModel* m, int g) {
  const char* name = mj_id2name(m, mjOBJ_GEOM, g);
  return name && *name ? std::string(name) : "geom" + std::to_string(g);
}

}  // namespace

TriangleMesh tessellate_geom(const mjModel* m, const mjData* d, int g, int segments) {
  if (!m || !d) throw ArgumentError("tessellate_geom: expected a model and its data, got null");
  if (g < 0 || g >= m->ngeom)
    throw ArgumentError("tessellate_geom: expected a geom id in [0, " + std::to_string(m->ngeom) +
                        "), got " + std::to_string(g));
  if (segments < 3)
    throw ArgumentError("tessellate_geom: segments: expected >= 3, got " +
                        std::to_string(segments));
  const mjtNum* size = m->geom_size + 3 * g;
  int rings = std::max(2, (segments + 1) / 2);
  rings += rings % 2;  // even, so a capsule has an equator

  TriangleMesh local;
  switch (m->geom_type[g]) {
    case mjGEOM_PLANE: {
      const double hx = size[0] > 0 ? size[0] : kInfinitePlaneHalfSize;
      const double hy = size[1] > 0 ? size[1] : kInfinitePlaneHalfSize;
      local.vertices = {Vec3(-hx, -hy, 0), Vec3(hx, -hy, 0), Vec3(hx, hy, 0), Vec3(-hx, hy, 0)};
      local.triangles = {Eigen::Vector3i(0, 1, 2), Eigen::Vector3i(0, 2, 3)};
      break;
    }
    case mjGEOM_HFIELD: {
      const int h = m->geom_dataid[g];
      const int nr = m->hfield_nrow[h], nc = m->hfield_ncol[h];
      const mjtNum* hs = m->hfield_size + 4 * h;
      const float* data = m->hfield_data + m->hfield_adr[h];
      for (int r = 0; r < nr; ++r)
        for (int c = 0; c < nc; ++c)
          local.vertices.emplace_back(hs[0] * (2.0 * c / (nc - 1) - 1.0),
                                      hs[1] * (2.0 * r / (nr - 1) - 1.0), hs[2] * data[r * nc + c]);
      for (int r = 0; r + 1 < nr; ++r)
        for (int c = 0; c + 1 < nc; ++c) {
          const int a = r * nc + c;
          local.triangles.emplace_back(a, a + 1, a + nc + 1);
          local.triangles.emplace_back(a, a + nc + 1, a + nc);
        }
      break;
    }
    case mjGEOM_SPHERE:
      local = lathe(round_profile(size[0], 0.0, rings), segments);
      break;
    case mjGEOM_CAPSULE:
      local = lathe(round_profile(size[0], size[1], rings), segments);
      break;
    case mjGEOM_ELLIPSOID:
      local = lathe(round_profile(1.0, 0.0, rings), segments);
      for (Vec3& v : local.vertices) v = v.cwiseProduct(Vec3(size[0], size[1], size[2]));
      break;
    case mjGEOM_CYLINDER:
      local = lathe({{0.0, -size[1]}, {size[0], -size[1]}, {size[0], size[1]}, {0.0, size[1]}},
                    segments);
      break;
    case mjGEOM_BOX:
      local = box_mesh(-Vec3(size[0], size[1], size[2]), Vec3(size[0], size[1], size[2]));
      break;
    case mjGEOM_MESH: {
      const int k = m->geom_dataid[g];
      const int va = m->mesh_vertadr[k], vn = m->mesh_vertnum[k];
      const int fa = m->mesh_faceadr[k], fn = m->mesh_facenum[k];
      local.vertices.reserve(vn);
      for (int i = 0; i < vn; ++i) {
        const float* v = m->mesh_vert + 3 * (va + i);
        local.vertices.emplace_back(v[0], v[1], v[2]);
      }
      local.triangles.reserve(fn);
      for (int i = 0; i < fn; ++i) {
        const int* f = m->mesh_face + 3 * (fa + i);
        local.triangles.emplace_back(f[0], f[1], f[2]);
      }
      break;
    }
    default:
      throw ArgumentError("geom " + std::to_string(g) + " ('" + geom_label(m, g) +
                          "'): expected a plane, hfield, sphere, capsule, ellipsoid, cylinder, "
                          "box or mesh, got type " +
                          std::to_string(m->geom_type[g]));
  }

  // World pose of the geom (geom_xmat is row-major).
  Pose X_WG = Pose::Identity();
  for (int r = 0; r < 3; ++r) {
    X_WG.translation()[r] = d->geom_xpos[3 * g + r];
    for (int c = 0; c < 3; ++c) X_WG.linear()(r, c) = d->geom_xmat[9 * g + 3 * r + c];
  }
  for (Vec3& v : local.vertices) v = X_WG * v;
  return local;
}

std::vector<SceneMesh> tessellate_geoms(const mjModel* m, const mjData* d,
                                        const std::function<bool(int geom_id)>& include,
                                        TruthLabel label, int segments) {
  if (!m || !d) throw ArgumentError("tessellate_geoms: expected a model and its data, got null");
  std::vector<SceneMesh> out;
  for (int g = 0; g < m->ngeom; ++g) {
    if (include && !include(g)) continue;
    SceneMesh sm;
    sm.mesh_W = tessellate_geom(m, d, g, segments);
    sm.label = label;
    sm.name = geom_label(m, g);
    out.push_back(std::move(sm));
  }
  return out;
}

}  // namespace flashtwin::sim
