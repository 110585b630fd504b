#pragma once
// Castings: parametric families (nominal "CAD" meshes) and users' own meshes, with
// procedurally generated flashes and their ground truth.
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::sim {

/// Casting families. Sizes are drawn from the documented ranges by the seed, unless given.
enum class CastingFamily {
  kFlangedPlate,  ///< rounded plate with bolt holes and ribs (bracket), 160–340 mm long
  kRoundFlange,   ///< round flange with hub, bore and bolt circle, 120–400 mm diameter
  kHousing,       ///< box housing: base flange with bolt holes, walls around a pocket
  kCover,         ///< pump/gearbox cover: flange with an off-centre filleted, drafted, domed body
  kMesh,          ///< a user's mesh file (STL/OBJ/PLY)
};

/// Parses "flanged_plate", "round_flange", "housing", "cover", "mesh". @throws ArgumentError.
CastingFamily family_from_string(const std::string& s);
std::string to_string(CastingFamily f);

/// Flash (fin) generation, all lengths [m].
struct FlashParams {
  bool parting_line = true;        ///< fin along the outline at the parting plane
  bool holes = true;               ///< ring fins in holes and bores cut by the parting plane
  double parting_height = -1;      ///< parting plane z in {C}; < 0: the family's default
  double thickness_min = 0.0003, thickness_max = 0.0015;  ///< fin thickness at the root
  double height_min = 0.001, height_max = 0.008;          ///< fin height (outline fins)
  double hole_height_max = 0.003;  ///< fin height in holes (also ≤ 40 % of the hole radius)
  double wave_amplitude = 0.25;    ///< relative amplitude of the wavy outer edge
  double wave_length = 0.015;      ///< [m] typical wave length of the outer edge
  int gaps = 2;                    ///< gaps (no flash) along the parting line
  double gap_length_max = 0.03;    ///< [m] longest gap
  double root_spacing = 0.0005;    ///< [m] sampling of the root curve
  double min_hole_radius = 0.003;  ///< holes smaller than this get no flash
};

struct CastingParams {
  CastingFamily family = CastingFamily::kFlangedPlate;
  std::uint64_t seed = 1;
  std::string mesh_path;           ///< kMesh: the file
  double mesh_scale = 1.0;         ///< kMesh: factor to metres (e.g. 0.001 for mm files)
  double chordal_error = 4e-5;     ///< [m] max deviation of tessellated arcs (≤ 0.05 mm)
  FlashParams flash;
};

/// One flash with its ground truth.
struct Fin {
  std::string kind;             ///< "parting_line" or "hole"
  TriangleMesh mesh;            ///< closed surface in {C}
  double volume = 0;            ///< [m^3]
  std::vector<Vec3> root;       ///< ordered root polyline on the nominal surface, {C}
  bool closed = false;          ///< root is a closed loop
  double thickness = 0;         ///< [m] at the root
  double max_height = 0;        ///< [m]
};

/// A generated (or loaded) casting in its own frame {C}: z up, resting on z = 0 with its
/// footprint centred on the origin.
struct Casting {
  CastingFamily family = CastingFamily::kFlangedPlate;
  std::string description;      ///< human-readable dimensions
  TriangleMesh nominal;         ///< the CAD model: watertight, outward-oriented
  std::vector<Fin> fins;        ///< ground truth: scoring only
  double parting_height = 0;    ///< [m]
  double analytic_volume = 0;   ///< [m^3] of the ideal (untessellated) part; 0 for meshes
  Vec3 size = Vec3::Zero();     ///< bounding box extents [m]

  double flash_volume() const;
  /// All fins as one mesh.
  TriangleMesh flash_mesh() const;
};

/// Ground-truth labelling of points near a casting (scoring only): a point is flash when it is
/// nearer to a fin's surface than to the nominal surface. Built once per casting.
class FlashLabeler {
 public:
  explicit FlashLabeler(const Casting& casting);
  ~FlashLabeler();
  /// @param p_C point in the casting frame {C} [m]
  bool is_flash(const Vec3& p_C) const;
  /// Distance to the nominal surface [m].
  double distance_to_nominal(const Vec3& p_C) const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

/// Generates or loads the casting and its flashes. Deterministic in params.seed.
/// @throws ArgumentError (impossible parameters), IoError/InputError (mesh file problems,
/// e.g. "part.stl: expected a closed surface, got 12 boundary edges (holes)").
Casting make_casting(const CastingParams& params);

/// Slices a closed mesh with the plane z = height: closed loops ordered with the solid on
/// their left (outer boundaries counter-clockwise seen from +z, holes clockwise).
std::vector<std::vector<Vec3>> slice_mesh(const TriangleMesh& mesh, double height);

}  // namespace flashtwin::sim
