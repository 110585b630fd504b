#pragma once
// MuJoCo geoms as world-frame triangle meshes, for the virtual scanner (Embree casts the rays;
// MuJoCo only says where things are). Only sim/ and its tests include this (it exposes mjModel).
#include <mujoco/mujoco.h>

#include <functional>
#include <vector>

#include "flashtwin/sim/scanner.hpp"

namespace flashtwin::sim {

/// One geom as a triangle mesh in the world frame, posed by d->geom_xpos / d->geom_xmat,
/// counter-clockwise seen from outside.
///  - plane: a square of the geom's half-sizes (size[0], size[1]), 3 m for a zero (infinite)
///    half-size, normal +z of the geom; one-sided and open (2 triangles).
///  - hfield: the elevation surface only (open grid, nrow × ncol vertices).
///  - sphere, capsule, cylinder, ellipsoid: closed surfaces of revolution with `segments`
///    around the axis and segments / 2 (at least 2, rounded up to even) from pole to pole.
///  - box: 8 vertices, 12 triangles; mesh: the model's vertices and faces.
/// Closed shapes share vertices between triangles, so check_mesh() sees them watertight.
/// @pre mj_kinematics (or mj_forward) has run on d.
/// @throws ArgumentError for a null model/data, a geom id out of range, segments < 3, or a geom
/// type that has no surface here.
TriangleMesh tessellate_geom(const mjModel* m, const mjData* d, int geom_id, int segments = 48);

/// Tessellates every geom for which `include(geom_id)` is true (all geoms when `include` is
/// empty) into one SceneMesh each, named after the geom ("geom<i>" when it has no name), all
/// with truth label `label`. Output order: increasing geom id.
/// @pre mj_kinematics (or mj_forward) has run on d.
/// @throws as tessellate_geom.
std::vector<SceneMesh> tessellate_geoms(const mjModel* m, const mjData* d,
                                        const std::function<bool(int geom_id)>& include,
                                        TruthLabel label, int segments = 48);

}  // namespace flashtwin::sim
