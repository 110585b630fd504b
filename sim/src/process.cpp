#include "flashtwin/sim/process.hpp"

#include <algorithm>
#include <array>
#include <bit>
#include <cmath>
#include <cstdio>
#include <limits>
#include <string>
#include <tuple>
#include <unordered_map>
#include <unordered_set>
#include <utility>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::sim {

namespace {

constexpr int kBrick = 8;                             // voxels per brick edge
constexpr std::int64_t kFieldOffset = 1 << 20;        // packed coordinates: 21 bits each
constexpr std::int64_t kVoxelLimit = (1 << 20) - 64;  // |voxel index| bound (keeps packing valid)

std::string number(double v) {
  char buf[64];
  std::snprintf(buf, sizeof buf, "%g", v);
  return buf;
}

[[noreturn]] void bad(const std::string& field, const std::string& expected, double got) {
  throw ArgumentError("process." + field + ": expected " + expected + ", got " + number(got));
}

std::uint64_t pack3(std::int64_t x, std::int64_t y, std::int64_t z) {
  return (static_cast<std::uint64_t>(x + kFieldOffset) << 42) |
         (static_cast<std::uint64_t>(y + kFieldOffset) << 21) |
         static_cast<std::uint64_t>(z + kFieldOffset);
}
std::uint64_t pack2(std::int64_t x, std::int64_t y) {
  return (static_cast<std::uint64_t>(x + kFieldOffset) << 21) |
         static_cast<std::uint64_t>(y + kFieldOffset);
}

// Floor division for possibly negative integers.
std::int64_t floor_div(std::int64_t a, std::int64_t b) {
  const std::int64_t q = a / b;
  return (a % b != 0 && ((a < 0) != (b < 0))) ? q - 1 : q;
}

// Index of the voxel whose centre (i + ½)·h is the first at or above x.
std::int64_t first_centre_at_or_above(double x, double h) {
  return static_cast<std::int64_t>(std::ceil(x / h - 0.5));
}
// Index of the last voxel whose centre is at or below x.
std::int64_t last_centre_at_or_below(double x, double h) {
  return static_cast<std::int64_t>(std::floor(x / h - 0.5));
}

// Hash for packed keys (the packing leaves low bits well mixed enough after this).
struct KeyHash {
  std::size_t operator()(std::uint64_t k) const {
    k ^= k >> 33;
    k *= 0xff51afd7ed558ccdULL;
    k ^= k >> 33;
    return static_cast<std::size_t>(k);
  }
};

}  // namespace

struct MaterialGrid::Impl {
  // One 8^3-voxel brick. Bit (x + 8y) of word z is local voxel (x, y, z).
  struct Brick {
    std::int32_t bx = 0, by = 0, bz = 0;
    std::uint16_t n_flash = 0;                             // remaining FLASH voxels
    std::uint16_t n_body = 0;                              // remaining BODY voxels
    std::uint16_t n_body0 = 0;                             // BODY voxels at build time
    std::array<std::uint8_t, 3> lo{0, 0, 0}, hi{7, 7, 7};  // local box of all material ever held
    std::array<std::uint64_t, 8> flash{}, body{}, body0{};
    std::vector<float> depth;  // empty, or 512 depths below the nominal surface [m] (NaN: not yet)
  };

  MaterialParams params;
  double h = 0;
  double depth_cap = 0;  // [m] bound of BODY depths (closest-point search radius)
  std::shared_ptr<const MeshBvh> nominal;
  std::vector<Brick> bricks;  // sorted by (bx, by, bz)
  std::unordered_map<std::uint64_t, std::pair<std::uint32_t, std::uint32_t>, KeyHash> columns;
  std::array<std::int64_t, 3> bmin{0, 0, 0}, bmax{-1, -1, -1};  // brick index bounds
  std::size_t flash0 = 0, flash = 0, body0 = 0, body_removed = 0;

  Vec3 centre(const Brick& b, int x, int y, int z) const {
    return Vec3((b.bx * kBrick + x + 0.5) * h, (b.by * kBrick + y + 0.5) * h,
                (b.bz * kBrick + z + 0.5) * h);
  }
  Vec3 centre(const Brick& b, int idx) const {
    return centre(b, idx & 7, (idx >> 3) & 7, idx >> 6);
  }
  const Brick* find(std::int64_t bx, std::int64_t by, std::int64_t bz) const {
    if (bx < bmin[0] || bx > bmax[0] || by < bmin[1] || by > bmax[1] || bz < bmin[2] ||
        bz > bmax[2])
      return nullptr;
    const auto it = columns.find(pack2(bx, by));
    if (it == columns.end()) return nullptr;
    for (std::uint32_t i = it->second.first; i < it->second.second; ++i)
      if (bricks[i].bz == bz) return &bricks[i];
    return nullptr;
  }
  // Depth of BODY voxel idx below the nominal surface, computed once and cached.
  float depth(Brick& b, int idx) {
    if (b.depth.empty()) b.depth.assign(512, std::numeric_limits<float>::quiet_NaN());
    float& d = b.depth[idx];
    if (std::isnan(d)) d = static_cast<float>(nominal->closest(centre(b, idx), depth_cap).distance);
    return d;
  }
  double depth_const(const Brick& b, int idx) const {
    if (!b.depth.empty() && !std::isnan(b.depth[idx])) return b.depth[idx];
    return nominal->closest(centre(b, idx), depth_cap).distance;
  }
};

using Brick = MaterialGrid::Impl::Brick;

struct MaterialAccess {
  static MaterialGrid::Impl& get(MaterialGrid& g) { return *g.impl_; }
  static const MaterialGrid::Impl& get(const MaterialGrid& g) { return *g.impl_; }
};

// ---------------------------------------------------------------------------------------------
// Parameters

void check_material_params(const MaterialParams& p) {
  if (!(std::isfinite(p.voxel_size) && p.voxel_size > 0))
    bad("voxel_size", "a finite voxel size > 0 [m]", p.voxel_size);
  if (!(std::isfinite(p.body_band) && p.body_band >= 0))
    bad("body_band", "a finite depth >= 0 [m]", p.body_band);
  if (!(std::isfinite(p.body_margin) && p.body_margin >= 0))
    bad("body_margin", "a finite distance >= 0 [m]", p.body_margin);
}

void check_tool_params(const ToolParams& t) {
  if (!(std::isfinite(t.radius) && t.radius > 0))
    bad("tool.radius", "a finite radius > 0 [m]", t.radius);
  if (!(std::isfinite(t.length) && t.length > 0))
    bad("tool.length", "a finite length > 0 [m]", t.length);
  if (t.axis_sign != 1 && t.axis_sign != -1) bad("tool.axis_sign", "+1 or -1", t.axis_sign);
  if (t.end == ToolEnd::kBall && t.length < t.radius)
    bad("tool.length", "a length >= radius (" + number(t.radius) + " m) for a ball end", t.length);
}

void check_force_params(const ForceParams& p) {
  if (!(std::isfinite(p.specific_energy) && p.specific_energy > 0))
    bad("force.specific_energy", "a finite energy > 0 [J/m^3]", p.specific_energy);
  if (!(std::isfinite(p.force_ratio) && p.force_ratio >= 0))
    bad("force.force_ratio", "a finite ratio >= 0", p.force_ratio);
  if (!(std::isfinite(p.spindle_rpm) && p.spindle_rpm > 0))
    bad("force.spindle_rpm", "a finite speed > 0 [rev/min]", p.spindle_rpm);
  if (!(std::isfinite(p.contact_stiffness) && p.contact_stiffness >= 0))
    bad("force.contact_stiffness", "a finite stiffness >= 0 [N/m]", p.contact_stiffness);
  if (!(std::isfinite(p.contact_damping) && p.contact_damping >= 0))
    bad("force.contact_damping", "a finite damping >= 0 [N·s/m]", p.contact_damping);
}

