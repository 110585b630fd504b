// Mesh files (read by assimp) and writing meshes and clouds (simple binary formats, atomic);
// clouds are read in cloud_io.cpp.
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include <assimp/Importer.hpp>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"
#include "cloud_formats.hpp"

namespace flashtwin {

namespace fs = std::filesystem;

namespace {

std::string lower_ext(const std::string& path) {
  std::string e = fs::path(path).extension().string();
  for (char& c : e) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return e;
}

void require_readable(const std::string& path) {
  std::error_code ec;
  if (!fs::exists(path, ec)) throw IoError(path + ": file not found");
  if (fs::is_directory(path, ec)) throw IoError(path + ": expected a file, got a directory");
  std::ifstream in(path, std::ios::binary);
  if (!in) throw IoError(path + ": cannot open for reading");
}

template <typename T>
void put(std::string& s, T v) {
  char b[sizeof(T)];
  std::memcpy(b, &v, sizeof(T));
  s.append(b, sizeof(T));
}

}  // namespace

TriangleMesh load_mesh(const std::string& path, double scale) {
  require_readable(path);
  if (!(scale > 0) || !std::isfinite(scale))
    throw ArgumentError(path + ": scale: expected a positive number, got " + std::to_string(scale));
  // PLY meshes are read by our own parser: assimp's PLY importer hung, aborted and asked for
  // gigabytes on fuzzed files (fuzz/README.md).
  if (lower_ext(path) == ".ply") {
    TriangleMesh mesh = detail::read_ply_mesh(path, scale);
    if (mesh.triangles.empty())
      throw InputError(path + ": expected a triangle mesh, got no triangles");
    weld_vertices(mesh, 1e-9 * std::max(1.0, scale));
    return mesh;
  }
  Assimp::Importer importer;
  // Validate before any post-processing step: assimp's own steps assert (abort) on face
  // indices past the vertices, and ReadFile does not promise to validate first.
  const aiScene* scene = importer.ReadFile(path, 0);
  if (scene) scene = importer.ApplyPostProcessing(aiProcess_ValidateDataStructure);
  if (scene)
    scene = importer.ApplyPostProcessing(aiProcess_Triangulate | aiProcess_JoinIdenticalVertices |
                                         aiProcess_PreTransformVertices);
  if (!scene || !scene->mRootNode)
    throw InputError(path + ": cannot read the mesh (" + importer.GetErrorString() + ")");
  TriangleMesh mesh;
  for (unsigned mi = 0; mi < scene->mNumMeshes; ++mi) {
    const aiMesh* am = scene->mMeshes[mi];
    const int off = static_cast<int>(mesh.vertices.size());
    for (unsigned v = 0; v < am->mNumVertices; ++v) {
      const aiVector3D& p = am->mVertices[v];
      const Vec3 q(p.x * scale, p.y * scale, p.z * scale);
      if (!q.allFinite())
        throw InputError(path + ": vertex " + std::to_string(v) + ": expected finite coordinates");
      mesh.vertices.push_back(q);
    }
    for (unsigned f = 0; f < am->mNumFaces; ++f) {
      const aiFace& face = am->mFaces[f];
      if (face.mNumIndices != 3) continue;  // points and lines carry no surface
      for (unsigned k = 0; k < 3; ++k)
        if (face.mIndices[k] >= am->mNumVertices)
          throw InputError(path + ": face " + std::to_string(f) + ": expected vertex indices below " +
                           std::to_string(am->mNumVertices) + ", got " +
                           std::to_string(face.mIndices[k]));
      mesh.triangles.emplace_back(off + static_cast<int>(face.mIndices[0]),
                                  off + static_cast<int>(face.mIndices[1]),
                                  off + static_cast<int>(face.mIndices[2]));
    }
  }
  if (mesh.triangles.empty())
    throw InputError(path + ": expected a triangle mesh, got no triangles");
  // STL stores each triangle's corners separately: weld them (1 nm) to recover topology.
  weld_vertices(mesh, 1e-9 * std::max(1.0, scale));
  return mesh;
}

void save_mesh(const std::string& path, const TriangleMesh& mesh) {
  const std::string ext = lower_ext(path);
  std::string out;
  if (ext == ".stl") {
    out.assign(80, '\0');
    const char header[] = "flashtwin binary STL";
    std::memcpy(out.data(), header, sizeof header - 1);
    put<std::uint32_t>(out, static_cast<std::uint32_t>(mesh.triangles.size()));
    for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
      const Vec3 n = mesh.triangle_normal(t);
      for (int k = 0; k < 3; ++k) put<float>(out, static_cast<float>(n[k]));
      for (int c = 0; c < 3; ++c)
        for (int k = 0; k < 3; ++k) put<float>(out, static_cast<float>(mesh.vertices[mesh.triangles[t][c]][k]));
      put<std::uint16_t>(out, 0);
    }
  } else if (ext == ".ply") {
    std::ostringstream h;
    h << "ply\nformat binary_little_endian 1.0\ncomment flashtwin mesh [m]\nelement vertex "
      << mesh.vertices.size() << "\nproperty double x\nproperty double y\nproperty double z\n"
      << "element face " << mesh.triangles.size() << "\nproperty list uchar int vertex_indices\n"
      << "end_header\n";
    out = h.str();
    for (const auto& v : mesh.vertices)
      for (int k = 0; k < 3; ++k) put<double>(out, v[k]);
    for (const auto& t : mesh.triangles) {
      put<std::uint8_t>(out, 3);
      for (int k = 0; k < 3; ++k) put<std::int32_t>(out, t[k]);
    }
  } else if (ext == ".obj") {
    std::ostringstream o;
    o.precision(17);
    o << "# flashtwin mesh [m]\n";
    for (const auto& v : mesh.vertices) o << "v " << v.x() << " " << v.y() << " " << v.z() << "\n";
    for (const auto& t : mesh.triangles)
      o << "f " << t[0] + 1 << " " << t[1] + 1 << " " << t[2] + 1 << "\n";
    out = o.str();
  } else {
    throw ArgumentError(path + ": expected a .stl, .ply or .obj file name, got '" + ext + "'");
  }
  write_text_file(path, out);
}

