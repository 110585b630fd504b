// The command line as a user meets it: exit codes 0/1/2 and one-line errors.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "test_util.hpp"

namespace {

struct CliRun {
  int code = -1;
  std::string out, err;
};

std::string slurp(const std::string& p) {
  std::ifstream in(p);
  std::stringstream ss;
  ss << in.rdbuf();
  return ss.str();
}

CliRun run(const std::string& args) {
  static int counter = 0;
  const std::string dir = ftest::temp_dir("cli" + std::to_string(counter++));
  const std::string cmd = std::string(FLASHTWIN_CLI) + " " + args + " >" + dir + "/out 2>" + dir +
                          "/err </dev/null";
  const int status = std::system(cmd.c_str());
  CliRun r;
  r.code = WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  r.out = slurp(dir + "/out");
  r.err = slurp(dir + "/err");
  return r;
}

int lines(const std::string& s) {
  int n = 0;
  for (char c : s) n += c == '\n';
  return n;
}

}  // namespace

TEST(Cli, HelpForEverySubcommand) {
  for (const char* sub : {"", "fk", "ik", "workspace", "cell"}) {
    const CliRun r = run(std::string(sub) + " --help");
    EXPECT_EQ(r.code, 0) << sub;
    EXPECT_NE(r.out.find("Usage"), std::string::npos) << sub;
  }
}

TEST(Cli, FkPrintsTheFlangePoseAsJson) {
  const CliRun r = run("fk --q \"0 0 0 0 0 0\" --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["X_BE"].size(), 16u);
  EXPECT_NEAR(j["X_BE"][3].get<double>(), 0.52, 1e-12);
  EXPECT_NEAR(j["X_BE"][7].get<double>(), 0.15, 1e-12);
  EXPECT_NEAR(j["X_BE"][11].get<double>(), -0.5, 1e-12);
}

TEST(Cli, FkThenIkRoundTrip) {
  const CliRun fk = run("fk --q \"0.3,-1.1,0.4,0.5,0.7,-0.2\" --json");
  ASSERT_EQ(fk.code, 0);
  std::string pose;
  const auto fk_json = nlohmann::json::parse(fk.out);
  for (const auto& v : fk_json["X_BE"]) pose += std::to_string(v.get<double>()) + " ";
  // to_string keeps 6 decimals: the pose is rigid to ~1e-6, within the CLI's tolerance.
  const CliRun ik = run("ik --json --pose \"" + pose + "\"");
  ASSERT_EQ(ik.code, 0) << ik.err;
  const auto j = nlohmann::json::parse(ik.out);
  ASSERT_GE(j["solutions"].size(), 1u);
  bool found = false;
  for (const auto& s : j["solutions"]) {
    const std::vector<double> q = s.get<std::vector<double>>();
    const double expect[6] = {0.3, -1.1, 0.4, 0.5, 0.7, -0.2};
    double m = 0;
    for (int i = 0; i < 6; ++i) m = std::max(m, std::abs(q[i] - expect[i]));
    found = found || m < 1e-4;
  }
  EXPECT_TRUE(found) << ik.out;
}

TEST(Cli, UnreachablePoseExitsOneWithReason) {
  const CliRun r = run("ik --json --pose \"1 0 0 3  0 1 0 0  0 0 1 0  0 0 0 1\"");
  EXPECT_EQ(r.code, 1);
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["status"], "unreachable");
  EXPECT_EQ(j["solutions"].size(), 0u);
}

TEST(Cli, BadInputExitsTwoWithOneLine) {
  const std::string tmp = ftest::temp_dir("cli_bad");
  {
    std::ofstream f(tmp + "/robot.yaml");
    f << "name: broken\ndh: [1, 2]\n";
  }
  struct Case {
    std::string args, needle;
  };
  const Case cases[] = {
      {"fk --q \"1 2 3\"", "--q: expected 6 numbers, got 3"},
      {"fk --q \"1 2 3 4 5 x\"", "expected numbers, got 'x'"},
      {"fk --q \"0 0 0 0 0 0\" --robot " + tmp + "/robot.yaml", "robot.yaml"},
      {"fk --q \"0 0 0 0 0 0\" --robot /nonexistent.yaml", "/nonexistent.yaml: file not found"},
      {"cell /nonexistent/scenario.yaml -o " + tmp + "/c", "scenario.yaml: file not found"},
      {"ik --pose \"2 0 0 0 0 1 0 0 0 0 1 0 0 0 0 1\"", "--pose: expected a rigid transform"},
      {"workspace --samples 0 -o " + tmp + "/w", "samples: expected a positive count"},
      {"nosuchcommand", ""},
  };
  for (const auto& c : cases) {
    const CliRun r = run(c.args);
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.needle), std::string::npos) << c.args << "\n" << r.err;
    if (!c.needle.empty()) EXPECT_EQ(lines(r.err), 1) << c.args << "\n" << r.err;
  }
  EXPECT_FALSE(std::filesystem::exists(tmp + "/c/cell.xml"));
}

TEST(Cli, CellWritesALoadableModelAndUrdf) {
  const std::string out = ftest::temp_dir("cli_cell");
  const CliRun r = run("cell " + ftest::source_path("scenarios/default.yaml") + " -o " +
                    out + " --json");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_EQ(j["njnt"], 6);
  EXPECT_TRUE(std::filesystem::exists(out + "/cell.xml"));
  EXPECT_TRUE(std::filesystem::exists(out + "/robot.urdf"));
}

TEST(Cli, WorkspaceWritesPlotAndReach) {
  const std::string out = ftest::temp_dir("cli_ws");
  const CliRun r = run("workspace --samples 20000 --json -o " + out);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_NEAR(j["max_reach_m"].get<double>(), 1.0, 0.05);
  EXPECT_GT(std::filesystem::file_size(out + "/workspace.png"), 10000u);
}