ToolParams tool_params_from(const ToolDescription& tool) {
  ToolParams t;
  t.radius = tool.radius;
  t.length = tool.length;
  t.axis_sign = -1;
  t.end = ToolEnd::kBall;
  return t;
}

// ---------------------------------------------------------------------------------------------
// Voxelisation

namespace {

// A surface crossing of a voxel column (i, j) at height z: +1 entering (surface faces down),
// −1 leaving (faces up), walking along +z.
struct Crossing {
  std::uint64_t col;
  double z;
  int sign;
};

// Edge function (twice the signed area of p0, p1, p), evaluated from the lexicographically
// smaller endpoint so that the two triangles sharing an edge get exactly opposite values.
double edge_fn(double x0, double y0, double x1, double y1, double px, double py) {
  if (x0 < x1 || (x0 == x1 && y0 < y1)) return (x1 - x0) * (py - y0) - (y1 - y0) * (px - x0);
  return -((x0 - x1) * (py - y1) - (y0 - y1) * (px - x1));
}

// Tie rule for points exactly on an edge p0 → p1 of a counter-clockwise triangle: exactly one of
// the two directions of an edge owns it, so shared edges are counted once.
bool owns_edge(double x0, double y0, double x1, double y1) {
  const double dx = x1 - x0, dy = y1 - y0;
  return dy < 0 || (dy == 0 && dx > 0);
}

// Rasterises the xy projection of triangle (A, B, C) onto the voxel columns with centres
// ((i + ½)h, (j + ½)h): emit(i, j, z, sign) for every column inside it, restricted to brick
// columns for which column_ok(bi, bj) holds. Vertical triangles cover no column.
template <class ColumnOk, class Emit>
void rasterize(const Vec3& A, const Vec3& B, const Vec3& C, double h, ColumnOk&& column_ok,
               Emit&& emit) {
  Vec3 a = A, b = B, c = C;
  double area = edge_fn(a.x(), a.y(), b.x(), b.y(), c.x(), c.y());
  if (area == 0) return;
  // Outward normal with +z component: the column leaves the solid here.
  const int sign = area > 0 ? -1 : +1;
  if (area < 0) {
    std::swap(b, c);
    area = -area;
  }
  const double xmin = std::min({a.x(), b.x(), c.x()}), xmax = std::max({a.x(), b.x(), c.x()});
  const double ymin = std::min({a.y(), b.y(), c.y()}), ymax = std::max({a.y(), b.y(), c.y()});
  const double zmin = std::min({a.z(), b.z(), c.z()}), zmax = std::max({a.z(), b.z(), c.z()});
  const std::int64_t i0 = first_centre_at_or_above(xmin, h), i1 = last_centre_at_or_below(xmax, h);
  const std::int64_t j0 = first_centre_at_or_above(ymin, h), j1 = last_centre_at_or_below(ymax, h);
  if (i0 > i1 || j0 > j1) return;
  const bool own_ab = owns_edge(a.x(), a.y(), b.x(), b.y());
  const bool own_bc = owns_edge(b.x(), b.y(), c.x(), c.y());
  const bool own_ca = owns_edge(c.x(), c.y(), a.x(), a.y());
  for (std::int64_t bi = floor_div(i0, kBrick); bi <= floor_div(i1, kBrick); ++bi)
    for (std::int64_t bj = floor_div(j0, kBrick); bj <= floor_div(j1, kBrick); ++bj) {
      if (!column_ok(bi, bj)) continue;
      const std::int64_t ia = std::max(i0, bi * kBrick), ib = std::min(i1, bi * kBrick + 7);
      const std::int64_t ja = std::max(j0, bj * kBrick), jb = std::min(j1, bj * kBrick + 7);
      for (std::int64_t i = ia; i <= ib; ++i) {
        const double px = (i + 0.5) * h;
        for (std::int64_t j = ja; j <= jb; ++j) {
          const double py = (j + 0.5) * h;
          const double wc = edge_fn(a.x(), a.y(), b.x(), b.y(), px, py);
          if (wc < 0 || (wc == 0 && !own_ab)) continue;
          const double wa = edge_fn(b.x(), b.y(), c.x(), c.y(), px, py);
          if (wa < 0 || (wa == 0 && !own_bc)) continue;
          const double wb = edge_fn(c.x(), c.y(), a.x(), a.y(), px, py);
          if (wb < 0 || (wb == 0 && !own_ca)) continue;
          const double sum = wa + wb + wc;
          double z = sum > 0 ? (wa * a.z() + wb * b.z() + wc * c.z()) / sum : a.z();
          z = std::clamp(z, zmin, zmax);
          emit(i, j, z, sign);
        }
      }
    }
}

// Walks the sorted crossings of each column and calls fill(i, j, k_lo, k_hi) for the runs of
// voxels whose centres have a nonzero winding number (inside the closed surfaces, whichever way
// they are oriented).
template <class Fill>
void fill_columns(std::vector<Crossing>& xs, double h, Fill&& fill) {
  std::sort(xs.begin(), xs.end(), [](const Crossing& p, const Crossing& q) {
    return p.col != q.col ? p.col < q.col : p.z < q.z;
  });
  std::size_t s = 0;
  while (s < xs.size()) {
    std::size_t e = s;
    while (e < xs.size() && xs[e].col == xs[s].col) ++e;
    const std::int64_t i = static_cast<std::int64_t>(xs[s].col >> 21) - kFieldOffset;
    const std::int64_t j = static_cast<std::int64_t>(xs[s].col & ((1u << 21) - 1)) - kFieldOffset;
    int w = 0;
    double z_in = 0;
    for (std::size_t n = s; n < e; ++n) {
      const int before = w;
      w += xs[n].sign;
      if (before == 0 && w != 0) z_in = xs[n].z;
      if (before != 0 && w == 0) {
        // Centres strictly above z_in and at or below z_out.
        const std::int64_t k0 = last_centre_at_or_below(z_in, h) + 1;
        const std::int64_t k1 = last_centre_at_or_below(xs[n].z, h);
        if (k0 <= k1) fill(i, j, k0, k1);
      }
    }
    s = e;
  }
}

// Bits of local voxels k0..k1 (inclusive, clamped to the brick) in the z-words of brick bz.
template <class SetWord>
void set_column_bits(std::int64_t i, std::int64_t j, std::int64_t k0, std::int64_t k1,
                     std::int64_t bz, SetWord&& set_word) {
  const std::int64_t za = std::max(k0, bz * kBrick) - bz * kBrick;
  const std::int64_t zb = std::min(k1, bz * kBrick + 7) - bz * kBrick;
  const std::uint64_t bit = std::uint64_t{1} << ((i - floor_div(i, kBrick) * kBrick) +
                                                 8 * (j - floor_div(j, kBrick) * kBrick));
  for (std::int64_t z = za; z <= zb; ++z) set_word(static_cast<int>(z), bit);
}

struct TmpBrick {
  std::int32_t bx, by, bz;
  std::array<std::uint64_t, 8> fin{}, inside{};
  bool band = false;
};

}  // namespace

