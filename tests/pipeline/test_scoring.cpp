// Scoring against ground truth: label precision/recall, the §4.5 path metric, expect: bounds.
#include <gtest/gtest.h>

#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scoring.hpp"

using namespace flashtwin;
using namespace flashtwin::pipeline;

TEST(Scoring, SegmentationCountsOnlyPointsWithATrueClass) {
  // truth: body, flash, background, outlier, mixed, flash; detected: flash on 0, 1, 3, 4.
  const std::vector<std::uint8_t> truth{0, 1, 2, 3, 4, 1};
  const std::vector<std::uint8_t> det{1, 1, 0, 1, 1, 0};
  const auto s = score_segmentation(det, truth);
  EXPECT_EQ(s.scored, 4u);
  EXPECT_EQ(s.true_positive, 1u);
  EXPECT_EQ(s.false_positive, 1u);
  EXPECT_EQ(s.false_negative, 1u);
  EXPECT_DOUBLE_EQ(s.precision, 0.5);
  EXPECT_DOUBLE_EQ(s.recall, 0.5);
}

TEST(Scoring, PathOffsetAndHalfCoverage) {
  // True root: 100 mm along x. Path: its first half, 0.2 mm above it.
  const std::vector<Curve> truth{{{Vec3(0, 0, 0), Vec3(0.1, 0, 0)}, false}};
  const std::vector<Curve> path{{{Vec3(0, 0, 2e-4), Vec3(0.02, 0, 2e-4), Vec3(0.05, 0, 2e-4)}, false}};
  const auto s = score_path(path, truth, 1e-4, 5e-4);
  EXPECT_NEAR(s.true_length, 0.1, 1e-12);
  EXPECT_NEAR(s.path_length, 0.05, 1e-12);
  EXPECT_NEAR(s.spurious_max, 2e-4, 1e-12);
  // Evaluation points at x ≤ 50.3 mm lie within 0.5 mm (hypot(0.3, 0.2) < 0.5 mm): ~50.3 %.
  EXPECT_NEAR(s.coverage, 0.503, 0.005);
  EXPECT_NEAR(s.max, std::hypot(0.05, 2e-4), 1e-9);
  EXPECT_GT(s.rmse, s.mean);
  // A closed square scored against itself: zero error, full coverage.
  const std::vector<Curve> sq{{{Vec3(0, 0, 0), Vec3(0.01, 0, 0), Vec3(0.01, 0.01, 0), Vec3(0, 0.01, 0)}, true}};
  const auto z = score_path(sq, sq);
  EXPECT_NEAR(z.true_length, 0.04, 1e-12);
  EXPECT_LT(z.max, 1e-12);
  EXPECT_DOUBLE_EQ(z.coverage, 1.0);
}

TEST(Scoring, UnseenRootFractionCountsRootWithNoSeenPointNearby) {
  // Root 100 mm along x; seen points 0.2 mm above its first 30 mm and 3 mm above the rest.
  const std::vector<Curve> roots{{{Vec3(0, 0, 0), Vec3(0.1, 0, 0)}, false}};
  std::vector<Vec3> seen;
  for (int i = 0; i <= 100; ++i) seen.push_back(Vec3(i * 1e-3, 0, i <= 30 ? 2e-4 : 3e-3));
  EXPECT_NEAR(unseen_root_fraction(roots, seen, 5e-4, 1e-3), 70.0 / 101.0, 1e-9);
  EXPECT_DOUBLE_EQ(unseen_root_fraction(roots, {}, 5e-4, 1e-3), 1.0);
  EXPECT_DOUBLE_EQ(unseen_root_fraction({}, seen), 0.0);
}

TEST(Scoring, CurveDistanceFindsFarSegments) {
  // A query far from every grid cell of the segment still gets the exact distance.
  const CurveDistance d({{{Vec3(0, 0, 0), Vec3(0.001, 0, 0)}, false}});
  EXPECT_NEAR(d(Vec3(0.0005, 0.3, 0)), 0.3, 1e-12);
  EXPECT_NEAR(d(Vec3(0.0005, 0.0004, 0)), 0.0004, 1e-12);
}

TEST(Scoring, ExpectationsReportEveryViolation) {
  Scenario sc;
  sc.expect = {{"path.rmse_mm", 0, 0.1, false, false},
               {"registration.confident", -1e300, 1e300, true, true},
               {"path.coverage", 0.99, 1e300, false, false},
               {"missing.key", 0, 1, false, false}};
  nlohmann::ordered_json m;
  m["path.rmse_mm"] = 0.05;
  m["registration.confident"] = false;
  m["path.coverage"] = 0.9;
  const auto bad = check_expectations(sc, m);
  ASSERT_EQ(bad.size(), 3u);
  EXPECT_NE(bad[0].find("registration.confident"), std::string::npos);
  EXPECT_NE(bad[1].find("path.coverage"), std::string::npos);
  EXPECT_NE(bad[2].find("missing.key"), std::string::npos);
}

TEST(Scoring, QualityNamesEveryLimitMissedAndByHowMuch) {
  const QualityLimits q;  // removed >= 99 %, residual <= 0.2 mm, gouge <= 0.1 mm, no stop
  nlohmann::ordered_json good;
  good["casting.flash_volume_mm3"] = 900.0;
  good["removal.flash_removed_fraction"] = 0.995;
  good["removal.residual_flash_max_mm"] = 0.15;
  good["removal.gouge_max_mm"] = 0.08;
  good["execution.paths_stopped_force_limit"] = 0;
  EXPECT_TRUE(quality_failures(q, good).empty());

  nlohmann::ordered_json bad = good;
  bad["removal.flash_removed_fraction"] = 0.44;
  bad["removal.residual_flash_max_mm"] = 5.2;
  bad["removal.gouge_max_mm"] = 1.5;
  bad["execution.paths_stopped_force_limit"] = 1;
  const auto f = quality_failures(q, bad);
  ASSERT_EQ(f.size(), 4u);
  EXPECT_NE(f[0].find("44.0 %"), std::string::npos) << f[0];
  EXPECT_NE(f[1].find("5.20 mm"), std::string::npos) << f[1];
  EXPECT_NE(f[2].find("1.50 mm"), std::string::npos) << f[2];
  EXPECT_NE(f[3].find("protective stop"), std::string::npos) << f[3];

  // Limits from the scenario's quality: block move the verdict.
  QualityLimits loose;
  loose.max_gouge_mm = 2;
  loose.max_residual_mm = 6;
  loose.min_removed_fraction = 0.4;
  loose.max_protective_stops = 1;
  EXPECT_TRUE(quality_failures(loose, bad).empty());

  // A part nobody ground (no removal measured) with flash on it misses the removal limit; one
  // without flash is good.
  nlohmann::ordered_json untouched;
  untouched["casting.flash_volume_mm3"] = 900.0;
  const auto u = quality_failures(q, untouched);
  ASSERT_EQ(u.size(), 1u);
  EXPECT_NE(u[0].find("removed 0.0 %"), std::string::npos) << u[0];
  untouched["casting.flash_volume_mm3"] = 0.0;
  EXPECT_TRUE(quality_failures(q, untouched).empty());
}
