#pragma once
// Flash detection (thesis §3.3–3.4): with the casting's estimated pose, the scan is compared
// with the CAD model; points off the nominal surface are clustered into flash regions; each
// region's alpha-shape boundary is split into the inner part (on the casting: the grinding
// line) and the outer part; the inner boundary is snapped onto the CAD surface, thinned by
// the improved voxel grid and ordered into polylines. Never reads ground truth.
#include <cstdint>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/mesh_query.hpp"

namespace flashtwin::perception {

/// Per-point label of a detection.
enum DetectLabel : std::uint8_t {
  kDetectBody = 0,     ///< on the nominal surface (within the threshold)
  kDetectFlash = 1,    ///< in a flash region
  kDetectIgnored = 2,  ///< outside the CAD box, on a support plane (table, fixture) or noise
};

struct DetectionParams {
  double crop_margin = 0.012;       ///< [m] the CAD bounding box grown by this is kept
  double noise_sigma = -1;          ///< [m] scanner noise; < 0: estimated from the points
                                    ///< on the CAD surface (robust, median absolute distance)
  double threshold_sigmas = 4.0;    ///< flash candidates lie farther than this × σ from the CAD
  double min_threshold = 0.08e-3;   ///< [m] lower bound of that threshold
  double max_threshold = 1.0e-3;    ///< [m] upper bound of that threshold
  double cluster_tolerance = 0;     ///< [m] Euclidean clustering; 0: 3 × spacing across lines
  int min_region_points = 40;       ///< smaller clusters are dropped as noise
  /// Clusters under 5 × min_region_points (a fin seen only obliquely: each scan line its own
  /// cluster) are re-clustered among themselves at this × the clustering tolerance; ≤ 1: off.
  double fragment_merge = 2.5;
  double support_distance = 0.5e-3; ///< [m] inlier band of support planes (table, fixture)
  double support_side_tolerance = 0.5e-3;  ///< [m] a plane with the whole CAD on one side
                                           ///< (within this) is a support, not a fin
  double alpha = 0;                 ///< [m] alpha-shape (rolling circle) radius; 0: 1.5 ×
                                    ///< spacing across lines
  double inner_band = 0;            ///< [m] boundary points within threshold + this of the
                                    ///< CAD are inner (on the casting); 0: 1.5 × spacing across lines
  /// [m] where no root point is seen (the root hidden from every view), boundary points within
  /// threshold + this of the CAD stand for it, snapped; only those landing ≥ max(1 mm, 3 ×
  /// spacing) from every seen root point. 0: off.
  double hidden_root_band = 2e-3;
  double path_voxel = 0.4e-3;       ///< [m] improved voxel grid over the snapped path points
  /// true: the thesis's improved voxel grid (per voxel the original point nearest the centroid);
  /// false: the plain voxel grid (the centroid itself), kept for the §3.4 comparison.
  bool path_voxel_nearest = true;
  double gap = 0;                   ///< [m] polylines split at gaps longer than this; 0:
                                    ///< max(4 × path_voxel, 4 × spacing across)
  double min_path_length = 2e-3;    ///< [m] shorter pieces of grinding line are dropped
  int smoothing = 3;                ///< moving-average half window along polylines [points]
  /// A hole's flash is a ring: an open path running at least 45° round a hole wall (circle
  /// fit within max(0.15 mm, 3σ), CAD normals towards its centre) is closed along that circle
  /// (refined on the CAD wall) where the CAD wall is there.
  bool close_holes = true;
  bool mid_plane = true;            ///< shift the path from the fin's visible face to its
                                    ///< mid-plane (half the thickness seen at the fin's edge)
};

/// One flash region (a fin or part of one).
struct FlashRegion {
  std::vector<std::uint32_t> points;  ///< indices into the input scan
  Vec3 centroid_C = Vec3::Zero();     ///< [m] in the casting frame {C}
  Vec3 normal_C = Vec3::UnitZ();      ///< local fin plane normal (towards the scanner)
  double extent_major = 0, extent_minor = 0;  ///< [m] size within the fin plane
  double max_height = 0;              ///< [m] largest distance of its points to the CAD
  double thickness = 0;               ///< [m] estimated at the fin's edge (0: not seen)
  int boundary_points = 0;            ///< alpha-shape boundary points
  int inner_points = 0;               ///< of which on the casting (inner boundary)
};

/// One ordered grinding line on the CAD surface.
struct FlashPath {
  int region = -1;
  std::vector<Vec3> points_C;   ///< [m] ordered, on the nominal surface, {C}
  std::vector<Vec3> normals_C;  ///< outward CAD surface normal at each point
  Vec3 fin_normal_C = Vec3::UnitZ();  ///< the region's fin plane normal
  bool closed = false;          ///< a closed loop (the last point connects to the first)
  double fin_height = 0;        ///< [m] its region's height off the CAD (FlashRegion::max_height)
  double length() const;        ///< [m] (including the closing segment)
};

struct DetectionResult {
  bool ran = false;                 ///< false: bad input, see message
  std::string message;
  std::vector<std::uint8_t> labels; ///< DetectLabel per input point
  std::vector<FlashRegion> regions;
  std::vector<FlashPath> paths;     ///< empty: nothing to grind
  double noise_sigma = 0;           ///< [m] used (given or estimated)
  double threshold = 0;             ///< [m] flash candidate distance
  double spacing = 0;               ///< [m] median nearest-neighbour spacing of the candidates
  double spacing_across = 0;        ///< [m] median spacing across scan lines (nearest
                                    ///< neighbour off the line to the nearest one); sets the
                                    ///< clustering, alpha, band and gap scales
  std::size_t cropped_points = 0;   ///< points inside the grown CAD box
  std::size_t candidate_points = 0; ///< off the CAD by more than the threshold
  std::size_t support_points = 0;   ///< candidates removed as support planes
  std::size_t path_points_before = 0;  ///< inner-boundary points entering the voxel grid
  std::size_t path_points_after = 0;   ///< points it kept (first pass, all regions)
  double path_voxel_time_s = 0;        ///< wall time of that first pass, all regions
  double time_s = 0;                ///< wall time
};

/// Detects flashes in `scan_M` (points in the scanner frame {M}) given the CAD model in {C}
/// and the estimated pose X_CM (maps scan points into {C}).
/// @throws ArgumentError for an empty scan, NaN/inf points, a pose that is not rigid,
/// impossible parameters, or a scan and CAD model whose sizes differ by units (no point near
/// the CAD, or extents differing by more than 50×).
DetectionResult detect_flash(const PointCloud& scan_M, const MeshBvh& cad_C, const Pose& X_CM,
                             const DetectionParams& params = {});

/// Orders unordered points of one curve into polylines: links of the Euclidean minimum
/// spanning tree up to `gap` long are kept, and longer ones (up to 4 × gap) where the curve is
/// sampled that sparsely round them (scan lines crossing a root a few millimetres apart: at
/// least two other links over gap / 1.5 within three of its lengths, it at most 1.5 × their
/// median); each component becomes the longest path through its tree, and pieces whose ends
/// lie within 3 × gap and continue into each other (within 30°) are joined. `closed` when it is
/// longer than 4 × gap and its ends are within gap (or its longest link), or it turns a full
/// circle with its ends closer than a quarter of its length and 4 × gap (a partly hidden loop).
struct Polyline {
  std::vector<Vec3> points;
  std::vector<int> source;  ///< index of each point in the input
  bool closed = false;
};
std::vector<Polyline> order_polylines(const std::vector<Vec3>& points, double gap);

/// The plane of a fin region's points [m]: the plane through three of them that most lie within
/// `band` of, among those holding at least half the points that touch the casting (`touch`,
/// one flag per point), by RANSAC from a fixed seed, refitted by least squares to those; the plain
/// least-squares plane when that holds as many (`consensus` false). Unit normal (either sign)
/// and a point on it.
struct FinPlane {
  Vec3 n = Vec3::UnitZ(), c = Vec3::Zero();
  bool consensus = false;
};
FinPlane fin_plane(const std::vector<Vec3>& pts, const std::vector<bool>& touch, double band);

/// Root normals within 30° of `fin_normal_C` (a face parallel to the fin: the root runs along
/// an edge) take the normal of the nearest point along the path whose normal is a wall's
/// (cyclic for closed paths). Returns how many were replaced; none when no point or every
/// point has a wall's normal.
int repair_fin_parallel_normals(FlashPath& path, const Vec3& fin_normal_C);

/// Joins open paths that continue each other (one root split between regions): ends within
/// `reach` [m], both leaving within 30° of one line (directions from the points within `span`
/// [m] of each end), the second's end within span/2 of the first's end line, fin planes within
/// 20°; the later path's leading points up to the first past the junction are dropped and the
/// joined path is oriented as detect_flash orients paths. Returns how many paths were joined
/// into others (removed from `paths`).
int join_continuing_paths(std::vector<FlashPath>& paths, double reach, double span);

/// 2-D alpha shape (rolling circle of radius alpha): flags of the points a circle of that
/// radius touches with no other point inside. `uv` holds the points in the fin plane [m].
std::vector<bool> alpha_boundary(const std::vector<Eigen::Vector2d>& uv, double alpha,
                                 const std::vector<bool>& test_only = {});

}  // namespace flashtwin::perception
