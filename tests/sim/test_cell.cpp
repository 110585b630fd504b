#include <gtest/gtest.h>

#include <cstring>
#include <filesystem>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/planner/kinematics.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "test_util.hpp"

using namespace flashtwin;

namespace {

Pose site_pose(const mjData* d, int id) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(d->site_xpos[3 * id], d->site_xpos[3 * id + 1], d->site_xpos[3 * id + 2]);
  Mat3 R;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) R(r, c) = d->site_xmat[9 * id + 3 * r + c];
  X.linear() = R;
  return X;
}

}  // namespace

TEST(Cell, MjcfFlangeAndTcpSitesMatchDhKinematics) {
  const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  const std::string dir = ftest::temp_dir("cell");
  const auto setup = pipeline::setup_cell(sc);
  const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
  const sim::MjModelPtr m = sim::load_mjcf_file(files.mjcf);
  const sim::MjDataPtr d = sim::make_data(m.get());
  // Contract names.
  int qadr[6];
  for (int i = 0; i < 6; ++i) {
    const int j = sim::require_id(m.get(), mjOBJ_JOINT, "joint" + std::to_string(i + 1));
    EXPECT_EQ(m->jnt_type[j], mjJNT_HINGE);
    EXPECT_EQ(m->jnt_limited[j], 1);
    EXPECT_DOUBLE_EQ(m->jnt_range[2 * j], sc.robot.limits[i].lower);
    qadr[i] = m->jnt_qposadr[j];
  }
  const int flange = sim::require_id(m.get(), mjOBJ_SITE, "flange");
  const int tcp = sim::require_id(m.get(), mjOBJ_SITE, "tcp");
  sim::require_id(m.get(), mjOBJ_BODY, "casting");
  EXPECT_EQ(m->nu, 6);

  Rng rng(99);
  double worst_p = 0, worst_r = 0, worst_tcp = 0;
  for (int n = 0; n < 1000; ++n) {
    Vector6 q;
    for (int i = 0; i < 6; ++i) {
      q[i] = rng.uniform(sc.robot.limits[i].lower, sc.robot.limits[i].upper);
      d->qpos[qadr[i]] = q[i];
    }
    mj_kinematics(m.get(), d.get());
    const Pose X_WE = setup.spec.X_WB * planner::fk_flange(sc.robot, q);
    const Pose X_WT = setup.spec.X_WB * planner::fk_tool(sc.robot, q);
    const Pose S = site_pose(d.get(), flange);
    worst_p = std::max(worst_p, (S.translation() - X_WE.translation()).norm());
    worst_r = std::max(worst_r, rotation_distance(S.linear(), X_WE.linear()));
    worst_tcp = std::max(worst_tcp,
                         (site_pose(d.get(), tcp).translation() - X_WT.translation()).norm());
  }
  EXPECT_LT(worst_p, 1e-9);
  EXPECT_LT(worst_r, 1e-9);
  EXPECT_LT(worst_tcp, 1e-9);
  std::printf("MJCF vs D-H FK over 1000 configurations: %.3g m, %.3g rad, TCP %.3g m\n", worst_p,
              worst_r, worst_tcp);
}

TEST(Cell, MassPropertiesReachMuJoCo) {
  const RobotModel robot = ftest::ft6();
  const sim::CellSpec spec;
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, spec), "cell.xml");
  double arm_mass = 0;
  for (int i = 1; i <= 6; ++i)
    arm_mass += m->body_mass[sim::require_id(m.get(), mjOBJ_BODY, "link" + std::to_string(i))];
  double expected = 0;
  for (const auto& l : robot.links) expected += l.mass;
  EXPECT_NEAR(arm_mass, expected, 1e-9);
  EXPECT_NEAR(m->body_mass[sim::require_id(m.get(), mjOBJ_BODY, "tool")],
              robot.tool.inertial.mass, 1e-9);
  EXPECT_DOUBLE_EQ(m->opt.timestep, 0.001);
}

TEST(Cell, ArmHangsUnderGravityWithoutActuation) {
  // Real dynamics: with zero torque the arm must move under gravity, and stay in its ranges.
  const RobotModel robot = ftest::ft6();
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, sim::CellSpec{}), "cell.xml");
  // Remove the position servos' action: gain 0 → zero torque.
  for (int i = 0; i < m->nu; ++i) {
    m->actuator_gainprm[i * mjNGAIN] = 0;
    m->actuator_biasprm[i * mjNBIAS + 1] = 0;
  }
  const auto d = sim::make_data(m.get());
  d->qpos[1] = -1.2;
  mj_forward(m.get(), d.get());
  const double z0 = d->site_xpos[3 * sim::require_id(m.get(), mjOBJ_SITE, "tcp") + 2];
  for (int k = 0; k < 500; ++k) mj_step(m.get(), d.get());
  const double z1 = d->site_xpos[3 * sim::require_id(m.get(), mjOBJ_SITE, "tcp") + 2];
  EXPECT_LT(z1, z0 - 0.01);
}

