// libFuzzer harness: pose JSON files (pipeline read_pose_from_string, both key sets the CLI
// uses), and the writer: every pose read must survive pose_json → read unchanged.
// Expected: flashtwin::InputError (ArgumentError for a non-rigid matrix); anything else
// (nlohmann::json's own exceptions included) is a finding.
#include <cmath>
#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <cstdlib>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>

#include "flashtwin/pipeline/pose_json.hpp"
#include "fuzz_common.hpp"

namespace {

void check_round_trip(const flashtwin::Pose& X) {
  // Not inside expect_input_error's scope: a pose we wrote must read back, whatever it is.
  const flashtwin::Pose Y = flashtwin::pipeline::read_pose_from_string(
      flashtwin::pipeline::pose_json(X).dump(), "round trip");
  const double dR = (X.linear() - Y.linear()).cwiseAbs().maxCoeff();
  if (!(dR <= 1e-12) || X.translation() != Y.translation()) {
    std::fprintf(stderr, "fuzz_pose_json: pose_json round trip changed the pose (rotation by %g)\n",
                 dR);
    std::abort();
  }
}

}  // namespace

extern "C" int LLVMFuzzerInitialize(int*, char***) {
  flashtwin::fuzz::quiet();
  return 0;
}

extern "C" int LLVMFuzzerTestOneInput(const std::uint8_t* data, std::size_t size) {
  const std::string text = flashtwin::fuzz::as_text(data, size);
  // `detect --pose` (T_target_source or X_CM) and `plan --pose` (X_BC or T_base_casting).
  const std::vector<std::vector<std::string>> key_sets = {{"T_target_source", "X_CM"},
                                                          {"X_BC", "T_base_casting"}};
  for (const auto& keys : key_sets) {
    bool read = false;
    flashtwin::Pose X;
    flashtwin::fuzz::expect_input_error([&] {
      X = flashtwin::pipeline::read_pose_from_string(text, "fuzz_pose.json", keys);
      read = true;
    });
    if (read) check_round_trip(X);
  }
  return 0;
}
