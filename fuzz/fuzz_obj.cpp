// libFuzzer harness: Wavefront OBJ meshes (core load_mesh, assimp picks the format by the
// extension). Expected: flashtwin::InputError (IoError); anything else is a finding.
// A `mtllib` line makes assimp look for the material file next to the input, in this
// process's scratch folder, where there is none.
#include <cstddef>
#include <cstdint>

#include "flashtwin/core/mesh.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const flashtwin::fuzz::ScratchFile file("input.obj", data, size);
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_mesh(file.path()); });
  return 0;
}
