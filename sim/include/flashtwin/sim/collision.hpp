#pragma once
// Collision checks of the robot against the cell: the arm's links, the spindle and the burr
// against the table, its legs, the fixture blocks, the scanner head, the robot's pedestal and
// base housing, the floor, the casting's CAD body and its standing flash. The burr cutting the
// casting (body or flash) is not a collision: the process model removes that material and
// counts any cut into the body as a gouge. Self-collision of the arm is not checked.
//
// Model apart from data: CellCollision holds the geometry (built once from the cell's mjModel
// and the casting's CAD tree), CollisionMonitor the state of a run that checks every step.
//
// Geometry (all exact signed distances on the obstacle side):
// - obstacles: the model's box, plane and cylinder geoms outside the arm (the cell's contract:
//   table_top, legs, fixture blocks, scanner_head, pedestal, floor, base housing); the casting
//   as its CAD tree posed at X_WC (the side of a point from the closest triangle's normal, exact
//   on faces and convex edges); flash as the material grid's FLASH voxels;
// - the robot: each capsule or sphere geom as balls along its axis (spacing ¼ radius: the union
//   lies within 0.8 % of the radius inside the capsule), each cylinder or box geom as points on
//   its surface (spacing radius / 8, between 2 and 10 mm): an obstacle's edge can reach between
//   two surface points by up to about ¼ spacing undetected (≤ 2.5 mm on the motor housings,
//   ≤ 1.1 mm on the spindle). Flash is checked against surface points only (the spindle and the
//   motor housings; capsules see the CAD body only).
// The arm's links 1 and 2 are not checked against the base housing, pedestal and floor they
// stand on.
#include <mujoco/mujoco.h>

#include <string>
#include <vector>

#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/transform.hpp"

namespace flashtwin::sim {

class MaterialGrid;

/// The closest approach found by a check.
struct CollisionHit {
  /// [m] signed clearance between a robot geom and an obstacle: < 0 is a penetration of that
  /// depth; capped at CellCollision::kReach (nothing nearer).
  double clearance = 0;
  std::string robot_geom;  ///< "spindle", "burr", "link3" (a geom of link 3), ...
  std::string obstacle;    ///< "table_top", "fixture_1", "scanner_head", "casting", "flash", ...
  Vec3 point_W = Vec3::Zero();  ///< the robot's sample nearest the obstacle, {W}
  bool colliding() const { return clearance < 0; }
};

/// The cell's collision geometry (immutable; checks are const and thread-safe).
class CellCollision {
 public:
  /// [m] clearances are found up to this far; beyond it a check reports kReach.
  static constexpr double kReach = 0.05;

  /// @param m the cell's model (robot bodies: body `link1` and its descendants)
  /// @param casting_C the casting's CAD body in {C}, closed and outward-oriented; kept by
  ///        reference (must outlive this object)
  /// @param X_WC where the casting stands (the true pose for the twin's measurement, the
  ///        estimated one for a planner)
  /// @param flash the material grid whose FLASH voxels count as obstacles (kept by reference),
  ///        or null (a planner: it knows no flash geometry)
  /// @throws InputError when the model has no body `link1`
  /// @param shank_radius ≥ 0: the radius of the tool's `shank` geom instead of the model's (a
  ///        burr from the tool rack on its own shank); < 0: the model's
  /// @param collet_radius ≥ 0: the radius of the tool's `collet` geom instead of the model's (a
  ///        rack burr's slim holder, holder_for); < 0: the model's
  CellCollision(const mjModel& m, const MeshBvh& casting_C, const Pose& X_WC,
                const MaterialGrid* flash = nullptr, double shank_radius = -1,
                double collet_radius = -1);

  /// Flash a planner knows of (perception's detected flash points, {W}) as obstacles of every
  /// robot geom, the burr included (a transit must not run through a fin: 8 mm fins stood in a
  /// transit planned 8 mm off the CAD and its burr hit them at transit speed). Points are thinned
  /// to one per `cell`-sized cube. Obstacle "flash (detected)". Call before any check.
  void set_known_flash(const std::vector<Vec3>& points_W, double cell = 2e-3);

