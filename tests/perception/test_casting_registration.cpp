// A real scan of a casting in the cell (with flashes, table, fixture, noise) registered to its
// CAD model.
#include <gtest/gtest.h>
#include <spdlog/spdlog.h>

#include <cstdlib>

#include "flashtwin/perception/registration.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/sim/scan_cell.hpp"
#include "test_util.hpp"

using namespace flashtwin;
using namespace flashtwin::perception;

namespace {

struct Case {
  std::string scenario;
  double max_mm, max_deg;
  bool must_be_confident = true;  ///< false: the pose may be refused, but never wrong and confident
  long long seed = -1;            ///< >= 0: instead of the scenario's seed
  bool as_run = false;            ///< scanned and registered as `flashtwin run` does (planned views)
};

void check_scenario(const Case& c) {
  if (std::getenv("FT_DEBUG")) spdlog::set_level(spdlog::level::debug);
  auto sc = pipeline::load_scenario(ftest::source_path("scenarios/" + c.scenario + ".yaml"));
  if (c.seed >= 0) pipeline::set_seed(sc, static_cast<std::uint64_t>(c.seed));
  const std::string dir = ftest::temp_dir("reg_" + c.scenario);
  RegistrationResult r;
  Pose X_CM;
  std::shared_ptr<const ModelTarget> target;
  if (c.as_run) {
    const auto ss = pipeline::scan_scenario(sc, dir, 2);
    target = ModelTarget::from_mesh(ss.setup.casting.nominal);
    const PointCloud cloud = pipeline::registration_cloud(sc, ss);
    // Points on the fixture blocks are gone; what goes is background (table, fixture), but for
    // the tips of the longest fins reaching towards a block.
    const std::size_t all = ss.scan.result.cloud_M.size();
    std::size_t background = 0;
    for (const auto t : ss.scan.result.truth) background += t == sim::kTruthBackground;
    if (!sc.placement.random) {
      EXPECT_LT(cloud.size(), all);
      EXPECT_LE(all - cloud.size(), background + (all - background) / 100);
    }
    r = register_scan(cloud, *target, pipeline::cell_registration_params());
    X_CM = ss.setup.spec.X_WC.inverse() * ss.scan.X_WM_true;
  } else {
    const auto setup = pipeline::setup_cell(sc);
    const auto files = sim::write_cell(sc.robot, setup.spec, setup.casting, dir);
    const auto scan = sim::scan_cell(files.mjcf, setup.casting, sc.scan, setup.spec.X_WM, setup.spec.X_WM);
    target = ModelTarget::from_mesh(setup.casting.nominal);
    RegistrationParams p;
    p.remove_support_plane = true;
    p.viewpoint = Vec3::Zero();  // the sensors look along +z of {M} from near its origin
    r = register_scan(scan.result.cloud_M, *target, p);
    X_CM = setup.spec.X_WC.inverse() * setup.spec.X_WM;
  }
  ASSERT_TRUE(r.ran) << r.message;
  const double deg = rotation_distance(r.T_target_source.linear(), X_CM.linear()) * 180 / M_PI;
  // Translation error at the part: the mean displacement of the model points.
  double mm = 0;
  for (std::size_t i = 0; i < target->dense().size(); i += 50) {
    const Vec3 q = target->dense().points[i].cast<double>();
    mm = std::max(mm, ((r.T_target_source * (X_CM.inverse() * q)) - q).norm() * 1000);
  }
  std::printf("%s: %.4f mm, %.5f deg, fitness %.3f, rmse %.4f mm, ambiguity %.3f, %s, %.0f ms (%s)\n",
              c.scenario.c_str(), mm, deg, r.fitness, r.rmse * 1000, r.ambiguity,
              r.confident ? "confident" : "NOT confident", r.time_s * 1000, r.stage.c_str());
  if (c.must_be_confident) {
    EXPECT_TRUE(r.confident) << r.message;
  }
  // The safety property: a confident answer is an accurate answer.
  if (r.confident || c.must_be_confident) {
    EXPECT_LT(mm, c.max_mm);
    EXPECT_LT(deg, c.max_deg);
  }
}

}  // namespace

