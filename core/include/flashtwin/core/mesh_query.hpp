#pragma once
// Closest-point queries on a triangle mesh through an axis-aligned bounding-box tree.
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin {

/// Result of a closest-point query.
struct ClosestPoint {
  double distance = 0;  ///< [m]
  Vec3 point = Vec3::Zero();
  int triangle = -1;
};

/// Bounding-volume hierarchy over a mesh's triangles (built once, queried many times; queries
/// are const and thread-safe). The mesh is copied in.
class MeshBvh {
 public:
  explicit MeshBvh(const TriangleMesh& mesh);
  /// Nearest point of the surface to p; searches only within max_distance (returns
  /// triangle = -1 when nothing is that close).
  ClosestPoint closest(const Vec3& p, double max_distance = 1e300) const;
  /// The same result, found faster when hint_triangle (e.g. the answer for a nearby point; -1:
  /// none) is close to p: its distance bounds the search from the start. Exact whatever the
  /// hint: the bound stays above the true minimum, and the traversal order does not depend on
  /// it, so the same triangle wins (ties included).
  ClosestPoint closest(const Vec3& p, double max_distance, int hint_triangle) const;
  const TriangleMesh& mesh() const { return mesh_; }

 private:
  struct Node {
    Eigen::AlignedBox3d box;
    int left = -1, right = -1;  ///< children, or -1 for leaves
    int first = 0, count = 0;   ///< range in order_ for leaves
  };
  int build(int first, int count, int depth);
  TriangleMesh mesh_;
  std::vector<int> order_;
  std::vector<Node> nodes_;
};

/// Closest point on triangle (a, b, c) to p (Ericson's region test).
Vec3 closest_on_triangle(const Vec3& p, const Vec3& a, const Vec3& b, const Vec3& c);

}  // namespace flashtwin
