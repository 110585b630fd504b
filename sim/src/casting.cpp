#include "flashtwin/sim/casting.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <unordered_map>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/random.hpp"
#include "triangulate.hpp"

namespace flashtwin::sim {

using detail::Vec2;
using Loop = std::vector<Vec2>;

CastingFamily family_from_string(const std::string& s) {
  if (s == "flanged_plate") return CastingFamily::kFlangedPlate;
  if (s == "round_flange") return CastingFamily::kRoundFlange;
  if (s == "housing") return CastingFamily::kHousing;
  if (s == "cover") return CastingFamily::kCover;
  if (s == "mesh") return CastingFamily::kMesh;
  throw ArgumentError("casting.family: expected flanged_plate, round_flange, housing, cover or mesh, got '" +
                      s + "'");
}

std::string to_string(CastingFamily f) {
  switch (f) {
    case CastingFamily::kFlangedPlate: return "flanged_plate";
    case CastingFamily::kRoundFlange: return "round_flange";
    case CastingFamily::kHousing: return "housing";
    case CastingFamily::kCover: return "cover";
    case CastingFamily::kMesh: return "mesh";
  }
  return "?";
}

double Casting::flash_volume() const {
  double v = 0;
  for (const auto& f : fins) v += f.volume;
  return v;
}

TriangleMesh Casting::flash_mesh() const {
  TriangleMesh m;
  for (const auto& f : fins) m.append(f.mesh);
  return m;
}

namespace {

// ---------------------------------------------------------------- 2-D outlines (CCW)

// Segments for an arc of radius r and angle `angle` so that the chord deviates ≤ err.
int arc_segments(double r, double angle, double err) {
  const double step = 2 * std::acos(std::max(-1.0, 1 - err / r));
  return std::max(1, static_cast<int>(std::ceil(angle / step)));
}

Loop circle(const Vec2& c, double r, double err) {
  const int n = std::max(12, arc_segments(r, 2 * M_PI, err));
  Loop l;
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    l.emplace_back(c.x() + r * std::cos(a), c.y() + r * std::sin(a));
  }
  return l;
}

// Circle of radius r about the origin cut by the chord x = xf (counter-clockwise).
Loop flatted_circle(double r, double xf, double err) {
  const double a0 = std::acos(xf / r);
  const int n = std::max(12, arc_segments(r, 2 * M_PI - 2 * a0, err));
  Loop l;
  for (int i = 0; i <= n; ++i) {
    const double a = a0 + (2 * M_PI - 2 * a0) * i / n;
    l.emplace_back(r * std::cos(a), r * std::sin(a));
  }
  return l;  // the last point (xf, −…) joins the first (xf, +…) along the flat
}

Loop rounded_rect(const Vec2& c, double lx, double ly, double rc, double err) {
  Loop l;
  const int n = arc_segments(rc, M_PI / 2, err);
  const double hx = lx / 2 - rc, hy = ly / 2 - rc;
  const Vec2 centres[4] = {{hx, -hy}, {hx, hy}, {-hx, hy}, {-hx, -hy}};
  for (int k = 0; k < 4; ++k) {
    const double a0 = -M_PI / 2 + k * M_PI / 2;
    for (int i = 0; i <= n; ++i) {
      const double a = a0 + (M_PI / 2) * i / n;
      l.emplace_back(c.x() + centres[k].x() + rc * std::cos(a),
                     c.y() + centres[k].y() + rc * std::sin(a));
    }
  }
  return l;
}

Loop rect(const Vec2& c, double lx, double ly) {
  return {{c.x() - lx / 2, c.y() - ly / 2},
          {c.x() + lx / 2, c.y() - ly / 2},
          {c.x() + lx / 2, c.y() + ly / 2},
          {c.x() - lx / 2, c.y() + ly / 2}};
}

Loop reversed(Loop l) {
  std::reverse(l.begin(), l.end());
  return l;
}

double rounded_rect_area(double lx, double ly, double rc) { return lx * ly - (4 - M_PI) * rc * rc; }

// ---------------------------------------------------------------- 2.5-D solid builder

// Stacked extrusions: vertical walls along loops and horizontal caps with holes. Vertices are
// duplicated per face and welded at the end (identical coordinates by construction).
class Builder {
 public:
  // Walls of a loop with the solid on its left (CCW outer, CW hole), from z0 up to z1.
  void walls(const Loop& l, double z0, double z1) {
    for (std::size_t i = 0, n = l.size(); i < n; ++i) {
      const Vec2& a = l[i];
      const Vec2& b = l[(i + 1) % n];
      const int a0 = v(a, z0), b0 = v(b, z0), b1 = v(b, z1), a1 = v(a, z1);
      mesh_.triangles.emplace_back(a0, b0, b1);
      mesh_.triangles.emplace_back(a0, b1, a1);
    }
  }
  // Horizontal face: `outer` CCW, `holes` CCW (reversed here); normal +z when up.
  void cap(const Loop& outer, const std::vector<Loop>& holes, double z, bool up) {
    std::vector<Loop> cw;
    for (const auto& h : holes) cw.push_back(reversed(h));
    const auto tris = detail::triangulate(outer, cw);
    FT_ASSERT(!tris.empty());
    std::vector<int> idx;
    for (const auto& p : outer) idx.push_back(v(p, z));
    for (const auto& h : cw)
      for (const auto& p : h) idx.push_back(v(p, z));
    for (const auto& t : tris) {
      if (up)
        mesh_.triangles.emplace_back(idx[t[0]], idx[t[1]], idx[t[2]]);
      else
        mesh_.triangles.emplace_back(idx[t[0]], idx[t[2]], idx[t[1]]);
    }
  }
  // Surface of revolution about the vertical axis through c, solid inside: `profile` holds
  // (radius, z) from the bottom rim upwards; a last point on the axis (radius 0) closes the
  // surface there. Ring vertices lie where circle(c, r, ·) with n points puts them, so a cap
  // whose hole is that circle welds to the bottom ring.
  void revolve(const Vec2& c, const std::vector<Vec2>& profile, int n) {
    std::vector<std::vector<int>> rings;
    for (const auto& rz : profile) {
      std::vector<int> ring;
      for (int i = 0; i < n; ++i) {
        const double a = 2 * M_PI * i / n;
        ring.push_back(v({c.x() + rz.x() * std::cos(a), c.y() + rz.x() * std::sin(a)}, rz.y()));
      }
      rings.push_back(std::move(ring));
    }
    for (std::size_t k = 0; k + 1 < rings.size(); ++k) {
      const bool apex = profile[k + 1].x() == 0;
      for (int i = 0; i < n; ++i) {
        const int j = (i + 1) % n;
        mesh_.triangles.emplace_back(rings[k][i], rings[k][j], rings[k + 1][j]);
        if (!apex) mesh_.triangles.emplace_back(rings[k][i], rings[k + 1][j], rings[k + 1][i]);
      }
    }
  }
  // A plate from z = 0 to t: `outline` (CCW) with through `holes`; its top cap also leaves
  // `on_top` open, the footprints of what stands on the plate.
  void plate(const Loop& outline, const std::vector<Loop>& holes, double t, const std::vector<Loop>& on_top) {
    cap(outline, holes, 0, false);
    walls(outline, 0, t);
    for (const auto& h : holes) walls(reversed(h), 0, t);
    std::vector<Loop> top_holes = holes;
    top_holes.insert(top_holes.end(), on_top.begin(), on_top.end());
    cap(outline, top_holes, t, true);
  }
  TriangleMesh finish() {
    weld_vertices(mesh_, 1e-12);
    return std::move(mesh_);
  }

