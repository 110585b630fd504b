#pragma once
// Helpers shared by the test suites.
#include <cstdlib>
#include <filesystem>
#include <random>
#include <string>
#include <unistd.h>

#include "flashtwin/core/robot.hpp"

namespace ftest {
using namespace flashtwin;

inline std::string source_path(const std::string& rel) {
  return std::string(FLASHTWIN_SOURCE_DIR) + "/" + rel;
}

inline RobotModel ft6() { return load_robot(source_path("models/robots/ft6.yaml")); }

/// A fresh, empty temporary folder for one test.
inline std::string temp_dir(const std::string& name) {
  const auto p = std::filesystem::temp_directory_path() /
                 ("flashtwin_test_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  return p.string();
}

}  // namespace ftest
