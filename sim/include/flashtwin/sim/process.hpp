#pragma once
// Process model of grinding (MuJoCo-free): the material that matters as a sparse voxel grid
// (flash, and a band of the nominal body near the flash so gouges can be measured), material
// removal by a cylindrical burr, the residual analysis behind the `removal.*` metrics, and the
// grinding force model behind `force.*`.
//
// Frames: everything geometric lives in the casting frame {C} (fins, nominal mesh, voxels);
// the tool frame {T} is the TCP at the burr tip (as the robot description's X_ET), so a
// removal step takes X_CT, the pose of {T} in {C}.
//
// Force model (grinding, Malkin & Guo): the tangential force follows from the power balance
// P = e_c · Q = F_t · v_s, i.e. F_t = e_c · Q / v_s with the specific grinding energy e_c
// [J/m^3], the material removal rate Q [m^3/s] and the wheel (burr) surface speed v_s [m/s];
// the normal force is F_n = (F_n/F_t) · F_t. Default e_c = 40 J/mm^3 = 4e10 J/m^3: the middle
// of the 20–60 J/mm^3 that S. Malkin and C. Guo, "Grinding Technology: Theory and Applications
// of Machining with Abrasives", 2nd ed., Industrial Press, 2008, ch. 6 (specific energy)
// report for conventional grinding of steels; F_n/F_t ≈ 2 for steels (same source, ch. 5–6).
#include <cstddef>
#include <cstdint>
#include <memory>
#include <vector>

#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/core/robot.hpp"
#include "flashtwin/core/transform.hpp"
#include "flashtwin/sim/casting.hpp"

namespace flashtwin::sim {

// ---------------------------------------------------------------------------------------------
// Material grid

/// Voxelisation of the material (fields named `process.<field>` in error messages).
struct MaterialParams {
  /// [m] voxel edge h; voxel (i, j, k) has its centre at (i+½, j+½, k+½)·h in {C}.
  double voxel_size = 1e-4;
  /// [m] depth of the nominal body tracked below its surface (at least: whole 8^3-voxel bricks
  /// are kept, so up to band + 1.4 bricks deep).
  double body_band = 1e-3;
  /// [m] the body is tracked only within this distance of a fin's surface (at least: bricks whose
  /// centre is within margin + ½ brick diagonal); gouges farther from every fin go unmeasured.
  /// Make it ≥ the tool radius.
  double body_margin = 8e-3;
};

/// @throws ArgumentError naming the field (`process.voxel_size`, ...) when not finite/positive.
void check_material_params(const MaterialParams& params);

/// What a voxel holds.
enum class VoxelLabel : std::uint8_t {
  kEmpty = 0,  ///< not tracked: air, deep body, far from fins, or removed flash
  kFlash = 1,  ///< flash still standing (centre inside a fin, outside the nominal body)
  kBody = 2,   ///< nominal body near a fin, not removed
  kGouge = 3,  ///< nominal body that was removed (a gouge)
};

/// The mutable state of the material: sparse 8^3-voxel bricks of bit masks (FLASH remaining,
/// BODY remaining, BODY originally) with per-brick counts, sorted by brick and indexed by brick
/// column. Built once per casting; material removal changes it. Copyable (deep copy).
class MaterialGrid {
 public:
  /// Voxelises the fins (scanline fill along z, exact for closed meshes) and the nominal body
  /// within `body_band` below the surface and `body_margin` of a fin.
  /// @param nominal_C the CAD body in {C}: closed, outward-oriented
  /// @param fins_C closed, outward-oriented fin meshes in {C} (may overlap the body: voxels inside
  ///        the nominal body are BODY, never FLASH)
  /// @throws ArgumentError (bad params, empty nominal mesh, NaN/inf vertices, meshes too large for
  ///         the voxel size: at most 2^20 voxels from the origin along any axis)
  MaterialGrid(const TriangleMesh& nominal_C, const std::vector<TriangleMesh>& fins_C,
               const MaterialParams& params = {});
  ~MaterialGrid();
  MaterialGrid(const MaterialGrid& other);
  MaterialGrid& operator=(const MaterialGrid& other);
  MaterialGrid(MaterialGrid&&) noexcept;
  MaterialGrid& operator=(MaterialGrid&&) noexcept;

  const MaterialParams& params() const;
  double voxel_size() const;    ///< [m]
  double voxel_volume() const;  ///< [m^3]
  /// The nominal body's closest-point tree (for distances to the CAD surface).
  const MeshBvh& nominal() const;

  std::size_t flash_voxels_initial() const;
  std::size_t flash_voxels_remaining() const;
  std::size_t body_voxels_initial() const;  ///< BODY voxels tracked
  std::size_t body_voxels_removed() const;  ///< gouge voxels
  std::size_t num_bricks() const;
  std::size_t memory_bytes() const;  ///< approximate heap use

