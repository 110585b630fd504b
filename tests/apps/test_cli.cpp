// The command line as a user meets it: exit codes 0/1/2 and one-line errors.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "flashtwin/core/mesh.hpp"
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

TEST(Cli, ScanWritesIdenticalCloudsForTheSameSeed) {
  const std::string a = ftest::temp_dir("cli_scan_a"), b = ftest::temp_dir("cli_scan_b");
  const std::string scen = ftest::source_path("scenarios/round_flange.yaml");
  const CliRun ra = run("scan " + scen + " --json -o " + a);
  ASSERT_EQ(ra.code, 0) << ra.err;
  const auto j = nlohmann::json::parse(ra.out);
  EXPECT_GT(j["points"].get<int>(), 100000);
  EXPECT_GT(j["rays_per_s"].get<double>(), 0);
  ASSERT_EQ(run("scan " + scen + " --json -o " + b).code, 0);
  for (const char* f : {"/scan.ply", "/scan.pcd"}) {
    const std::string x = slurp(a + f), y = slurp(b + f);
    EXPECT_GT(x.size(), 1000000u);
    EXPECT_TRUE(x == y) << f << " differs between two runs with the same seed";
  }
  // The cloud reads back through PCL with the same point count.
  EXPECT_EQ(flashtwin::load_cloud(a + "/scan.pcd").size(), j["points"].get<std::size_t>());
  EXPECT_EQ(flashtwin::load_cloud(a + "/scan.ply").size(), j["points"].get<std::size_t>());
}

TEST(Cli, RenderWritesPngsOfTheRequestedSize) {
  const std::string out = ftest::temp_dir("cli_render");
  const CliRun r = run("render " + ftest::source_path("scenarios/housing.yaml") +
                       " --camera overview --width 320 --height 240 --json -o " + out);
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j["images"].size(), 1u);
  const std::string png = slurp(j["images"][0].get<std::string>());
  ASSERT_GT(png.size(), 24u);
  // PNG IHDR: width and height, big-endian, at bytes 16..23.
  auto be32 = [&](std::size_t o) {
    return (static_cast<unsigned char>(png[o]) << 24) | (static_cast<unsigned char>(png[o + 1]) << 16) |
           (static_cast<unsigned char>(png[o + 2]) << 8) | static_cast<unsigned char>(png[o + 3]);
  };
  EXPECT_EQ(be32(16), 320u);
  EXPECT_EQ(be32(20), 240u);
  const CliRun bad = run("render " + ftest::source_path("scenarios/housing.yaml") +
                         " --camera nosuchcamera -o " + out);
  EXPECT_EQ(bad.code, 2);
  EXPECT_NE(bad.err.find("nosuchcamera"), std::string::npos) << bad.err;
}

TEST(Cli, BadCastingInputExitsTwo) {
  const std::string dir = ftest::temp_dir("cli_casting");
  const std::string robot = ftest::source_path("models/robots/ft6.yaml");
  auto scenario = [&](const std::string& name, const std::string& casting) {
    std::ofstream f(dir + "/" + name);
    f << "name: t\nrobot: " << robot << "\ncasting: " << casting << "\n";
    return dir + "/" + name;
  };
  {  // a mesh with a hole: an open box (five faces)
    std::ofstream f(dir + "/open.obj");
    f << "v 0 0 0\nv 0.1 0 0\nv 0.1 0.1 0\nv 0 0.1 0\nv 0 0 0.1\nv 0.1 0 0.1\nv 0.1 0.1 0.1\nv 0 0.1 0.1\n"
         "f 1 3 2\nf 1 4 3\nf 1 2 6\nf 1 6 5\nf 2 3 7\nf 2 7 6\nf 3 4 8\nf 3 8 7\nf 4 1 5\nf 4 5 8\n";
  }
  struct Case {
    std::string casting, needle;
  };
  const Case cases[] = {
      {"{family: teapot}", "casting.family: expected flanged_plate"},
      {"{family: housing, flash: {height: [-0.001, 0.002]}}", "casting.flash.height"},
      {"{family: mesh, mesh: nowhere.stl}", "nowhere.stl: file not found"},
      {"{family: mesh, mesh: open.obj}", "open.obj: expected a closed surface"},
      {"{family: housing, colour: red}", "casting.colour"},
  };
  int k = 0;
  for (const auto& c : cases) {
    const std::string path = scenario("s" + std::to_string(k++) + ".yaml", c.casting);
    const CliRun r = run("cell " + path + " -o " + dir + "/out" + std::to_string(k));
    EXPECT_EQ(r.code, 2) << c.casting << "\n" << r.err;
    EXPECT_NE(r.err.find(c.needle), std::string::npos) << c.casting << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << r.err;
  }
}

TEST(Cli, RegisterRecoversAScanPoseAndRejectsBadClouds) {
  const std::string dir = ftest::temp_dir("cli_register");
  // A moved copy of a subsampled bunny registered back to the bunny mesh.
  const flashtwin::TriangleMesh bunny =
      flashtwin::load_mesh(std::string(FLASHTWIN_SHARED_DATA) + "/bunny/bun_zipper.ply");
  const flashtwin::Pose X = flashtwin::pose_from_xyz_rpy(flashtwin::Vec3(0.05, -0.02, 0.1),
                                                         flashtwin::Vec3(0.4, -1.1, 2.0));
  flashtwin::PointCloud src;
  for (std::size_t i = 0; i < bunny.vertices.size(); i += 3)
    src.points.push_back((X.inverse() * bunny.vertices[i]).cast<float>());
  flashtwin::save_pcd(dir + "/scan.pcd", src);
  const CliRun r = run("register --json --source " + dir + "/scan.pcd --target " +
                       std::string(FLASHTWIN_SHARED_DATA) + "/bunny/bun_zipper.ply");
  ASSERT_EQ(r.code, 0) << r.err;
  const auto j = nlohmann::json::parse(r.out);
  EXPECT_TRUE(j["confident"].get<bool>());
  const auto m = j["T_target_source"].get<std::vector<double>>();
  ASSERT_EQ(m.size(), 16u);
  EXPECT_NEAR(m[3], 0.05, 1e-4);
  EXPECT_NEAR(m[7], -0.02, 1e-4);
  EXPECT_NEAR(m[11], 0.1, 1e-4);

  flashtwin::PointCloud few;
  for (int i = 0; i < 5; ++i) few.points.emplace_back(0.01f * i, 0.f, 0.f);
  flashtwin::save_ply(dir + "/few.ply", few);
  flashtwin::PointCloud nan = src;
  nan.points[3].x() = std::numeric_limits<float>::quiet_NaN();
  flashtwin::save_pcd(dir + "/nan.pcd", nan);
  {
    std::ofstream f(dir + "/garbage.pcd");
    f << "this is not a point cloud\n";
  }
  const std::string target = " --target " + std::string(FLASHTWIN_SHARED_DATA) + "/bunny/bun_zipper.ply";
  const struct {
    std::string file, needle;
  } cases[] = {{"few.ply", "at least 10 points"},
               {"nan.pcd", "point 3"},
               {"garbage.pcd", "garbage.pcd"},
               {"missing.pcd", "missing.pcd: file not found"}};
  for (const auto& c : cases) {
    const CliRun b = run("register --source " + dir + "/" + c.file + target);
    EXPECT_EQ(b.code, 2) << c.file << "\n" << b.err;
    EXPECT_NE(b.err.find(c.needle), std::string::npos) << c.file << "\n" << b.err;
  }
}
