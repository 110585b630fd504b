#pragma once
// The MuJoCo cell: robot on a pedestal, worktable, casting, cameras and lights, written as a
// self-contained MJCF (DESIGN.md contract: joints joint1..joint6, sites flange and tcp, body
// casting).
#include <cstddef>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/sim/casting.hpp"

namespace flashtwin::sim {

/// A fixture block: a box standing on the worktable top beside the casting (drawn and scanned;
/// no MuJoCo contact, like the casting).
struct FixtureBlock {
  std::string name;                     ///< geom name in the MJCF
  Pose X_WF = Pose::Identity();         ///< box centre and axes {F} in {W}
  Vec3 half_size{0.012, 0.03, 0.0125};  ///< [m] half extents along the axes of {F}
};

/// Geometry of the cell (world frame {W}: z up, floor at z = 0).
struct CellSpec {
  /// Robot base {B} (D-H frame 0, at the shoulder) in {W}.
  Pose X_WB = Pose(Eigen::Translation3d(0.0, 0.0, 0.95));
  double base_height = 0.35;  ///< [m] robot base housing below {B}, on top of the pedestal
  /// Worktable top centre in {W} (z = top surface).
  Pose X_WTable = Pose(Eigen::Translation3d(0.75, 0.0, 0.78));
  Vec3 table_size{0.8, 0.9, 0.05};  ///< [m] top plate extents (x, y, thickness)
  /// Casting frame {C} in {W}.
  Pose X_WC = Pose(Eigen::Translation3d(0.70, 0.0, 0.78));
  /// Scanner frame {M} in {W} (true mount pose): above the table, z_M pointing down.
  Pose X_WM = Pose(Eigen::Translation3d(0.70, 0.0, 1.25)) *
              Pose(Eigen::AngleAxisd(M_PI, Vec3::UnitX()));
  double timestep = 0.001;           ///< [s] MuJoCo step (≥ 1 kHz)
  /// Position-actuator stiffness per joint [N·m/rad], tuned for the FT6; torque-limited by the
  /// robot's limits. A robot description's `servo:` block replaces kp and damping.
  std::array<double, kNumJoints> kp{20000, 20000, 10000, 2000, 1500, 800};
  std::array<double, kNumJoints> damping{300, 300, 150, 20, 15, 8};  ///< joint damping [N·m·s/rad]
  /// Riser: a support block the casting stands on, so the burr grinding a fin low on the part
  /// hangs below the part's bottom instead of in the table (a real cell's answer: the part on
  /// raised pads). 0: the casting rests on the table top. The riser is the box under the
  /// casting's lowest face (its footprint shrunk by riser_inset, at least 20 x 20 mm), from the
  /// table top up to the casting's lowest point; it is a fixture block named "riser".
  double riser_height = 0;     ///< [m]
  double riser_inset = 0.015;  ///< [m] riser edges inside the casting's lowest face
  /// Fixture blocks; empty: the two locating blocks of fixture_blocks() (and the riser), laid
  /// out beside (under) the casting when the cell is written.
  std::vector<FixtureBlock> fixtures;
};

/// MuJoCo 2.2.2 refuses a model with a mesh of more faces than this ("number of faces should be
/// between 1 and 200000").
constexpr std::size_t kMaxMeshFaces = 200000;

/// Splits a mesh into ceil(F / max_faces) parts of at most max_faces triangles each, keeping
/// every triangle exactly (same corners, same winding); each part holds only the vertices it
/// uses. Part k of n takes triangles k, k + n, k + 2n, ...: every part spans the whole surface,
/// because MuJoCo computes a volume for each mesh and refuses a flat one. A mesh within the
/// limit comes back unchanged as the only part. @pre max_faces > 0.
std::vector<TriangleMesh> split_mesh(const TriangleMesh& mesh,
                                     std::size_t max_faces = kMaxMeshFaces);

/// Name of part k of a split mesh (its asset, geom and file stem): `base` for part 0, so an
/// unsplit mesh keeps its name, and `base_part<k>` for the others.
std::string mesh_part_name(const std::string& base, std::size_t k);

/// True when `name` is `base` or a part of it (`base_part<k>`). The casting's geoms
/// `casting_body` and `casting_flash` are several geoms (of body `casting`) when their mesh
/// has more than kMaxMeshFaces faces: find them all with this, or by body.
bool is_mesh_part(const std::string& name, const std::string& base);

/// MJCF text of the robot's body chain (body `base` with links link1..link6, tool body `tool`,
/// sites `flange` and `tcp`), to be placed inside <worldbody>; `X_WB` places the base.
std::string arm_mjcf(const RobotModel& robot, const Pose& X_WB, const CellSpec& spec);

/// Mesh files of the casting the MJCF refers to (paths relative to the MJCF's folder). A mesh
/// over kMaxMeshFaces faces is several files (split_mesh), each becoming a mesh asset and a geom
/// named by mesh_part_name.
struct CastingAssets {
  std::vector<std::string> nominal_stl;  ///< the casting body: one file per part
  std::vector<std::string> flash_stl;    ///< all fins: one file per part (empty: no flash)
  Vec3 lo = Vec3(-0.1, -0.1, 0), hi = Vec3(0.1, 0.1, 0.05);  ///< nominal bounds in {C} [m]
};

/// The radius of the shank a burr of `burr_radius` stands on: the tool's shank_radius, but at
/// most the burr's radius less 1 mm (small burrs come on thinner shanks, 3 mm for heads under
/// 6 mm), so the shank stays off the wall the burr grinds.
double shank_radius_for(const ToolDescription& tool, double burr_radius);

/// What holds a burr of `burr_radius`: its shank (shank_radius_for) and the collet's radius,
/// the mounted collet nut's for the mounted burr, the rack's slim holder's
/// (ToolDescription::rack_collet_radius) for a smaller one from the tool rack.
struct BurrHolder {
  double shank_radius = 0;  ///< [m]
  double collet_radius = 0; ///< [m]
};
BurrHolder holder_for(const ToolDescription& tool, double burr_radius);

/// MJCF text of the whole cell; without assets the casting is a box of the default bounds.
/// The fixture is spec.fixtures, or when that is empty two blocks 22 mm outside the casting's
/// bounds along its x axis (fixture_blocks without the mesh test).
std::string cell_mjcf(const RobotModel& robot, const CellSpec& spec,
                      const CastingAssets* casting = nullptr);

/// Summary of a compiled MuJoCo model, for users and tests.
struct ModelSummary {
  int nbody = 0, njnt = 0, nu = 0, ngeom = 0, nsite = 0, ncam = 0;
  double timestep = 0;
};

/// Files written by write_cell.
struct CellFiles {
  std::string mjcf;         ///< DIR/cell.xml (self-contained with DIR/meshes/)
  std::string urdf;         ///< DIR/robot.urdf
  std::string cad;          ///< DIR/casting_cad.stl: the nominal casting in {C} (the "CAD model")
  std::string truth;        ///< DIR/truth/: ground truth for scoring only
  ModelSummary model;       ///< what MuJoCo compiled from cell.xml
};

/// Writes the cell: DIR/cell.xml, DIR/meshes/*.stl, DIR/robot.urdf, DIR/casting_cad.stl and the
/// ground truth (DIR/truth/: fins.stl, flash_truth.json with each fin's volume and root
/// polyline in {C} and {W}); then loads cell.xml with MuJoCo to prove it compiles. Meshes over
/// kMaxMeshFaces faces go to MuJoCo split (meshes/casting_nominal.stl,
/// casting_nominal_part1.stl, ...: mesh_part_name);
/// casting_cad.stl and the truth keep the exact, whole meshes. The fixture is spec.fixtures or
/// fixture_blocks(spec, casting.nominal). It does not check the layout (check_cell_layout).
/// @throws IoError (cannot write), InputError (MuJoCo rejects it).
CellFiles write_cell(const RobotModel& robot, const CellSpec& spec, const Casting& casting,
                     const std::string& dir);

/// Writes DIR/<name>.xml: the cell of write_cell (which must have written DIR before: the nominal
/// mesh is reused) with the casting's flash replaced by `flash_C` (in {C}; empty: no flash),
/// saved as DIR/meshes/<name>_flash.stl (split like write_cell's meshes when over
/// kMaxMeshFaces faces). Used for the "after grinding" renders. Returns the path.
/// @throws IoError, InputError (MuJoCo rejects it).
std::string write_cell_variant(const RobotModel& robot, const CellSpec& spec,
                               const TriangleMesh& nominal, const TriangleMesh& flash_C,
                               const std::string& dir, const std::string& name);

/// Writes the ground truth of a casting placed at X_WC into `dir`: fins.stl ({C}) and
/// flash_truth.json (fin kinds, volumes, root polylines in {C}, X_WC). Scoring only.
void write_ground_truth(const Casting& casting, const Pose& X_WC, const std::string& dir);

/// The pose of {C} in {W} that rests the casting on the table top: given the position (x, y)
/// on the table [m] and an orientation R_TC relative to the table frame, z is chosen so the
/// lowest point of the rotated casting touches the table, or the riser's top
/// (spec.riser_height above the table) when the cell has one.
Pose rest_on_table(const CellSpec& spec, const TriangleMesh& nominal, double x, double y,
                   const Mat3& R_TC);

/// Compiles an MJCF file with MuJoCo. @throws InputError with MuJoCo's message.
ModelSummary check_mjcf(const std::string& path);

/// The default fixture of a placed casting: two locating blocks (24 x 60 mm, 25 mm over the
/// riser's height, names fixture_left and fixture_right) standing on the table top on either
/// side of the casting
/// along its x axis (turned with its yaw about the table normal), centred on its y extent and
/// 22 mm outside its bounds in {C} (clear of the flash and the burr grinding it). A block that would still cut into the placed mesh (a tilted
/// casting) slides outward along its x axis until it is 22 mm clear of the mesh's part within
/// the block's width and height. With spec.riser_height > 0 a third block, "riser", stands
/// under the casting: its footprint the bounds (in the blocks' axes) of the placed mesh's
/// vertices within 1 mm of its lowest point, shrunk by spec.riser_inset on each side (at least
/// 10 mm half-width about their centre), from the table top up to the casting's lowest point;
/// shrunk further about its centre (the same scale along both axes) until it stands 5 mm inside
/// every edge of the lowest face, its outline and the openings in it (bolt holes: the burr
/// grinding a hole's flash needs room beneath it).
/// Reads spec.X_WTable, spec.X_WC and the riser keys; ignores spec.fixtures.
std::vector<FixtureBlock> fixture_blocks(const CellSpec& spec, const TriangleMesh& nominal_C);

/// Tolerances of check_cell_layout.
struct CellCheckParams {
  /// [m] slack of every test: overhang of the casting past the table's edge, fixture blocks
  /// cutting into the casting or the table top or standing above it, robot base and scanner
  /// head overlapping the table (numerical noise; tessellated curves lie inside the true ones).
  double tolerance = 1e-4;
};

/// Checks that the cell makes sense before anything runs in it:
///  - the casting's footprint (its placed nominal mesh in the table plane) lies on the table top
///    and its lowest point on the top surface (on the riser's top with a riser);
///  - every fixture block (spec.fixtures, or fixture_blocks when empty) stands on the table top
///    (bottom on the surface, centre over the top) and does not cut into the casting's nominal
///    mesh (exact box-triangle and inside tests against the mesh);
///  - the robot base (pedestal and base housing) and the scanner head are clear of the table's
///    volume (its top's footprint from the floor up to the top surface).
/// Errors name the scenario field to change (cell.table.size, casting.placement,
/// cell.robot_base, cell.scanner_mount), on one line, without the file (the caller adds it).
/// pipeline::setup_cell runs it for every scenario's cell.
/// @pre nominal_C is closed and outward-oriented (as make_casting makes it).
/// @throws ConfigError on the first failed test; ArgumentError for a mesh with no triangles.
void check_cell_layout(const CellSpec& spec, const TriangleMesh& nominal_C,
                       const CellCheckParams& params = {});

/// The arm at its home pose (where it waits while the cell scans) does not reach into the
/// scanner head: the capsules drawn along each link's D-H offsets and the spindle, against the
/// head's box. pipeline::setup_cell runs it for every scenario's cell.
/// @throws ConfigError naming cell.scanner_mount, the part of the arm and how deep it goes.
void check_arm_clear_of_scanner(const RobotModel& robot, const CellSpec& spec);

}  // namespace flashtwin::sim
