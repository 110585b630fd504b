#include "triangulate.hpp"

#include <algorithm>
#include <cmath>
#include <limits>

namespace flashtwin::sim::detail {

double signed_area(const std::vector<Vec2>& loop) {
  double a = 0;
  for (std::size_t i = 0, n = loop.size(); i < n; ++i) {
    const Vec2& p = loop[i];
    const Vec2& q = loop[(i + 1) % n];
    a += p.x() * q.y() - q.x() * p.y();
  }
  return a / 2;
}

namespace {

double cross(const Vec2& o, const Vec2& a, const Vec2& b) {
  return (a.x() - o.x()) * (b.y() - o.y()) - (a.y() - o.y()) * (b.x() - o.x());
}

bool point_in_triangle(const Vec2& p, const Vec2& a, const Vec2& b, const Vec2& c) {
  // Closed triangle test; points equal to a corner do not count (bridge duplicates).
  if (p == a || p == b || p == c) return false;
  return cross(a, b, p) >= 0 && cross(b, c, p) >= 0 && cross(c, a, p) >= 0;
}

// Does segment p-q properly cross segment a-b (touching endpoints excluded)?
bool segments_cross(const Vec2& p, const Vec2& q, const Vec2& a, const Vec2& b) {
  const double d1 = cross(p, q, a), d2 = cross(p, q, b), d3 = cross(a, b, p), d4 = cross(a, b, q);
  return ((d1 > 0 && d2 < 0) || (d1 < 0 && d2 > 0)) && ((d3 > 0 && d4 < 0) || (d3 < 0 && d4 > 0));
}

// Is q strictly inside the angle at vertex b of a boundary a → b → c with the region on its
// left (works for convex and reflex b)?
bool in_wedge(const Vec2& a, const Vec2& b, const Vec2& c, const Vec2& q) {
  const bool convex = cross(a, b, c) >= 0;
  return convex ? (cross(a, b, q) > 0 && cross(b, c, q) > 0)
                : !(cross(a, b, q) <= 0 && cross(b, c, q) <= 0);
}

bool on_segment(const Vec2& q, const Vec2& a, const Vec2& b) {
  const double len2 = (b - a).squaredNorm();
  if (len2 == 0) return false;
  const double t = (q - a).dot(b - a) / len2;
  if (t <= 0 || t >= 1) return false;
  return std::abs(cross(a, b, q)) <= 1e-12 * len2;
}

}  // namespace

std::vector<std::array<int, 3>> triangulate(const std::vector<Vec2>& outer,
                                            const std::vector<std::vector<Vec2>>& holes) {
  std::vector<Vec2> pts(outer);
  std::vector<int> ring(outer.size());
  for (std::size_t i = 0; i < outer.size(); ++i) ring[i] = static_cast<int>(i);
  std::vector<std::vector<int>> hole_idx;
  for (const auto& h : holes) {
    std::vector<int> idx;
    for (const auto& p : h) {
      idx.push_back(static_cast<int>(pts.size()));
      pts.push_back(p);
    }
    hole_idx.push_back(idx);
  }
  // Bridge holes in order of decreasing rightmost x: from the hole's rightmost vertex to the
  // nearest ring vertex whose connecting segment crosses no edge (ring or remaining holes).
  std::vector<int> order(holes.size());
  for (std::size_t i = 0; i < order.size(); ++i) order[i] = static_cast<int>(i);
  auto max_x = [&](int h) {
    double m = -std::numeric_limits<double>::infinity();
    for (int i : hole_idx[h]) m = std::max(m, pts[i].x());
    return m;
  };
  std::sort(order.begin(), order.end(), [&](int a, int b) { return max_x(a) > max_x(b); });
  std::vector<bool> bridged(holes.size(), false);
  for (int h : order) {
    const auto& hi = hole_idx[h];
    int m = 0;
    for (std::size_t k = 1; k < hi.size(); ++k)
      if (pts[hi[k]].x() > pts[hi[m]].x()) m = static_cast<int>(k);
    const Vec2 M = pts[hi[m]];
    // Candidate ring positions sorted by distance to M.
    std::vector<int> cand(ring.size());
    for (std::size_t k = 0; k < ring.size(); ++k) cand[k] = static_cast<int>(k);
    std::sort(cand.begin(), cand.end(), [&](int a, int b) {
      return (pts[ring[a]] - M).squaredNorm() < (pts[ring[b]] - M).squaredNorm();
    });
    int chosen = -1;
    for (int k : cand) {
      const Vec2 P = pts[ring[k]];
      bool blocked = false;
      for (std::size_t e = 0; e < ring.size() && !blocked; ++e)
        blocked = segments_cross(M, P, pts[ring[e]], pts[ring[(e + 1) % ring.size()]]);
      for (std::size_t o = 0; o < holes.size() && !blocked; ++o) {
        if (bridged[o]) continue;
        const auto& oi = hole_idx[o];
        for (std::size_t e = 0; e < oi.size() && !blocked; ++e)
          blocked = segments_cross(M, P, pts[oi[e]], pts[oi[(e + 1) % oi.size()]]);
      }
      // The bridge must leave P into the polygon interior (M inside the ring's angle at P)
      // and leave M away from the hole (P inside the hole boundary's solid-side angle at M).
      if (!blocked) {
        const Vec2 prev = pts[ring[(k + ring.size() - 1) % ring.size()]];
        const Vec2 next = pts[ring[(k + 1) % ring.size()]];
        const Vec2 hprev = pts[hi[(m + hi.size() - 1) % hi.size()]];
        const Vec2 hnext = pts[hi[(m + 1) % hi.size()]];
        blocked = !in_wedge(prev, P, next, M) || !in_wedge(hprev, M, hnext, P);
      }
      // A bridge through a vertex (collinear touch) is no proper crossing but still invalid.
      for (std::size_t q = 0; q < pts.size() && !blocked; ++q) {
        if (pts[q] == M || pts[q] == P) continue;
        blocked = on_segment(pts[q], M, P);
      }
      if (!blocked) {
        chosen = k;
        break;
      }
    }
    if (chosen < 0) return {};
    // Splice: ... P, M, hole..., M, P, ...
    std::vector<int> splice;
    for (std::size_t k = 0; k <= hi.size(); ++k) splice.push_back(hi[(m + k) % hi.size()]);
    splice.push_back(ring[chosen]);
    ring.insert(ring.begin() + chosen + 1, splice.begin(), splice.end());
    bridged[h] = true;
  }

  // Ear clipping on the single ring.
  std::vector<std::array<int, 3>> tris;
  std::vector<int> poly = ring;
  std::size_t guard = 0, start = 0;
  while (poly.size() > 3 && guard < 4 * ring.size() * ring.size() + 16) {
    bool clipped = false;
    const std::size_t n = poly.size();
    // Resume where the last ear was cut: keeps the whole clipping near O(n²).
    for (std::size_t step = 0; step < n; ++step, ++guard) {
      const std::size_t i = (start + step) % n;
      const int ia = poly[(i + n - 1) % n], ib = poly[i], ic = poly[(i + 1) % n];
      const Vec2 &a = pts[ia], &b = pts[ib], &c = pts[ic];
      if (cross(a, b, c) <= 0) continue;  // reflex or degenerate
      bool ear = true;
      for (std::size_t k = 0; k < n && ear; ++k) {
        const int ip = poly[k];
        if (ip == ia || ip == ib || ip == ic) continue;
        if (point_in_triangle(pts[ip], a, b, c)) ear = false;
      }
      if (!ear) continue;
      tris.push_back({ia, ib, ic});
      poly.erase(poly.begin() + static_cast<long>(i));
      start = i == 0 ? 0 : i - 1;
      clipped = true;
      break;
    }
    if (!clipped) {
      // Only collinear leftovers: drop a zero-area vertex, else give up.
      bool dropped = false;
      for (std::size_t i = 0; i < poly.size(); ++i) {
        const std::size_t n2 = poly.size();
        if (std::abs(cross(pts[poly[(i + n2 - 1) % n2]], pts[poly[i]], pts[poly[(i + 1) % n2]])) <
            1e-18) {
          poly.erase(poly.begin() + static_cast<long>(i));
          dropped = true;
          break;
        }
      }
      if (!dropped) return {};
    }
  }
  if (poly.size() == 3 && cross(pts[poly[0]], pts[poly[1]], pts[poly[2]]) > 0)
    tris.push_back({poly[0], poly[1], poly[2]});
  return tris;
}

}  // namespace flashtwin::sim::detail
