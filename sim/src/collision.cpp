#include "flashtwin/sim/collision.hpp"

#include <algorithm>
#include <array>
#include <set>
#include <span>
#include <cmath>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/process.hpp"

namespace flashtwin::sim {

namespace {

Pose geom_pose(const mjData& d, int g) {
  Pose X = Pose::Identity();
  const mjtNum* R = d.geom_xmat + 9 * g;
  X.linear() << R[0], R[1], R[2], R[3], R[4], R[5], R[6], R[7], R[8];
  X.translation() = Vec3(d.geom_xpos[3 * g], d.geom_xpos[3 * g + 1], d.geom_xpos[3 * g + 2]);
  return X;
}

std::string name_of(const mjModel& m, mjtObj type, int id) {
  const char* n = mj_id2name(&m, type, id);
  return n ? n : "";
}

// Is body b body `root` or below it?
bool below(const mjModel& m, int b, int root) {
  for (; b > 0; b = m.body_parentid[b])
    if (b == root) return true;
  return false;
}

// Points on a circle of radius r at height z (about z), at most `spacing` apart.
void ring(double r, double z, double spacing, std::vector<Vec3>& out) {
  const int n = std::max(3, static_cast<int>(std::ceil(2 * M_PI * r / spacing)));
  for (int i = 0; i < n; ++i) {
    const double a = 2 * M_PI * i / n;
    out.emplace_back(r * std::cos(a), r * std::sin(a), z);
  }
}

// Surface points of a cylinder about z (radius r, half-length hl): rings on its side and
// concentric rings on its two end faces, at most `spacing` apart.
std::vector<Vec3> cylinder_points(double r, double hl, double spacing) {
  std::vector<Vec3> p;
  const int nz = std::max(1, static_cast<int>(std::ceil(2 * hl / spacing)));
  for (int j = 0; j <= nz; ++j) ring(r, -hl + 2 * hl * j / nz, spacing, p);
  const int nr = std::max(1, static_cast<int>(std::ceil(r / spacing)));
  for (const double z : {-hl, hl}) {
    p.emplace_back(0, 0, z);
    for (int i = 1; i < nr; ++i) ring(r * i / nr, z, spacing, p);
  }
  return p;
}

// Surface points of a box of half extents h, at most `spacing` apart on each face.
std::vector<Vec3> box_points(const Vec3& h, double spacing) {
  std::vector<Vec3> p;
  for (int axis = 0; axis < 3; ++axis) {
    const int u = (axis + 1) % 3, v = (axis + 2) % 3;
    const int nu = std::max(1, static_cast<int>(std::ceil(2 * h[u] / spacing)));
    const int nv = std::max(1, static_cast<int>(std::ceil(2 * h[v] / spacing)));
    for (const double s : {-1.0, 1.0})
      for (int i = 0; i <= nu; ++i)
        for (int j = 0; j <= nv; ++j) {
          Vec3 q;
          q[axis] = s * h[axis];
          q[u] = -h[u] + 2 * h[u] * i / nu;
          q[v] = -h[v] + 2 * h[v] * j / nv;
          p.push_back(q);
        }
  }
  return p;
}

// Spacing of a geom's surface points: an eighth of its radius (or least half extent), 2–10 mm.
double surface_spacing(double size) { return std::clamp(size / 8, 2e-3, 10e-3); }

// Signed distance of p (in the geom's frame) to a box of half extents h, a cylinder about z of
// radius R and half-length hl, or the plane z = 0 (its solid side z < 0): negative inside.
double box_distance(const Vec3& q, const Vec3& h) {
  const Vec3 d = q.cwiseAbs() - h;
  return d.cwiseMax(0.0).norm() + std::min(d.maxCoeff(), 0.0);
}
double cylinder_distance(const Vec3& q, double R, double hl) {
  const double dr = std::hypot(q.x(), q.y()) - R, dz = std::abs(q.z()) - hl;
  return std::hypot(std::max(dr, 0.0), std::max(dz, 0.0)) + std::min(std::max(dr, dz), 0.0);
}

}  // namespace

CellCollision::CellCollision(const mjModel& m, const MeshBvh& casting_C, const Pose& X_WC,
                             const MaterialGrid* flash, double shank_radius, double collet_radius)
    : casting_C_(casting_C), X_CW_(X_WC.inverse()), flash_(flash) {
  const int link1 = require_id(&m, mjOBJ_BODY, "link1");
  const int link3 = mj_name2id(&m, mjOBJ_BODY, "link3");
  const int base = mj_name2id(&m, mjOBJ_BODY, "base");
  const int casting = mj_name2id(&m, mjOBJ_BODY, "casting");
  for (int g = 0; g < m.ngeom; ++g) {
    const int b = m.geom_bodyid[g];
    const int type = m.geom_type[g];
    Vec3 size(m.geom_size[3 * g], m.geom_size[3 * g + 1], m.geom_size[3 * g + 2]);
    std::string name = name_of(m, mjOBJ_GEOM, g);
    if (name == "shank" && shank_radius >= 0) size[0] = shank_radius;
    if (name == "collet" && collet_radius >= 0) size[0] = collet_radius;
    if (below(m, b, link1)) {
      RobotGeom rg;
      rg.geom = g;
      rg.body = b;
      rg.name = name.empty() ? name_of(m, mjOBJ_BODY, b) : name;
      rg.on_base_links = link3 < 0 || !below(m, b, link3);
      rg.type = type;
      rg.size = size;
      if (type == mjGEOM_CAPSULE || type == mjGEOM_SPHERE) {
        // Balls along the axis a quarter radius apart.
        const double r = size[0], hl = type == mjGEOM_CAPSULE ? size[1] : 0.0;
        const int n = std::max(1, static_cast<int>(std::ceil(2 * hl / (r / 4))));
        for (int i = 0; i <= n; ++i) rg.balls.push_back({Vec3(0, 0, n ? -hl + 2 * hl * i / n : 0), r});
      } else if (type == mjGEOM_CYLINDER) {
        for (const Vec3& p : cylinder_points(size[0], size[1], surface_spacing(size[0])))
          rg.balls.push_back({p, 0.0});
      } else if (type == mjGEOM_BOX) {
        for (const Vec3& p : box_points(size, surface_spacing(size.minCoeff()))) rg.balls.push_back({p, 0.0});
      } else {
        continue;  // no other robot geom type in the cell's contract
      }
      for (const Ball& ball : rg.balls) rg.extent = std::max(rg.extent, ball.centre.norm() + ball.radius);
      robot_.push_back(std::move(rg));
      continue;
    }
    if (b == casting) continue;  // the casting is its CAD tree (and the grid's flash)
    if (type != mjGEOM_BOX && type != mjGEOM_PLANE && type != mjGEOM_CYLINDER) continue;
    Obstacle o;
    o.geom = g;
    o.type = type;
    o.size = size;
    o.name = name.empty() ? name_of(m, mjOBJ_BODY, b) : name;
    o.under_base = b == base || name == "pedestal" || name == "floor";
    obstacles_.push_back(std::move(o));
  }
  if (robot_.empty()) throw InputError("model: expected robot geoms on body 'link1' and below");
  // Obstacles do not move: their poses from the model's default configuration.
  const MjDataPtr dp = make_data(&m);
  mj_kinematics(&m, dp.get());
  for (Obstacle& o : obstacles_) o.X_WG = geom_pose(*dp, o.geom);
  for (const Vec3& v : casting_C_.mesh().vertices) casting_box_W_.extend(X_WC * v);
}

void CellCollision::set_known_flash(const std::vector<Vec3>& points_W, double cell) {
  if (!(cell > 0)) throw ArgumentError("set_known_flash: expected a cell size > 0 [m]");
  known_flash_W_.clear();
  known_flash_box_W_.setEmpty();
  std::set<std::array<long, 3>> seen;  // the cubes kept
  for (const Vec3& p : points_W) {
    const std::array<long, 3> key{std::lround(std::floor(p.x() / cell)), std::lround(std::floor(p.y() / cell)),
                                  std::lround(std::floor(p.z() / cell))};
    if (!seen.insert(key).second) continue;
    known_flash_W_.push_back(p);
    known_flash_box_W_.extend(p);
  }
}

double CellCollision::geom_distance(const RobotGeom& rg, const Vec3& q) {
  switch (rg.type) {
    case mjGEOM_SPHERE:
      return q.norm() - rg.size[0];
    case mjGEOM_CAPSULE:
      return Vec3(q.x(), q.y(), q.z() - std::clamp(q.z(), -rg.size[1], rg.size[1])).norm() - rg.size[0];
    case mjGEOM_CYLINDER:
      return cylinder_distance(q, rg.size[0], rg.size[1]);
    default:  // mjGEOM_BOX
      return box_distance(q, rg.size);
  }
}

bool CellCollision::checks_flash(std::size_t k) const {
  return flash_ && robot_[k].name != "burr" && !robot_[k].balls.empty() && robot_[k].balls.front().radius == 0;
}

double CellCollision::obstacle_distance(const Obstacle& o, const Vec3& p_W) const {
  const Vec3 q = o.X_WG.inverse() * p_W;
  switch (o.type) {
    case mjGEOM_BOX:
      return box_distance(q, o.size);
    case mjGEOM_CYLINDER:
      return cylinder_distance(q, o.size[0], o.size[1]);
    default:  // mjGEOM_PLANE: z = 0 in its frame, solid below
      return q.z();
  }
}

CollisionHit CellCollision::check_geom(const mjData& d, std::size_t k, double reach) const {
  const RobotGeom& rg = robot_[k];
  const Pose X_WG = geom_pose(d, rg.geom);
  CollisionHit best;
  best.clearance = reach;
  best.robot_geom = rg.name;
  // Broad phase: obstacles (and the casting) farther than extent + reach from the geom's
  // origin cannot come nearer than reach.
  const double far = rg.extent + reach;
  std::vector<const Obstacle*> near;
  for (const Obstacle& o : obstacles_) {
    if (o.under_base && rg.on_base_links) continue;
    if (obstacle_distance(o, X_WG.translation()) < far) near.push_back(&o);
  }
  // The burr cutting the casting is the process model's (unless a planner asks for it).
  const bool cuts = rg.name == "burr" && !burr_checks_body_;
  const bool casting_near = !cuts && casting_box_W_.exteriorDistance(X_WG.translation()) < far;
  int hint = -1;
  // Nothing near the geom: its balls need no look (most geoms, most of the time).
  const std::span<const Ball> balls = !near.empty() || casting_near ? std::span<const Ball>(rg.balls)
                                                                     : std::span<const Ball>();
  for (const Ball& ball : balls) {
    const Vec3 p_W = X_WG * ball.centre;
    for (const Obstacle* o : near) {
      const double c = obstacle_distance(*o, p_W) - ball.radius;
      if (c < best.clearance) best = {c, rg.name, o->name, p_W};
    }
    if (!casting_near) continue;
    const double within = best.clearance + ball.radius;
    if (casting_box_W_.exteriorDistance(p_W) > within) continue;
    const Vec3 p_C = X_CW_ * p_W;
    const ClosestPoint cp = casting_C_.closest(p_C, within, ball.hint >= 0 ? ball.hint : hint);
    if (cp.triangle < 0) continue;
    hint = ball.hint = cp.triangle;
    const Vec3 n = casting_C_.mesh().triangle_normal(static_cast<std::size_t>(cp.triangle));
    const double signed_d = (p_C - cp.point).dot(n) < 0 ? -cp.distance : cp.distance;
    if (signed_d - ball.radius < best.clearance) best = {signed_d - ball.radius, rg.name, "casting", p_W};
  }
  if (checks_flash(k)) {
    const CollisionHit f = check_flash(d, k);
    if (f.clearance < best.clearance) best = f;
  }
  if (!known_flash_W_.empty() && known_flash_box_W_.exteriorDistance(X_WG.translation()) < far) {
    const Pose X_GW = X_WG.inverse();
    for (const Vec3& p_W : known_flash_W_) {
      if ((p_W - X_WG.translation()).norm() >= rg.extent + best.clearance) continue;
      const double c = geom_distance(rg, X_GW * p_W);
      if (c < best.clearance) best = {c, rg.name, "flash (detected)", p_W};
    }
  }
  return best;
}

CollisionHit CellCollision::check_flash(const mjData& d, std::size_t k) const {
  const RobotGeom& rg = robot_[k];
  CollisionHit hit;
  hit.clearance = kReach;
  hit.robot_geom = rg.name;
  if (!checks_flash(k)) return hit;
  const Pose X_WG = geom_pose(d, rg.geom);
  if (casting_box_W_.exteriorDistance(X_WG.translation()) > rg.extent) return hit;
  const Pose X_CG = X_CW_ * X_WG;
  for (const Ball& ball : rg.balls) {
    const Vec3 p_C = X_CG * ball.centre;
    if (flash_->label_at(p_C) != VoxelLabel::kFlash) continue;
    // Inside standing flash: the depth is not known, at least part of a voxel.
    return {-0.5 * flash_->voxel_size(), rg.name, "flash", X_WG * ball.centre};
  }
  return hit;
}

CollisionHit CellCollision::check(const mjData& d, double reach) const {
  CollisionHit best;
  best.clearance = reach;
  for (std::size_t k = 0; k < robot_.size(); ++k) {
    CollisionHit h = check_geom(d, k, reach);
    if (h.clearance < best.clearance) best = std::move(h);
  }
  return best;
}

CollisionMonitor::CollisionMonitor(const CellCollision& cell) : cell_(cell), state_(cell.robot_geoms()) {}

CollisionHit CollisionMonitor::update(const mjData& d) {
  CollisionHit best;
  best.clearance = CellCollision::kReach;
  for (std::size_t k = 0; k < state_.size(); ++k) {
    State& s = state_[k];
    const Pose X_WG = geom_pose(d, cell_.geom_id(k));
    // How far any sample of the geom can have moved since a pose: the origin's travel plus the
    // rotation angle times the samples' reach from it.
    const auto moved = [&](const Pose& X) {
      return (X_WG.translation() - X.translation()).norm() +
             rotation_distance(X_WG.linear(), X.linear()) * cell_.extent(k);
    };
    if (!s.valid || s.hit.clearance <= 0 || moved(s.X_WG) >= s.hit.clearance) {
      s.hit = cell_.check_geom(d, k);
      s.X_WG = s.X_WG_flash = X_WG;
      s.valid = true;
      ++checks_;
    } else if (cell_.checks_flash(k) && moved(s.X_WG_flash) >= kFlashStep) {
      // Flash is not in the clearance: its voxels are looked up every kFlashStep of motion.
      const CollisionHit f = cell_.check_flash(d, k);
      s.X_WG_flash = X_WG;
      if (f.colliding()) s.hit = f;
    }
    if (s.hit.clearance < best.clearance) best = s.hit;
  }
  return best;
}

}  // namespace flashtwin::sim