 private:
  int v(const Vec2& p, double z) {
    mesh_.vertices.emplace_back(p.x(), p.y(), z);
    return static_cast<int>(mesh_.vertices.size()) - 1;
  }
  TriangleMesh mesh_;
};

// ---------------------------------------------------------------- families

struct Family {
  TriangleMesh mesh;
  double analytic_volume = 0;
  double parting_height = 0;
  std::string description;
};

std::string mm(double v) {
  char b[32];
  std::snprintf(b, sizeof b, "%.1f", v * 1000);
  return b;
}

Family flanged_plate(Rng& rng, double err) {
  const double L = rng.uniform(0.16, 0.34);
  const double W = rng.uniform(0.10, std::min(0.22, 0.75 * L));
  const double T = rng.uniform(0.012, 0.025);
  const double rc = rng.uniform(0.008, 0.025);
  const double rh = rng.uniform(0.0045, 0.008);
  const double inset = std::max(rc, 2.4 * rh);
  const double hr = rng.uniform(0.012, 0.035), wr = rng.uniform(0.006, 0.012);
  // Ribs off-centre and a fifth hole on one side: real castings carry datum features, and a
  // part without symmetry has one registration answer.
  const double yr1 = 0.2 * W, yr2 = -0.06 * W;
  const double Lr = L - 2 * inset - 2 * rh - 0.01;

  const Loop outline = rounded_rect({0, 0}, L, W, rc, err);
  std::vector<Loop> holes;
  for (int sx = -1; sx <= 1; sx += 2)
    for (int sy = -1; sy <= 1; sy += 2)
      holes.push_back(circle({sx * (L / 2 - inset), sy * (W / 2 - inset)}, rh, err));
  holes.push_back(circle({L / 2 - inset, 0}, rh, err));
  std::vector<Loop> ribs = {rect({0, yr1}, Lr, wr), rect({0, yr2}, Lr, wr)};

  Builder b;
  b.plate(outline, holes, T, ribs);
  for (const auto& r : ribs) {
    b.walls(r, T, T + hr);
    b.cap(r, {}, T + hr, true);
  }
  Family f;
  f.mesh = b.finish();
  f.analytic_volume = (rounded_rect_area(L, W, rc) - 5 * M_PI * rh * rh) * T + 2 * Lr * wr * hr;
  f.parting_height = T / 2;
  f.description = "flanged plate " + mm(L) + " x " + mm(W) + " x " + mm(T) + " mm, 5 bolt holes d" +
                  mm(2 * rh) + ", 2 ribs " + mm(wr) + " x " + mm(hr) + " mm";
  return f;
}

Family round_flange(Rng& rng, double err) {
  const double R = rng.uniform(0.06, 0.2);
  const double T = rng.uniform(0.014, 0.03);
  const double Rh = rng.uniform(0.3, 0.45) * R;
  const double Rb = rng.uniform(0.5, 0.7) * Rh;
  const double Hh = rng.uniform(0.02, 0.05);
  const int nb = R < 0.09 ? 4 : (R < 0.14 ? 6 : 8);
  const double Rc = (R + Rh) / 2;
  // Bolt holes must clear the rim, the hub and each other by 4 mm.
  const double rb_max = std::min({R - Rc - 0.004, Rc - Rh - 0.004, Rc * std::sin(M_PI / nb) - 0.004});
  const double rb = std::min(rng.uniform(0.005, 0.011), rb_max);
  FT_ASSERT(rb > 0.002);

  // A flat on the rim (a datum, as on real flanges) breaks the rotational symmetry.
  const double xf = 0.92 * R;
  const Loop disc = flatted_circle(R, xf, err), hub = circle({0, 0}, Rh, err),
             bore = circle({0, 0}, Rb, err);
  std::vector<Loop> bolts;
  for (int i = 0; i < nb; ++i) {
    const double a = 2 * M_PI * (i + 0.5) / nb;
    bolts.push_back(circle({Rc * std::cos(a), Rc * std::sin(a)}, rb, err));
  }
  Builder b;
  std::vector<Loop> bottom_holes = bolts;
  bottom_holes.push_back(bore);
  b.cap(disc, bottom_holes, 0, false);
  b.walls(disc, 0, T);
  for (const auto& h : bolts) b.walls(reversed(h), 0, T);
  b.walls(reversed(bore), 0, T + Hh);
  std::vector<Loop> top_holes = bolts;
  top_holes.push_back(hub);
  b.cap(disc, top_holes, T, true);
  b.walls(hub, T, T + Hh);
  b.cap(hub, {bore}, T + Hh, true);
  Family f;
  f.mesh = b.finish();
  const double segment = R * R * std::acos(xf / R) - xf * std::sqrt(R * R - xf * xf);
  f.analytic_volume =
      (M_PI * (R * R - Rb * Rb - nb * rb * rb) - segment) * T + M_PI * (Rh * Rh - Rb * Rb) * Hh;
  f.parting_height = T / 2;
  f.description = "round flange d" + mm(2 * R) + " x " + mm(T) + " mm with a flat, hub d" + mm(2 * Rh) + " x " +
                  mm(Hh) + " mm, bore d" + mm(2 * Rb) + ", " + std::to_string(nb) +
                  " bolt holes d" + mm(2 * rb);
  return f;
}

Family housing(Rng& rng, double err) {
  const double L = rng.uniform(0.18, 0.36);
  const double W = rng.uniform(0.12, std::min(0.26, 0.8 * L));
  const double Tb = rng.uniform(0.010, 0.018);
  const double rc = rng.uniform(0.008, 0.02);
  const double rh = rng.uniform(0.0045, 0.007);
  const double m = 2 * rh + 0.012;  // flange margin around the walls
  const double tw = rng.uniform(0.006, 0.012);
  const double Hw = rng.uniform(0.03, 0.08);
  const double rc2 = tw + rng.uniform(0.004, 0.012);
  // The walls sit off-centre on the flange (a wider mounting margin on one side), so the part
  // has no rotational symmetry.
  const double extra = rng.uniform(0.02, 0.045);
  const double Lo = L - 2 * m - extra, Wo = W - 2 * m;
  const Vec2 wc(extra / 2, 0);

  const Loop outline = rounded_rect({0, 0}, L, W, rc, err);
  const Loop outer = rounded_rect(wc, Lo, Wo, rc2, err);
  const Loop inner = rounded_rect(wc, Lo - 2 * tw, Wo - 2 * tw, rc2 - tw, err);
  std::vector<Loop> holes;
  for (int sx = -1; sx <= 1; sx += 2)
    for (int sy = -1; sy <= 1; sy += 2)
      holes.push_back(circle({sx * (L / 2 - m / 2), sy * (W / 2 - m / 2)}, rh, err));
  for (int sy = -1; sy <= 1; sy += 2) holes.push_back(circle({0, sy * (W / 2 - m / 2)}, rh, err));

  Builder b;
  b.plate(outline, holes, Tb, {outer});
  b.cap(inner, {}, Tb, true);  // pocket floor
  b.walls(outer, Tb, Tb + Hw);
  b.walls(reversed(inner), Tb, Tb + Hw);
  b.cap(outer, {inner}, Tb + Hw, true);
  Family f;
  f.mesh = b.finish();
  f.analytic_volume = (rounded_rect_area(L, W, rc) - 6 * M_PI * rh * rh) * Tb +
                      (rounded_rect_area(Lo, Wo, rc2) -
                       rounded_rect_area(Lo - 2 * tw, Wo - 2 * tw, rc2 - tw)) *
                          Hw;
  f.parting_height = Tb / 2;
  f.description = "housing " + mm(L) + " x " + mm(W) + " mm flange " + mm(Tb) + " mm, walls " +
                  mm(tw) + " x " + mm(Hw) + " mm, 6 bolt holes d" + mm(2 * rh);
  return f;
}

// A pump or gearbox cover: a rounded-rectangle flange with six bolt holes carrying, off-centre,
// a round body as foundries make it: a concave fillet at the flange, a drafted wall (1-3°, the
// draft that lets the pattern leave the sand) and a spherical dome. The parting plane runs
// across the dome, so the parting-line fin stands on a curved, sloped wall.
Family cover(Rng& rng, double err) {
  const double L = rng.uniform(0.2, 0.34);
  const double W = rng.uniform(0.65, 0.85) * L;
  const double T = rng.uniform(0.012, 0.02);
  const double rc = rng.uniform(0.01, 0.025);
  const double rh = rng.uniform(0.0045, 0.007);
  const double m = rh + 0.008;  // bolt-hole centre to flange edge
  // The body stands off-centre along x (no half-turn symmetry) and clears the bolt holes at the
  // flange's ends and the long edges by 4 mm (fillet included).
  const double dx = (rng.uniform(0, 1) < 0.5 ? -1 : 1) * rng.uniform(0.04, 0.1) * L;
  const double rf = rng.uniform(0.003, 0.006);  // fillet radius
  const double base_max = std::min(L / 2 - m - std::abs(dx) - rh - 0.004, W / 2 - 0.006);
  const double Rb = rng.uniform(0.7, 1.0) * base_max - rf;  // wall radius at the fillet's top
  FT_ASSERT(Rb > 0.02);
  const double draft = rng.uniform(1.0, 3.0) * M_PI / 180;
  const double Hw = rng.uniform(0.01, 0.03);  // drafted wall height
  const double R1 = Rb - Hw * std::tan(draft);
  const double Hd = rng.uniform(0.35, 0.8) * R1;  // dome height
  const double Rs = (R1 * R1 + Hd * Hd) / (2 * Hd);  // dome sphere radius
  const double z0 = T + rf, z1 = z0 + Hw, zc = z1 + Hd - Rs;  // wall foot, dome foot, sphere centre

  // Profile (radius, z) from the fillet's foot on the flange up to the dome's apex.
  std::vector<Vec2> profile;
  const int nf = arc_segments(rf, M_PI / 2, err);
  for (int i = 0; i <= nf; ++i) {  // concave quarter circle about (Rb + rf, T + rf)
    const double a = -M_PI / 2 - (M_PI / 2) * i / nf;
    profile.emplace_back(Rb + rf + rf * std::cos(a), T + rf + rf * std::sin(a));
  }
  profile.front() = {Rb + rf, T};  // exactly on the foot circle of the flange's top cap
  profile.back() = {Rb, z0};
  profile.emplace_back(R1, z1);  // the drafted wall: a cone
  const double phi1 = std::asin(R1 / Rs);
  const int nd = arc_segments(Rs, phi1, err);
  for (int i = 1; i <= nd; ++i) {
    const double phi = phi1 * (1 - double(i) / nd);
    profile.emplace_back(Rs * std::sin(phi), zc + Rs * std::cos(phi));
  }
  profile.back() = {0, z1 + Hd};

  const Vec2 bc(dx, 0);
  const Loop outline = rounded_rect({0, 0}, L, W, rc, err);
  const Loop foot = circle(bc, Rb + rf, err);
  std::vector<Loop> holes;
  for (int sx = -1; sx <= 1; sx += 2) {
    for (int sy = -1; sy <= 1; sy += 2) holes.push_back(circle({sx * (L / 2 - m), sy * (W / 2 - m)}, rh, err));
    holes.push_back(circle({sx * (L / 2 - m), 0}, rh, err));
  }
  Builder b;
  b.plate(outline, holes, T, {foot});
  b.revolve(bc, profile, static_cast<int>(foot.size()));
  Family f;
  f.mesh = b.finish();
  // Volume: the flange, the fillet ring (Simpson's rule over z of π r(z)²), the cone frustum and
  // the spherical cap.
  double fillet = 0;
  const int ns = 2000;
  for (int i = 0; i <= ns; ++i) {
    const double u = double(i) / ns, z = rf * u;  // height above the flange
    const double r = Rb + rf - std::sqrt(std::max(0.0, rf * rf - (z - rf) * (z - rf)));
    const double w = (i == 0 || i == ns) ? 1 : (i % 2 ? 4 : 2);
    fillet += w * M_PI * r * r;
  }
  fillet *= rf / ns / 3;
  f.analytic_volume = (rounded_rect_area(L, W, rc) - 6 * M_PI * rh * rh) * T + fillet +
                      M_PI * Hw * (Rb * Rb + Rb * R1 + R1 * R1) / 3 + M_PI * Hd * Hd * (3 * Rs - Hd) / 3;
  // Across the dome, where its wall slopes 20-60° off the vertical.
  f.parting_height = z1 + rng.uniform(0.15, 0.5) * Hd;
  char deg[16];
  std::snprintf(deg, sizeof deg, "%.1f", draft * 180 / M_PI);
  f.description = "cover " + mm(L) + " x " + mm(W) + " x " + mm(T) + " mm flange, 6 bolt holes d" + mm(2 * rh) +
                  ", body d" + mm(2 * Rb) + " (fillet r" + mm(rf) + ", wall " + mm(Hw) + " mm at " + std::string(deg) +
                  "° draft, dome " + mm(Hd) + " mm high)";
  return f;
}

}  // namespace