void save_ply(const std::string& path, const PointCloud& cloud) {
  const bool has_n = !cloud.normals.empty(), has_l = !cloud.labels.empty();
  FT_ASSERT(!has_n || cloud.normals.size() == cloud.size());
  FT_ASSERT(!has_l || cloud.labels.size() == cloud.size());
  std::ostringstream h;
  h << "ply\nformat binary_little_endian 1.0\ncomment flashtwin point cloud [m]\nelement vertex "
    << cloud.size() << "\nproperty float x\nproperty float y\nproperty float z\n";
  if (has_n) h << "property float nx\nproperty float ny\nproperty float nz\n";
  if (has_l) h << "property uchar label\n";
  h << "end_header\n";
  std::string out = h.str();
  out.reserve(out.size() + cloud.size() * (12 + (has_n ? 12 : 0) + (has_l ? 1 : 0)));
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    for (int k = 0; k < 3; ++k) put<float>(out, cloud.points[i][k]);
    if (has_n)
      for (int k = 0; k < 3; ++k) put<float>(out, cloud.normals[i][k]);
    if (has_l) put<std::uint8_t>(out, cloud.labels[i]);
  }
  write_text_file(path, out);
}

void save_pcd(const std::string& path, const PointCloud& cloud) {
  const bool has_n = !cloud.normals.empty(), has_l = !cloud.labels.empty();
  FT_ASSERT(!has_n || cloud.normals.size() == cloud.size());
  FT_ASSERT(!has_l || cloud.labels.size() == cloud.size());
  std::ostringstream h;
  h << "# .PCD v0.7 - flashtwin point cloud [m]\nVERSION 0.7\nFIELDS x y z"
    << (has_n ? " normal_x normal_y normal_z" : "") << (has_l ? " label" : "") << "\nSIZE 4 4 4"
    << (has_n ? " 4 4 4" : "") << (has_l ? " 4" : "") << "\nTYPE F F F" << (has_n ? " F F F" : "")
    << (has_l ? " U" : "") << "\nCOUNT 1 1 1" << (has_n ? " 1 1 1" : "") << (has_l ? " 1" : "")
    << "\nWIDTH " << cloud.size() << "\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS "
    << cloud.size() << "\nDATA binary\n";
  std::string out = h.str();
  for (std::size_t i = 0; i < cloud.size(); ++i) {
    for (int k = 0; k < 3; ++k) put<float>(out, cloud.points[i][k]);
    if (has_n)
      for (int k = 0; k < 3; ++k) put<float>(out, cloud.normals[i][k]);
    if (has_l) put<std::uint32_t>(out, cloud.labels[i]);
  }
  write_text_file(path, out);
}

}  // namespace flashtwin