MaterialGrid::MaterialGrid(const TriangleMesh& nominal_C, const std::vector<TriangleMesh>& fins_C,
                           const MaterialParams& params)
    : impl_(std::make_unique<Impl>()) {
  check_material_params(params);
  Impl& g = *impl_;
  g.params = params;
  const double h = params.voxel_size;
  g.h = h;
  const double brick = kBrick * h;
  const double brick_half_diag = 0.5 * std::sqrt(3.0) * brick;

  // Input checks: finite vertices, valid indices, a size the packed coordinates can hold.
  if (nominal_C.triangles.empty())
    throw ArgumentError("process: nominal mesh: expected a closed mesh, got 0 triangles");
  double extent = 0;
  auto check_mesh_input = [&](const TriangleMesh& m, const std::string& what) {
    for (const auto& v : m.vertices) {
      if (!v.allFinite())
        throw ArgumentError("process: " + what + ": expected finite vertices, got NaN/inf");
      extent = std::max(extent, v.cwiseAbs().maxCoeff());
    }
    const int n = static_cast<int>(m.vertices.size());
    for (const auto& t : m.triangles)
      if (t.minCoeff() < 0 || t.maxCoeff() >= n)
        throw ArgumentError("process: " + what + ": expected vertex indices in [0, " +
                            std::to_string(n) + "), got a triangle (" + std::to_string(t[0]) +
                            ", " + std::to_string(t[1]) + ", " + std::to_string(t[2]) + ")");
  };
  check_mesh_input(nominal_C, "nominal mesh");
  for (std::size_t f = 0; f < fins_C.size(); ++f)
    check_mesh_input(fins_C[f], "fin " + std::to_string(f));
  const double reach = extent + params.body_margin + params.body_band + 4 * brick;
  if (reach / h >= static_cast<double>(kVoxelLimit))
    bad("voxel_size",
        "a voxel size >= " + number(reach / kVoxelLimit) + " m for meshes reaching " +
            number(extent) + " m from the origin",
        h);

  g.nominal = std::make_shared<MeshBvh>(nominal_C);
  g.depth_cap = params.body_band + 2 * brick_half_diag + h;

  std::vector<TmpBrick> tmp;
  std::unordered_map<std::uint64_t, std::uint32_t, KeyHash> tmp_index;
  auto tmp_at = [&](std::int64_t bx, std::int64_t by, std::int64_t bz) -> TmpBrick& {
    const auto [it, fresh] =
        tmp_index.try_emplace(pack3(bx, by, bz), static_cast<std::uint32_t>(tmp.size()));
    if (fresh) {
      TmpBrick t;
      t.bx = static_cast<std::int32_t>(bx);
      t.by = static_cast<std::int32_t>(by);
      t.bz = static_cast<std::int32_t>(bz);
      tmp.push_back(t);
    }
    return tmp[it->second];
  };

  // 1. Fins: scanline fill along z of the union of the fin meshes.
  {
    std::vector<Crossing> xs;
    auto all = [](std::int64_t, std::int64_t) { return true; };
    auto emit = [&](std::int64_t i, std::int64_t j, double z, int sign) {
      xs.push_back({pack2(i, j), z, sign});
    };
    for (const auto& fin : fins_C)
      for (const auto& t : fin.triangles)
        rasterize(fin.vertices[t[0]], fin.vertices[t[1]], fin.vertices[t[2]], h, all, emit);
    fill_columns(xs, h, [&](std::int64_t i, std::int64_t j, std::int64_t k0, std::int64_t k1) {
      const std::int64_t bi = floor_div(i, kBrick), bj = floor_div(j, kBrick);
      for (std::int64_t bz = floor_div(k0, kBrick); bz <= floor_div(k1, kBrick); ++bz) {
        TmpBrick& t = tmp_at(bi, bj, bz);
        set_column_bits(i, j, k0, k1, bz, [&](int z, std::uint64_t bit) { t.fin[z] |= bit; });
      }
    });
  }

  // 2. Where the body is tracked: bricks whose centre is within margin + half a brick diagonal of
  // a fin's surface. Super-cells (blocks of sc^3 bricks) around the fin bricks carry the distance
  // of their centre to the fins, so most bricks are decided by the triangle inequality and only
  // those near the limit need a closest-point query of their own.
  if (!tmp.empty()) {
    const std::int64_t sc = std::max<std::int64_t>(
        4, static_cast<std::int64_t>(std::ceil(params.body_margin / (2 * brick))));
    const double cell = sc * brick;
    const double cell_half_diag = 0.5 * std::sqrt(3.0) * cell;
    const double limit = params.body_margin + brick_half_diag;
    const std::int64_t reach_sc = static_cast<std::int64_t>(std::ceil((limit + brick) / cell));
    TriangleMesh all_fins;
    for (const auto& fin : fins_C) all_fins.append(fin);
    const MeshBvh fin_bvh(all_fins);
    std::unordered_set<std::uint64_t, KeyHash> seeds;
    std::unordered_map<std::uint64_t, double, KeyHash> near;  // super-cell -> centre distance
    for (const auto& t : tmp)
      seeds.insert(pack3(floor_div(t.bx, sc), floor_div(t.by, sc), floor_div(t.bz, sc)));
    for (const auto key : seeds) {
      const std::int64_t cx = static_cast<std::int64_t>(key >> 42) - kFieldOffset;
      const std::int64_t cy =
          static_cast<std::int64_t>((key >> 21) & ((1u << 21) - 1)) - kFieldOffset;
      const std::int64_t cz = static_cast<std::int64_t>(key & ((1u << 21) - 1)) - kFieldOffset;
      for (std::int64_t dx = -reach_sc; dx <= reach_sc; ++dx)
        for (std::int64_t dy = -reach_sc; dy <= reach_sc; ++dy)
          for (std::int64_t dz = -reach_sc; dz <= reach_sc; ++dz) {
            const auto [it, fresh] = near.try_emplace(pack3(cx + dx, cy + dy, cz + dz), -1.0);
            if (!fresh) continue;
            const Vec3 c(((cx + dx) * sc + 0.5 * sc) * brick, ((cy + dy) * sc + 0.5 * sc) * brick,
                         ((cz + dz) * sc + 0.5 * sc) * brick);
            it->second = fin_bvh.closest(c, limit + cell_half_diag + brick).distance;
          }
    }
    std::unordered_map<std::uint64_t, bool, KeyHash> brick_near;  // bricks that needed a query
    auto near_fin = [&](std::int64_t bx, std::int64_t by, std::int64_t bz, const Vec3& c,
                        double cell_dist, const Vec3& cell_centre) {
      const double delta = (c - cell_centre).norm();
      if (cell_dist - delta > limit) return false;
      if (cell_dist + delta <= limit) return true;
      const auto [it, fresh] = brick_near.try_emplace(pack3(bx, by, bz), false);
      if (fresh) it->second = fin_bvh.closest(c, limit).triangle >= 0;
      return it->second;
    };

    // 3. Band bricks: bricks near a fin whose centre is within band + half a brick diagonal of a
    // nominal triangle.
    const double grow = params.body_band + brick_half_diag;
    for (const auto& t : nominal_C.triangles) {
      const Vec3& A = nominal_C.vertices[t[0]];
      const Vec3& B = nominal_C.vertices[t[1]];
      const Vec3& C = nominal_C.vertices[t[2]];
      const Vec3 lo = A.cwiseMin(B).cwiseMin(C).array() - grow;
      const Vec3 hi = A.cwiseMax(B).cwiseMax(C).array() + grow;
      std::array<std::int64_t, 3> b0, b1;
      for (int k = 0; k < 3; ++k) {
        // Bricks whose centre (b + ½)·brick lies in [lo, hi].
        b0[k] = static_cast<std::int64_t>(std::ceil(lo[k] / brick - 0.5));
        b1[k] = static_cast<std::int64_t>(std::floor(hi[k] / brick - 0.5));
      }
      if (b0[0] > b1[0] || b0[1] > b1[1] || b0[2] > b1[2]) continue;
      for (std::int64_t sx = floor_div(b0[0], sc); sx <= floor_div(b1[0], sc); ++sx)
        for (std::int64_t sy = floor_div(b0[1], sc); sy <= floor_div(b1[1], sc); ++sy)
          for (std::int64_t sz = floor_div(b0[2], sc); sz <= floor_div(b1[2], sc); ++sz) {
            const auto cell_it = near.find(pack3(sx, sy, sz));
            if (cell_it == near.end() || cell_it->second > limit + cell_half_diag) continue;
            const Vec3 cell_centre((sx + 0.5) * cell, (sy + 0.5) * cell, (sz + 0.5) * cell);
            for (std::int64_t bx = std::max(b0[0], sx * sc);
                 bx <= std::min(b1[0], sx * sc + sc - 1); ++bx)
              for (std::int64_t by = std::max(b0[1], sy * sc);
                   by <= std::min(b1[1], sy * sc + sc - 1); ++by)
                for (std::int64_t bz = std::max(b0[2], sz * sc);
                     bz <= std::min(b1[2], sz * sc + sc - 1); ++bz) {
                  const auto it = tmp_index.find(pack3(bx, by, bz));
                  if (it != tmp_index.end() && tmp[it->second].band) continue;
                  const Vec3 c((bx + 0.5) * brick, (by + 0.5) * brick, (bz + 0.5) * brick);
                  if ((closest_on_triangle(c, A, B, C) - c).squaredNorm() > grow * grow) continue;
                  if (!near_fin(bx, by, bz, c, cell_it->second, cell_centre)) continue;
                  tmp_at(bx, by, bz).band = true;
                }
          }
    }

    // 4. Inside the nominal body: scanline fill along z, only in the columns of candidate bricks.
    std::unordered_map<std::uint64_t, std::vector<std::uint32_t>, KeyHash> column_bricks;
    for (std::uint32_t n = 0; n < tmp.size(); ++n)
      column_bricks[pack2(tmp[n].bx, tmp[n].by)].push_back(n);
    std::vector<Crossing> xs;
    auto ok = [&](std::int64_t bi, std::int64_t bj) {
      return column_bricks.count(pack2(bi, bj)) > 0;
    };
    auto emit = [&](std::int64_t i, std::int64_t j, double z, int sign) {
      xs.push_back({pack2(i, j), z, sign});
    };
    for (const auto& t : nominal_C.triangles)
      rasterize(nominal_C.vertices[t[0]], nominal_C.vertices[t[1]], nominal_C.vertices[t[2]], h, ok,
                emit);
    fill_columns(xs, h, [&](std::int64_t i, std::int64_t j, std::int64_t k0, std::int64_t k1) {
      const auto it = column_bricks.find(pack2(floor_div(i, kBrick), floor_div(j, kBrick)));
      if (it == column_bricks.end()) return;
      for (const std::uint32_t n : it->second) {
        TmpBrick& t = tmp[n];
        if (std::int64_t{t.bz} * kBrick + 7 < k0 || std::int64_t{t.bz} * kBrick > k1) continue;
        set_column_bits(i, j, k0, k1, t.bz, [&](int z, std::uint64_t bit) { t.inside[z] |= bit; });
      }
    });
  }

  // 5. Final bricks: FLASH = in a fin and outside the body; BODY = inside the body in band bricks.
  g.bricks.reserve(tmp.size());
  for (const auto& t : tmp) {
    Brick b;
    b.bx = t.bx;
    b.by = t.by;
    b.bz = t.bz;
    int nf = 0, nb = 0;
    for (int z = 0; z < 8; ++z) {
      b.flash[z] = t.fin[z] & ~t.inside[z];
      b.body[z] = t.band ? t.inside[z] : 0;
      b.body0[z] = b.body[z];
      nf += std::popcount(b.flash[z]);
      nb += std::popcount(b.body[z]);
    }
    if (nf == 0 && nb == 0) continue;
    b.n_flash = static_cast<std::uint16_t>(nf);
    b.n_body = b.n_body0 = static_cast<std::uint16_t>(nb);
    // Tight local box of the material, for the tool's brick culling.
    std::array<int, 3> lo{8, 8, 8}, hi{-1, -1, -1};
    for (int z = 0; z < 8; ++z) {
      const std::uint64_t m = b.flash[z] | b.body0[z];
      if (!m) continue;
      lo[2] = std::min(lo[2], z);
      hi[2] = std::max(hi[2], z);
      for (int y = 0; y < 8; ++y) {
        const auto row = static_cast<std::uint8_t>(m >> (8 * y));
        if (!row) continue;
        lo[1] = std::min(lo[1], y);
        hi[1] = std::max(hi[1], y);
        lo[0] = std::min(lo[0], std::countr_zero(row));
        hi[0] = std::max(hi[0], 7 - std::countl_zero(row));
      }
    }
    for (int k = 0; k < 3; ++k) {
      b.lo[k] = static_cast<std::uint8_t>(lo[k]);
      b.hi[k] = static_cast<std::uint8_t>(hi[k]);
    }
    g.flash0 += nf;
    g.body0 += nb;
    g.bricks.push_back(std::move(b));
  }
  g.flash = g.flash0;
  std::sort(g.bricks.begin(), g.bricks.end(), [](const Brick& p, const Brick& q) {
    return std::tie(p.bx, p.by, p.bz) < std::tie(q.bx, q.by, q.bz);
  });
  for (std::uint32_t n = 0; n < g.bricks.size();) {
    std::uint32_t e = n;
    while (e < g.bricks.size() && g.bricks[e].bx == g.bricks[n].bx &&
           g.bricks[e].by == g.bricks[n].by)
      ++e;
    g.columns.emplace(pack2(g.bricks[n].bx, g.bricks[n].by), std::make_pair(n, e));
    n = e;
  }
  if (!g.bricks.empty()) {
    g.bmin = {g.bricks.front().bx, g.bricks.front().by, g.bricks.front().bz};
    g.bmax = g.bmin;
    for (const auto& b : g.bricks) {
      const std::array<std::int64_t, 3> c{b.bx, b.by, b.bz};
      for (int k = 0; k < 3; ++k) {
        g.bmin[k] = std::min(g.bmin[k], c[k]);
        g.bmax[k] = std::max(g.bmax[k], c[k]);
      }
    }
  }
}

