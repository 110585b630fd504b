#include "flashtwin/core/config.hpp"

#include <cmath>
#include <filesystem>
#include <functional>
#include <limits>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

namespace flashtwin {

namespace fs = std::filesystem;

ConfigNode::ConfigNode(YAML::Node node, std::string file, std::string path,
                       std::shared_ptr<std::set<std::string>> used)
    : node_(std::move(node)), file_(std::move(file)), path_(std::move(path)),
      used_(std::move(used)) {}

ConfigNode ConfigNode::load_file(const std::string& path) {
  return load_string(read_text_file(path), path);
}

namespace {

/// A mapping key as text. @throws ConfigError when the key is a list or a mapping.
std::string key_text(const YAML::Node& key, const std::string& file, const std::string& where) {
  if (!key.IsScalar())
    throw ConfigError(file + ": " + (where.empty() ? std::string("(top level)") : where) +
                      ": expected text keys, got a " + (key.IsSequence() ? "list" : "mapping") +
                      " as a key");
  return key.Scalar();
}

/// Refuses documents no configuration needs and every reader would choke on: nesting deeper
/// than kMaxDepth (also what an alias cycle such as `&a [*a]` looks like), more than kMaxNodes
/// nodes once aliases are expanded (the "billion laughs"), and non-text keys.
void check_shape(const YAML::Node& root, const std::string& file) {
  constexpr int kMaxDepth = 64;
  constexpr long kMaxNodes = 1000000;
  long nodes = 0;
  std::function<void(const YAML::Node&, int)> visit = [&](const YAML::Node& n, int depth) {
    if (depth > kMaxDepth)
      throw ConfigError(file + ": expected at most " + std::to_string(kMaxDepth) +
                        " levels of nesting, got more (or an alias that contains itself)");
    if (++nodes > kMaxNodes)
      throw ConfigError(file + ": expected at most " + std::to_string(kMaxNodes) +
                        " YAML nodes with aliases expanded, got more");
    if (n.IsMap()) {
      for (const auto& kv : n) {
        key_text(kv.first, file, "");
        visit(kv.second, depth + 1);
      }
    } else if (n.IsSequence()) {
      for (const auto& e : n) visit(e, depth + 1);
    }
  };
  visit(root, 0);
}

}  // namespace

ConfigNode ConfigNode::load_string(const std::string& text, const std::string& name) {
  YAML::Node root;
  try {
    root = YAML::Load(text);
  } catch (const YAML::Exception& e) {
    throw ConfigError(name + ": line " + std::to_string(e.mark.line + 1) +
                      ": malformed YAML: " + e.msg);
  }
  check_shape(root, name);
  if (!root.IsMap())
    throw ConfigError(name + ": expected a YAML mapping at the top level, got " +
                      (root.IsNull() ? std::string("an empty document")
                                     : std::string("something else")));
  return ConfigNode(root, name, "", std::make_shared<std::set<std::string>>());
}

std::string ConfigNode::child_path(const std::string& key) const {
  return path_.empty() ? key : path_ + "." + key;
}

void ConfigNode::fail(const std::string& msg) const {
  throw ConfigError(file_ + ": " + (path_.empty() ? std::string("(top level)") : path_) + ": " +
                    msg);
}

std::string ConfigNode::describe() const {
  if (!node_.IsDefined() || node_.IsNull()) return "nothing";
  if (node_.IsScalar()) return "'" + node_.Scalar() + "'";
  if (node_.IsSequence()) return "a list";
  return "a mapping";
}

bool ConfigNode::has(const std::string& key) const {
  if (!node_.IsMap()) return false;
  if (!node_[key]) return false;
  used_->insert(child_path(key));
  return true;
}

ConfigNode ConfigNode::at(const std::string& key) const {
  if (!node_.IsMap()) fail("expected a mapping with key '" + key + "', got " + describe());
  YAML::Node child = node_[key];
  if (!child) fail("missing required key '" + key + "'");
  used_->insert(child_path(key));
  return ConfigNode(child, file_, child_path(key), used_);
}

ConfigNode ConfigNode::operator[](std::size_t i) const {
  if (!node_.IsSequence() || i >= node_.size())
    fail("expected a list with at least " + std::to_string(i + 1) + " entries, got " +
         describe());
  return ConfigNode(node_[i], file_, path_ + "[" + std::to_string(i) + "]", used_);
}

std::vector<std::string> ConfigNode::keys() const {
  std::vector<std::string> out;
  if (!node_.IsMap()) return out;
  for (const auto& kv : node_) out.push_back(key_text(kv.first, file_, path_));
  return out;
}

double ConfigNode::as_double() const {
  if (!node_.IsScalar()) fail("expected a number, got " + describe());
  double v = 0;
  try {
    v = node_.as<double>();
  } catch (const YAML::Exception&) {
    fail("expected a number, got " + describe());
  }
  if (!std::isfinite(v)) fail("expected a finite number, got " + describe());
  return v;
}

double ConfigNode::as_double(double lo, double hi) const {
  const double v = as_double();
  if (v < lo || v > hi) {
    std::ostringstream os;
    os << "expected a number in [" << lo << ", " << hi << "], got " << v;
    fail(os.str());
  }
  return v;
}

long long ConfigNode::as_int(long long lo, long long hi) const {
  if (!node_.IsScalar()) fail("expected an integer, got " + describe());
  long long v = 0;
  try {
    v = node_.as<long long>();
  } catch (const YAML::Exception&) {
    fail("expected an integer, got " + describe());
  }
  if (v < lo || v > hi)
    fail("expected an integer in [" + std::to_string(lo) + ", " + std::to_string(hi) +
         "], got " + std::to_string(v));
  return v;
}

bool ConfigNode::as_bool() const {
  if (!node_.IsScalar()) fail("expected true or false, got " + describe());
  try {
    return node_.as<bool>();
  } catch (const YAML::Exception&) {
    fail("expected true or false, got " + describe());
  }
}

std::string ConfigNode::as_string() const {
  if (!node_.IsScalar()) fail("expected a string, got " + describe());
  return node_.Scalar();
}

std::vector<double> ConfigNode::as_doubles(std::size_t n) const {
  if (!node_.IsSequence() || node_.size() != n)
    fail("expected a list of " + std::to_string(n) + " numbers, got " +
         (node_.IsSequence() ? "a list of " + std::to_string(node_.size()) : describe()));
  std::vector<double> out(n);
  for (std::size_t i = 0; i < n; ++i) out[i] = (*this)[i].as_double();
  return out;
}

Vec3 ConfigNode::as_vec3() const {
  const auto v = as_doubles(3);
  return {v[0], v[1], v[2]};
}

double ConfigNode::get_double(const std::string& key, double lo, double hi) const {
  return at(key).as_double(lo, hi);
}
double ConfigNode::get_double(const std::string& key, double lo, double hi,
                              double fallback) const {
  return has(key) ? at(key).as_double(lo, hi) : fallback;
}
long long ConfigNode::get_int(const std::string& key, long long lo, long long hi,
                              long long fallback) const {
  return has(key) ? at(key).as_int(lo, hi) : fallback;
}
bool ConfigNode::get_bool(const std::string& key, bool fallback) const {
  return has(key) ? at(key).as_bool() : fallback;
}
std::string ConfigNode::get_string(const std::string& key) const { return at(key).as_string(); }
std::string ConfigNode::get_string(const std::string& key, const std::string& fallback) const {
  return has(key) ? at(key).as_string() : fallback;
}
Vec3 ConfigNode::get_vec3(const std::string& key) const { return at(key).as_vec3(); }
Vec3 ConfigNode::get_vec3(const std::string& key, const Vec3& fallback) const {
  return has(key) ? at(key).as_vec3() : fallback;
}

Pose ConfigNode::get_pose(const std::string& key, const Pose& fallback) const {
  if (!has(key)) return fallback;
  const ConfigNode p = at(key);
  if (!p.is_map()) p.fail("expected a pose {xyz: [x, y, z], rpy: [r, p, y]}, got " + p.describe());
  const Vec3 xyz = p.get_vec3("xyz", Vec3::Zero());
  const Vec3 rpy = p.get_vec3("rpy", Vec3::Zero());
  return pose_from_xyz_rpy(xyz, rpy);
}

void ConfigNode::check_all_used() const {
  std::vector<std::string> unknown;
  // Walk maps and sequences below this node; a key is unknown when nobody asked for it.
  std::function<void(const YAML::Node&, const std::string&)> walk =
      [&](const YAML::Node& n, const std::string& p) {
        if (n.IsMap()) {
          for (const auto& kv : n) {
            const std::string k = key_text(kv.first, file_, p);
            const std::string cp = p.empty() ? k : p + "." + k;
            if (!used_->count(cp))
              unknown.push_back(cp);
            else
              walk(kv.second, cp);
          }
        } else if (n.IsSequence()) {
          for (std::size_t i = 0; i < n.size(); ++i)
            walk(n[i], p + "[" + std::to_string(i) + "]");
        }
      };
  walk(node_, path_);
  if (!unknown.empty()) {
    std::string list;
    for (const auto& u : unknown) list += (list.empty() ? "" : ", ") + u;
    throw ConfigError(file_ + ": unknown key" + (unknown.size() > 1 ? "s " : " ") + list +
                      " (misspelt or not supported here)");
  }
}

std::string resolve_relative(const std::string& base, const std::string& p) {
  const fs::path pp(p);
  if (pp.is_absolute()) return p;
  return (fs::path(base).parent_path() / pp).lexically_normal().string();
}

}  // namespace flashtwin
