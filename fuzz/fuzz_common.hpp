#pragma once
// Shared pieces of the libFuzzer harnesses.
//
// The contract every harness checks (DESIGN.md, Style 4; core/errors.hpp): bad input makes a
// reader throw flashtwin::InputError (IoError, ConfigError, ArgumentError derive from it).
// A harness catches that and nothing else, so any other exception (std::bad_alloc,
// std::logic_error, YAML::Exception, nlohmann::json::exception, PCL's exceptions), a crash,
// a sanitizer report, a leak or a hang is a finding.
#include <spdlog/spdlog.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <string>

#include "flashtwin/core/errors.hpp"

namespace flashtwin::fuzz {

/// This process's scratch folder (/tmp/flashtwin-fuzz-<pid>), created on first use and removed
/// at exit. libFuzzer's -jobs/-workers/-fork run separate processes, so none share a file.
inline const std::string& scratch_dir() {
  // Never destroyed: the atexit hook below runs after static destructors registered later.
  static const std::string* const dir = [] {
    namespace fs = std::filesystem;
    const fs::path d = fs::temp_directory_path() / ("flashtwin-fuzz-" + std::to_string(::getpid()));
    std::error_code ec;
    fs::create_directories(d, ec);
    if (ec) {
      std::fprintf(stderr, "fuzz: cannot create %s: %s\n", d.c_str(), ec.message().c_str());
      std::abort();
    }
    auto* s = new std::string(d.string());
    std::atexit([] {
      std::error_code e;
      std::filesystem::remove_all(scratch_dir(), e);
    });
    return s;
  }();
  return *dir;
}

/// The fuzzer's bytes as a file `name` (its extension picks the reader) in the scratch folder,
/// removed again when this goes out of scope.
class ScratchFile {
 public:
  ScratchFile(const std::string& name, const std::uint8_t* data, std::size_t size)
      : path_(scratch_dir() + "/" + name) {
    std::ofstream out(path_, std::ios::binary | std::ios::trunc);
    out.write(reinterpret_cast<const char*>(data), static_cast<std::streamsize>(size));
    out.close();
    if (!out) {
      // The harness's own failure, not the reader's: stop loudly.
      std::fprintf(stderr, "fuzz: cannot write %s\n", path_.c_str());
      std::abort();
    }
  }
  ~ScratchFile() {
    std::error_code ec;
    std::filesystem::remove(path_, ec);
  }
  ScratchFile(const ScratchFile&) = delete;
  ScratchFile& operator=(const ScratchFile&) = delete;

  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

/// The fuzzer's bytes as a string.
inline std::string as_text(const std::uint8_t* data, std::size_t size) {
  return std::string(reinterpret_cast<const char*>(data), size);
}

/// Runs `read` and swallows the documented bad-input exceptions (InputError and its subclasses);
/// everything else propagates and aborts the run as a finding.
template <typename F>
void expect_input_error(F&& read) {
  try {
    read();
  } catch (const InputError&) {
  }
}

/// Logging off: the readers' messages would dominate the run time.
inline void quiet() {
  spdlog::set_level(spdlog::level::off);
}

/// Root of the source tree (FLASHTWIN_HOME at run time, else the configured source dir).
inline std::string source_root() {
  const char* home = std::getenv("FLASHTWIN_HOME");
  return home ? home : FLASHTWIN_SOURCE_DIR;
}

}  // namespace flashtwin::fuzz