MaterialGrid::~MaterialGrid() = default;
MaterialGrid::MaterialGrid(const MaterialGrid& other)
    : impl_(std::make_unique<Impl>(*other.impl_)) {}
MaterialGrid& MaterialGrid::operator=(const MaterialGrid& other) {
  if (this != &other) impl_ = std::make_unique<Impl>(*other.impl_);
  return *this;
}
MaterialGrid::MaterialGrid(MaterialGrid&&) noexcept = default;
MaterialGrid& MaterialGrid::operator=(MaterialGrid&&) noexcept = default;

const MaterialParams& MaterialGrid::params() const {
  return impl_->params;
}
double MaterialGrid::voxel_size() const {
  return impl_->h;
}
double MaterialGrid::voxel_volume() const {
  return impl_->h * impl_->h * impl_->h;
}
const MeshBvh& MaterialGrid::nominal() const {
  return *impl_->nominal;
}
std::size_t MaterialGrid::flash_voxels_initial() const {
  return impl_->flash0;
}
std::size_t MaterialGrid::flash_voxels_remaining() const {
  return impl_->flash;
}
std::size_t MaterialGrid::body_voxels_initial() const {
  return impl_->body0;
}
std::size_t MaterialGrid::body_voxels_removed() const {
  return impl_->body_removed;
}
std::size_t MaterialGrid::num_bricks() const {
  return impl_->bricks.size();
}

std::size_t MaterialGrid::memory_bytes() const {
  std::size_t n = impl_->bricks.capacity() * sizeof(Brick) +
                  impl_->columns.size() * (sizeof(std::uint64_t) + 2 * sizeof(std::uint32_t) + 16);
  for (const auto& b : impl_->bricks) n += b.depth.capacity() * sizeof(float);
  return n;
}

Vec3 MaterialGrid::voxel_centre(const Vec3& p_C) const {
  const double h = impl_->h;
  return Vec3((std::floor(p_C.x() / h) + 0.5) * h, (std::floor(p_C.y() / h) + 0.5) * h,
              (std::floor(p_C.z() / h) + 0.5) * h);
}

