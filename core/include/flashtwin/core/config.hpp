#pragma once
// Strict YAML access for robot and scenario files: every read names the file and the dotted
// key path in its error ("robot.yaml: joints[2].limits.velocity: expected a number > 0, got
// -1"), and keys nobody read are reported as unknown instead of being silently ignored.
#include <yaml-cpp/yaml.h>

#include <memory>
#include <set>
#include <string>
#include <vector>

#include "flashtwin/core/transform.hpp"

namespace flashtwin {

/// A node of a YAML document with its file name and key path, for error messages.
class ConfigNode {
 public:
  /// Parses a YAML file. @throws IoError (missing/unreadable), ConfigError (syntax).
  static ConfigNode load_file(const std::string& path);
  /// Parses YAML text; `name` stands in for the file name in messages.
  static ConfigNode load_string(const std::string& text, const std::string& name);

  const std::string& file() const { return file_; }
  /// Dotted key path of this node ("" for the root).
  const std::string& path() const { return path_; }
  bool is_map() const { return node_.IsMap(); }
  bool is_sequence() const { return node_.IsSequence(); }
  bool is_scalar() const { return node_.IsScalar(); }
  bool is_null() const { return node_.IsNull(); }
  std::size_t size() const { return node_.size(); }

  /// True when the map has `key` (marks it as known).
  bool has(const std::string& key) const;
  /// Required child. @throws ConfigError when missing or when this is not a map.
  ConfigNode at(const std::string& key) const;
  /// Element of a sequence. @throws ConfigError when out of range.
  ConfigNode operator[](std::size_t i) const;
  /// Child keys of a map in document order.
  std::vector<std::string> keys() const;

  double as_double() const;
  /// A number within [lo, hi]. @throws ConfigError naming the field.
  double as_double(double lo, double hi) const;
  long long as_int(long long lo, long long hi) const;
  bool as_bool() const;
  std::string as_string() const;
  /// A sequence of exactly `n` numbers.
  std::vector<double> as_doubles(std::size_t n) const;
  Vec3 as_vec3() const;

  // Convenience: required and optional fields of a map.
  double get_double(const std::string& key, double lo, double hi) const;
  double get_double(const std::string& key, double lo, double hi, double fallback) const;
  long long get_int(const std::string& key, long long lo, long long hi, long long fallback) const;
  bool get_bool(const std::string& key, bool fallback) const;
  std::string get_string(const std::string& key) const;
  std::string get_string(const std::string& key, const std::string& fallback) const;
  Vec3 get_vec3(const std::string& key) const;
  Vec3 get_vec3(const std::string& key, const Vec3& fallback) const;
  /// A pose written as {xyz: [x, y, z], rpy: [r, p, y]} (both optional, zero by default).
  Pose get_pose(const std::string& key, const Pose& fallback) const;

  /// @throws ConfigError listing the keys of this map (recursively below it) that were never
  /// read: a typo must not be ignored.
  void check_all_used() const;

  /// Throws ConfigError "<file>: <path>: <msg>".
  [[noreturn]] void fail(const std::string& msg) const;
  /// What the node holds, for "got ...": the scalar as written, "a list", "a mapping".
  std::string describe() const;

 private:
  ConfigNode(YAML::Node node, std::string file, std::string path,
             std::shared_ptr<std::set<std::string>> used);
  std::string child_path(const std::string& key) const;

  YAML::Node node_;
  std::string file_, path_;
  // Dotted paths of every key read anywhere in the document; shared by all nodes of it.
  std::shared_ptr<std::set<std::string>> used_;
};

/// Path `p` resolved against the directory of file `base` when relative.
std::string resolve_relative(const std::string& base, const std::string& p);

}  // namespace flashtwin