  /// Label of the voxel whose cell contains p_C.
  VoxelLabel label_at(const Vec3& p_C) const;
  /// Centre [m, {C}] of the voxel whose cell contains p_C.
  Vec3 voxel_centre(const Vec3& p_C) const;

  struct Impl;  ///< defined in process.cpp

 private:
  std::unique_ptr<Impl> impl_;
  friend struct MaterialAccess;
};

/// Grid of a generated casting: its nominal mesh and all its fins.
MaterialGrid make_material_grid(const Casting& casting, const MaterialParams& params = {});

// ---------------------------------------------------------------------------------------------
// Tool and removal

enum class ToolEnd : std::uint8_t {
  kFlat,  ///< cylinder with a flat end face at the TCP
  kBall,  ///< hemispherical end of `radius` (cylinder from u = radius on), its tip at the TCP
};

/// A cylindrical burr in the tool frame {T} (fields named `process.tool.<field>`).
struct ToolParams {
  double radius = 0.006;  ///< [m] cutting radius
  double length = 0.020;  ///< [m] cutting length from the TCP (tip) towards the shank
  int axis_sign = -1;     ///< the cutter occupies axial u ∈ [0, length] along axis_sign·z_T
                          ///< from the TCP (−1: z_T points out of the tool, as in ft6.yaml)
  ToolEnd end = ToolEnd::kBall;  ///< tip shape at the TCP (kBall needs length ≥ radius)
};

/// @throws ArgumentError naming the field (`process.tool.radius`, ...).
void check_tool_params(const ToolParams& tool);

/// Tool parameters of a robot description's tool (radius, length; ball tip at the TCP, cutter
/// along −z_T, as the MJCF cell draws the burr).
ToolParams tool_params_from(const ToolDescription& tool);

/// True when p_C lies inside the tool posed at X_CT (closed set).
bool tool_contains(const ToolParams& tool, const Pose& X_CT, const Vec3& p_C);

/// What one removal step took away (voxel centres inside the tool are removed).
struct StepRemoval {
  double flash_volume = 0;         ///< [m^3] FLASH removed in this step
  double body_volume = 0;          ///< [m^3] BODY removed in this step (gouging)
  std::size_t flash_count = 0;     ///< FLASH voxels removed
  std::size_t body_count = 0;      ///< BODY voxels removed
  Vec3 centroid_C = Vec3::Zero();  ///< [m] centroid of all removed voxels (valid when count() > 0)
  double max_depth = 0;  ///< [m] deepest removed BODY voxel centre below the nominal surface
  /// Current penetration of the tool into the nominal body [m]: deepest BODY voxel centre (removed
  /// now or earlier) inside the tool; drives the contact penalty force. Saturates near body_band.
  double penetration = 0;
  /// [m] centre of the deepest BODY voxel inside the tool (the one giving `penetration`; valid
  /// when penetration > 0)
  Vec3 deepest_C = Vec3::Zero();
  Vec3 contact_centroid_C = Vec3::Zero();  ///< [m] centroid of BODY voxels inside the tool
  std::size_t contact_count = 0;           ///< BODY voxels (removed or not) inside the tool

