#include "flashtwin/pipeline/pose_json.hpp"

#include <algorithm>
#include <array>
#include <nlohmann/json.hpp>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

namespace flashtwin::pipeline {

using json = nlohmann::json;

namespace {

// A pose is at most two arrays deep (4x4); deeper nesting is refused well before the
// recursion below could exhaust the stack on a crafted file.
constexpr int kMaxPoseDepth = 32;

}  // namespace

json pose_json(const Pose& X) {
  const auto m = to_row_major(X);
  return json(std::vector<double>(m.begin(), m.end()));
}

Pose read_pose_from_string(const std::string& text, const std::string& name,
                           const std::vector<std::string>& keys) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    // parse_error, and out_of_range for numbers beyond double ("1e999").
    throw InputError(name + ": expected JSON with a 4x4 pose, got a parse error (" + e.what() +
                     ")");
  }
  if (j.is_object()) {
    std::string names;
    bool found = false;
    for (const auto& k : keys) {
      names += (names.empty() ? "'" : " or '") + k + "'";
      if (!found && j.contains(k)) {
        j = json(j[k]);
        found = true;
      }
    }
    if (!found) throw InputError(name + ": expected key " + names + " with 16 numbers");
  }
  std::vector<double> v;
  const auto collect = [&](const json& a, int depth, auto&& self) -> void {
    if (a.is_array()) {
      if (depth >= kMaxPoseDepth)
        throw InputError(name + ": expected a 4x4 pose, got arrays nested deeper than " +
                         std::to_string(kMaxPoseDepth));
      for (const auto& e : a) self(e, depth + 1, self);
    } else if (a.is_number()) {
      v.push_back(a.get<double>());
    } else {
      // Objects are named, not dumped: dump() recurses as deep as the object does.
      throw InputError(name + ": expected numbers in the pose, got " +
                       (a.is_object() ? std::string("an object") : a.dump()));
    }
  };
  collect(j, 0, collect);
  if (v.size() != 16)
    throw InputError(name + ": expected 16 numbers (row-major 4x4), got " +
                     std::to_string(v.size()));
  std::array<double, 16> a{};
  std::copy(v.begin(), v.end(), a.begin());
  return pose_from_row_major(a, name);
}

Pose read_pose_file(const std::string& path, const std::vector<std::string>& keys) {
  return read_pose_from_string(read_text_file(path), path, keys);
}

}  // namespace flashtwin::pipeline
