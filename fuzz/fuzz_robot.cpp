// libFuzzer harness: robot description YAML (core parse_robot, what load_robot calls).
// Expected: flashtwin::InputError (ConfigError); anything else is a finding.
#include <cstddef>
#include <cstdint>
#include <string>

#include "flashtwin/core/robot.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text = flashtwin::fuzz::as_text(data, size);
  flashtwin::fuzz::expect_input_error(
      [&] { (void)flashtwin::parse_robot(text, "fuzz_robot.yaml"); });
  return 0;
}
