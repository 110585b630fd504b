#pragma once
// Helpers shared by the test suites.
#include <sys/wait.h>
#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <random>
#include <sstream>
#include <string>
#include <vector>

#include "flashtwin/core/robot.hpp"

namespace ftest {
using namespace flashtwin;

inline std::string source_path(const std::string& rel) {
  return std::string(FLASHTWIN_SOURCE_DIR) + "/" + rel;
}

inline RobotModel ft6() { return load_robot(source_path("models/robots/ft6.yaml")); }

/// The temporary folders this test process made; removed when it exits (a run's cell and
/// outputs take up to half a gigabyte, and a suite of hundreds filled the disk of a CI
/// machine). FLASHTWIN_KEEP_TEST_DIRS=1 keeps them for a look after a failure.
struct TempDirs {
  std::vector<std::filesystem::path> made;
  ~TempDirs() {
    if (const char* keep = std::getenv("FLASHTWIN_KEEP_TEST_DIRS"); keep && std::string(keep) == "1") return;
    std::error_code ec;
    for (const auto& p : made) std::filesystem::remove_all(p, ec);
  }
};

/// A fresh, empty temporary folder for one test.
inline std::string temp_dir(const std::string& name) {
  static TempDirs dirs;
  const auto p = std::filesystem::temp_directory_path() /
                 ("flashtwin_test_" + name + "_" + std::to_string(::getpid()));
  std::filesystem::remove_all(p);
  std::filesystem::create_directories(p);
  dirs.made.push_back(p);
  return p.string();
}

/// A file's bytes ("" when it cannot be read).
inline std::string slurp(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

/// Runs a shell command line; its exit status (-1 when it did not exit normally).
inline int shell(const std::string& command) {
  const int status = std::system(command.c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

}  // namespace ftest
