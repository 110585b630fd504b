#pragma once
// Reading grinding paths back from the paths.json that `flashtwin detect` writes
// (write_paths in run.hpp), for `flashtwin plan`.
#include <string>
#include <vector>

#include "flashtwin/planner/grind_planner.hpp"

namespace flashtwin::pipeline {

/// Parses paths.json text: an object with a "paths" array whose entries have "points"
/// ([x, y, z] each, frame {C}, metres) and optionally "normals" (one per point), "fin_normal"
/// and "closed"; other keys are ignored. `name` stands in for the file name in messages.
/// @throws InputError naming `name` and the entry ("paths[2].points[5]: expected [x, y, z]").
std::vector<planner::GrindPath> read_paths_from_string(const std::string& text,
                                                       const std::string& name);

/// Reads a paths.json file (see read_paths_from_string).
/// @throws IoError (missing/unreadable file), and what read_paths_from_string throws.
std::vector<planner::GrindPath> read_paths_file(const std::string& path);

}  // namespace flashtwin::pipeline