VoxelLabel MaterialGrid::label_at(const Vec3& p_C) const {
  const double h = impl_->h;
  if (!p_C.allFinite() || p_C.cwiseAbs().maxCoeff() / h >= static_cast<double>(kVoxelLimit))
    return VoxelLabel::kEmpty;
  const auto i = static_cast<std::int64_t>(std::floor(p_C.x() / h));
  const auto j = static_cast<std::int64_t>(std::floor(p_C.y() / h));
  const auto k = static_cast<std::int64_t>(std::floor(p_C.z() / h));
  const Brick* b = impl_->find(floor_div(i, kBrick), floor_div(j, kBrick), floor_div(k, kBrick));
  if (!b) return VoxelLabel::kEmpty;
  const int z = static_cast<int>(k - std::int64_t{b->bz} * kBrick);
  const std::uint64_t bit = std::uint64_t{1} << ((i - std::int64_t{b->bx} * kBrick) +
                                                 8 * (j - std::int64_t{b->by} * kBrick));
  if (b->flash[z] & bit) return VoxelLabel::kFlash;
  if (b->body[z] & bit) return VoxelLabel::kBody;
  if (b->body0[z] & bit) return VoxelLabel::kGouge;
  return VoxelLabel::kEmpty;
}

MaterialGrid make_material_grid(const Casting& casting, const MaterialParams& params) {
  std::vector<TriangleMesh> fins;
  fins.reserve(casting.fins.size());
  for (const auto& f : casting.fins) fins.push_back(f.mesh);
  return MaterialGrid(casting.nominal, fins, params);
}

// ---------------------------------------------------------------------------------------------
// Tool

namespace {

// The posed cutter: axial coordinate u = a·(p − p0) from the tip p0 (the TCP) along the unit
// axis a into the tool; cylinder for u ∈ [u_lo, L], plus when ball-ended the hemisphere u ≤ r of
// the ball of radius r at p0 + r·a (u_lo = r).
struct ToolShape {
  Vec3 p0, a, ball_centre;
  double r = 0, r2 = 0, L = 0, u_lo = 0;
  bool ball = false;
  // Row-interval constants: radial quadratic A·t² + B·t + C ≤ 0 along x, with A = 1 − a_x².
  double ax = 0, A = 0, inv_ax = 0;
  bool along_x = false, across_x = false;  // axis parallel to x (A ≈ 0); perpendicular (a_x ≈ 0)

  ToolShape(const ToolParams& t, const Pose& X_CT) {
    p0 = X_CT.translation();
    a = (t.axis_sign * X_CT.linear().col(2)).normalized();
    r = t.radius;
    r2 = r * r;
    L = t.length;
    ball = t.end == ToolEnd::kBall;
    u_lo = ball ? r : 0.0;
    ball_centre = p0 + r * a;
    ax = a.x();
    A = 1 - ax * ax;
    along_x = A < 1e-12;
    across_x = std::abs(ax) < 1e-12;
    inv_ax = across_x ? 0.0 : 1.0 / ax;
  }

  bool contains(const Vec3& p) const {
    const Vec3 d = p - p0;
    const double u = a.dot(d);
    if (u >= u_lo && u <= L && d.squaredNorm() - u * u <= r2) return true;
    return ball && u <= r && (p - ball_centre).squaredNorm() <= r2;
  }

  // Parameter interval [t0, t1] of the line q + t·e_x (t ∈ [0, t_max]) inside the tool: one
  // interval, the tool being convex. False when the line misses it.
  bool row_interval(const Vec3& q, double t_max, double& t0, double& t1) const {
    const Vec3 w = q - p0;
    const double aw = a.dot(w);
    bool any = false;
    // Cylinder: radial condition, then the axial one u_lo ≤ aw + a_x·t ≤ L.
    double c0 = -1e300, c1 = 1e300;
    const double C = w.squaredNorm() - aw * aw - r2;
    bool cyl;
    if (along_x) {
      cyl = C <= 0;
    } else {
      const double B = 2 * (w.x() - aw * ax);
      const double disc = B * B - 4 * A * C;
      cyl = disc >= 0;
      if (cyl) {
        // Roots without cancellation (the axis may be nearly along x, A small).
        const double qr = -0.5 * (B + std::copysign(std::sqrt(disc), B));
        const double ra = qr / A, rb = qr != 0 ? C / qr : ra;
        c0 = std::min(ra, rb);
        c1 = std::max(ra, rb);
      }
    }
    if (cyl) {
      if (across_x) {
        cyl = aw >= u_lo && aw <= L;
      } else {
        double ta = (u_lo - aw) * inv_ax, tb = (L - aw) * inv_ax;
        if (ta > tb) std::swap(ta, tb);
        c0 = std::max(c0, ta);
        c1 = std::min(c1, tb);
        cyl = c0 <= c1;
      }
    }
    if (cyl) {
      t0 = c0;
      t1 = c1;
      any = true;
      if (t0 <= 0 && t1 >= t_max) return true;  // the hemisphere cannot widen it within the row
    }
    // Hemisphere: |q + t·e_x − centre|² ≤ r² on the tip side aw + a_x·t ≤ r.
    if (ball && std::min(aw, aw + ax * t_max) <= r) {
      const Vec3 e = q - ball_centre;
      const double disc = e.x() * e.x() - (e.squaredNorm() - r2);
      if (disc >= 0) {
        const double s = std::sqrt(disc);
        double b0 = -e.x() - s, b1 = -e.x() + s;
        if (across_x) {
          if (aw > r) b1 = b0 - 1;
        } else if (ax > 0) {
          b1 = std::min(b1, (r - aw) * inv_ax);
        } else {
          b0 = std::max(b0, (r - aw) * inv_ax);
        }
        if (b0 <= b1) {
          t0 = any ? std::min(t0, b0) : b0;
          t1 = any ? std::max(t1, b1) : b1;
          any = true;
        }
      }
    }
    return any;
  }
};

// Adds the centres of the voxels of bit mask m in z-word z of brick b to sum: the sums of the
// local x and y indices come from popcounts of the masks of their binary digits.
void add_centres(const MaterialGrid::Impl& g, const Brick& b, int z, std::uint64_t m, Vec3& sum) {
  constexpr std::uint64_t kX1 = 0xAAAAAAAAAAAAAAAAULL, kX2 = 0xCCCCCCCCCCCCCCCCULL,
                          kX4 = 0xF0F0F0F0F0F0F0F0ULL, kY1 = 0xFF00FF00FF00FF00ULL,
                          kY2 = 0xFFFF0000FFFF0000ULL, kY4 = 0xFFFFFFFF00000000ULL;
  const double n = std::popcount(m);
  const double sx =
      std::popcount(m & kX1) + 2.0 * std::popcount(m & kX2) + 4.0 * std::popcount(m & kX4);
  const double sy =
      std::popcount(m & kY1) + 2.0 * std::popcount(m & kY2) + 4.0 * std::popcount(m & kY4);
  sum += g.h * Vec3(n * (b.bx * kBrick + 0.5) + sx, n * (b.by * kBrick + 0.5) + sy,
                    n * (b.bz * kBrick + z + 0.5));
}

}  // namespace

bool tool_contains(const ToolParams& tool, const Pose& X_CT, const Vec3& p_C) {
  return ToolShape(tool, X_CT).contains(p_C);
}

