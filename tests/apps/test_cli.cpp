// The command line as a user meets it: exit codes 0/1/2 and one-line errors.
#include <gtest/gtest.h>
#include <sys/wait.h>

#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>

#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/transform.hpp"
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
  for (const char* sub : {"", "fk", "ik", "workspace", "cell", "run", "sweep", "plan", "detect"}) {
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

TEST(Cli, ControllerAxesOfAUrdfArmAndItsLibraryTwinGiveOnePose) {
  // KUKA's A1..A6 through the ROS-style URDF and through kuka_kr16.yaml's controller mapping.
  const std::string a = "--q \"10 -80 95 20 60 -30\" --deg --axes --json --robot ";
  const CliRun u = run("-q fk " + a + ftest::source_path("models/robots/urdf/kuka_kr16_2.urdf"));
  const CliRun y = run("-q fk " + a + ftest::source_path("models/robots/kuka_kr16.yaml"));
  ASSERT_EQ(u.code, 0) << u.err;
  ASSERT_EQ(y.code, 0) << y.err;
  const auto ju = nlohmann::json::parse(u.out), jy = nlohmann::json::parse(y.out);
  for (int i = 0; i < 12; ++i)
    EXPECT_NEAR(ju["X_BT"][i].get<double>(), jy["X_BT"][i].get<double>(), 1e-9) << i;
  // ik --axes gives the axis values back among its solutions.
  std::string pose;
  for (const auto& v : jy["X_BE"]) pose += std::to_string(v.get<double>()) + " ";
  const CliRun ik = run("-q ik --json --deg --axes --robot " +
                        ftest::source_path("models/robots/kuka_kr16.yaml") + " --pose \"" + pose + "\"");
  ASSERT_EQ(ik.code, 0) << ik.err;
  bool found = false;
  const double expect[6] = {10, -80, 95, 20, 60, -30};
  const auto jik = nlohmann::json::parse(ik.out);
  for (const auto& s : jik["solutions"]) {
    double m = 0;
    for (int i = 0; i < 6; ++i)  // up to whole turns (A6 may come back as 330°)
      m = std::max(m, std::abs(std::remainder(s[i].get<double>() - expect[i], 360.0)));
    found = found || m < 1e-3;
  }
  EXPECT_TRUE(found) << ik.out;
  // A URDF that is not a 6R arm: exit 2 naming the file.
  const std::string bad = ftest::temp_dir("cli_urdf") + "/five.urdf";
  { std::ofstream(bad) << "<robot name=\"r\"><link name=\"a\"/></robot>"; }
  const CliRun b = run("fk --q \"0 0 0 0 0 0\" --robot " + bad);
  EXPECT_EQ(b.code, 2);
  EXPECT_NE(b.err.find("five.urdf: expected a serial chain of 6 revolute joints, found 0"),
            std::string::npos)
      << b.err;
}

namespace {

flashtwin::Pose pose_of(const nlohmann::json& v) {
  Eigen::Matrix4d M;
  for (int i = 0; i < 16; ++i) M(i / 4, i % 4) = v[i].get<double>();
  flashtwin::Pose X;
  X.matrix() = M;
  return X;
}

}  // namespace

// `flashtwin job` on inputs that carry no ground truth: a scan exported by `flashtwin scan`
// read back as a plain PLY, the CAD as STL, the default scenario as the cell file. The pose it
// finds is the cell's true one; in millimetres (scan and CAD) it is the same job; a CAD that is
// not the scanned part is refused with no program written.
TEST(Cli, JobFromAPlainScanAndCadPlansThePartWhereItIs) {
  const std::string d = ftest::temp_dir("cli_job");
  ASSERT_EQ(run("-q scan " + ftest::source_path("scenarios/default.yaml") + " -o " + d + "/scan").code, 0);
  const std::string cell = ftest::source_path("scenarios/default.yaml");
  const CliRun j = run("-q job --json --scan " + d + "/scan/scan.ply --cad " + d +
                       "/scan/cell/casting_cad.stl --cell " + cell + " -o " + d + "/job");
  ASSERT_EQ(j.code, 0) << j.err;
  const auto js = nlohmann::json::parse(j.out);
  EXPECT_TRUE(js["registration.confident"].get<bool>());
  EXPECT_GT(js["paths.count"].get<int>(), 0);
  EXPECT_EQ(js["trajectory.paths_failed"].get<int>(), 0);
  EXPECT_TRUE(std::filesystem::exists(d + "/job/plan/path_0/flashtwin_path_0.src"));
  // The truth the scan command wrote (the job never read it): X_WC; the cell's X_WB.
  std::ifstream tf(d + "/scan/cell/truth/flash_truth.json");
  const auto truth = nlohmann::json::parse(tf);
  const flashtwin::Pose X_BC_true = flashtwin::Pose(Eigen::Translation3d(0, 0, 0.95)).inverse() * pose_of(truth["X_WC"]);
  const flashtwin::Pose X_BC = pose_of(js["X_BC"]);
  EXPECT_LT((X_BC.translation() - X_BC_true.translation()).norm(), 1e-4);
  EXPECT_LT(flashtwin::rotation_distance(X_BC.linear(), X_BC_true.linear()) * 180 / M_PI, 0.05);

  // The rehearsal (the scanned flash as material, ground with the plans) predicts what the
  // twin's own run of the same seed measures against its truth: removal within 2 %.
  EXPECT_TRUE(js["rehearsal.quality.pass"].get<bool>()) << js["rehearsal.quality.failures"].dump();
  ASSERT_EQ(run("-q run " + cell + " --no-report -o " + d + "/run").code, 0);
  std::ifstream mf(d + "/run/metrics.json");
  const auto twin = nlohmann::json::parse(mf);
  EXPECT_NEAR(js["rehearsal.removal.flash_removed_fraction"].get<double>(),
              twin["removal.flash_removed_fraction"].get<double>(), 0.02);
  EXPECT_NEAR(js["rehearsal.removal.gouge_max_mm"].get<double>(),
              twin["removal.gouge_max_mm"].get<double>(), 0.05);
  EXPECT_EQ(js["rehearsal.motion"], "program");  // the written programs, read back, rehearsed
  // Its 3D view: the scan, the paths, the tool paths, the rehearsal's prediction and the arm.
  const std::string view = flashtwin::read_text_file(d + "/job/view3d.html");
  EXPECT_NE(view.find("job on scan.ply"), std::string::npos);
  for (const char* layer : {"\"scan\":", "\"toolpath\":", "\"residual\":", "\"robot\":"})
    EXPECT_NE(view.find(layer), std::string::npos) << layer;
  EXPECT_EQ(view.find("\"roots\":"), std::string::npos);  // no truth in a job's view

  // The job's programs run as the controller runs them on the twin's true part (what the scan
  // saw): the part to its limits, as the twin's own run of the plans.
  const CliRun rp = run("-q replay --json " + cell + " --job " + d + "/job -o " + d + "/replay");
  ASSERT_EQ(rp.code, 0) << rp.out << rp.err;
  const auto rj = nlohmann::json::parse(rp.out);
  EXPECT_EQ(rj["program.count"].get<int>(), js["trajectory.path_pieces"].get<int>());
  EXPECT_GE(rj["removal.flash_removed_fraction"].get<double>(), 0.99);
  EXPECT_LE(rj["removal.residual_flash_max_mm"].get<double>(), 0.2);
  EXPECT_LE(rj["removal.gouge_max_mm"].get<double>(), 0.1);
  EXPECT_NEAR(rj["removal.flash_removed_fraction"].get<double>(),
              twin["removal.flash_removed_fraction"].get<double>(), 0.01);

  // The same scan and CAD in millimetres: units guessed, the same pose.
  flashtwin::PointCloud mm = flashtwin::load_cloud(d + "/scan/scan.ply");
  for (auto& p : mm.points) p *= 1000.0f;
  flashtwin::save_ply(d + "/scan_mm.ply", mm);
  flashtwin::TriangleMesh cad = flashtwin::load_mesh(d + "/scan/cell/casting_cad.stl", 1000.0);
  flashtwin::save_mesh(d + "/cad_mm.stl", cad);
  const CliRun jm = run("-q job --json --scan " + d + "/scan_mm.ply --cad " + d + "/cad_mm.stl --cell " +
                        cell + " -o " + d + "/job_mm");
  ASSERT_EQ(jm.code, 0) << jm.err;
  const flashtwin::Pose X_BC_mm = pose_of(nlohmann::json::parse(jm.out)["X_BC"]);
  EXPECT_LT((X_BC_mm.translation() - X_BC_true.translation()).norm(), 1e-4);

  // Another part's CAD (the cover family's), into the folder of the job above: refused, exit 1,
  // and the earlier job's programs are gone (no program stands beside a refusal).
  ASSERT_TRUE(std::filesystem::exists(d + "/job/plan"));
  ASSERT_EQ(run("-q cell " + ftest::source_path("scenarios/cover.yaml") + " -o " + d + "/cover").code, 0);
  const CliRun jr = run("-q job --scan " + d + "/scan/scan.ply --cad " + d +
                        "/cover/casting_cad.stl --cell " + cell + " -o " + d + "/job");
  EXPECT_EQ(jr.code, 1) << jr.out << jr.err;
  EXPECT_NE(jr.out.find("job refused"), std::string::npos) << jr.out;
  EXPECT_FALSE(std::filesystem::exists(d + "/job/plan"));
  EXPECT_FALSE(std::filesystem::exists(d + "/job/plans.json"));
  std::ifstream rf(d + "/job/job.json");
  EXPECT_TRUE(nlohmann::json::parse(rf)["refused"].get<bool>());
  // A refused job has no program to replay: bad input, exit 2, naming its job.json.
  const CliRun rr = run("-q replay " + cell + " --job " + d + "/job -o " + d + "/replay_refused");
  EXPECT_EQ(rr.code, 2) << rr.out << rr.err;
  EXPECT_NE(rr.err.find("job.json: expected a job that wrote programs"), std::string::npos) << rr.err;
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
    if (!c.needle.empty()) {
      EXPECT_EQ(lines(r.err), 1) << c.args << "\n" << r.err;
    }
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
  // --seed picks another casting and placement, as run and sweep do.
  const std::string c = ftest::temp_dir("cli_scan_c");
  ASSERT_EQ(run("scan " + scen + " --seed 77 --json -o " + c).code, 0);
  EXPECT_TRUE(slurp(a + "/scan.ply") != slurp(c + "/scan.ply"));
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

namespace {

// metrics.json without the wall-clock figures (the only thing allowed to differ between runs).
nlohmann::json without_timings(nlohmann::json m) {
  for (auto it = m.begin(); it != m.end();) {
    const std::string k = it.key();
    const bool timing = k.rfind("timing.", 0) == 0 || k == "sim.realtime_factor" ||
                        k == "sim.step_us" || k == "scan.rays_per_s" || k == "registration.time_s" ||
                        k == "segmentation.time_s";
    it = timing ? m.erase(it) : std::next(it);
  }
  return m;
}

}  // namespace

TEST(Cli, RunIsDeterministicAndWritesTheClosedLoopOutputs) {
  // The default scenario end to end, twice with the same seed, on 1 and on 2 threads:
  // identical metrics (timings aside), all DESIGN.md keys present, the report self-contained.
  // (It ran the user-mesh scenario until its seed-11 part failed on the collet touching the
  // bracket's upright leg, the path it left and the transits it could not leave cleanly: README "The whole job".)
  const std::string a = ftest::temp_dir("run_a"), b = ftest::temp_dir("run_b");
  const std::string sc = ftest::source_path("scenarios/default.yaml");
  const CliRun ra = run("-q run " + sc + " -o " + a + " --threads 1");
  const CliRun rb = run("-q run " + sc + " -o " + b + " --threads 2 --no-report");
  // Exit 1 exactly when the part fails its quality limits.
  ASSERT_TRUE(ra.code == 0 || ra.code == 1) << ra.err;
  ASSERT_EQ(rb.code, ra.code) << rb.err;
  const auto ma = nlohmann::json::parse(slurp(a + "/metrics.json"));
  const auto mb = nlohmann::json::parse(slurp(b + "/metrics.json"));
  EXPECT_EQ(ra.code, ma["quality.pass"].get<bool>() ? 0 : 1) << ma["quality.failures"].dump();
  EXPECT_EQ(without_timings(ma), without_timings(mb));
  for (const char* k :
       {"registration.rotation_error_deg", "registration.translation_error_mm",
        "registration.confident", "registration.time_s", "segmentation.precision",
        "segmentation.recall", "path.rmse_mm", "path.mean_mm", "path.max_mm", "path.coverage",
        "trajectory.max_joint_velocity_ratio", "trajectory.max_joint_accel_ratio",
        "trajectory.min_manipulability", "execution.tracking_rmse_mm", "execution.tracking_max_mm",
        "execution.joint_limit_violations", "removal.flash_removed_fraction",
        "removal.residual_flash_max_mm", "removal.gouge_max_mm", "removal.gouge_volume_mm3",
        "force.mean_n", "force.rmse_n", "force.max_n", "timing.total_s", "timing.scan_s",
        "timing.perception_s", "timing.planning_s", "timing.execution_s", "sim.realtime_factor",
        "scan.points", "scan.rays_per_s", "quality.pass", "quality.failures",
        "execution.collisions", "execution.first_collision", "cycle.time_s",
        "trajectory.transits", "trajectory.transits_refused"})
    EXPECT_TRUE(ma.contains(k)) << k;
  EXPECT_EQ(ma["execution.joint_limit_violations"], 0);
  EXPECT_GT(ma["removal.flash_removed_fraction"].get<double>(), 0.5);
  const std::string html = slurp(a + "/report.html");
  EXPECT_NE(html.find("data:image/png;base64,"), std::string::npos);
  EXPECT_EQ(html.find("src=\"report/"), std::string::npos);  // nothing linked, all embedded
  EXPECT_NE(html.find("removal.flash_removed_fraction"), std::string::npos);
  EXPECT_TRUE(std::filesystem::exists(a + "/trajectory.csv"));
  EXPECT_TRUE(std::filesystem::exists(a + "/plan/path_0/flashtwin_path_0.src"));
  EXPECT_TRUE(std::filesystem::exists(a + "/plan/path_0/joint_positions.png"));
  EXPECT_FALSE(std::filesystem::exists(b + "/report.html"));
  EXPECT_FALSE(std::filesystem::exists(b + "/plan/path_0/joint_positions.png"));  // --no-report
  EXPECT_TRUE(std::filesystem::exists(b + "/plan/path_0/trajectory.csv"));
}

TEST(Cli, RunRejectsBadScenariosWithExitTwo) {
  const std::string tmp = ftest::temp_dir("cli_run_bad");
  const std::string sc = ftest::source_path("scenarios/default.yaml");
  {
    std::ofstream f(tmp + "/malformed.yaml");
    f << "name: x\nseed: [1, 2\n";
  }
  {
    std::ofstream f(tmp + "/missing_mesh.yaml");
    f << "name: m\nrobot: " << ftest::source_path("models/robots/ft6.yaml")
      << "\ncasting: {family: mesh, mesh: /nonexistent/part.stl}\n";
  }
  {
    std::ofstream f(tmp + "/no_sweep.yaml");  // a scenario without an expect_sweep: block
    f << "name: n\nrobot: " << ftest::source_path("models/robots/ft6.yaml")
      << "\ncasting: {family: flanged_plate}\n";
  }
  {
    std::ofstream f(tmp + "/alias_cycle.yaml");
    f << "name: a\nrobot: " << ftest::source_path("models/robots/ft6.yaml")
      << "\ncasting: {family: flanged_plate}\nscanner: {views: &v [*v]}\n";
  }
  {
    // A binary STL whose header promises 1,000 triangles and holds half of one.
    std::string stl(80, ' ');
    const std::uint32_t n = 1000;
    stl.append(reinterpret_cast<const char*>(&n), 4);
    stl.append(25, '\1');
    std::ofstream(tmp + "/truncated.stl", std::ios::binary) << stl;
    std::ofstream f(tmp + "/truncated_mesh.yaml");
    f << "name: t\nrobot: " << ftest::source_path("models/robots/ft6.yaml")
      << "\ncasting: {family: mesh, mesh: truncated.stl, scale: 0.001}\n";
  }
  struct Case {
    std::string args, needle;
  };
  const Case cases[] = {
      {"run " + tmp + "/malformed.yaml -o " + tmp + "/o1", "malformed.yaml"},
      {"run " + sc + " -o " + tmp + "/o2 --set planning.fed=0.01", "planning.fed"},
      {"run " + sc + " -o " + tmp + "/o3 --set process.voxel_size=0", "process.voxel_size"},
      {"run " + sc + " -o " + tmp + "/o4 --set tool.radius=-1", "tool.radius"},
      {"run " + tmp + "/missing_mesh.yaml -o " + tmp + "/o5", "/nonexistent/part.stl"},
      {"sweep " + sc + " -o " + tmp + "/o6 --seeds 5-1", "--seeds 5-1"},
      {"sweep " + sc + " -o " + tmp + "/o7 --shard 3/2", "--shard 3/2"},
      // NaN, huge, wrong units, an impossible cell, hostile YAML, a truncated mesh.
      {"run " + sc + " -o " + tmp + "/o8 --set planning.feed=.nan", "planning.feed"},
      {"run " + sc + " -o " + tmp + "/o9 --set planning.feed=1e308", "planning.feed"},
      {"run " + sc + " -o " + tmp + "/o10 --set cell.table.size=[800,900,50]", "cell.table.size"},
      {"run " + sc + " -o " + tmp + "/o11 --set cell.table.size=[0.05,0.05,0.05]", "table top"},
      {"run " + tmp + "/alias_cycle.yaml -o " + tmp + "/o12", "alias_cycle.yaml"},
      {"run " + tmp + "/truncated_mesh.yaml -o " + tmp + "/o13", "truncated.stl"},
      {"sweep " + tmp + "/no_sweep.yaml -o " + tmp + "/o14 --check", "expect_sweep"},
      // A fault drill that is another placement, or leaves no burr.
      {"run " + sc + " -o " + tmp + "/o15 --set faults.part_offset.xyz=[0,0.1,0]", "faults.part_offset"},
      {"run " + sc + " -o " + tmp + "/o16 --set faults.tool_radius_error=-0.0028", "faults.tool_radius_error"},
      {"run " + sc + " -o " + tmp + "/o18 --set faults.tcp_offset=[0,0,0.05]", "faults.tcp_offset"},
      {"run " + sc + " -o " + tmp + "/o19 --set faults.sensor_bias.force=[0,3000,0]", "faults.sensor_bias.force"},
      // A second setup for a part the fixture holds one way up.
      {"run " + sc + " -o " + tmp + "/o17 --set casting.placement.turn_over=true", "turn_over"},
  };
  for (const auto& c : cases) {
    const CliRun r = run("-q " + c.args);  // -q: no progress lines on stderr, only the error
    EXPECT_EQ(r.code, 2) << c.args << "\n" << r.err;
    EXPECT_NE(r.err.find(c.needle), std::string::npos) << c.args << "\n" << r.err;
    EXPECT_EQ(lines(r.err), 1) << c.args << "\n" << r.err;
  }
  for (const char* o : {"/o1", "/o2", "/o3", "/o4", "/o5", "/o8", "/o9", "/o10", "/o11", "/o12", "/o13", "/o15", "/o16", "/o17", "/o18", "/o19"})
    EXPECT_FALSE(std::filesystem::exists(tmp + o + "/metrics.json")) << o;
}

// A part that fails its quality limits exits 1 and says why, in the summary, metrics.json and
// the report's verdict; the scenario's expect: bounds are then notes, not the exit code. The
// default plate with a protective stop at 100 N: its first cut trips it.
TEST(Cli, ABadPartExitsOneAndSaysWhy) {
  const std::string out = ftest::temp_dir("cli_bad_part");
  const CliRun r = run("run " + ftest::source_path("scenarios/default.yaml") + " -o " + out +
                       " --set execution.max_force=100");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.out.find("bad part"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("protective stop"), std::string::npos) << r.out;
  const auto m = nlohmann::json::parse(slurp(out + "/metrics.json"));
  EXPECT_EQ(m["quality.pass"], false);
  ASSERT_TRUE(m["quality.failures"].is_array());
  EXPECT_FALSE(m["quality.failures"].empty());
  EXPECT_EQ(m["exit_code"], 1);
  const std::string report = slurp(out + "/report.html");
  EXPECT_NE(report.find("verdict bad"), std::string::npos);
  EXPECT_NE(report.find("bad part"), std::string::npos);
}

TEST(Cli, OutOfReachIsRefusedWithTheReason) {
  const std::string out = ftest::temp_dir("cli_reach");
  const CliRun r =
      run("run " + ftest::source_path("scenarios/out_of_reach.yaml") + " -o " + out + " --no-report");
  EXPECT_EQ(r.code, 1) << r.err;
  EXPECT_NE(r.out.find("could not be planned"), std::string::npos) << r.out;
  EXPECT_NE(r.out.find("unreachable"), std::string::npos) << r.out;
  const auto m = nlohmann::json::parse(slurp(out + "/metrics.json"));
  EXPECT_EQ(m["trajectory.paths_planned"], 0);
  EXPECT_FALSE(m.contains("execution.paths_executed"));
}

TEST(Cli, PlanTurnsDetectedPathsIntoTrajectoriesAndPrograms) {
  // A straight 60 mm fin root along the top edge of a box wall, the box in front of the robot.
  const std::string dir = ftest::temp_dir("cli_plan");
  flashtwin::save_mesh(dir + "/box.stl",
                       flashtwin::box_mesh(flashtwin::Vec3(-0.05, -0.05, 0), flashtwin::Vec3(0.05, 0.05, 0.04)));
  nlohmann::json paths;
  nlohmann::json pts = nlohmann::json::array(), nrm = nlohmann::json::array();
  for (int i = 0; i <= 60; ++i) {
    pts.push_back({0.05, -0.03 + 0.001 * i, 0.02});
    nrm.push_back({1.0, 0.0, 0.0});
  }
  paths["paths"] = {{{"points", pts}, {"normals", nrm}, {"fin_normal", {0, 0, 1}}, {"closed", false}}};
  std::ofstream(dir + "/paths.json") << paths.dump();
  std::ofstream(dir + "/pose.json") << "{\"X_BC\": [1,0,0,0.6, 0,1,0,0, 0,0,1,-0.2, 0,0,0,1]}";
  const CliRun r = run("plan --path " + dir + "/paths.json --cad " + dir + "/box.stl --pose " + dir +
                       "/pose.json -o " + dir + "/out --export urscript --json");
  ASSERT_EQ(r.code, 0) << r.err << r.out;
  const auto j = nlohmann::json::parse(r.out);
  ASSERT_EQ(j.size(), 1u);
  EXPECT_EQ(j[0]["status"], "ok");
  EXPECT_LE(j[0]["max_joint_velocity_ratio"].get<double>(), 1.0);
  EXPECT_TRUE(std::filesystem::exists(dir + "/out/path_0/trajectory.csv"));
  const std::string prog = slurp(dir + "/out/path_0/flashtwin_path_0.script");
  EXPECT_NE(prog.find("def flashtwin_path_0"), std::string::npos);
  // The same path 20 mm off the CAD surface: a frame or unit mistake, exit 2.
  std::ofstream(dir + "/pose2.json") << "{\"X_BC\": [1,0,0,0.6, 0,1,0,0, 0,0,1,-0.2, 0,0,0,1]}";
  for (auto& p : paths["paths"][0]["points"]) p[0] = 0.07;
  std::ofstream(dir + "/far.json") << paths.dump();
  const CliRun bad = run("plan --path " + dir + "/far.json --cad " + dir + "/box.stl --pose " + dir +
                         "/pose2.json -o " + dir + "/out2");
  EXPECT_EQ(bad.code, 2) << bad.err;
  EXPECT_NE(bad.err.find("off the CAD surface"), std::string::npos) << bad.err;
}