  std::size_t count() const { return flash_count + body_count; }
  double volume() const { return flash_volume + body_volume; }
};

/// Removes every FLASH and BODY voxel whose centre is inside the tool posed at X_CT. Visits only
/// bricks near the tool (bounding box, then distance to the axis), accepts bricks inside the tool
/// whole, tests voxels row by row (exact interval of each voxel row) only in boundary bricks.
/// BODY depths below the nominal surface are computed on first contact and cached.
/// @throws ArgumentError (bad tool params, non-finite pose) — checked once on entry.
StepRemoval remove_material(const ToolParams& tool, MaterialGrid& grid, const Pose& X_CT);

// ---------------------------------------------------------------------------------------------
// Residual analysis

/// Remaining and removed material (the `removal.*` metrics, in SI units).
struct ResidualReport {
  double flash_volume_initial = 0;    ///< [m^3] voxelised flash before grinding
  double flash_volume_remaining = 0;  ///< [m^3]
  double flash_removed_fraction = 1;  ///< removed / initial voxelised flash (1 when there was none)
  double residual_flash_max = 0;  ///< [m] farthest remaining FLASH voxel centre from the nominal
                                  ///< surface, among those still joined to the casting (0 when
                                  ///< none is left)
  /// Remaining FLASH no longer joined to the casting (26-neighbourhood through FLASH voxels to
  /// a remaining BODY voxel): chips cut loose, which would fall off. Counted as remaining in
  /// flash_volume_remaining, left out of residual_flash_max.
  double loose_flash_volume = 0;  ///< [m^3]
  std::size_t loose_flash_voxels = 0;
  double gouge_max_depth = 0;     ///< [m] deepest removed BODY voxel centre below the surface
  double gouge_volume = 0;        ///< [m^3] removed BODY
  std::size_t flash_voxels_remaining = 0;
  std::size_t gouge_voxels = 0;
};

/// Residual flash and gouges (branch and bound over bricks for the max height: exact on voxel
/// centres). Accuracy: about one voxel.
ResidualReport analyze_residual(const MaterialGrid& grid);

/// Centres [m, {C}] of the voxels that now carry `label` (kFlash: residual map for a re-scan;
/// kGouge: gouge map; kBody: tracked intact body). Shape: one point per voxel.
std::vector<Vec3> voxel_points(const MaterialGrid& grid, VoxelLabel label);

/// Centres [m, {C}] of the remaining FLASH voxels.
std::vector<Vec3> remaining_flash_points(const MaterialGrid& grid);
/// Centres of the remaining FLASH voxels, split into those still joined to the casting and
/// those cut loose (chips that would fall off; see ResidualReport::loose_flash_volume).
struct RemainingFlash {
  std::vector<Vec3> attached, loose;
};
RemainingFlash split_remaining_flash(const MaterialGrid& grid);

/// Closed surface of the remaining flash: the voxel faces between remaining FLASH voxels and
/// anything else, outward-oriented, the faces of each plane merged into rectangles (2 triangles
/// each; they meet in T-junctions, so edges are not all shared, and where voxels touch only
/// along an edge four faces meet). Its volume equals the remaining voxelised flash volume and
/// its area the exposed faces'.
TriangleMesh remaining_flash_mesh(const MaterialGrid& grid);

// ---------------------------------------------------------------------------------------------
// Force

/// Grinding force model (fields named `process.force.<field>`); see the header comment.
struct ForceParams {
  double specific_energy = 4e10;   ///< e_c [J/m^3] (40 J/mm^3, steel, conventional grinding)
  double force_ratio = 2.0;        ///< F_n / F_t [-] (≈ 2 for steels)
  double spindle_rpm = 20000;      ///< [rev/min] burr speed: v_s = 2π · radius · rpm / 60
  double contact_stiffness = 2e5;  ///< k [N/m] penalty on penetration of the nominal body
  double contact_damping = 0;  ///< c [N·s/m] on the tool's speed into the body while penetrating
};

/// @throws ArgumentError naming the field.
void check_force_params(const ForceParams& params);

/// Wrench on the tool, in {C} (the frame of X_CT and v_CT), torque about the TCP. To apply it
/// in MuJoCo (`xfrc_applied`: world frame, about the body's centre of mass) rotate by R_WC and
/// shift the moment: τ_com = R_WC·τ + (p_WT − p_Wcom) × R_WC·f.
struct GrindingWrench {
  Vec3 force_C = Vec3::Zero();   ///< [N] total force on the tool
  Vec3 torque_C = Vec3::Zero();  ///< [N·m] about the TCP
  double normal_force = 0;       ///< [N] normal grinding force F_n + penalty (`force.*` metrics)
  double tangential_force = 0;   ///< [N] F_t
  double penalty_force = 0;      ///< [N] k·penetration + damping
  double removal_rate = 0;       ///< Q [m^3/s]
  double cutting_speed = 0;      ///< v_s [m/s]
};

/// Grinding force of one removal step: F_t = e_c·Q/v_s with Q = removed volume / dt, opposite to
/// the tool's velocity (its part perpendicular to the normal; when the tool does not move
/// sideways, along z_T × n, the reaction to a burr turning counter-clockwise about +z_T);
/// F_n = ratio·F_t along n, the unit vector from the removed material's centroid to the tool
/// axis, perpendicular to the axis (along the axis into the shank when the centroid is on it);
/// plus k·penetration + c·(speed into the body) along the same kind of direction from the
/// contact centroid. Forces act at the respective centroids.
/// @param dt step duration [s] (> 0)
/// @param X_CT tool pose in {C} used for the step
/// @param v_CT velocity of the TCP in {C} [m/s]
/// @throws ArgumentError (bad params, dt ≤ 0 or not finite) — checked once on entry.
GrindingWrench grinding_force(const ForceParams& params, const ToolParams& tool,
                              const StepRemoval& step, double dt, const Pose& X_CT,
                              const Vec3& v_CT);

/// Contact penalty k·penetration + c·(speed into the body) [N] (0 when not penetrating).
double penalty_force(const ForceParams& params, double penetration, double speed_in);

/// Burr surface speed v_s = 2π · radius · rpm / 60 [m/s].
double cutting_speed(const ForceParams& params, const ToolParams& tool);

}  // namespace flashtwin::sim
