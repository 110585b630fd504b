// libFuzzer harness: paths.json as `flashtwin detect` writes it and `flashtwin plan` reads it
// (pipeline read_paths_from_string). Expected: flashtwin::InputError; anything else
// (nlohmann::json's own exceptions included) is a finding.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <string>

#include "flashtwin/pipeline/paths_io.hpp"
#include "fuzz_common.hpp"

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text = flashtwin::fuzz::as_text(data, size);
  flashtwin::fuzz::expect_input_error([&] {
    const auto paths = flashtwin::pipeline::read_paths_from_string(text, "fuzz_paths.json");
    // What the reader promises for what it accepts: finite coordinates, one normal per point
    // when there are normals.
    for (const auto& g : paths) {
      bool ok = g.normals_C.empty() || g.normals_C.size() == g.points_C.size();
      for (const auto& p : g.points_C) ok = ok && p.allFinite();
      for (const auto& n : g.normals_C) ok = ok && n.allFinite();
      ok = ok && g.fin_normal_C.allFinite();
      if (!ok) {
        std::fprintf(stderr,
                     "fuzz_paths_json: accepted a path with non-finite or unmatched data\n");
        std::abort();
      }
    }
  });
  return 0;
}