TEST(CastingRegistration, DefaultPlateScanWithFlashesAndTable) { check_scenario({"default", 0.05, 0.02}); }
// A plate whose long axis rests on a few features: the polish alone stopped 8.0 mm off along it,
// confident; the search along the weakest translation direction finds the right offset.
TEST(CastingRegistration, PlateDoesNotSlideAlongItsLongAxis) {
  check_scenario({"default", 0.1, 0.02, false, 5006});
}
// Scanned as `flashtwin run` scans it, a plate whose robust polish stopped 0.34 mm off along the
// long axis, confident (its end faces, the only surfaces facing that way, were down-weighted as
// outliers): the pose settles where those faces agree.
TEST(CastingRegistration, PlateSettlesWhereItsEndFacesAgree) {
  check_scenario({"default", 0.05, 0.02, true, 5021, true});
}
// The round flange is symmetric but for a small flat on its rim: only the flat's evidence
// decides between the turned poses. Today it is registered and confident, but the decision is
// fragile (a smaller global point set turns it 135°, then refused), so the test asserts the
// safety property: accurate, or refused.
TEST(CastingRegistration, RoundFlangeIsAccurateOrRefused) {
  check_scenario({"round_flange", 0.05, 0.02, false});
}
// Scanned as `flashtwin run` scans them (planned views), two seeds where a pose turned by a
// bolt-hole pitch explained more points than the true one (its rim and top face explain points
// near their edges by chance): 6002 was refused as ambiguous, 6006 registered 90° off and
// refused. The points lying far from the other pose's model (the flat) decide for the truth.
TEST(CastingRegistration, RoundFlangeIsDecidedByItsFlatNotByTheMostPointsExplained) {
  for (const long long seed : {6002LL, 6006LL}) check_scenario({"round_flange", 0.05, 0.02, true, seed, true});
}
// The housing's walls stand off-centre on its flange: turned half-way about the vertical, the
// walls fit again and the overhanging flange lands on a fixture block, whose points had
// explained it (seed 7043: confidently 180° off). Registration sees the scan without the
// points on the cell's known fixture.
TEST(CastingRegistration, HousingIsNotTurnedOntoItsFixture) {
  check_scenario({"housing", 0.05, 0.02, true, 7043, true});
}
// Seed 6017 (a 400 mm flange, eight 19 mm bolt holes, the flat under a fixture block): the local
// turns found the pose that explains the scan best, then the ICP on its subset turned it 8° off
// the bolt holes, confident (6.2° error). An ICP run that explains fewer points than its start is
// not taken.
TEST(CastingRegistration, RoundFlangeIsNotTurnedOffItsBoltHolesByTheIcp) {
  check_scenario({"round_flange", 0.05, 0.02, true, 6017, true});
}
// Seed 7030: the finalist at the true turn stood 7 mm off along the flange (its end walls, the
// only surfaces facing that way, explained nothing), so the half-turned pose, whose walls fit,
// won on evidence and was confidently 180° off. Each finalist first settles along its weakly
// constrained direction.
TEST(CastingRegistration, HousingFinalistsSettleAlongTheFlangeBeforeTheyAreCompared) {
  check_scenario({"housing", 0.05, 0.02, true, 7030, true});
}
TEST(CastingRegistration, Housing) { check_scenario({"housing", 0.05, 0.02}); }
TEST(CastingRegistration, TiltedPlate) { check_scenario({"tilted", 0.05, 0.02}); }
TEST(CastingRegistration, UserMeshAngleBracket) { check_scenario({"user_mesh", 0.05, 0.02}); }
TEST(CastingRegistration, NoisyHousingIsAccurateOrRefused) {
  // 5x noise and 10x outliers (the scenario's calibration error is not applied here: the scan
  // is taken from the true mount pose).
  check_scenario({"noisy", 0.05, 0.02, false});
}
