// libFuzzer harness: PLY files, both readers of them: the point-cloud reader (core load_cloud:
// scans) and the mesh reader (core load_mesh: a user's CAD as PLY), both core/src/cloud_io.cpp.
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
  const flashtwin::fuzz::ScratchFile file("input.ply", data, size);
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_cloud(file.path()); });
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_mesh(file.path()); });
  return 0;
}
