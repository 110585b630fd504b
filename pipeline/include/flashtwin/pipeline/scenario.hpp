#pragma once
// Scenario files (scenarios/*.yaml): which robot, which cell, which casting, which seed.
#include <cstdint>
#include <string>

#include "flashtwin/core/robot.hpp"
#include "flashtwin/sim/cell.hpp"

namespace flashtwin::pipeline {

struct Scenario {
  std::string name;
  std::string file;         ///< the scenario file it was read from
  std::string description;
  std::uint64_t seed = 1;   ///< master seed of every random choice of the run
  RobotModel robot;
  sim::CellSpec cell;
};

/// Reads and validates a scenario; relative paths inside are resolved against its folder.
/// @throws IoError (missing file), ConfigError (naming file and key: malformed, out of range,
/// unknown keys).
Scenario load_scenario(const std::string& path);

}  // namespace flashtwin::pipeline