// ---------------------------------------------------------------- slicing

std::vector<std::vector<Vec3>> slice_mesh(const TriangleMesh& mesh, double height) {
  // Keep the plane off the vertices so every crossing is a proper edge crossing.
  double h = height;
  for (int attempt = 0; attempt < 8; ++attempt) {
    bool on_vertex = false;
    for (const auto& v : mesh.vertices)
      if (std::abs(v.z() - h) < 1e-10) {
        on_vertex = true;
        break;
      }
    if (!on_vertex) break;
    h += 1e-9;
  }
  auto key = [](int a, int b) {
    return (static_cast<std::uint64_t>(std::min(a, b)) << 32) | static_cast<std::uint32_t>(std::max(a, b));
  };
  auto crossing = [&](int a, int b) {
    if (a > b) std::swap(a, b);  // same point from both triangles sharing the edge
    const Vec3& pa = mesh.vertices[a];
    const Vec3& pb = mesh.vertices[b];
    const double t = (h - pa.z()) / (pb.z() - pa.z());
    Vec3 p = pa + t * (pb - pa);
    p.z() = h;
    return p;
  };
  // Segment from edge key → (end edge key, start point).
  std::unordered_map<std::uint64_t, std::pair<std::uint64_t, Vec3>> next;
  for (std::size_t t = 0; t < mesh.triangles.size(); ++t) {
    const auto& f = mesh.triangles[t];
    std::vector<std::pair<std::uint64_t, Vec3>> hits;
    for (int k = 0; k < 3; ++k) {
      const int a = f[k], b = f[(k + 1) % 3];
      const bool sa = mesh.vertices[a].z() > h, sb = mesh.vertices[b].z() > h;
      if (sa != sb) hits.emplace_back(key(a, b), crossing(a, b));
    }
    if (hits.size() != 2) continue;
    // Solid on the left: direction along z × (outward normal).
    const Vec3 n = mesh.triangle_normal(t);
    const Vec3 d = Vec3::UnitZ().cross(n);
    if ((hits[1].second - hits[0].second).dot(d) < 0) std::swap(hits[0], hits[1]);
    next[hits[0].first] = {hits[1].first, hits[0].second};
  }
  std::vector<std::vector<Vec3>> loops;
  std::unordered_map<std::uint64_t, bool> used;
  // Deterministic order: start from the smallest unused key.
  std::vector<std::uint64_t> keys;
  for (const auto& kv : next) keys.push_back(kv.first);
  std::sort(keys.begin(), keys.end());
  for (std::uint64_t start : keys) {
    if (used[start]) continue;
    std::vector<Vec3> loop;
    std::uint64_t k = start;
    while (!used[k]) {
      used[k] = true;
      const auto it = next.find(k);
      if (it == next.end()) break;
      loop.push_back(it->second.second);
      k = it->second.first;
    }
    if (k == start && loop.size() >= 3) loops.push_back(std::move(loop));
  }
  return loops;
}

