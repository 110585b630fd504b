#pragma once
// Point-cloud preprocessing: validation, voxel-grid downsampling, statistical outlier removal,
// normals by k-NN PCA with consistent orientation, the thesis's γ feature points, removal of
// the support plane (table).
#include <limits>
#include <string>
#include <vector>

#include "flashtwin/core/mesh.hpp"

namespace flashtwin::perception {

/// "" when the cloud has at least `min_points` points, all finite; otherwise why not.
std::string validate_cloud(const PointCloud& cloud, std::size_t min_points = 10);

/// Voxel grid: one point per occupied voxel at the centroid of its points (normals averaged
/// and re-normalised when present). Deterministic order. @pre voxel > 0.
PointCloud voxel_downsample(const PointCloud& cloud, double voxel);

/// The thesis's improved voxel grid (§3.4): per voxel the original point nearest the voxel's
/// centroid is kept, so the output is a subset of the input (no averaging bias at edges and
/// corners). Deterministic order. @pre voxel > 0.
PointCloud voxel_downsample_nearest(const PointCloud& cloud, double voxel);

/// Drops points whose mean distance to their k neighbours exceeds mean + std_mult · std.
PointCloud remove_statistical_outliers(const PointCloud& cloud, int k, double std_mult);

/// Normals by PCA of the k nearest neighbours. Orientation: towards `viewpoint` when it is
/// finite; otherwise away from the centroid, then made consistent by propagation over the
/// neighbour graph from the point farthest from the centroid.
void estimate_normals(PointCloud& cloud, int k,
                      const Vec3& viewpoint = Vec3::Constant(std::numeric_limits<double>::quiet_NaN()));

/// The thesis's feature measure γ_i: mean angle [rad] between a point's normal and its k
/// neighbours' normals (orientation-free). @pre cloud has normals.
std::vector<float> normal_variation(const PointCloud& cloud, int k);

/// Indices of the `fraction` of points with the largest γ (at least 4 when possible).
std::vector<int> feature_points(const std::vector<float>& gamma, double fraction);

/// Finds the dominant support plane (RANSAC over planes with at most 5 % of the off-plane points
/// on one side: a part stands on its support, while a big face of the part has the rest of the
/// part on its other side); when it holds at least `min_share` of the points, removes
/// it (points within `distance` [m]) and everything on its far side, then keeps the largest
/// Euclidean cluster (points linked within `cluster_tolerance` [m]). Returns the cloud
/// unchanged when there is no dominant plane.
PointCloud remove_support_plane(const PointCloud& cloud, double distance, double cluster_tolerance,
                                double min_share = 0.2, std::uint64_t seed = 1);

}  // namespace flashtwin::perception
