// libFuzzer harness: PCD point clouds (core load_cloud, core/src/cloud_io.cpp).
// Expected: flashtwin::InputError (IoError, ArgumentError); anything else is a finding.
#include <cstddef>
#include <cstdint>

#include "flashtwin/core/mesh.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const flashtwin::fuzz::ScratchFile file("input.pcd", data, size);
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_cloud(file.path()); });
  return 0;
}