TEST(Cell, LoadErrorsAreInputErrors) {
  EXPECT_THROW(sim::load_mjcf_string("<mujoco><worldbody><body><geom type=\"nonsense\"/>"
                                     "</body></worldbody></mujoco>"),
               InputError);
  EXPECT_THROW(sim::load_mjcf_file("/nonexistent/cell.xml"), InputError);
}

TEST(Scenario, RejectsMissingFilesUnknownKeysAndBadValues) {
  const std::string dir = ftest::temp_dir("scenario");
  auto write = [&](const std::string& name, const std::string& text) {
    const std::string p = dir + "/" + name;
    FILE* f = std::fopen(p.c_str(), "w");
    std::fputs(text.c_str(), f);
    std::fclose(f);
    return p;
  };
  const std::string robot = ftest::source_path("models/robots/ft6.yaml");
  const std::string ok = "name: t\nrobot: " + robot + "\ncasting: {family: housing}\n";
  EXPECT_NO_THROW(pipeline::load_scenario(write("ok.yaml", ok)));
  EXPECT_THROW(pipeline::load_scenario(dir + "/missing.yaml"), IoError);
  try {
    pipeline::load_scenario(write("typo.yaml", ok + "cell: {tabel: {}}\n"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("cell.tabel"), std::string::npos) << e.what();
  }
  try {
    pipeline::load_scenario(write("neg.yaml", "name: t\nrobot: " + robot +
                                                   "\ncasting: {family: housing, flash: {height: [0.002, -0.001]}}\n"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("casting.flash.height"), std::string::npos) << e.what();
  }
  try {
    pipeline::load_scenario(write("fam.yaml", "name: t\nrobot: " + robot + "\ncasting: {family: teapot}\n"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("casting.family: expected flanged_plate"), std::string::npos)
        << e.what();
  }
  try {
    pipeline::load_scenario(write("off.yaml", "name: t\nrobot: " + robot +
                                                   "\ncasting: {family: housing, placement: {x: 3}}\n"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("casting.placement"), std::string::npos) << e.what();
  }
  try {
    pipeline::load_scenario(write("norobot.yaml", "name: t\nrobot: nowhere.yaml\ncasting: {family: housing}\n"));
    FAIL();
  } catch (const ConfigError& e) {
    EXPECT_NE(std::string(e.what()).find("robot"), std::string::npos) << e.what();
  }
}

TEST(Cell, ServosHoldTheHomeKeyframeAgainstGravity) {
  const RobotModel robot = ftest::ft6();
  const auto m = sim::load_mjcf_string(sim::cell_mjcf(robot, sim::CellSpec{}), "cell.xml");
  const auto d = sim::make_data(m.get());
  const int key = sim::require_id(m.get(), mjOBJ_KEY, "home");
  mj_resetDataKeyframe(m.get(), d.get(), key);
  for (int k = 0; k < 2000; ++k) mj_step(m.get(), d.get());  // 2 s at 1 kHz
  double worst = 0;
  for (int i = 0; i < 6; ++i) worst = std::max(worst, std::abs(d->qpos[i] - robot.home[i]));
  // Position servos with finite stiffness sag a little under gravity, but hold the pose.
  EXPECT_LT(worst, 0.02);
  EXPECT_GT(worst, 0.0);  // and it is real dynamics, not a frozen state
  for (int i = 0; i < 6; ++i) EXPECT_LT(std::abs(d->qvel[i]), 1e-2);
}

TEST(Cell, CastingRestsOnTheTableInAnyOrientation) {
  auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  sc.placement.random = true;
  sc.placement.random_tilt = true;
  for (std::uint64_t seed = 1; seed <= 5; ++seed) {
    sc.seed = seed;
    const auto setup = pipeline::setup_cell(sc);
    double min_z = 1e9;
    for (const auto& v : setup.casting.nominal.vertices)
      min_z = std::min(min_z, (setup.spec.X_WC * v).z());
    EXPECT_NEAR(min_z, setup.spec.X_WTable.translation().z(), 1e-12);
  }
}

TEST(Cell, WrittenCellHasCastingMeshesAndGroundTruth) {
  const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  const auto setup = pipeline::setup_cell(sc);
  const std::string dir = ftest::temp_dir("cell_files");
  const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
  const auto m = sim::load_mjcf_file(files.mjcf);
  const int body = sim::require_id(m.get(), mjOBJ_BODY, "casting");
  const int geom = sim::require_id(m.get(), mjOBJ_GEOM, "casting_body");
  EXPECT_EQ(m->geom_bodyid[geom], body);
  EXPECT_EQ(m->geom_type[geom], mjGEOM_MESH);
  sim::require_id(m.get(), mjOBJ_GEOM, "casting_flash");
  sim::require_id(m.get(), mjOBJ_BODY, "scanner");
  // The CAD model file is the nominal mesh, in {C}.
  const TriangleMesh cad = load_mesh(files.cad);
  EXPECT_NEAR(cad.volume(), setup.casting.nominal.volume(), 1e-6 * setup.casting.nominal.volume());
  EXPECT_TRUE(std::filesystem::exists(files.truth + "/flash_truth.json"));
  EXPECT_TRUE(std::filesystem::exists(files.truth + "/fins.stl"));
}

#include "flashtwin/sim/renderer.hpp"
#include "flashtwin/sim/scan_cell.hpp"

TEST(Cell, CastingIsVisibleFromTheDefaultCamera) {
  const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  const auto setup = pipeline::setup_cell(sc);
  const std::string dir = ftest::temp_dir("cell_render");
  const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
  const auto m = sim::load_mjcf_file(files.mjcf);
  const auto d = sim::make_data(m.get());
  mj_resetDataKeyframe(m.get(), d.get(), sim::require_id(m.get(), mjOBJ_KEY, "home"));
  mj_forward(m.get(), d.get());
  sim::OffscreenRenderer renderer(m.get(), 400, 300);
  const Image with = renderer.render(d.get(), "overview");
  ASSERT_EQ(with.width(), 400);
  ASSERT_EQ(with.height(), 300);
  // Hide the casting (and its flash) and render again: the difference is the casting.
  for (const char* g : {"casting_body", "casting_flash"})
    m->geom_rgba[4 * sim::require_id(m.get(), mjOBJ_GEOM, g) + 3] = 0;
  const Image without = renderer.render(d.get(), "overview");
  int differing = 0;
  for (int y = 0; y < 300; ++y)
    for (int x = 0; x < 400; ++x) {
      const Rgb a = with.get(x, y), b = without.get(x, y);
      differing += std::abs(a.r - b.r) + std::abs(a.g - b.g) + std::abs(a.b - b.b) > 30;
    }
  EXPECT_GT(differing, 100);  // the casting covers a visible patch of the overview
}

TEST(Cell, ScanOfTheCellSeesTheCastingAndItsFlashesDeterministically) {
  const auto sc = pipeline::load_scenario(ftest::source_path("scenarios/default.yaml"));
  const auto setup = pipeline::setup_cell(sc);
  const std::string dir = ftest::temp_dir("cell_scan");
  const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
  sim::ScanParams p = sc.scan;
  for (auto& v : p.views) v.line.profile_spacing = 0.002;  // coarse: quick
  const auto a = sim::scan_cell(files.mjcf, setup.casting, p, setup.spec.X_WM, setup.spec.X_WM);
  const auto b = sim::scan_cell(files.mjcf, setup.casting, p, setup.spec.X_WM, setup.spec.X_WM);
  ASSERT_EQ(a.result.cloud_M.size(), b.result.cloud_M.size());
  EXPECT_EQ(std::memcmp(a.result.cloud_M.points.data(), b.result.cloud_M.points.data(),
                        a.result.cloud_M.size() * sizeof(Eigen::Vector3f)),
            0);
  std::size_t body = 0, flash = 0;
  const sim::FlashLabeler labeler(setup.casting);
  const Pose X_CM = setup.spec.X_WC.inverse() * setup.spec.X_WM;
  int flash_near_fin = 0;
  for (std::size_t i = 0; i < a.result.truth.size(); ++i) {
    body += a.result.truth[i] == sim::kTruthBody;
    if (a.result.truth[i] == sim::kTruthFlash) {
      ++flash;
      // Noise-free enough to agree with the geometric labeller most of the time.
      flash_near_fin += labeler.is_flash(X_CM * a.result.cloud_M.points[i].cast<double>());
    }
  }
  EXPECT_GT(body, 10000u);
  EXPECT_GT(flash, 500u);
  EXPECT_GT(flash_near_fin, static_cast<int>(0.9 * flash));
}
