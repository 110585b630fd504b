#pragma once
// Pose estimation: register a scan (source) to a CAD model (target). The project's method is
// PCA principal-axis alignment + 4PCS global registration + normal-constrained ICP; PCL
// baselines live in baselines.hpp. No PCL types in this header.
#include <memory>
#include <string>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::perception {

/// Outcome of a registration, whatever the method.
struct RegistrationResult {
  bool ran = false;            ///< false: bad input (see message); the pose is meaningless
  Pose T_target_source = Pose::Identity();  ///< maps source points into the target frame
  bool confident = false;      ///< the method's own verdict (inliers, residual, ambiguity)
  double fitness = 0;          ///< inlier fraction of the source [0, 1]
  double rmse = 0;             ///< inlier RMSE [m]
  double ambiguity = 0;        ///< score of the best distinct alternative / best score [0, 1]
  /// Along a weakly constrained translation direction (if any): the facing surfaces' sharp
  /// inlier peak over the highest count away from it (1: no weak direction was examined).
  double weak_direction_peak = 1;
  double time_s = 0;           ///< wall time of the call
  std::string stage;           ///< which global stage produced the pose ("pca", "4pcs", ...)
  std::string message;         ///< why not confident / what failed
};

/// Parameters of the target model (built once per CAD model).
struct TargetParams {
  int mesh_samples = 60000;        ///< points sampled on a mesh target (area-uniform)
  double coarse_voxel = 1.0 / 40;  ///< coarse voxel size, fraction of the bounding-box diagonal
  double fine_voxel = 1.0 / 250;   ///< fine voxel size, fraction of the diagonal
  int normal_k = 12;               ///< neighbours for normals of cloud targets
  std::uint64_t seed = 1;          ///< sampling seed
};

/// A registration target: dense points with outward normals, a k-d tree over them, coarse and
/// fine subsets, principal axes and feature points. Immutable after construction and safe to
/// share across threads and scans of the same part.
class ModelTarget {
 public:
  /// From a CAD mesh: area-uniform samples with the triangles' normals.
  /// @throws ArgumentError for an empty or degenerate mesh.
  static std::shared_ptr<const ModelTarget> from_mesh(const TriangleMesh& mesh,
                                                      const TargetParams& params = {});
  /// from_mesh through a small process-wide cache (the last 4 meshes, compared in full): runs
  /// of a sweep over one part (a user's mesh) build its target once. Thread-safe; the same
  /// result as from_mesh.
  static std::shared_ptr<const ModelTarget> from_mesh_cached(const TriangleMesh& mesh,
                                                             const TargetParams& params = {});
  /// From a point cloud (normals estimated when missing).
  /// @throws ArgumentError for fewer than 10 points or NaN/inf coordinates.
  static std::shared_ptr<const ModelTarget> from_cloud(const PointCloud& cloud,
                                                       const TargetParams& params = {});
  ~ModelTarget();
  double diagonal() const;            ///< bounding-box diagonal [m]
  const PointCloud& dense() const;    ///< all target points with normals
  const PointCloud& coarse() const;   ///< coarse voxel subset with normals
  struct Impl;
  const Impl& impl() const { return *impl_; }

 private:
  explicit ModelTarget(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

/// Parameters of the project's method (lengths relative to the target's diagonal unless [m]).
struct RegistrationParams {
  // Preprocessing of the source.
  double coarse_voxel = 1.0 / 40;     ///< voxel size for the global stage
  double fine_voxel = 1.0 / 250;      ///< voxel size for the final ICP
  int normal_k = 12;                  ///< neighbours for normals and for γ features
  int sor_k = 16;                     ///< statistical outlier removal: neighbours
  double sor_std = 2.5;               ///< ... and the std-dev multiplier
  double feature_fraction = 0.3;      ///< keep this share of points with the largest γ
  bool remove_support_plane = false;  ///< drop the dominant plane (table) and keep the
                                      ///< largest cluster above it (scans of a cell)
  // Global stage.
  bool use_pca = true;                ///< try the 4 proper PCA axis alignments
  bool use_4pcs = true;               ///< run 4PCS when PCA is not convincing
  double pca_accept_fitness = 0.85;   ///< PCA + ICP result good enough to skip 4PCS
  int fpcs_bases = 200;               ///< 4PCS: coplanar bases tried at most
  double fpcs_overlap = 0.6;          ///< 4PCS: expected overlap (base width)
  double fpcs_delta = 1.0 / 50;       ///< 4PCS: congruence tolerance (fraction of diagonal)
  // ICP.
  bool point_to_plane = true;         ///< final ICP point-to-plane (else point-to-point)
  bool reciprocal = true;             ///< keep only mutual nearest neighbours
  double normal_angle = 0.6;          ///< [rad] τ: reject pairs whose normals differ more
  int icp_iterations = 25;            ///< reciprocal, normal-constrained ICP iterations
  int polish_iterations = 7;          ///< final robust point-to-plane passes over every fine point
  double icp_converge = 1e-3;         ///< stop when the relative error change is below this
  // Verdict.
  double min_fitness = 0.6;           ///< inlier share needed to be confident
  double max_rmse = 1.0 / 300;        ///< inlier RMSE allowed (fraction of the diagonal)
  double max_ambiguity = 0.6;         ///< runner-up evidence / winner evidence allowed (see Result)
  /// Source viewpoint for normal orientation ({S} frame of the source points); NaN = unknown
  /// (normals then point away from the centroid and are made consistent over neighbours).
  Vec3 viewpoint = Vec3::Constant(std::numeric_limits<double>::quiet_NaN());
  /// After the polish, a translation direction whose constraint eigenvalue is below this share
  /// of the strongest is searched (offsets up to diag/15, a quarter fine voxel apart) for the pose
  /// that explains the most points.
  double weak_direction_ratio = 0.1;
  /// ... and the best offset is taken when it explains this share more points than the polish.
  double weak_direction_gain = 0.01;
  /// Then the pose settles where the surfaces facing that direction agree (their sharp inliers
  /// peak); the pose is confident only when that peak is this many times the highest count
  /// more than three bands away from it (1: no check).
  double weak_direction_peak = 1.5;
  /// After the polish, a turn (the translation following) whose stiffness at half the diagonal
  /// is below this share of the strongest translation's is searched likewise (turns up to
  /// 2/15 rad about its axis) for the pose that explains the most points.
  double weak_turn_ratio = 0.01;
};

/// The project's registration: preprocessing, PCA alignment (4 proper rotations), 4PCS, ICP
/// with reciprocal correspondences, distance threshold and normal-angle rejection, coarse to
/// fine, then the verdict. Never throws for bad clouds: returns ran = false with a message.
RegistrationResult register_scan(const PointCloud& source, const ModelTarget& target,
                                 const RegistrationParams& params = {});

}  // namespace flashtwin::perception
