#pragma once
// Scanning a written cell: the cell's geometry posed from MuJoCo's state (robot at a
// keyframe), the casting and its flashes as exact meshes, scanned with Embree. MuJoCo-free
// interface for the pipeline and the CLI.
#include <string>

#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/scanner.hpp"

namespace flashtwin::sim {

/// Default views of the cell's scanner: a line profiler swept 0.4 m across the table straight
/// down, and four views tilted by 30° about the sweep axis (seeing the four side walls).
std::vector<ScanView> default_scan_views();

/// X_WM perturbed by a seeded rigid error of the given size: translation `translation` [m]
/// along a random direction, rotation `rotation` [rad] about a random axis.
Pose perturb_pose(const Pose& X_WM, double translation, double rotation, std::uint64_t seed);

struct CellScan {
  ScanResult result;     ///< points in {M} (as the true mount sees them), truth labels
  Pose X_WM_nominal;     ///< the calibrated scanner pose reported beside the cloud
  Pose X_WM_true;        ///< where the scanner really is (scoring only)
  std::size_t scene_triangles = 0;
};

/// Scans the cell of `mjcf_path` with the robot at `keyframe`: every geom except the
/// casting's and the scanner head's is background; the casting (nominal = body, fins = flash)
/// is placed at the pose MuJoCo gives body `casting`.
/// @throws InputError (model), ArgumentError (scan parameters).
CellScan scan_cell(const std::string& mjcf_path, const Casting& casting, const ScanParams& params,
                   const Pose& X_WM_nominal, const Pose& X_WM_true,
                   const std::string& keyframe = "home");

}  // namespace flashtwin::sim