// ---------------------------------------------------------------- flashes

namespace {

double loop_area_xy(const std::vector<Vec3>& l) {
  double a = 0;
  for (std::size_t i = 0, n = l.size(); i < n; ++i)
    a += l[i].x() * l[(i + 1) % n].y() - l[(i + 1) % n].x() * l[i].y();
  return a / 2;
}

// Root samples along a closed loop: every loop vertex plus points at most `spacing` apart, each
// with its in-plane outward normal (right of the direction of travel) and arc length.
struct RootSample {
  Vec3 p;
  Vec3 n;
  double s;
};

std::vector<RootSample> sample_loop(const std::vector<Vec3>& loop, double spacing) {
  std::vector<RootSample> out;
  const std::size_t n = loop.size();
  auto seg_normal = [&](std::size_t i) {
    const Vec3 d = loop[(i + 1) % n] - loop[i];
    Vec3 r(d.y(), -d.x(), 0);
    const double len = r.norm();
    return len > 0 ? Vec3(r / len) : Vec3::Zero();
  };
  double s = 0;
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3& a = loop[i];
    const Vec3& b = loop[(i + 1) % n];
    const double len = (b - a).norm();
    const int pieces = std::max(1, static_cast<int>(std::ceil(len / spacing)));
    Vec3 nv = seg_normal((i + n - 1) % n) + seg_normal(i);
    nv = nv.norm() > 1e-12 ? Vec3(nv.normalized()) : seg_normal(i);
    out.push_back({a, nv, s});
    for (int k = 1; k < pieces; ++k)
      out.push_back({a + (b - a) * (double(k) / pieces), seg_normal(i), s + len * k / pieces});
    s += len;
  }
  return out;
}

