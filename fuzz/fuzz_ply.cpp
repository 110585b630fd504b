// libFuzzer harness: PLY files, both readers of them: the point-cloud reader (core load_cloud,
// PCL's PLYReader: scans) and the mesh reader (core load_mesh, assimp: a user's CAD as PLY).
// Expected: flashtwin::InputError (IoError, ArgumentError); anything else is a finding.
#include <pcl/console/print.h>

#include <cstddef>
#include <cstdint>

#include "flashtwin/core/mesh.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  pcl::console::setVerbosityLevel(pcl::console::L_ALWAYS);
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const flashtwin::fuzz::ScratchFile file("input.ply", data, size);
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_cloud(file.path()); });
  flashtwin::fuzz::expect_input_error([&] { (void)flashtwin::load_mesh(file.path()); });
  return 0;
}