StepRemoval remove_material(const ToolParams& tool, MaterialGrid& grid, const Pose& X_CT) {
  check_tool_params(tool);
  if (!X_CT.matrix().allFinite())
    throw ArgumentError("process: tool pose X_CT: expected finite entries, got NaN/inf");
  MaterialGrid::Impl& g = MaterialAccess::get(grid);
  StepRemoval out;
  if (g.bricks.empty()) return out;
  const ToolShape T(tool, X_CT);
  const double h = g.h, inv_h = 1 / g.h;
  const Vec3 p1 = T.p0 + T.L * T.a;

  // Bricks whose voxel centres can fall in the tool's bounding box.
  std::array<std::int64_t, 3> b0, b1;
  for (int k = 0; k < 3; ++k) {
    const double lo = std::min(T.p0[k], p1[k]) - T.r, hi = std::max(T.p0[k], p1[k]) + T.r;
    const double lim = static_cast<double>(kVoxelLimit);
    const double ilo = std::clamp(std::ceil(lo / h - 0.5), -lim, lim);
    const double ihi = std::clamp(std::floor(hi / h - 0.5), -lim, lim);
    b0[k] = std::max(g.bmin[k], floor_div(static_cast<std::int64_t>(ilo), kBrick));
    b1[k] = std::min(g.bmax[k], floor_div(static_cast<std::int64_t>(ihi), kBrick));
    if (b0[k] > b1[k]) return out;
  }

  Vec3 removed_sum = Vec3::Zero(), contact_sum = Vec3::Zero();
  std::size_t removed_flash = 0, removed_body = 0;
  for (std::int64_t bx = b0[0]; bx <= b1[0]; ++bx)
    for (std::int64_t by = b0[1]; by <= b1[1]; ++by) {
      const auto col = g.columns.find(pack2(bx, by));
      if (col == g.columns.end()) continue;
      for (std::uint32_t n = col->second.first; n < col->second.second; ++n) {
        Brick& b = g.bricks[n];
        if (b.bz < b0[2]) continue;
        if (b.bz > b1[2]) break;
        if (b.n_flash == 0 && b.n_body0 == 0) continue;

        // Cull with the box of the brick's voxel centres: distance to the axis segment, then the
        // separating axes perpendicular to and along the tool axis.
        const Vec3 clo((b.bx * kBrick + b.lo[0] + 0.5) * h, (b.by * kBrick + b.lo[1] + 0.5) * h,
                       (b.bz * kBrick + b.lo[2] + 0.5) * h);
        const Vec3 chi((b.bx * kBrick + b.hi[0] + 0.5) * h, (b.by * kBrick + b.hi[1] + 0.5) * h,
                       (b.bz * kBrick + b.hi[2] + 0.5) * h);
        const Vec3 c = 0.5 * (clo + chi), e = 0.5 * (chi - clo);
        const Vec3 w = c - T.p0;
        const double u = T.a.dot(w);
        const double ext_a = e.dot(T.a.cwiseAbs());
        if (u - ext_a > T.L || u + ext_a < 0) continue;
        const Vec3 perp = w - u * T.a;
        const double rho = perp.norm();
        if (rho > 1e-12 && rho - e.dot((perp / rho).cwiseAbs()) > T.r) continue;
        const double us = std::clamp(u, 0.0, T.L);
        if ((w - us * T.a).norm() > T.r + e.norm()) continue;

        // Inside mask: whole brick when all corners of the centre box are inside (convex tool),
        // else per voxel row from the exact row interval.
        std::array<std::uint64_t, 8> in{};
        bool full = true;
        for (int k = 0; k < 8 && full; ++k)
          full = T.contains(Vec3(k & 1 ? chi.x() : clo.x(), k & 2 ? chi.y() : clo.y(),
                                 k & 4 ? chi.z() : clo.z()));
        bool any = false;
        if (full) {
          in.fill(~std::uint64_t{0});
          any = true;
        } else {
          const double x_base = b.bx * kBrick * h;
          for (int z = b.lo[2]; z <= b.hi[2]; ++z) {
            const std::uint64_t material = b.flash[z] | b.body0[z];
            if (!material) continue;
            for (int y = b.lo[1]; y <= b.hi[1]; ++y) {
              if (!((material >> (8 * y)) & 0xFF)) continue;
              const Vec3 q(x_base, (b.by * kBrick + y + 0.5) * h, (b.bz * kBrick + z + 0.5) * h);
              double t0 = 0, t1 = -1;
              if (!T.row_interval(q, kBrick * h, t0, t1)) continue;
              const double x0 = std::max(0.0, std::ceil(t0 * inv_h - 0.5));
              const double x1 = std::min(7.0, std::floor(t1 * inv_h - 0.5));
              if (x0 > x1) continue;
              const int xa = static_cast<int>(x0), xb = static_cast<int>(x1);
              const std::uint64_t row =
                  ((std::uint64_t{1} << (xb + 1)) - 1) & ~((std::uint64_t{1} << xa) - 1);
              in[z] |= row << (8 * y);
              any = true;
            }
          }
        }
        if (!any) continue;

        // Take the material; BODY voxels inside the tool give the penetration (cached depths).
        int nf = 0, nb = 0;
        for (int z = 0; z < 8; ++z) {
          const std::uint64_t f = b.flash[z] & in[z];
          const std::uint64_t body_now = b.body[z] & in[z];
          const std::uint64_t contact = b.body0[z] & in[z];
          if (f) {
            b.flash[z] &= ~f;
            nf += std::popcount(f);
            add_centres(g, b, z, f, removed_sum);
          }
          if (!contact) continue;
          out.contact_count += static_cast<std::size_t>(std::popcount(contact));
          add_centres(g, b, z, contact, contact_sum);
          float deepest = 0;
          int deepest_idx = -1;
          for (std::uint64_t m = contact; m; m &= m - 1) {
            const int idx = z * 64 + std::countr_zero(m);
            const float d = g.depth(b, idx);
            if (d > deepest) {
              deepest = d;
              deepest_idx = idx;
            }
          }
          if (deepest_idx >= 0 && deepest > out.penetration) {
            out.penetration = deepest;
            out.deepest_C = g.centre(b, deepest_idx);
          }
          if (body_now) {
            b.body[z] &= ~body_now;
            nb += std::popcount(body_now);
            add_centres(g, b, z, body_now, removed_sum);
            for (std::uint64_t m = body_now; m; m &= m - 1)
              out.max_depth = std::max(out.max_depth,
                                       static_cast<double>(b.depth[z * 64 + std::countr_zero(m)]));
          }
        }
        b.n_flash = static_cast<std::uint16_t>(b.n_flash - nf);
        b.n_body = static_cast<std::uint16_t>(b.n_body - nb);
        removed_flash += nf;
        removed_body += nb;
      }
    }

  g.flash -= removed_flash;
  g.body_removed += removed_body;
  const double vv = h * h * h;
  out.flash_count = removed_flash;
  out.body_count = removed_body;
  out.flash_volume = removed_flash * vv;
  out.body_volume = removed_body * vv;
  if (out.count() > 0) out.centroid_C = removed_sum / static_cast<double>(out.count());
  if (out.contact_count > 0)
    out.contact_centroid_C = contact_sum / static_cast<double>(out.contact_count);
  return out;
}

// ---------------------------------------------------------------------------------------------
// Residual analysis