// Smooth random profile in [0, 1] along arc length (two sinusoids with random phases).
struct Profile {
  double p1, p2, phi1, phi2, phi3, lambda;
  double base(double s) const { return 0.5 + 0.5 * std::sin(2 * M_PI * s / p1 + phi1) * std::cos(2 * M_PI * s / p2 + phi2); }
  double wave(double s) const {
    return 0.65 * std::sin(2 * M_PI * s / lambda + phi3) + 0.35 * std::sin(2 * M_PI * s / (0.37 * lambda) + 2 * phi3);
  }
};

// A closed ribbon (the fin) along root samples [i0, i1] (inclusive; wraps when closed).
TriangleMesh ribbon(const std::vector<RootSample>& r, const std::vector<double>& height,
                    double t_root, double t_tip, bool closed) {
  TriangleMesh m;
  const std::size_t n = r.size();
  const Vec3 z = Vec3::UnitZ();
  for (std::size_t i = 0; i < n; ++i) {
    const Vec3 tip = r[i].p + height[i] * r[i].n;
    m.vertices.push_back(r[i].p + 0.5 * t_root * z);  // A: root top
    m.vertices.push_back(r[i].p - 0.5 * t_root * z);  // B: root bottom
    m.vertices.push_back(tip + 0.5 * t_tip * z);      // C: tip top
    m.vertices.push_back(tip - 0.5 * t_tip * z);      // D: tip bottom
  }
  auto A = [](std::size_t i) { return static_cast<int>(4 * i); };
  auto B = [](std::size_t i) { return static_cast<int>(4 * i + 1); };
  auto C = [](std::size_t i) { return static_cast<int>(4 * i + 2); };
  auto D = [](std::size_t i) { return static_cast<int>(4 * i + 3); };
  const std::size_t segs = closed ? n : n - 1;
  for (std::size_t i = 0; i < segs; ++i) {
    const std::size_t j = (i + 1) % n;
    m.triangles.emplace_back(A(i), C(i), A(j));  // top
    m.triangles.emplace_back(A(j), C(i), C(j));
    m.triangles.emplace_back(B(i), B(j), D(i));  // bottom
    m.triangles.emplace_back(B(j), D(j), D(i));
    m.triangles.emplace_back(C(i), D(i), D(j));  // outer edge
    m.triangles.emplace_back(C(i), D(j), C(j));
    m.triangles.emplace_back(A(i), B(j), B(i));  // root face, on the casting wall
    m.triangles.emplace_back(A(i), A(j), B(j));
  }
  if (!closed) {
    m.triangles.emplace_back(A(0), B(0), D(0));
    m.triangles.emplace_back(A(0), D(0), C(0));
    const std::size_t e = n - 1;
    m.triangles.emplace_back(A(e), D(e), B(e));
    m.triangles.emplace_back(A(e), C(e), D(e));
  }
  return m;
}

