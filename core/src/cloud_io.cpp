// Reading point clouds: PLY (ascii, binary little/big endian) and PCD v0.7 (ascii, binary,
// binary_compressed), parsed here with every size checked against the file. PCL 1.13's readers
// crashed, overflowed or asserted on malformed files within minutes of fuzzing (fuzz/README.md),
// so no byte of a cloud reaches them.
#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>
#include <vector>

#include "cloud_formats.hpp"
#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"

namespace flashtwin {

namespace fs = std::filesystem;

namespace detail {

namespace {

std::vector<std::string> words_of(const std::string& line) {
  std::istringstream is(line);
  std::vector<std::string> w;
  for (std::string t; is >> t;) w.push_back(t);
  return w;
}

bool parse_count(const std::string& t, std::uint64_t max, std::uint64_t& out) {
  if (t.empty() || t.size() > 12 || t.find_first_not_of("0123456789") != std::string::npos)
    return false;
  out = std::stoull(t);
  return out <= max;
}

/// A whole token as a number (strtod: also nan and inf, which the caller judges).
bool parse_number(const std::string& t, double& x) {
  char* end = nullptr;
  x = std::strtod(t.c_str(), &end);
  return end != t.c_str() && *end == '\0';
}

/// Next header line of `text` from `pos` (advanced past it), without its line end.
bool next_line(const std::string& text, std::size_t& pos, std::size_t limit, std::string& line) {
  if (pos >= text.size() || pos >= limit) return false;
  std::size_t e = text.find('\n', pos);
  if (e == std::string::npos) e = text.size();
  line = text.substr(pos, e - pos);
  if (!line.empty() && line.back() == '\r') line.pop_back();
  pos = e + 1;
  return true;
}

constexpr std::size_t kHeaderLimit = 65536;  // headers are short; past this it is no header

// ---- Scalar values in binary data.

/// Reads one value of type `t` at p (little- or big-endian) as double. @pre p + t.bytes fits.
double read_value(const unsigned char* p, ScalarType t, bool big_endian) {
  unsigned char b[8];
  for (int k = 0; k < t.bytes; ++k) b[k] = p[big_endian ? t.bytes - 1 - k : k];
  switch (t.kind) {
    case 'f':
      if (t.bytes == 4) {
        float f;
        std::memcpy(&f, b, 4);
        return f;
      } else {
        double d;
        std::memcpy(&d, b, 8);
        return d;
      }
    case 'i': {
      std::int64_t v = 0;
      std::memcpy(&v, b, static_cast<std::size_t>(t.bytes));
      const int shift = 64 - 8 * t.bytes;  // sign-extend
      return static_cast<double>(static_cast<std::int64_t>(static_cast<std::uint64_t>(v) << shift) >> shift);
    }
    default: {
      std::uint64_t v = 0;
      std::memcpy(&v, b, static_cast<std::size_t>(t.bytes));
      return static_cast<double>(v);
    }
  }
}

/// Where a cloud's coordinates and normals sit among a record's values (-1: absent).
struct Slots {
  int x = -1, y = -1, z = -1, nx = -1, ny = -1, nz = -1;
  bool has_normals() const { return nx >= 0 && ny >= 0 && nz >= 0; }
};

Slots slots_of(const std::vector<std::string>& names) {
  Slots s;
  for (int i = 0; i < static_cast<int>(names.size()); ++i) {
    const std::string& n = names[static_cast<std::size_t>(i)];
    if (n == "x") s.x = i;
    if (n == "y") s.y = i;
    if (n == "z") s.z = i;
    if (n == "nx" || n == "normal_x") s.nx = i;
    if (n == "ny" || n == "normal_y") s.ny = i;
    if (n == "nz" || n == "normal_z") s.nz = i;
  }
  return s;
}

/// Appends a point (and normal) from one record's values.
void add_point(const std::vector<double>& v, const Slots& s, PointCloud& out) {
  out.points.emplace_back(static_cast<float>(v[s.x]), static_cast<float>(v[s.y]),
                          static_cast<float>(v[s.z]));
  if (s.has_normals())
    out.normals.emplace_back(static_cast<float>(v[s.nx]), static_cast<float>(v[s.ny]),
                             static_cast<float>(v[s.nz]));
}

/// LZF decompression (the format PCD's binary_compressed uses): literal runs and back
/// references into the output; every run and reference is checked against both buffers.
bool lzf_decompress(const unsigned char* in, std::size_t in_size, unsigned char* out,
                    std::size_t out_size) {
  std::size_t ip = 0, op = 0;
  while (ip < in_size) {
    const unsigned ctrl = in[ip++];
    if (ctrl < 32) {  // literal run of ctrl + 1 bytes
      const std::size_t n = ctrl + 1;
      if (ip + n > in_size || op + n > out_size) return false;
      std::memcpy(out + op, in + ip, n);
      ip += n;
      op += n;
    } else {  // back reference: length (ctrl >> 5) + 2, distance from the low bits
      std::size_t len = ctrl >> 5;
      if (len == 7) {
        if (ip >= in_size) return false;
        len += in[ip++];
      }
      if (ip >= in_size) return false;
      const std::size_t dist = ((ctrl & 0x1fu) << 8) + in[ip++] + 1;
      len += 2;
      if (dist > op || op + len > out_size) return false;
      for (std::size_t k = 0; k < len; ++k, ++op) out[op] = out[op - dist];  // may overlap
    }
  }
  return op == out_size;
}

}  // namespace

bool scalar_type(const std::string& name, ScalarType& t) {
  static const std::map<std::string, ScalarType> types{
      {"char", {'i', 1}},    {"uchar", {'u', 1}},  {"short", {'i', 2}},  {"ushort", {'u', 2}},
      {"int", {'i', 4}},     {"uint", {'u', 4}},   {"float", {'f', 4}},  {"double", {'f', 8}},
      {"int8", {'i', 1}},    {"uint8", {'u', 1}},  {"int16", {'i', 2}},  {"uint16", {'u', 2}},
      {"int32", {'i', 4}},   {"uint32", {'u', 4}}, {"float32", {'f', 4}}, {"float64", {'f', 8}}};
  const auto it = types.find(name);
  if (it == types.end()) return false;
  t = it->second;
  return true;
}

PlyHeader read_ply_header(const std::string& path, const std::string& text) {
  auto bad = [&](const std::string& what) {
    throw InputError(path + ": expected a PLY header, " + what);
  };
  PlyHeader h;
  std::size_t pos = 0;
  std::string line;
  if (!next_line(text, pos, kHeaderLimit, line) || line != "ply") bad("got no 'ply' first line");
  bool end = false;
  while (!end && next_line(text, pos, kHeaderLimit, line)) {
    const auto w = words_of(line);
    if (w.empty()) bad("got an empty header line");
    if (w[0] == "comment" || w[0] == "obj_info") continue;
    if (w[0] == "format") {
      if (!h.format.empty() || w.size() != 3 || w[2] != "1.0" ||
          (w[1] != "ascii" && w[1] != "binary_little_endian" && w[1] != "binary_big_endian"))
        bad("got a format line '" + line.substr(0, 40) + "'");
      h.format = w[1];
    } else if (w[0] == "element") {
      PlyElement e;
      if (w.size() != 3 || !parse_count(w[2], 1ULL << 31, e.count))
        bad("got an element line '" + line.substr(0, 40) + "'");
      e.name = w[1];
      for (const PlyElement& o : h.elements)
        if (o.name == e.name) bad("got element '" + e.name + "' twice");
      h.elements.push_back(e);
    } else if (w[0] == "property") {
      PlyProperty p;
      const bool list = w.size() == 5 && w[1] == "list" && scalar_type(w[2], p.count_type) &&
                        p.count_type.kind != 'f' && scalar_type(w[3], p.value_type);
      const bool single = w.size() == 3 && scalar_type(w[1], p.value_type);
      if (h.elements.empty() || !(list || single))
        bad("got a property line '" + line.substr(0, 40) + "'");
      p.list = list;
      p.name = w.back();
      h.elements.back().props.push_back(p);
    } else if (w[0] == "end_header" && w.size() == 1) {
      end = true;
    } else {
      bad("got an unknown line '" + line.substr(0, 40) + "'");
    }
  }
  if (h.format.empty()) bad("got no format line");
  if (!end) bad("got no end_header in the first 64 KB");
  h.body_at = pos;
  return h;
}

/// Walks every item of every element of a PLY body, handing each item to
/// `item(element index, values, list values)`: one value per property (a list's length for a
/// list), and the values of the item's lists one after another. Checks every count and size
/// against the data.
template <class Item>
void walk_ply_body(const std::string& path, const std::string& text, const PlyHeader& h,
                   Item&& item) {
  std::vector<double> values, lists;
  if (h.format == "ascii") {
    std::size_t pos = h.body_at;
    std::string line;
    for (std::size_t k = 0; k < h.elements.size(); ++k) {
      const PlyElement& e = h.elements[k];
      for (std::uint64_t i = 0; i < e.count; ++i) {
        if (!next_line(text, pos, text.size(), line))
          throw InputError(path + ": element '" + e.name + "': expected " +
                           std::to_string(e.count) + " lines, got " + std::to_string(i));
        const auto w = words_of(line);
        std::size_t t = 0;
        values.clear();
        lists.clear();
        bool ok = true;
        auto number = [&](double& x) { return t < w.size() && parse_number(w[t++], x); };
        for (const PlyProperty& p : e.props) {
          double x = 0;
          ok = ok && number(x);
          if (ok && p.list) {
            ok = x >= 0 && x <= 1e6 && x == std::floor(x);
            for (long j = 0; ok && j < static_cast<long>(x); ++j) {
              double y = 0;
              ok = number(y);
              lists.push_back(y);
            }
          }
          values.push_back(x);
        }
        if (!ok || t != w.size())
          throw InputError(path + ": element '" + e.name + "' item " + std::to_string(i) +
                           ": expected the numbers its properties list, got '" +
                           line.substr(0, 40) + "'");
        item(k, values, lists);
      }
    }
    return;
  }
  const bool big = h.format == "binary_big_endian";
  const auto* data = reinterpret_cast<const unsigned char*>(text.data());
  std::size_t pos = h.body_at;
  auto short_data = [&](const PlyElement& e, std::uint64_t i) {
    throw InputError(path + ": element '" + e.name + "' item " + std::to_string(i) +
                     ": expected more data, got the end of the file");
  };
  for (std::size_t k = 0; k < h.elements.size(); ++k) {
    const PlyElement& e = h.elements[k];
    for (std::uint64_t i = 0; i < e.count; ++i) {
      values.clear();
      lists.clear();
      for (const PlyProperty& p : e.props) {
        if (p.list) {
          if (pos + static_cast<std::size_t>(p.count_type.bytes) > text.size()) short_data(e, i);
          const double n = read_value(data + pos, p.count_type, big);
          pos += static_cast<std::size_t>(p.count_type.bytes);
          if (!(n >= 0 && n <= 1e6))
            throw InputError(path + ": element '" + e.name + "' item " + std::to_string(i) +
                             ": expected a list length in [0, 10^6], got " + std::to_string(n));
          const std::size_t bytes = static_cast<std::size_t>(p.value_type.bytes);
          if (pos + static_cast<std::size_t>(n) * bytes > text.size()) short_data(e, i);
          for (std::size_t j = 0; j < static_cast<std::size_t>(n); ++j, pos += bytes)
            lists.push_back(read_value(data + pos, p.value_type, big));
          values.push_back(n);
        } else {
          if (pos + static_cast<std::size_t>(p.value_type.bytes) > text.size()) short_data(e, i);
          values.push_back(read_value(data + pos, p.value_type, big));
          pos += static_cast<std::size_t>(p.value_type.bytes);
        }
      }
      item(k, values, lists);
    }
  }
}

TriangleMesh read_ply_mesh(const std::string& path, double scale) {
  const std::string text = read_text_file(path);
  const PlyHeader h = read_ply_header(path, text);
  // The vertex element's x, y, z and the face element's index list.
  std::size_t vertex_el = h.elements.size(), face_el = h.elements.size();
  int x = -1, y = -1, z = -1;
  for (std::size_t k = 0; k < h.elements.size(); ++k) {
    const PlyElement& e = h.elements[k];
    if (e.name == "vertex") {
      vertex_el = k;
      for (int i = 0; i < static_cast<int>(e.props.size()); ++i) {
        const PlyProperty& p = e.props[static_cast<std::size_t>(i)];
        if (p.list) continue;
        if (p.name == "x") x = i;
        if (p.name == "y") y = i;
        if (p.name == "z") z = i;
      }
    }
    if (e.name == "face") {
      int lists = 0;
      for (const PlyProperty& p : e.props) lists += p.list;
      if (lists != 1)
        throw InputError(path + ": element 'face': expected one list of vertex indices, got " +
                         std::to_string(lists) + " lists");
      face_el = k;
    }
  }
  if (vertex_el == h.elements.size() || x < 0 || y < 0 || z < 0 || face_el == h.elements.size())
    throw InputError(path + ": expected a PLY mesh (element vertex with x, y, z and element face "
                     "with vertex indices), got none");
  TriangleMesh mesh;
  const std::uint64_t nv = h.elements[vertex_el].count;
  std::uint64_t face = 0;
  walk_ply_body(path, text, h, [&](std::size_t k, const std::vector<double>& v,
                                   const std::vector<double>& idx) {
    if (k == vertex_el) {
      const Vec3 q(v[static_cast<std::size_t>(x)] * scale, v[static_cast<std::size_t>(y)] * scale,
                   v[static_cast<std::size_t>(z)] * scale);
      if (!q.allFinite())
        throw InputError(path + ": vertex " + std::to_string(mesh.vertices.size()) +
                         ": expected finite coordinates");
      mesh.vertices.push_back(q);
    } else if (k == face_el) {
      for (const double i : idx)
        if (!(i >= 0 && i < static_cast<double>(nv)) || i != std::floor(i))
          throw InputError(path + ": face " + std::to_string(face) + ": expected vertex indices in [0, " +
                           std::to_string(nv) + "), got " + std::to_string(i));
      // A polygon as a fan; points and lines (fewer than 3 corners) carry no surface.
      for (std::size_t j = 2; j < idx.size(); ++j)
        mesh.triangles.emplace_back(static_cast<int>(idx[0]), static_cast<int>(idx[j - 1]),
                                    static_cast<int>(idx[j]));
      ++face;
    }
  });
  return mesh;
}

PcdHeader read_pcd_header(const std::string& path, const std::string& text) {
  auto bad = [&](const std::string& what) {
    throw InputError(path + ": expected a PCD header, " + what);
  };
  std::map<std::string, std::vector<std::string>> keys;
  std::size_t pos = 0;
  std::string line;
  bool data = false;
  while (!data && next_line(text, pos, kHeaderLimit, line)) {
    const auto w = words_of(line);
    if (w.empty() || w[0][0] == '#') continue;
    static const char* known[] = {"VERSION", "FIELDS", "SIZE",      "TYPE",   "COUNT",
                                  "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
    if (std::find_if(std::begin(known), std::end(known), [&](const char* k) { return w[0] == k; }) ==
        std::end(known))
      bad("got an unknown line '" + line.substr(0, 40) + "'");
    if (keys.count(w[0])) bad("got " + w[0] + " twice");
    keys[w[0]] = std::vector<std::string>(w.begin() + 1, w.end());
    data = w[0] == "DATA";
  }
  if (!data) bad("got no DATA line in the first 64 KB");
  for (const char* k : {"FIELDS", "SIZE", "TYPE", "WIDTH", "HEIGHT", "POINTS"})
    if (!keys.count(k)) bad(std::string("got no ") + k + " line");
  PcdHeader h;
  h.fields = keys["FIELDS"];
  const std::size_t n = h.fields.size();
  if (n == 0 || n > 256) bad("got " + std::to_string(n) + " fields");
  if (!keys.count("COUNT")) keys["COUNT"] = std::vector<std::string>(n, "1");
  for (const char* k : {"SIZE", "TYPE", "COUNT"})
    if (keys[k].size() != n)
      bad(std::string("got ") + std::to_string(keys[k].size()) + " " + k + " entries for " +
          std::to_string(n) + " fields");
  for (std::size_t i = 0; i < n; ++i) {
    const std::string& sz = keys["SIZE"][i];
    const std::string& ty = keys["TYPE"][i];
    if (sz != "1" && sz != "2" && sz != "4" && sz != "8") bad("got SIZE " + sz);
    if (ty != "I" && ty != "U" && ty != "F") bad("got TYPE " + ty);
    if (ty == "F" && sz != "4" && sz != "8") bad("got a float field of " + sz + " bytes");
    std::uint64_t count = 0;
    if (!parse_count(keys["COUNT"][i], 1 << 16, count) || count < 1)
      bad("got COUNT " + keys["COUNT"][i]);
    h.types.push_back({ty == "F" ? 'f' : ty == "I" ? 'i' : 'u', std::stoi(sz)});
    h.counts.push_back(static_cast<int>(count));
    h.point_step += count * static_cast<std::uint64_t>(std::stoi(sz));
    h.values += count;
  }
  if (keys["WIDTH"].size() != 1 || !parse_count(keys["WIDTH"][0], 1ULL << 31, h.width) ||
      keys["HEIGHT"].size() != 1 || !parse_count(keys["HEIGHT"][0], 1ULL << 31, h.height) ||
      keys["POINTS"].size() != 1 || !parse_count(keys["POINTS"][0], 1ULL << 31, h.points))
    bad("got a WIDTH, HEIGHT or POINTS that is not a count");
  if (h.width * h.height != h.points)
    bad("got WIDTH x HEIGHT = " + std::to_string(h.width * h.height) + " but POINTS " +
        std::to_string(h.points));
  if (keys.count("VIEWPOINT")) {
    const auto& vp = keys["VIEWPOINT"];
    bool ok = vp.size() == 7;
    for (const auto& t : vp) {
      double x = 0;
      ok = ok && parse_number(t, x) && std::isfinite(x);
    }
    if (!ok) bad("got a VIEWPOINT that is not 7 numbers");
  }
  const auto& d = keys["DATA"];
  if (d.size() != 1 || (d[0] != "ascii" && d[0] != "binary" && d[0] != "binary_compressed"))
    bad("got DATA that is not ascii, binary or binary_compressed");
  h.data = d[0];
  h.body_at = pos;
  return h;
}

namespace {

PointCloud read_pcd(const std::string& path, const std::string& text) {
  const PcdHeader h = read_pcd_header(path, text);
  // Values of a record: fields in order, each `count` values; the cloud takes the first
  // value of x, y, z and the normals.
  std::vector<std::string> names;
  for (std::size_t f = 0; f < h.fields.size(); ++f)
    for (int c = 0; c < h.counts[f]; ++c) names.push_back(c == 0 ? h.fields[f] : "");
  const Slots s = slots_of(names);
  if (s.x < 0 || s.y < 0 || s.z < 0)
    throw InputError(path + ": expected x, y and z fields, got FIELDS without them");
  PointCloud out;
  std::vector<double> v(h.values);
  if (h.data == "ascii") {
    std::size_t pos = h.body_at;
    std::string line;
    std::uint64_t n = 0;
    while (n < h.points && next_line(text, pos, text.size(), line)) {
      const auto w = words_of(line);
      if (w.empty()) continue;
      bool ok = w.size() == h.values;
      for (std::size_t k = 0; ok && k < w.size(); ++k) ok = parse_number(w[k], v[k]);
      if (!ok)
        throw InputError(path + ": point " + std::to_string(n) + ": expected " +
                         std::to_string(h.values) + " numbers on its line, got '" +
                         line.substr(0, 40) + "'");
      add_point(v, s, out);
      ++n;
    }
    if (n < h.points)
      throw InputError(path + ": expected " + std::to_string(h.points) + " points, got " +
                       std::to_string(n));
    return out;
  }
  const std::uint64_t body = text.size() > h.body_at ? text.size() - h.body_at : 0;
  const std::uint64_t need = h.points * h.point_step;
  const auto* data = reinterpret_cast<const unsigned char*>(text.data()) + h.body_at;
  std::vector<unsigned char> unpacked;
  if (h.data == "binary_compressed") {
    // Two sizes, then LZF data that unpacks to the fields one after another (all points' x,
    // then all y, ...).
    std::uint32_t sizes[2] = {0, 0};
    if (body >= 8) std::memcpy(sizes, data, 8);
    if (body < 8 || sizes[1] != need || 8 + static_cast<std::uint64_t>(sizes[0]) > body)
      throw InputError(path + ": expected a compressed block unpacking to " + std::to_string(need) +
                       " bytes within the file, got " + std::to_string(sizes[0]) + " -> " +
                       std::to_string(sizes[1]) + " bytes in " + std::to_string(body));
    unpacked.resize(need);
    if (!lzf_decompress(data + 8, sizes[0], unpacked.data(), unpacked.size()))
      throw InputError(path + ": expected LZF data unpacking to " + std::to_string(need) +
                       " bytes, got corrupt data");
  } else if (body < need) {
    throw InputError(path + ": expected " + std::to_string(need) +
                     " bytes of binary point data, got " + std::to_string(body));
  }
  out.points.reserve(h.points);
  for (std::uint64_t i = 0; i < h.points; ++i) {
    std::size_t k = 0, field_at = 0;
    for (std::size_t f = 0; f < h.fields.size(); ++f) {
      const std::size_t bytes = static_cast<std::size_t>(h.types[f].bytes);
      const std::size_t width = bytes * static_cast<std::size_t>(h.counts[f]);
      for (int c = 0; c < h.counts[f]; ++c, ++k) {
        const unsigned char* p =
            unpacked.empty() ? data + i * h.point_step + field_at + c * bytes
                             : unpacked.data() + h.points * field_at + i * width + c * bytes;
        v[k] = read_value(p, h.types[f], false);
      }
      field_at += width;
    }
    add_point(v, s, out);
  }
  return out;
}

PointCloud read_ply_cloud(const std::string& path, const std::string& text) {
  const PlyHeader h = read_ply_header(path, text);
  std::vector<std::string> names;
  for (const PlyElement& e : h.elements)
    if (e.name == "vertex")
      for (const PlyProperty& p : e.props) names.push_back(p.list ? "" : p.name);
  const Slots s = slots_of(names);
  if (s.x < 0 || s.y < 0 || s.z < 0)
    throw InputError(path + ": expected a vertex element with x, y and z, got none");
  PointCloud out;
  std::size_t vertex_el = 0;
  while (h.elements[vertex_el].name != "vertex") ++vertex_el;  // present: slots_of found x
  walk_ply_body(path, text, h, [&](std::size_t k, const std::vector<double>& v, const std::vector<double>&) {
    if (k == vertex_el) add_point(v, s, out);
  });
  return out;
}

}  // namespace
}  // namespace detail

PointCloud load_cloud(const std::string& path) {
  std::string ext = fs::path(path).extension().string();
  for (char& c : ext) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  if (ext != ".pcd" && ext != ".ply")
    throw ArgumentError(path + ": expected a .ply or .pcd point cloud, got '" + ext + "'");
  const std::string text = read_text_file(path);  // IoError when missing or unreadable
  PointCloud cloud = ext == ".pcd" ? detail::read_pcd(path, text) : detail::read_ply_cloud(path, text);
  for (std::size_t i = 0; i < cloud.size(); ++i)
    if (!cloud.points[i].allFinite())
      throw InputError(path + ": point " + std::to_string(i) +
                       ": expected finite coordinates, got NaN or inf");
  return cloud;
}

}  // namespace flashtwin
