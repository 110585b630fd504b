#pragma once
// Triangle meshes and point clouds (plain Eigen containers: no PCL in widely included headers).
#include <Eigen/Core>
#include <cstdint>
#include <string>
#include <vector>

#include "flashtwin/core/transform.hpp"

namespace flashtwin {

/// Indexed triangle mesh; counter-clockwise triangles seen from outside (outward normals).
struct TriangleMesh {
  std::vector<Vec3> vertices;                ///< [m]
  std::vector<Eigen::Vector3i> triangles;    ///< vertex indices

  std::size_t num_triangles() const { return triangles.size(); }
  /// Signed volume by the divergence theorem [m^3] (positive for outward-oriented closed meshes).
  double volume() const;
  /// Surface area [m^2].
  double area() const;
  /// Axis-aligned bounds; zero when empty.
  void bounds(Vec3& lo, Vec3& hi) const;
  /// Unit normal of triangle t (zero for degenerate triangles).
  Vec3 triangle_normal(std::size_t t) const;
  /// Appends another mesh (indices shifted).
  void append(const TriangleMesh& other);
  /// The mesh with every vertex mapped by X.
  TriangleMesh transformed(const Pose& X) const;
};

/// Closed, outward-oriented axis-aligned box [lo, hi] (8 vertices, 12 triangles).
TriangleMesh box_mesh(const Vec3& lo, const Vec3& hi);

/// Topology report of a mesh.
struct MeshCheck {
  std::size_t boundary_edges = 0;     ///< edges used by one triangle (holes)
  std::size_t nonmanifold_edges = 0;  ///< edges used by more than two triangles
  std::size_t inconsistent_edges = 0; ///< edges whose two triangles traverse it the same way
  std::size_t degenerate_triangles = 0;
  bool watertight() const { return boundary_edges == 0 && nonmanifold_edges == 0; }
  bool consistently_oriented() const { return inconsistent_edges == 0; }
};

/// Edge-based topology check (vertices are compared by index: weld first).
MeshCheck check_mesh(const TriangleMesh& mesh);

/// Merges vertices closer than `tol` [m] and drops triangles that become degenerate.
void weld_vertices(TriangleMesh& mesh, double tol);

/// Flips triangles so that each connected component is consistently oriented and encloses a
/// positive volume. Returns false when a component cannot be oriented (non-orientable or
/// non-manifold).
bool orient_consistently(TriangleMesh& mesh);

/// Reads STL/OBJ/PLY (and what else assimp reads) into one mesh, scaled by `scale`, welded.
/// @throws IoError (missing/unreadable file), InputError (no triangles in it).
TriangleMesh load_mesh(const std::string& path, double scale = 1.0);

/// Writes binary STL, or ASCII PLY/OBJ, chosen by the extension (.stl, .ply, .obj), atomically.
/// @throws IoError, ArgumentError (unknown extension).
void save_mesh(const std::string& path, const TriangleMesh& mesh);

/// A point cloud with optional per-point normals and labels.
struct PointCloud {
  std::vector<Eigen::Vector3f> points;   ///< [m]
  std::vector<Eigen::Vector3f> normals;  ///< empty, or one per point
  std::vector<std::uint8_t> labels;      ///< empty, or one per point (meaning set by the writer)
  std::size_t size() const { return points.size(); }
  bool empty() const { return points.empty(); }
};

/// Writes a cloud as binary little-endian PLY (x y z [nx ny nz] [label]), atomically.
void save_ply(const std::string& path, const PointCloud& cloud);
/// Writes a cloud as binary PCD v0.7 (x y z [normal_x ...] [label]), atomically.
void save_pcd(const std::string& path, const PointCloud& cloud);
/// Reads PLY (ascii or binary, vertices only; faces ignored) or PCD (ascii or binary).
/// Points with NaN/inf coordinates make it throw InputError naming the file and point index.
PointCloud load_cloud(const std::string& path);

}  // namespace flashtwin
