// libFuzzer harness: scenario YAML (pipeline::load_scenario, with `--set` overrides).
// Expected: flashtwin::InputError (ConfigError, IoError); anything else is a finding.
//
// load_scenario reads a file and resolves the robot path against the scenario's folder, so
// the input is written to <scratch>/scenarios/fuzz.yaml next to a copy of the shipped robot
// at <scratch>/models/robots/ft6.yaml: the seeds say `robot: ../models/robots/ft6.yaml`,
// as the shipped scenarios do. Leading lines "#set KEY=VALUE" (YAML comments, so the file
// stays the same document) become overrides, as `flashtwin run --set KEY=VALUE` gives them.
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

#include "flashtwin/core/io.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "fuzz_common.hpp"

namespace {

// The "#set " lines at the top of the input.
std::vector<std::string> leading_overrides(const std::string& text) {
  std::vector<std::string> out;
  std::size_t pos = 0;
  while (text.compare(pos, 5, "#set ") == 0) {
    const std::size_t end = text.find('\n', pos);
    out.push_back(
        text.substr(pos + 5, end == std::string::npos ? std::string::npos : end - pos - 5));
    if (end == std::string::npos) break;
    pos = end + 1;
  }
  return out;
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  namespace fs = std::filesystem;
  flashtwin::fuzz::quiet();
  const std::string robot = flashtwin::fuzz::source_root() + "/models/robots/ft6.yaml";
  const fs::path dir = fs::path(flashtwin::fuzz::scratch_dir());
  try {
    fs::create_directories(dir / "scenarios");
    fs::create_directories(dir / "models" / "robots");
    flashtwin::write_text_file((dir / "models" / "robots" / "ft6.yaml").string(),
                               flashtwin::read_text_file(robot));
  } catch (const std::exception& e) {
    std::fprintf(stderr,
                 "fuzz_scenario: cannot set up the scratch folder (set FLASHTWIN_HOME?): %s\n",
                 e.what());
    std::abort();
  }
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const flashtwin::fuzz::ScratchFile file("scenarios/fuzz.yaml", data, size);
  const std::vector<std::string> overrides =
      leading_overrides(flashtwin::fuzz::as_text(data, size));
  flashtwin::fuzz::expect_input_error(
      [&] { (void)flashtwin::pipeline::load_scenario(file.path(), overrides); });
  return 0;
}
