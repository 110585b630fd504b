#pragma once
// PCL baselines for the registration comparison (same inputs, same result type).
#include <string>

#include "flashtwin/perception/registration.hpp"

namespace flashtwin::perception {

enum class Baseline {
  kSacIaNdt,    ///< FPFH features + SAC-IA, refined by NDT
  kSacIaNdtIcp, ///< FPFH features + SAC-IA, refined by NDT, then ICP
  kNdtIcp,      ///< NDT from identity, refined by ICP
  kIss3dscIcp,  ///< ISS keypoints + 3D shape context + correspondence RANSAC, refined by ICP
  kFpcsIcp,     ///< PCL's FPCSInitialAlignment (4PCS), refined by ICP
};

/// "sacia-ndt", "sacia-ndt-icp", "ndt-icp", "iss-3dsc-icp", "fpcs-icp". @throws ArgumentError.
Baseline baseline_from_string(const std::string& s);
std::string to_string(Baseline b);

/// Runs a PCL baseline. Parameters scale with the target's bounding-box diagonal. `confident`
/// is PCL's own convergence flag combined with the same fitness/RMSE thresholds as ours.
/// Never throws for bad clouds: returns ran = false with a message.
RegistrationResult register_baseline(Baseline method, const PointCloud& source,
                                     const PointCloud& target, std::uint64_t seed = 1);

}  // namespace flashtwin::perception