namespace {

// Flash voxels still joined to the casting: flood fill (26-neighbourhood) from the FLASH
// voxels that touch a remaining BODY voxel. The rest are chips cut loose, which would fall off.
std::vector<std::array<std::uint64_t, 8>> attached_flash(const MaterialGrid::Impl& g) {
  using Brick = MaterialGrid::Impl::Brick;
  std::vector<std::array<std::uint64_t, 8>> seen(g.bricks.size());
  auto bit_of = [](int x, int y) { return std::uint64_t{1} << (x + 8 * y); };
  // The 27 bricks around each brick holding flash (itself at 13; -1: none), looked up once:
  // the fill below only walks flash voxels, so only their bricks need neighbours.
  std::vector<std::int32_t> row_of(g.bricks.size(), -1);
  std::vector<std::array<std::int32_t, 27>> around;
  for (std::uint32_t n = 0; n < g.bricks.size(); ++n) {
    const Brick& b = g.bricks[n];
    if (b.n_flash == 0) continue;
    row_of[n] = static_cast<std::int32_t>(around.size());
    std::array<std::int32_t, 27> a;
    for (int k = 0; k < 27; ++k) {
      const Brick* nb = g.find(b.bx + k % 3 - 1, b.by + (k / 3) % 3 - 1, b.bz + k / 9 - 1);
      a[static_cast<std::size_t>(k)] = nb ? static_cast<std::int32_t>(nb - g.bricks.data()) : -1;
    }
    around.push_back(a);
  }
  // Calls f(brick index, x, y, z) for every neighbour voxel of local voxel (x, y, z) of brick n.
  auto for_neighbours = [&](std::uint32_t n, int x, int y, int z, auto&& f) {
    const auto& a = around[static_cast<std::size_t>(row_of[n])];
    for (int dz = -1; dz <= 1; ++dz)
      for (int dy = -1; dy <= 1; ++dy)
        for (int dx = -1; dx <= 1; ++dx) {
          if (!dx && !dy && !dz) continue;
          const int nx = x + dx, ny = y + dy, nz = z + dz;
          // Which brick of the 3×3×3 block, and the voxel's local coordinates in it.
          const int sx = nx < 0 ? 0 : (nx > 7 ? 2 : 1), sy = ny < 0 ? 0 : (ny > 7 ? 2 : 1),
                    sz = nz < 0 ? 0 : (nz > 7 ? 2 : 1);
          const std::int32_t k = a[static_cast<std::size_t>(sx + 3 * sy + 9 * sz)];
          if (k < 0) continue;
          f(static_cast<std::uint32_t>(k), nx & 7, ny & 7, nz & 7);
        }
  };
  std::vector<std::pair<std::uint32_t, int>> stack;
  for (std::uint32_t n = 0; n < g.bricks.size(); ++n) {
    const Brick& b = g.bricks[n];
    if (b.n_flash == 0) continue;
    for (int z = 0; z < 8; ++z)
      for (std::uint64_t m = b.flash[z]; m; m &= m - 1) {
        const int bit = std::countr_zero(m);
        bool touches = false;
        for_neighbours(n, bit & 7, bit >> 3, z, [&](std::uint32_t k, int x, int y, int zz) {
          touches = touches || (g.bricks[k].body[zz] & bit_of(x, y));
        });
        if (touches && !(seen[n][z] & (std::uint64_t{1} << bit))) {
          seen[n][z] |= std::uint64_t{1} << bit;
          stack.emplace_back(n, z * 64 + bit);
        }
      }
  }
  while (!stack.empty()) {
    const auto [n, idx] = stack.back();
    stack.pop_back();
    const int bit = idx & 63, z = idx >> 6;
    for_neighbours(n, bit & 7, bit >> 3, z, [&](std::uint32_t k, int x, int y, int zz) {
      const std::uint64_t mb = bit_of(x, y);
      if ((g.bricks[k].flash[zz] & mb) && !(seen[k][zz] & mb)) {
        seen[k][zz] |= mb;
        stack.emplace_back(k, zz * 64 + x + 8 * y);
      }
    });
  }
  return seen;
}

}  // namespace

ResidualReport analyze_residual(const MaterialGrid& grid) {
  const MaterialGrid::Impl& g = MaterialAccess::get(grid);
  const auto attached = attached_flash(g);
  const double vv = g.h * g.h * g.h;
  ResidualReport r;
  r.flash_voxels_remaining = g.flash;
  r.flash_volume_initial = g.flash0 * vv;
  r.flash_volume_remaining = g.flash * vv;
  r.flash_removed_fraction =
      g.flash0 > 0 ? static_cast<double>(g.flash0 - g.flash) / static_cast<double>(g.flash0) : 1.0;
  r.gouge_voxels = g.body_removed;
  r.gouge_volume = g.body_removed * vv;
  for (std::uint32_t n = 0; n < g.bricks.size(); ++n)
    for (int z = 0; z < 8; ++z)
      r.loose_flash_voxels += static_cast<std::size_t>(
          std::popcount(g.bricks[n].flash[z] & ~attached[n][z]));
  r.loose_flash_volume = static_cast<double>(r.loose_flash_voxels) * vv;

  // Highest residual flash: bricks in decreasing order of an upper bound of their voxels'
  // distance (centre distance + half diagonal); stop when no brick can beat the best voxel.
  const double half_diag = 0.5 * std::sqrt(3.0) * 7 * g.h;
  std::vector<std::pair<double, std::uint32_t>> order;
  for (std::uint32_t n = 0; n < g.bricks.size(); ++n) {
    const Brick& b = g.bricks[n];
    if (b.n_flash == 0) continue;
    const Vec3 c((b.bx * kBrick + 4) * g.h, (b.by * kBrick + 4) * g.h, (b.bz * kBrick + 4) * g.h);
    order.emplace_back(g.nominal->closest(c).distance + half_diag, n);
  }
  std::sort(order.begin(), order.end(), std::greater<>());
  double best = 0;
  for (const auto& [bound, n] : order) {
    if (bound <= best) break;
    const Brick& b = g.bricks[n];
    for (int z = 0; z < 8; ++z)
      for (std::uint64_t m = b.flash[z] & attached[n][z]; m; m &= m - 1) {
        const int bit = std::countr_zero(m);
        const Vec3 p = g.centre(b, bit & 7, bit >> 3, z);
        // A hit within `best` means this voxel cannot raise the maximum.
        if (g.nominal->closest(p, best).triangle >= 0) continue;
        best = std::max(best, g.nominal->closest(p).distance);
      }
  }
  r.residual_flash_max = best;

  for (const auto& b : g.bricks) {
    if (b.n_body == b.n_body0) continue;
    for (int z = 0; z < 8; ++z)
      for (std::uint64_t m = b.body0[z] & ~b.body[z]; m; m &= m - 1)
        r.gouge_max_depth =
            std::max(r.gouge_max_depth, g.depth_const(b, z * 64 + std::countr_zero(m)));
  }
  return r;
}

std::vector<Vec3> voxel_points(const MaterialGrid& grid, VoxelLabel label) {
  const MaterialGrid::Impl& g = MaterialAccess::get(grid);
  std::vector<Vec3> out;
  if (label == VoxelLabel::kEmpty) return out;
  for (const auto& b : g.bricks)
    for (int z = 0; z < 8; ++z) {
      std::uint64_t m = 0;
      if (label == VoxelLabel::kFlash) m = b.flash[z];
      if (label == VoxelLabel::kBody) m = b.body[z];
      if (label == VoxelLabel::kGouge) m = b.body0[z] & ~b.body[z];
      for (; m; m &= m - 1) {
        const int bit = std::countr_zero(m);
        out.push_back(g.centre(b, bit & 7, bit >> 3, z));
      }
    }
  return out;
}

std::vector<Vec3> remaining_flash_points(const MaterialGrid& grid) {
  return voxel_points(grid, VoxelLabel::kFlash);
}

RemainingFlash split_remaining_flash(const MaterialGrid& grid) {
  const MaterialGrid::Impl& g = MaterialAccess::get(grid);
  const auto joined = attached_flash(g);
  RemainingFlash out;
  for (std::uint32_t n = 0; n < g.bricks.size(); ++n) {
    const auto& b = g.bricks[n];
    for (int z = 0; z < 8; ++z)
      for (std::uint64_t m = b.flash[z]; m; m &= m - 1) {
        const int bit = std::countr_zero(m);
        const bool on = (joined[n][z] >> bit) & 1;
        (on ? out.attached : out.loose).push_back(g.centre(b, bit & 7, bit >> 3, z));
      }
  }
  return out;
}