  /// Checks the burr against the CAD body too (a planner's transits: between paths the burr must
  /// not pass through the casting; while grinding its cut into the body is the process model's
  /// gouge). Obstacle "casting". Call before any check.
  void set_burr_checks_body(bool on) { burr_checks_body_ = on; }
  /// Number of robot geoms checked.
  std::size_t robot_geoms() const { return robot_.size(); }
  /// The closest approach of robot geom k (0 ≤ k < robot_geoms()) to any obstacle, with the
  /// geom posed as in d (geom_xpos / geom_xmat: after mj_kinematics or a step); nothing nearer
  /// than `reach` (≤ kReach): clearance `reach` (a smaller reach is faster). Keeps search hints
  /// between calls (same answers): one CellCollision per thread, as the mjData it reads.
  CollisionHit check_geom(const mjData& d, std::size_t k, double reach = kReach) const;
  /// The closest approach of the whole robot.
  CollisionHit check(const mjData& d, double reach = kReach) const;
  /// Only the flash voxels against geom k's surface points (cheap: grid look-ups): obstacle
  /// "flash" with clearance −½ voxel (the depth is not known) when a point lies in standing
  /// flash, else kReach.
  CollisionHit check_flash(const mjData& d, std::size_t k) const;
  /// Model geom id of robot geom k.
  int geom_id(std::size_t k) const { return robot_[k].geom; }
  /// [m] bound on the distance of geom k's samples (ball surfaces included) from its frame origin.
  double extent(std::size_t k) const { return robot_[k].extent; }
  /// True when geom k is checked against flash (it has surface points and a grid was given).
  bool checks_flash(std::size_t k) const;

 private:
  struct Ball {
    Vec3 centre;    // in the geom frame
    double radius;  // 0: a surface point
    // The casting triangle nearest the ball at its last check: the next check starts its search
    // bounded by it (a bound only: the same answer, found sooner as the robot moves on).
    mutable int hint = -1;
  };
  struct RobotGeom {
    int geom = -1, body = -1;
    std::string name;
    std::vector<Ball> balls;
    int type = 0;              // mjGEOM_CAPSULE, _SPHERE, _CYLINDER or _BOX
    Vec3 size = Vec3::Zero();  // MuJoCo's geom size (radius, half-length; box half extents)
    double extent = 0;
    bool on_base_links = false;  // link 1 or 2: not checked against the base and pedestal
  };
  struct Obstacle {
    int geom = -1;
    int type = 0;  // mjGEOM_BOX, mjGEOM_PLANE, mjGEOM_CYLINDER
    Vec3 size = Vec3::Zero();
    Pose X_WG = Pose::Identity();
    std::string name;
    bool under_base = false;  // base housing or pedestal
  };
  double obstacle_distance(const Obstacle& o, const Vec3& p_W) const;
  // Signed distance of point q (in robot geom rg's frame) to the geom's solid: < 0 inside.
  static double geom_distance(const RobotGeom& rg, const Vec3& q);

  std::vector<RobotGeom> robot_;
  std::vector<Obstacle> obstacles_;
  const MeshBvh& casting_C_;
  Pose X_CW_;
  Eigen::AlignedBox3d casting_box_W_;  // the CAD body's bounds in {W}
  const MaterialGrid* flash_ = nullptr;
  std::vector<Vec3> known_flash_W_;
  Eigen::AlignedBox3d known_flash_box_W_;
  bool burr_checks_body_ = false;
};

/// Checks a running simulation at every step without redoing the geometry where nothing can
/// have changed: a geom is checked again once its frame has moved (translation + rotation
/// angle × extent) as far as its last clearance, or every kFlashStep against the flash voxels
/// while it is near the casting. The result is what a check of every geom at every step gives,
/// up to the sampling above.
class CollisionMonitor {
 public:
  static constexpr double kFlashStep = 5e-4;  ///< [m]

  explicit CollisionMonitor(const CellCollision& cell);
  /// The robot's closest approach at d's geom poses (every robot geom's latest clearance).
  CollisionHit update(const mjData& d);
  /// Full geometric checks done so far (for the benchmarks).
  std::size_t checks() const { return checks_; }

 private:
  struct State {
    Pose X_WG = Pose::Identity();
    Pose X_WG_flash = Pose::Identity();
    CollisionHit hit;
    bool valid = false;
  };
  const CellCollision& cell_;
  std::vector<State> state_;
  std::size_t checks_ = 0;
};

}  // namespace flashtwin::sim
