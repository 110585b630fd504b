#include <gtest/gtest.h>

#include "flashtwin/core/config.hpp"
#include "flashtwin/core/errors.hpp"

using namespace flashtwin;

namespace {
std::string message_of(const std::function<void()>& f) {
  try {
    f();
  } catch (const InputError& e) {
    return e.what();
  }
  return "";
}
}  // namespace

TEST(Config, ReadsTypedFieldsWithDefaults) {
  const auto n = ConfigNode::load_string("a: 1.5\nb: {c: [1, 2, 3]}\nflag: true\n", "t.yaml");
  EXPECT_DOUBLE_EQ(n.get_double("a", 0, 2), 1.5);
  EXPECT_EQ(n.at("b").get_vec3("c"), Vec3(1, 2, 3));
  EXPECT_TRUE(n.get_bool("flag", false));
  EXPECT_DOUBLE_EQ(n.get_double("missing", 0, 10, 7.0), 7.0);
  EXPECT_NO_THROW(n.check_all_used());
}

TEST(Config, UnknownKeysAreReportedWithTheirPath) {
  const auto n = ConfigNode::load_string("a: 1\nb: {c: 2, typo: 3}\n", "t.yaml");
  n.get_double("a", 0, 2);
  n.at("b").get_double("c", 0, 5);
  const std::string msg = message_of([&] { n.check_all_used(); });
  EXPECT_NE(msg.find("t.yaml"), std::string::npos) << msg;
  EXPECT_NE(msg.find("b.typo"), std::string::npos) << msg;
}

TEST(Config, OutOfRangeNamesFileFieldAndValue) {
  const auto n = ConfigNode::load_string("speed: -3\n", "cell.yaml");
  const std::string msg = message_of([&] { n.get_double("speed", 0, 10); });
  EXPECT_NE(msg.find("cell.yaml: speed: expected a number in [0, 10], got -3"),
            std::string::npos)
      << msg;
}

TEST(Config, NonNumberAndWrongListLength) {
  const auto n = ConfigNode::load_string("x: abc\nv: [1, 2]\n", "f.yaml");
  EXPECT_NE(message_of([&] { n.get_double("x", 0, 1); }).find("expected a number, got 'abc'"),
            std::string::npos);
  EXPECT_NE(message_of([&] { n.get_vec3("v"); }).find("expected a list of 3 numbers"),
            std::string::npos);
}

TEST(Config, MissingFileAndMalformedYaml) {
  EXPECT_THROW(ConfigNode::load_file("/nonexistent/x.yaml"), IoError);
  const std::string msg = message_of([] { ConfigNode::load_string("a: [1, 2\n", "bad.yaml"); });
  EXPECT_NE(msg.find("bad.yaml: line"), std::string::npos) << msg;
  EXPECT_THROW(ConfigNode::load_string("", "empty.yaml"), ConfigError);
  EXPECT_THROW(ConfigNode::load_string("- 1\n- 2\n", "list.yaml"), ConfigError);
}

TEST(Config, MissingRequiredKey) {
  const auto n = ConfigNode::load_string("a: 1\n", "f.yaml");
  const std::string msg = message_of([&] { n.at("robot"); });
  EXPECT_NE(msg.find("missing required key 'robot'"), std::string::npos) << msg;
}
