// libFuzzer harness: STL meshes, ASCII and binary (core load_mesh, assimp picks the format by
// the extension). Expected: flashtwin::InputError (IoError); anything else is a finding.
#include <cstddef>
#include <cstdint>

#include "flashtwin/core/mesh.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const flashtwin::fuzz::ScratchFile file("input.stl", data, size);
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_mesh(file.path()); });
  return 0;
}
