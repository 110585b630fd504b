#pragma once
// Poses as JSON: 16 numbers, the 4x4 homogeneous matrix row-major. `flashtwin fk/register
// --json` write them; `flashtwin detect --pose` and `plan --pose` read them.
#include <nlohmann/json_fwd.hpp>
#include <string>
#include <vector>

#include "flashtwin/core/transform.hpp"

namespace flashtwin::pipeline {

/// The pose as a JSON array of 16 numbers (row-major 4x4).
nlohmann::json pose_json(const Pose& X);

/// Parses a pose from JSON text: 16 numbers (flat or as 4x4 nested arrays), either the whole
/// document or, when the document is an object, the value of the first of `keys` it has.
/// `name` stands in for the file name in messages.
/// @throws InputError naming `name` (not JSON, no such key, not 16 numbers), ArgumentError
/// (NaN/inf, or not a rigid transform).
Pose read_pose_from_string(const std::string& text, const std::string& name,
                           const std::vector<std::string>& keys = {"T_target_source", "X_CM"});

/// Reads a pose file (see read_pose_from_string).
/// @throws IoError (missing/unreadable file), and what read_pose_from_string throws.
Pose read_pose_file(const std::string& path,
                    const std::vector<std::string>& keys = {"T_target_source", "X_CM"});

}  // namespace flashtwin::pipeline
