#pragma once
// PLY and PCD layouts as read by cloud_io.cpp (internal to core): headers parsed strictly,
// every size checked against the file before a byte of data is read.
#include <cstdint>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::detail {

/// A binary scalar: kind 'i' (signed), 'u' (unsigned) or 'f' (IEEE float), size in bytes.
struct ScalarType {
  char kind = 'f';
  int bytes = 4;
};

/// PLY type names (char ... float64) → ScalarType; false for anything else.
bool scalar_type(const std::string& name, ScalarType& type);

struct PlyProperty {
  std::string name;
  bool list = false;
  ScalarType count_type;  ///< lists only: type of the length
  ScalarType value_type;
};

struct PlyElement {
  std::string name;
  std::uint64_t count = 0;
  std::vector<PlyProperty> props;
};

struct PlyHeader {
  std::string format;  ///< ascii | binary_little_endian | binary_big_endian
  std::vector<PlyElement> elements;
  std::size_t body_at = 0;  ///< offset of the data in the file
};

/// Parses the header of a PLY file's text. @throws InputError naming the file and the line.
PlyHeader read_ply_header(const std::string& path, const std::string& text);

/// A PLY mesh (element vertex with x, y, z times `scale`; element face with one index list,
/// polygons as fans), every item of the file checked. Not welded.
/// @throws IoError (unreadable), InputError naming the file, element and item.
TriangleMesh read_ply_mesh(const std::string& path, double scale);

struct PcdHeader {
  std::vector<std::string> fields;
  std::vector<ScalarType> types;
  std::vector<int> counts;
  std::uint64_t width = 0, height = 0, points = 0;
  std::uint64_t point_step = 0;  ///< bytes of one point
  std::uint64_t values = 0;      ///< values of one point (sum of the counts)
  std::string data;              ///< ascii | binary | binary_compressed
  std::size_t body_at = 0;
};

/// Parses the header of a PCD v0.7 file's text. @throws InputError naming the file.
PcdHeader read_pcd_header(const std::string& path, const std::string& text);

}  // namespace flashtwin::detail