Fin make_fin(const std::string& kind, const std::vector<RootSample>& r, const Profile& prof,
             double h_lo, double h_hi, double amp, double t_root, bool closed) {
  std::vector<double> h(r.size());
  const double taper = 0.003;  // [m] fins thin out towards a gap
  const double s0 = r.front().s, s1 = r.back().s;
  for (std::size_t i = 0; i < r.size(); ++i) {
    const double s = r[i].s;
    // Slowly varying height with a wavy edge, kept within [h_lo, h_hi].
    const double u = std::clamp(prof.base(s) * (1 + amp * prof.wave(s)), 0.0, 1.0);
    double v = h_lo + (h_hi - h_lo) * u;
    if (!closed) {
      const double e = std::min(s - s0, s1 - s) / taper;
      if (e < 1) v *= 0.25 + 0.75 * e;
    }
    h[i] = v;
  }
  Fin f;
  f.kind = kind;
  f.mesh = ribbon(r, h, t_root, 0.6 * t_root, closed);
  f.volume = f.mesh.volume();
  f.closed = closed;
  f.thickness = t_root;
  f.max_height = *std::max_element(h.begin(), h.end());
  for (const auto& s : r) f.root.push_back(s.p);
  return f;
}

std::vector<Fin> make_fins(const TriangleMesh& nominal, double z_p, const FlashParams& fp, Rng& rng) {
  std::vector<Fin> fins;
  auto loops = slice_mesh(nominal, z_p);
  // The parting line runs along the largest outer boundary of the section.
  int outline = -1;
  double best = 0;
  for (std::size_t i = 0; i < loops.size(); ++i) {
    const double a = loop_area_xy(loops[i]);
    if (a > best) {
      best = a;
      outline = static_cast<int>(i);
    }
  }
  auto new_profile = [&](double perimeter) {
    Profile p;
    p.p1 = perimeter / rng.uniform(1.0, 3.0);
    p.p2 = perimeter / rng.uniform(0.5, 1.5);
    p.phi1 = rng.uniform(0, 2 * M_PI);
    p.phi2 = rng.uniform(0, 2 * M_PI);
    p.phi3 = rng.uniform(0, 2 * M_PI);
    p.lambda = fp.wave_length * rng.uniform(0.7, 1.3);
    return p;
  };
  if (fp.parting_line && outline >= 0) {
    const auto samples = sample_loop(loops[outline], fp.root_spacing);
    const double perimeter = samples.back().s + (loops[outline].front() - loops[outline].back()).norm();
    const Profile prof = new_profile(perimeter);
    const double t = rng.uniform(fp.thickness_min, fp.thickness_max);
    // Gaps: random arc-length intervals without flash.
    std::vector<std::pair<double, double>> gaps;
    // One gap per equal share of the perimeter, so gaps never overlap.
    for (int g = 0; g < fp.gaps; ++g) {
      const double share = perimeter / fp.gaps;
      const double len = std::min(rng.uniform(0.3, 1.0) * fp.gap_length_max, 0.5 * share);
      const double at = share * (g + rng.uniform(0.05, 0.45));
      gaps.emplace_back(at, at + len);
    }
    auto in_gap = [&](double s) {
      for (const auto& [a, b] : gaps)
        if ((s >= a && s <= b) || (s + perimeter >= a && s + perimeter <= b)) return true;
      return false;
    };
    if (gaps.empty()) {
      fins.push_back(make_fin("parting_line", samples, prof, fp.height_min, fp.height_max,
                              fp.wave_amplitude, t, true));
    } else {
      // Start the walk inside a gap so every flash run is contiguous.
      std::size_t start = 0;
      while (start < samples.size() && !in_gap(samples[start].s)) ++start;
      std::vector<RootSample> run;
      for (std::size_t k = 0; k <= samples.size(); ++k) {
        const RootSample& smp = samples[(start + k) % samples.size()];
        RootSample unwrapped = smp;
        if (start + k >= samples.size()) unwrapped.s += perimeter;
        const bool flash = !in_gap(smp.s) && k < samples.size();
        if (flash) run.push_back(unwrapped);
        if ((!flash || k == samples.size()) && run.size() >= 4) {
          fins.push_back(make_fin("parting_line", run, prof, fp.height_min, fp.height_max,
                                  fp.wave_amplitude, t, false));
        }
        if (!flash) run.clear();
      }
    }
  }
  if (fp.holes) {
    for (std::size_t i = 0; i < loops.size(); ++i) {
      const double a = loop_area_xy(loops[i]);
      if (a >= 0) continue;  // outer boundaries
      const double r = std::sqrt(-a / M_PI);
      if (r < fp.min_hole_radius) continue;
      const auto samples = sample_loop(loops[i], fp.root_spacing);
      const Profile prof = new_profile(2 * M_PI * r);
      const double t = rng.uniform(fp.thickness_min, fp.thickness_max);
      const double h_hi = std::min(fp.hole_height_max, 0.4 * r);
      fins.push_back(make_fin("hole", samples, prof, std::min(fp.height_min, 0.5 * h_hi), h_hi,
                              fp.wave_amplitude, t, true));
    }
  }
  return fins;
}

