#include "flashtwin/pipeline/paths_io.hpp"

#include <cmath>

#include <nlohmann/json.hpp>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

namespace flashtwin::pipeline {

using json = nlohmann::json;

std::vector<planner::GrindPath> read_paths_from_string(const std::string& text,
                                                       const std::string& name) {
  json j;
  try {
    j = json::parse(text);
  } catch (const json::exception& e) {
    // parse_error, and out_of_range for numbers beyond double ("1e999").
    throw InputError(name + ": expected the paths JSON of `flashtwin detect`, got a parse error (" +
                     e.what() + ")");
  }
  if (!j.is_object() || !j.contains("paths") || !j["paths"].is_array())
    throw InputError(name + ": expected an object with a 'paths' array");
  const auto vec = [&](const json& a, const std::string& where) {
    if (!a.is_array() || a.size() != 3 || !a[0].is_number() || !a[1].is_number() ||
        !a[2].is_number())
      throw InputError(name + ": " + where + ": expected [x, y, z]");
    Vec3 v(a[0].get<double>(), a[1].get<double>(), a[2].get<double>());
    if (!v.allFinite()) throw InputError(name + ": " + where + ": expected finite numbers");
    return v;
  };
  const json& paths = j["paths"];
  std::vector<planner::GrindPath> out;
  for (std::size_t k = 0; k < paths.size(); ++k) {
    const json& p = paths[k];
    const std::string where = "paths[" + std::to_string(k) + "]";
    if (!p.is_object() || !p.contains("points") || !p["points"].is_array())
      throw InputError(name + ": " + where + ": expected 'points'");
    planner::GrindPath g;
    for (std::size_t i = 0; i < p["points"].size(); ++i)
      g.points_C.push_back(vec(p["points"][i], where + ".points[" + std::to_string(i) + "]"));
    if (p.contains("normals")) {
      if (!p["normals"].is_array() || p["normals"].size() != g.points_C.size())
        throw InputError(name + ": " + where + ".normals: expected one per point");
      for (std::size_t i = 0; i < p["normals"].size(); ++i)
        g.normals_C.push_back(vec(p["normals"][i], where + ".normals[" + std::to_string(i) + "]"));
    }
    if (p.contains("fin_normal")) g.fin_normal_C = vec(p["fin_normal"], where + ".fin_normal");
    if (p.contains("closed")) {
      // json::value() would throw nlohmann's type_error for a non-boolean.
      if (!p["closed"].is_boolean())
        throw InputError(name + ": " + where + ".closed: expected true or false, got " +
                         p["closed"].type_name());
      g.closed = p["closed"].get<bool>();
    }
    if (p.contains("fin_height")) {
      const json& h = p["fin_height"];
      if (!h.is_number() || !std::isfinite(h.get<double>()) || h.get<double>() < 0)
        throw InputError(name + ": " + where + ".fin_height: expected a number >= 0 [m], got " +
                         h.dump());
      g.fin_height = h.get<double>();
    }
    out.push_back(std::move(g));
  }
  return out;
}

std::vector<planner::GrindPath> read_paths_file(const std::string& path) {
  return read_paths_from_string(read_text_file(path), path);
}

}  // namespace flashtwin::pipeline