TriangleMesh remaining_flash_mesh(const MaterialGrid& grid) {
  const MaterialGrid::Impl& g = MaterialAccess::get(grid);
  auto flash_at = [&](std::int64_t i, std::int64_t j, std::int64_t k) {
    const Brick* b = g.find(floor_div(i, kBrick), floor_div(j, kBrick), floor_div(k, kBrick));
    if (!b) return false;
    const std::int64_t z = k - std::int64_t{b->bz} * kBrick;
    const std::int64_t bit =
        (i - std::int64_t{b->bx} * kBrick) + 8 * (j - std::int64_t{b->by} * kBrick);
    return ((b->flash[z] >> bit) & 1) != 0;
  };
  // The exposed faces, grouped by orientation (axis d, side s) and by the plane they lie in:
  // face (d, s) of voxel v lies in plane v[d] + (s > 0) and covers the unit square at
  // (v[du], v[dv]) in it, du = d + 1 and dv = d + 2 (mod 3).
  struct Face {
    std::int64_t plane, u, v;
    bool operator<(const Face& o) const { return std::tie(plane, v, u) < std::tie(o.plane, o.v, o.u); }
  };
  std::array<std::vector<Face>, 6> faces;  // index 2·d + (s > 0)
  for (const auto& b : g.bricks) {
    if (b.n_flash == 0) continue;
    for (int z = 0; z < 8; ++z)
      for (std::uint64_t m = b.flash[z]; m; m &= m - 1) {
        const int bit = std::countr_zero(m);
        const std::array<std::int64_t, 3> v{std::int64_t{b.bx} * kBrick + (bit & 7),
                                            std::int64_t{b.by} * kBrick + (bit >> 3),
                                            std::int64_t{b.bz} * kBrick + z};
        for (int d = 0; d < 3; ++d)
          for (int s = 0; s < 2; ++s) {
            std::array<std::int64_t, 3> nb = v;
            nb[d] += s ? 1 : -1;
            if (flash_at(nb[0], nb[1], nb[2])) continue;
            faces[2 * d + s].push_back({v[d] + s, v[(d + 1) % 3], v[(d + 2) % 3]});
          }
      }
  }
  TriangleMesh mesh;
  std::unordered_map<std::uint64_t, int, KeyHash> vertex;
  auto corner = [&](const std::array<std::int64_t, 3>& c) {
    const auto [it, fresh] = vertex.try_emplace(pack3(c[0], c[1], c[2]), static_cast<int>(mesh.vertices.size()));
    if (fresh) mesh.vertices.emplace_back(c[0] * g.h, c[1] * g.h, c[2] * g.h);
    return it->second;
  };
  // Greedy meshing: the faces of one plane merged into rectangles (a run along u, grown along
  // v while the whole run continues), two triangles each. The surface is the same, with far
  // fewer triangles on a fin's flat sides (a voxel mesh of a 2 mm fin has millions); the
  // rectangles meet in T-junctions, so the triangles cover the surface without sharing all edges.
  for (int d = 0; d < 3; ++d)
    for (int s = 0; s < 2; ++s) {
      std::vector<Face>& fs = faces[2 * d + s];
      std::sort(fs.begin(), fs.end());
      // The faces not yet merged into a rectangle, by (plane, u, v).
      std::unordered_set<std::uint64_t, KeyHash> left;
      left.reserve(fs.size());
      for (const Face& f : fs) left.insert(pack3(f.plane, f.u, f.v));
      const int du = (d + 1) % 3, dv = (d + 2) % 3;
      for (const Face& f : fs) {
        if (left.erase(pack3(f.plane, f.u, f.v)) == 0) continue;  // in an earlier rectangle
        std::int64_t u1 = f.u + 1;  // the run [f.u, u1) along u
        while (left.erase(pack3(f.plane, u1, f.v)) != 0) ++u1;
        std::int64_t v1 = f.v + 1;  // rows [f.v, v1)
        const auto row_left = [&](std::int64_t v) {
          for (std::int64_t u = f.u; u < u1; ++u)
            if (!left.count(pack3(f.plane, u, v))) return false;
          return true;
        };
        for (; row_left(v1); ++v1)
          for (std::int64_t u = f.u; u < u1; ++u) left.erase(pack3(f.plane, u, v1));
        std::array<std::int64_t, 3> c0{};
        c0[d] = f.plane;
        c0[du] = f.u;
        c0[dv] = f.v;
        std::array<std::int64_t, 3> c1 = c0, c2 = c0, c3 = c0;
        c1[du] = u1;
        c2[du] = u1;
        c2[dv] = v1;
        c3[dv] = v1;
        const int i0 = corner(c0), i1 = corner(c1), i2 = corner(c2), i3 = corner(c3);
        // Counter-clockwise seen from outside (+d for s = 1).
        if (s) {
          mesh.triangles.emplace_back(i0, i1, i2);
          mesh.triangles.emplace_back(i0, i2, i3);
        } else {
          mesh.triangles.emplace_back(i0, i2, i1);
          mesh.triangles.emplace_back(i0, i3, i2);
        }
      }
    }
  return mesh;
}

// ---------------------------------------------------------------------------------------------
// Force

double penalty_force(const ForceParams& params, double penetration, double speed_in) {
  if (!(penetration > 0)) return 0;
  return params.contact_stiffness * penetration + params.contact_damping * speed_in;
}

double cutting_speed(const ForceParams& params, const ToolParams& tool) {
  return 2 * M_PI * tool.radius * params.spindle_rpm / 60.0;
}

GrindingWrench grinding_force(const ForceParams& params, const ToolParams& tool,
                              const StepRemoval& step, double dt, const Pose& X_CT,
                              const Vec3& v_CT) {
  check_force_params(params);
  check_tool_params(tool);
  if (!(std::isfinite(dt) && dt > 0)) bad("force.dt", "a finite time step > 0 [s]", dt);
  if (!X_CT.matrix().allFinite() || !v_CT.allFinite())
    throw ArgumentError(
        "process: grinding_force: expected a finite pose and velocity, got NaN/inf");
  GrindingWrench out;
  const Vec3 p_tcp = X_CT.translation();
  const Vec3 a = (tool.axis_sign * X_CT.linear().col(2)).normalized();
  const Vec3 z_T = X_CT.linear().col(2).normalized();
  out.cutting_speed = cutting_speed(params, tool);

  // Unit vector from a point to the tool axis, perpendicular to it (into the shank when the point
  // lies on the axis: end-face contact pushes the tool back along its axis).
  auto towards_axis = [&](const Vec3& p) -> Vec3 {
    const Vec3 w = p_tcp - p;
    const Vec3 perp = w - a.dot(w) * a;
    const double len = perp.norm();
    return len > 1e-3 * tool.radius ? Vec3(perp / len) : a;
  };

  if (step.count() > 0) {
    out.removal_rate = step.volume() / dt;
    out.tangential_force = params.specific_energy * out.removal_rate / out.cutting_speed;
    const double fn = params.force_ratio * out.tangential_force;
    const Vec3 n = towards_axis(step.centroid_C);
    // Tangential: against the feed (the velocity without its normal part); a tool that does not
    // move sideways feels the reaction of a burr turning counter-clockwise about +z_T.
    Vec3 feed = v_CT - v_CT.dot(n) * n;
    Vec3 t;
    if (feed.norm() > 1e-9) {
      t = -feed.normalized();
    } else {
      t = z_T.cross(n);
      t = t.norm() > 1e-12 ? Vec3(t.normalized()) : Vec3::Zero();
    }
    const Vec3 f = fn * n + out.tangential_force * t;
    out.force_C += f;
    out.torque_C += (step.centroid_C - p_tcp).cross(f);
    out.normal_force += fn;
  }
  if (step.penetration > 0 && step.contact_count > 0) {
    const Vec3 n = towards_axis(step.contact_centroid_C);
    out.penalty_force = penalty_force(params, step.penetration, std::max(0.0, -v_CT.dot(n)));
    const Vec3 f = out.penalty_force * n;
    out.force_C += f;
    out.torque_C += (step.contact_centroid_C - p_tcp).cross(f);
    out.normal_force += out.penalty_force;
  }
  return out;
}

}  // namespace flashtwin::sim