void check_flash_params(const FlashParams& fp) {
  auto bad = [](const std::string& f, const std::string& exp, double v) {
    throw ArgumentError("casting.flash." + f + ": expected " + exp + ", got " + std::to_string(v));
  };
  if (!(fp.thickness_min > 0) || fp.thickness_max < fp.thickness_min)
    bad("thickness_min", "0 < thickness_min <= thickness_max", fp.thickness_min);
  if (!(fp.height_min > 0) || fp.height_max < fp.height_min)
    bad("height_min", "0 < height_min <= height_max", fp.height_min);
  if (!(fp.hole_height_max > 0)) bad("hole_height_max", "a positive height", fp.hole_height_max);
  if (fp.wave_amplitude < 0 || fp.wave_amplitude > 0.9)
    bad("wave_amplitude", "a value in [0, 0.9]", fp.wave_amplitude);
  if (!(fp.wave_length > 0)) bad("wave_length", "a positive length", fp.wave_length);
  if (fp.gaps < 0) bad("gaps", "a count >= 0", fp.gaps);
  if (!(fp.root_spacing > 1e-5 && fp.root_spacing < 0.01))
    bad("root_spacing", "a spacing in (0.01, 10) mm", fp.root_spacing);
}

}  // namespace

Casting make_casting(const CastingParams& params) {
  check_flash_params(params.flash);
  if (!(params.chordal_error > 0 && params.chordal_error <= 5e-5))
    throw ArgumentError("casting.chordal_error: expected (0, 0.05] mm, got " +
                        std::to_string(params.chordal_error * 1000) + " mm");
  Rng rng(params.seed);
  Casting c;
  c.family = params.family;
  Family f;
  switch (params.family) {
    case CastingFamily::kFlangedPlate: f = flanged_plate(rng, params.chordal_error); break;
    case CastingFamily::kRoundFlange: f = round_flange(rng, params.chordal_error); break;
    case CastingFamily::kHousing: f = housing(rng, params.chordal_error); break;
    case CastingFamily::kCover: f = cover(rng, params.chordal_error); break;
    case CastingFamily::kMesh: {
      if (params.mesh_path.empty())
        throw ArgumentError("casting.mesh: expected a mesh file for family 'mesh', got none");
      f.mesh = load_mesh(params.mesh_path, params.mesh_scale);
      MeshCheck chk = check_mesh(f.mesh);
      if (!chk.consistently_oriented() || f.mesh.volume() < 0) orient_consistently(f.mesh);
      chk = check_mesh(f.mesh);
      if (chk.boundary_edges > 0)
        throw InputError(params.mesh_path + ": expected a closed surface, got " +
                         std::to_string(chk.boundary_edges) + " boundary edges (holes in the mesh)");
      if (chk.nonmanifold_edges > 0)
        throw InputError(params.mesh_path + ": expected a manifold surface, got " +
                         std::to_string(chk.nonmanifold_edges) + " edges shared by > 2 triangles");
      if (!chk.consistently_oriented())
        throw InputError(params.mesh_path + ": expected an orientable surface, got " +
                         std::to_string(chk.inconsistent_edges) + " inconsistent edges");
      // Casting frame: footprint centred on the origin, resting on z = 0.
      Vec3 lo, hi;
      f.mesh.bounds(lo, hi);
      const Vec3 ext = hi - lo;
      if (ext.maxCoeff() < 0.02 || ext.maxCoeff() > 2.0)
        throw InputError(params.mesh_path + ": expected a part 20 mm to 2 m across (check " +
                         "casting.scale), got " + std::to_string(ext.maxCoeff()) + " m");
      Pose X = Pose::Identity();
      X.translation() = Vec3(-(lo.x() + hi.x()) / 2, -(lo.y() + hi.y()) / 2, -lo.z());
      f.mesh = f.mesh.transformed(X);
      f.parting_height = ext.z() / 2;
      f.description = "user mesh " + params.mesh_path;
      break;
    }
  }
  c.nominal = std::move(f.mesh);
  c.analytic_volume = f.analytic_volume;
  c.description = f.description;
  c.parting_height = params.flash.parting_height >= 0 ? params.flash.parting_height : f.parting_height;
  Vec3 lo, hi;
  c.nominal.bounds(lo, hi);
  c.size = hi - lo;
  if (c.parting_height <= lo.z() || c.parting_height >= hi.z())
    throw ArgumentError("casting.flash.parting_height: expected a height inside the part (0, " +
                        std::to_string(hi.z()) + ") m, got " + std::to_string(c.parting_height));
  // Flashes get their own random stream so that their parameters do not shift the part's.
  Rng flash_rng(params.seed * 0x9E3779B97F4A7C15ULL + 17);
  c.fins = make_fins(c.nominal, c.parting_height, params.flash, flash_rng);
  return c;
}

struct FlashLabeler::Impl {
  MeshBvh nominal;
  std::unique_ptr<MeshBvh> fins;
  explicit Impl(const Casting& c) : nominal(c.nominal) {
    const TriangleMesh f = c.flash_mesh();
    if (!f.triangles.empty()) fins = std::make_unique<MeshBvh>(f);
  }
};

FlashLabeler::FlashLabeler(const Casting& casting) : impl_(std::make_unique<Impl>(casting)) {}
FlashLabeler::~FlashLabeler() = default;

bool FlashLabeler::is_flash(const Vec3& p_C) const {
  if (!impl_->fins) return false;
  const double dn = impl_->nominal.closest(p_C).distance;
  return impl_->fins->closest(p_C, dn).distance < dn;
}

double FlashLabeler::distance_to_nominal(const Vec3& p_C) const {
  return impl_->nominal.closest(p_C).distance;
}

}  // namespace flashtwin::sim
