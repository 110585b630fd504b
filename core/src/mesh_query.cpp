#include "flashtwin/core/mesh_query.hpp"

#include <algorithm>
#include <cmath>

namespace flashtwin {

Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c) {
  // Voronoi regions of the vertices, then edges, then the face.
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return a;
  const Vec3 bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return a + ab * (d1 / (d1 - d3));
  const Vec3 cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return a + ac * (d2 / (d2 - d6));
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0)
    return b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6)));
  const double denom = 1.0 / (va + vb + vc);
  return a + ab * (vb * denom) + ac * (vc * denom);
}

MeshBvh::MeshBvh(const TriangleMesh& mesh) : mesh_(mesh) {
  order_.resize(mesh_.triangles.size());
  for (std::size_t i = 0; i < order_.size(); ++i) order_[i] = static_cast<int>(i);
  nodes_.reserve(2 * order_.size() / 4 + 1);
  if (!order_.empty()) build(0, static_cast<int>(order_.size()), 0);
}

int MeshBvh::build(int first, int count, int depth) {
  Node node;
  Eigen::AlignedBox3d centroids;
  for (int i = first; i < first + count; ++i) {
    const auto& t = mesh_.triangles[order_[i]];
    for (int k = 0; k < 3; ++k) node.box.extend(mesh_.vertices[t[k]]);
    centroids.extend((mesh_.vertices[t[0]] + mesh_.vertices[t[1]] + mesh_.vertices[t[2]]) / 3);
  }
  const int id = static_cast<int>(nodes_.size());
  nodes_.push_back(node);
  if (count <= 4 || depth > 40) {
    nodes_[id].first = first;
    nodes_[id].count = count;
    return id;
  }
  // Median split along the longest axis of the centroid bounds.
  int axis = 0;
  centroids.sizes().maxCoeff(&axis);
  const int mid = first + count / 2;
  std::nth_element(order_.begin() + first, order_.begin() + mid, order_.begin() + first + count,
                   [&](int a, int b) {
                     const auto& ta = mesh_.triangles[a];
                     const auto& tb = mesh_.triangles[b];
                     return mesh_.vertices[ta[0]][axis] + mesh_.vertices[ta[1]][axis] +
                                mesh_.vertices[ta[2]][axis] <
                            mesh_.vertices[tb[0]][axis] + mesh_.vertices[tb[1]][axis] +
                                mesh_.vertices[tb[2]][axis];
                   });
  const int l = build(first, mid - first, depth + 1);
  const int r = build(mid, first + count - mid, depth + 1);
  nodes_[id].left = l;
  nodes_[id].right = r;
  return id;
}

ClosestPoint MeshBvh::closest(const Vec3& p, double max_distance) const {
  return closest(p, max_distance, -1);
}

ClosestPoint MeshBvh::closest(const Vec3& p, double max_distance, int hint_triangle) const {
  ClosestPoint best;
  best.distance = max_distance;
  if (nodes_.empty()) return best;
  double best2 = max_distance * max_distance;
  // The search starts bounded by the hint's squared distance, nudged up so that the true
  // minimum stays strictly below it: the winner is then accepted exactly as without a hint.
  if (hint_triangle >= 0 && static_cast<std::size_t>(hint_triangle) < mesh_.triangles.size()) {
    const auto& t = mesh_.triangles[static_cast<std::size_t>(hint_triangle)];
    const double d2 = (closest_on_triangle(p, mesh_.vertices[t[0]], mesh_.vertices[t[1]],
                                           mesh_.vertices[t[2]]) - p).squaredNorm();
    best2 = std::min(best2, d2 * (1 + 1e-9) + 1e-300);
  }
  // Depth-first, nearer child first, pruned by box distance.
  int stack[128];
  int top = 0;
  stack[top++] = 0;
  while (top > 0) {
    const Node& n = nodes_[stack[--top]];
    if (n.box.squaredExteriorDistance(p) >= best2) continue;
    if (n.left < 0) {
      for (int i = n.first; i < n.first + n.count; ++i) {
        const auto& t = mesh_.triangles[order_[i]];
        const Vec3 q = closest_on_triangle(p, mesh_.vertices[t[0]], mesh_.vertices[t[1]],
                                           mesh_.vertices[t[2]]);
        const double d2 = (q - p).squaredNorm();
        if (d2 < best2) {
          best2 = d2;
          best.point = q;
          best.triangle = order_[i];
        }
      }
      continue;
    }
    const double dl = nodes_[n.left].box.squaredExteriorDistance(p);
    const double dr = nodes_[n.right].box.squaredExteriorDistance(p);
    if (dl < dr) {
      stack[top++] = n.right;
      stack[top++] = n.left;
    } else {
      stack[top++] = n.left;
      stack[top++] = n.right;
    }
  }
  best.distance = best.triangle >= 0 ? std::sqrt(best2) : max_distance;
  return best;
}

}  // namespace flashtwin
