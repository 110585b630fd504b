// Process model: voxelisation of fins and body, material removal by the burr, residual
// analysis and the grinding force model.
#include <gtest/gtest.h>

#include <array>
#include <cmath>
#include <set>
#include <string>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/sim/casting.hpp"
#include "flashtwin/sim/process.hpp"

using namespace flashtwin;
using namespace flashtwin::sim;

namespace {

constexpr double mm = 1e-3;


// The test cell: a body box x ∈ [−30, 0], y ∈ [−60, 60], z ∈ [0, 20] mm with a parting-line-like
// fin on its x = 0 wall: x ∈ [0, 5], y ∈ [−20, 20], z ∈ [9.5, 10.5] mm (200 mm^3).
struct Cell {
  TriangleMesh body = box_mesh(Vec3(-30, -60, 0) * mm, Vec3(0, 60, 20) * mm);
  TriangleMesh fin = box_mesh(Vec3(0, -20, 9.5) * mm, Vec3(5, 20, 10.5) * mm);
  double fin_volume = 5 * 40 * 1 * mm * mm * mm;
};

// Cylinder burr r = 3 mm, 12 mm long, flat end, standing upright: z_T = −z_C, cutter along
// −z_T = +z_C from the TCP, so a TCP at z = 4 mm covers z ∈ [4, 16] mm.
ToolParams upright_tool() {
  ToolParams t;
  t.radius = 3 * mm;
  t.length = 12 * mm;
  t.axis_sign = -1;
  t.end = ToolEnd::kFlat;
  return t;
}
Pose upright_pose(double x, double y) {
  Pose X = Pose::Identity();
  X.linear() = Eigen::AngleAxisd(M_PI, Vec3::UnitX()).toRotationMatrix();
  X.translation() = Vec3(x, y, 4 * mm);
  return X;
}

// ∫ sqrt(R² − s²) ds.
double circle_integral(double R, double s) {
  return 0.5 * (s * std::sqrt(R * R - s * s) + R * R * std::asin(s / R));
}

// Moves the upright tool along +y from y0 to y1 in steps of `step`; sums what it removes.
StepRemoval pass(MaterialGrid& grid, const ToolParams& tool, double x, double y0, double y1,
                 double step) {
  StepRemoval total;
  const int n = static_cast<int>(std::round((y1 - y0) / step));
  for (int k = 0; k <= n; ++k) {
    const StepRemoval s = remove_material(tool, grid, upright_pose(x, y0 + (y1 - y0) * k / n));
    total.flash_count += s.flash_count;
    total.body_count += s.body_count;
    total.flash_volume += s.flash_volume;
    total.body_volume += s.body_volume;
    total.max_depth = std::max(total.max_depth, s.max_depth);
    total.penetration = std::max(total.penetration, s.penetration);
  }
  return total;
}

// Ray parity along a skewed direction (independent of the scanline voxeliser).
bool inside_by_parity(const TriangleMesh& m, const Vec3& p) {
  const Vec3 d = Vec3(0.5773, 0.3371, 0.7436).normalized();
  int hits = 0;
  for (const auto& t : m.triangles) {
    const Vec3 &a = m.vertices[t[0]], &b = m.vertices[t[1]], &c = m.vertices[t[2]];
    const Vec3 e1 = b - a, e2 = c - a, q = d.cross(e2);
    const double det = e1.dot(q);
    if (std::abs(det) < 1e-30) continue;
    const Vec3 s = p - a;
    const double u = s.dot(q) / det;
    if (u < 0 || u > 1) continue;
    const Vec3 r = s.cross(e1);
    const double v = d.dot(r) / det;
    if (v < 0 || u + v > 1) continue;
    if (e2.dot(r) / det > 0) ++hits;
  }
  return hits % 2 == 1;
}

// An input error of type ArgumentError whose message names `field`.
template <class F>
void expect_argument_error(F&& f, const std::string& field) {
  try {
    f();
    ADD_FAILURE() << "expected ArgumentError naming " << field;
  } catch (const ArgumentError& e) {
    EXPECT_NE(std::string(e.what()).find(field), std::string::npos) << e.what();
  }
}

}  // namespace

TEST(MaterialGrid, BoxFinVolumeAndLabels) {
  const Cell cell;
  const MaterialGrid grid(cell.body, {cell.fin});
  const double v = grid.flash_voxels_initial() * grid.voxel_volume();
  EXPECT_NEAR(v, cell.fin_volume, 0.01 * cell.fin_volume);
  EXPECT_EQ(grid.flash_voxels_remaining(), grid.flash_voxels_initial());
  EXPECT_GT(grid.body_voxels_initial(), 0u);

  EXPECT_EQ(grid.label_at(Vec3(2.53, 0.17, 10.02) * mm), VoxelLabel::kFlash);
  EXPECT_EQ(grid.label_at(Vec3(4.97, -19.93, 10.47) * mm), VoxelLabel::kFlash);
  EXPECT_EQ(grid.label_at(Vec3(5.03, 0, 10) * mm), VoxelLabel::kEmpty);   // beyond the tip
  EXPECT_EQ(grid.label_at(Vec3(2, 0, 10.53) * mm), VoxelLabel::kEmpty);   // above the fin
  EXPECT_EQ(grid.label_at(Vec3(-0.03, 0, 10) * mm), VoxelLabel::kBody);   // wall behind the root
  EXPECT_EQ(grid.label_at(Vec3(-0.5, 5, 14) * mm), VoxelLabel::kBody);    // band near the fin
  EXPECT_EQ(grid.label_at(Vec3(-10, 0, 10) * mm), VoxelLabel::kEmpty);    // deep inside
  EXPECT_EQ(grid.label_at(Vec3(-0.5, 50, 10) * mm), VoxelLabel::kEmpty);  // far from the fin

  // An inside-out fin voxelises the same (nonzero winding).
  TriangleMesh flipped = cell.fin;
  for (auto& t : flipped.triangles) std::swap(t[1], t[2]);
  const MaterialGrid grid_flipped(cell.body, {flipped});
  EXPECT_EQ(grid_flipped.flash_voxels_initial(), grid.flash_voxels_initial());
}

TEST(MaterialGrid, TiltedFinVolume) {
  // A free fin turned 30° about z and 10° about x: scanlines cross slanted faces.
  Cell cell;
  Pose X = Pose::Identity();
  X.linear() = (Eigen::AngleAxisd(0.5236, Vec3::UnitZ()) * Eigen::AngleAxisd(0.1745, Vec3::UnitX()))
                   .toRotationMatrix();
  X.translation() = Vec3(20, 3, 31) * mm;
  const TriangleMesh fin = box_mesh(Vec3(0, -20, -0.5) * mm, Vec3(5, 20, 0.5) * mm).transformed(X);
  const MaterialGrid grid(cell.body, {fin});
  EXPECT_NEAR(grid.flash_voxels_initial() * grid.voxel_volume(), cell.fin_volume,
              0.01 * cell.fin_volume);
}

TEST(MaterialGrid, CastingFlashVolume) {
  CastingParams cp;
  cp.seed = 7;
  const Casting casting = make_casting(cp);
  ASSERT_FALSE(casting.fins.empty());
  const MaterialGrid grid = make_material_grid(casting);
  const double v = grid.flash_voxels_initial() * grid.voxel_volume();
  // Fins only 0.3–1.5 mm thick: a few voxels across, so allow 5 %.
  EXPECT_NEAR(v, casting.flash_volume(), 0.05 * casting.flash_volume());
  EXPECT_GT(grid.body_voxels_initial(), 0u);
  // Flash voxel centres lie inside a fin and outside the nominal body (sampled).
  const auto pts = remaining_flash_points(grid);
  const TriangleMesh fins = casting.flash_mesh();
  for (std::size_t k = 0; k < pts.size(); k += pts.size() / 25 + 1) {
    EXPECT_TRUE(inside_by_parity(fins, pts[k])) << k;
    EXPECT_FALSE(inside_by_parity(casting.nominal, pts[k])) << k;
  }
}

TEST(Removal, StraightPassRemovesSweptVolume) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const ToolParams tool = upright_tool();
  // Axis 3 mm from the wall: the burr is tangent to the body and covers x ∈ [0, 6] mm.
  const StepRemoval total = pass(grid, tool, 3 * mm, -30 * mm, 0.0, 5e-6);
  // Swept stadium ∩ fin: the rectangle up to y = 0 plus the front half-disc within x ∈ [0, 5].
  const double area = 5 * 20 + (circle_integral(3, 2) - circle_integral(3, -3));  // [mm^2]
  const double expected = area * 1 * mm * mm * mm;
  EXPECT_NEAR(total.flash_volume, expected, 0.02 * expected);
  EXPECT_EQ(total.body_count, 0u);
  EXPECT_EQ(total.penetration, 0.0);
  const ResidualReport r = analyze_residual(grid);
  EXPECT_EQ(r.gouge_voxels, 0u);
  EXPECT_LT(r.gouge_max_depth, grid.voxel_size());
  EXPECT_NEAR(r.flash_volume_remaining, r.flash_volume_initial - total.flash_volume, 1e-15);
}

TEST(Removal, TangentToolTakesNoBody) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const StepRemoval s = remove_material(upright_tool(), grid, upright_pose(3 * mm, 0));
  EXPECT_GT(s.flash_count, 0u);
  EXPECT_EQ(s.body_count, 0u);
  EXPECT_EQ(s.contact_count, 0u);
  EXPECT_LT(analyze_residual(grid).gouge_max_depth, grid.voxel_size());
  // The removed flash lies in front of the axis (towards the fin tip) on average.
  EXPECT_GT(s.centroid_C.x(), 0.0);
  EXPECT_NEAR(s.centroid_C.z(), 10 * mm, 0.05 * mm);
}

TEST(Removal, PushedToolGougesHalfAMillimetre) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const ToolParams tool = upright_tool();
  const double h = grid.voxel_size();
  const StepRemoval s = remove_material(tool, grid, upright_pose(2.5 * mm, 0));
  EXPECT_GT(s.body_count, 0u);
  EXPECT_NEAR(s.max_depth, 0.5 * mm, h);
  EXPECT_NEAR(s.penetration, 0.5 * mm, h);
  EXPECT_NEAR(analyze_residual(grid).gouge_max_depth, 0.5 * mm, h);
  // Standing still: nothing new to remove, but the penetration (spring force) stays.
  const StepRemoval again = remove_material(tool, grid, upright_pose(2.5 * mm, 0));
  EXPECT_EQ(again.count(), 0u);
  EXPECT_NEAR(again.penetration, s.penetration, 1e-12);

  // A pass 0.5 mm deep over 20 mm: a slab d·Ly plus the circular segment, 12 mm tall.
  const StepRemoval total = pass(grid, tool, 2.5 * mm, -10 * mm, 10 * mm, 5e-6);
  (void)total;
  const double d = 0.5, r = 3, Ly = 20;
  const double segment = r * r * std::acos((r - d) / r) - (r - d) * std::sqrt(2 * r * d - d * d);
  const double expected = (d * Ly + segment) * 12 * mm * mm * mm;
  const ResidualReport rep = analyze_residual(grid);
  EXPECT_NEAR(rep.gouge_volume, expected, 0.03 * expected);
  EXPECT_NEAR(rep.gouge_max_depth, 0.5 * mm, h);
}

TEST(Removal, MatchesBruteForceOnRandomPoses) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  Rng rng(42);
  for (int trial = 0; trial < 25; ++trial) {
    ToolParams tool;
    tool.radius = rng.uniform(0.5, 4) * mm;
    tool.length = rng.uniform(tool.radius / mm, 12) * mm;
    tool.end = trial % 2 ? ToolEnd::kBall : ToolEnd::kFlat;
    tool.axis_sign = trial % 3 ? -1 : 1;
    Pose X = Pose::Identity();
    const Vec3 axis = Vec3(rng.normal(), rng.normal(), rng.normal()).normalized();
    X.linear() = Eigen::AngleAxisd(rng.uniform(0, 2 * M_PI), axis).toRotationMatrix();
    X.translation() = Vec3(rng.uniform(-3, 6), rng.uniform(-22, 22), rng.uniform(6, 14)) * mm;

    // Independent point test: axial coordinate and distance from the axis.
    const Vec3 a = tool.axis_sign * X.linear().col(2);
    const double r = tool.radius;
    auto inside = [&](const Vec3& p) {
      const Vec3 d = p - X.translation();
      const double u = d.dot(a);
      const double rho = (d - u * a).norm();
      if (tool.end == ToolEnd::kBall && u <= r && (p - (X.translation() + r * a)).norm() <= r)
        return true;
      const double u0 = tool.end == ToolEnd::kBall ? r : 0.0;
      return u >= u0 && u <= tool.length && rho <= r;
    };
    std::size_t flash = 0, body = 0, contact = 0;
    Vec3 sum = Vec3::Zero();
    double pen = 0;
    for (const Vec3& p : voxel_points(grid, VoxelLabel::kFlash))
      if (inside(p)) ++flash, sum += p;
    for (const Vec3& p : voxel_points(grid, VoxelLabel::kBody))
      if (inside(p)) {
        ++body, ++contact, sum += p;
        pen = std::max(pen, grid.nominal().closest(p).distance);
      }
    for (const Vec3& p : voxel_points(grid, VoxelLabel::kGouge))
      if (inside(p)) ++contact, pen = std::max(pen, grid.nominal().closest(p).distance);

    const StepRemoval s = remove_material(tool, grid, X);
    EXPECT_EQ(s.flash_count, flash) << trial;
    EXPECT_EQ(s.body_count, body) << trial;
    EXPECT_EQ(s.contact_count, contact) << trial;
    EXPECT_NEAR(s.penetration, pen, 1e-7) << trial;
    if (flash + body > 0) {
      EXPECT_LT((s.centroid_C - sum / double(flash + body)).norm(), 1e-9);
    }
  }
}

TEST(Residual, PartialAndFullPass) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const double h = grid.voxel_size();
  const ToolParams tool = upright_tool();
  const ResidualReport before = analyze_residual(grid);
  EXPECT_NEAR(before.residual_flash_max, 5 * mm, h);
  EXPECT_DOUBLE_EQ(before.flash_removed_fraction, 0.0);

  // Half the fin ground flush: the other half still stands 5 mm.
  pass(grid, tool, 3 * mm, -30 * mm, 0.0, 2e-5);
  const ResidualReport half = analyze_residual(grid);
  EXPECT_NEAR(half.residual_flash_max, 5 * mm, h);
  EXPECT_GT(half.flash_removed_fraction, 0.5);
  EXPECT_LT(half.flash_removed_fraction, 0.6);
  for (const Vec3& p : remaining_flash_points(grid)) ASSERT_GT(p.y(), 0.0);

  // The residual mesh holds exactly the remaining voxels and covers exactly their exposed
  // faces, in far fewer triangles than two per face (coplanar faces merged).
  const TriangleMesh m = remaining_flash_mesh(grid);
  EXPECT_NEAR(m.volume(), half.flash_volume_remaining, 1e-6 * half.flash_volume_remaining);
  std::set<std::array<long, 3>> voxels;
  const auto key = [h](const Vec3& p) {
    return std::array<long, 3>{std::lround(p.x() / h - 0.5), std::lround(p.y() / h - 0.5), std::lround(p.z() / h - 0.5)};
  };
  for (const Vec3& p : remaining_flash_points(grid)) voxels.insert(key(p));
  std::size_t exposed = 0;
  for (const auto& v : voxels)
    for (int d = 0; d < 3; ++d)
      for (const long s : {-1L, 1L}) {
        auto nb = v;
        nb[static_cast<std::size_t>(d)] += s;
        exposed += voxels.count(nb) == 0 ? 1 : 0;
      }
  EXPECT_NEAR(m.area(), static_cast<double>(exposed) * h * h, 1e-6 * static_cast<double>(exposed) * h * h);
  EXPECT_LT(m.triangles.size(), exposed / 10);

  pass(grid, tool, 3 * mm, 0.0, 30 * mm, 2e-5);
  const ResidualReport full = analyze_residual(grid);
  EXPECT_EQ(full.flash_voxels_remaining, 0u);
  EXPECT_DOUBLE_EQ(full.flash_removed_fraction, 1.0);
  EXPECT_EQ(full.residual_flash_max, 0.0);
  EXPECT_EQ(full.gouge_voxels, 0u);
  EXPECT_TRUE(remaining_flash_mesh(grid).triangles.empty());
}

TEST(Residual, ChipCutLooseAlongTheRootIsNotResidual) {
  // A 2 mm burr cuts the fin's root strip (x in [0, 2] mm) over part of its length, then over
  // all of it: the outer 3 mm stay joined while any root is left, then fall off as a chip.
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const double h = grid.voxel_size();
  ToolParams tool = upright_tool();
  tool.radius = 1 * mm;
  pass(grid, tool, 1 * mm, -25 * mm, 10 * mm, 2e-5);
  const ResidualReport held = analyze_residual(grid);
  EXPECT_NEAR(held.residual_flash_max, 5 * mm, h);
  EXPECT_EQ(held.loose_flash_voxels, 0u);
  pass(grid, tool, 1 * mm, 10 * mm, 25 * mm, 2e-5);
  const ResidualReport loose = analyze_residual(grid);
  EXPECT_EQ(loose.residual_flash_max, 0.0);
  EXPECT_EQ(loose.gouge_voxels, 0u);
  // The chip: 3 x 40 x 1 mm, still counted as remaining flash volume.
  EXPECT_NEAR(loose.loose_flash_volume, 120 * mm * mm * mm, 0.05 * 120 * mm * mm * mm);
  EXPECT_DOUBLE_EQ(loose.loose_flash_volume, loose.flash_volume_remaining);
  const RemainingFlash split = split_remaining_flash(grid);
  EXPECT_TRUE(split.attached.empty());
  EXPECT_EQ(split.loose.size(), loose.loose_flash_voxels);
}

TEST(Residual, CopiesAreIndependent) {
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const MaterialGrid fresh = grid;
  remove_material(upright_tool(), grid, upright_pose(3 * mm, 0));
  EXPECT_LT(grid.flash_voxels_remaining(), fresh.flash_voxels_remaining());
  EXPECT_EQ(fresh.flash_voxels_remaining(), fresh.flash_voxels_initial());
}

TEST(Force, KnownRemovalRate) {
  ForceParams fp;
  ToolParams tool = upright_tool();
  StepRemoval s;
  s.flash_count = 25;
  s.flash_volume = 25e-12;  // 25 voxels of 0.1 mm: 2.5e-11 m^3
  const Pose X = upright_pose(0, 0);
  s.centroid_C = X.translation() + Vec3(2 * mm, 0, 6 * mm);  // +x of the axis, mid-cutter
  const double dt = 1e-3;
  const Vec3 v(0, 0.005, 0);  // feeding along +y
  const GrindingWrench w = grinding_force(fp, tool, s, dt, X, v);

  const double vs = 2 * M_PI * 0.003 * 20000 / 60;  // 6.283 m/s
  const double Q = 25e-12 / dt;
  const double ft = 4e10 * Q / vs;  // 0.159 N
  const double fn = 2 * ft;
  EXPECT_NEAR(w.cutting_speed, vs, 1e-12);
  EXPECT_NEAR(w.removal_rate, Q, 1e-18);
  EXPECT_NEAR(w.tangential_force, ft, 0.01 * ft);
  EXPECT_NEAR(w.normal_force, fn, 0.01 * fn);
  EXPECT_EQ(w.penalty_force, 0.0);
  // Normal from the material (+x of the axis) to the axis: −x; tangential against the feed: −y.
  const Vec3 f_expected(-fn, -ft, 0);
  EXPECT_LT((w.force_C - f_expected).norm(), 0.01 * f_expected.norm());
  EXPECT_LT((w.torque_C - (s.centroid_C - X.translation()).cross(w.force_C)).norm(), 1e-12);

  // Contact penalty: 0.1 mm penetration at −x of the axis pushes the tool along +x.
  s.penetration = 1e-4;
  s.contact_count = 10;
  s.contact_centroid_C = X.translation() + Vec3(-2.9 * mm, 0, 6 * mm);
  fp.contact_damping = 100;
  const GrindingWrench wp = grinding_force(fp, tool, s, dt, X, Vec3(-0.01, 0.005, 0));
  const double pen = 2e5 * 1e-4 + 100 * 0.01;  // spring + damping on 10 mm/s into the wall
  EXPECT_NEAR(wp.penalty_force, pen, 1e-9);
  EXPECT_NEAR(wp.normal_force, fn + pen, 0.01 * (fn + pen));
  EXPECT_NEAR(wp.force_C.x(), -fn + pen, 0.01 * (fn + pen));

  // No removal, no contact: no force.
  const GrindingWrench zero = grinding_force(ForceParams{}, tool, StepRemoval{}, dt, X, v);
  EXPECT_EQ(zero.force_C.norm(), 0.0);
  EXPECT_EQ(zero.torque_C.norm(), 0.0);
}

TEST(Force, MeanForceOfASteadyPass) {
  // Feed 5 mm/s at 1 kHz through a 5 mm × 1 mm fin: Q = 25 mm^3/s on average.
  const Cell cell;
  MaterialGrid grid(cell.body, {cell.fin});
  const ToolParams tool = upright_tool();
  const ForceParams fp;
  const double dt = 1e-3, v = 0.005, y0 = -15 * mm, y1 = -2 * mm;
  pass(grid, tool, 3 * mm, -30 * mm, y0, v * dt);
  double sum_t = 0, sum_n = 0;
  int n = 0;
  for (double y = y0 + v * dt; y <= y1; y += v * dt, ++n) {
    const Pose X = upright_pose(3 * mm, y);
    const StepRemoval s = remove_material(tool, grid, X);
    const GrindingWrench w = grinding_force(fp, tool, s, dt, X, Vec3(0, v, 0));
    sum_t += w.tangential_force;
    sum_n += w.normal_force;
    EXPECT_LE(w.force_C.y(), 0.0);  // against the feed
  }
  const double ft = fp.specific_energy * (v * 5 * mm * 1 * mm) / cutting_speed(fp, tool);
  EXPECT_NEAR(sum_t / n, ft, 0.03 * ft);
  EXPECT_NEAR(sum_n / n, 2 * ft, 0.03 * 2 * ft);
}

TEST(Params, BadValuesNameTheField) {
  const Cell cell;
  const double nan = std::nan("");
  auto grid_with = [&](MaterialParams p) {
    return [=] { MaterialGrid g(cell.body, {cell.fin}, p); };
  };
  MaterialParams p;
  p.voxel_size = 0;
  expect_argument_error(grid_with(p), "voxel_size");
  p.voxel_size = -1e-4;
  expect_argument_error(grid_with(p), "voxel_size");
  p.voxel_size = nan;
  expect_argument_error(grid_with(p), "voxel_size");
  p = MaterialParams{};
  p.body_band = nan;
  expect_argument_error(grid_with(p), "body_band");
  p = MaterialParams{};
  p.body_margin = -1;
  expect_argument_error(grid_with(p), "body_margin");
  expect_argument_error([&] { MaterialGrid g(TriangleMesh{}, {cell.fin}); }, "nominal");

  MaterialGrid grid(cell.body, {cell.fin});
  auto remove_with = [&](ToolParams t) {
    return [&grid, t] { remove_material(t, grid, upright_pose(0, 0)); };
  };
  ToolParams t;
  t.radius = 0;
  expect_argument_error(remove_with(t), "tool.radius");
  t.radius = -1;
  expect_argument_error(remove_with(t), "tool.radius");
  t.radius = nan;
  expect_argument_error(remove_with(t), "tool.radius");
  t = ToolParams{};
  t.length = nan;
  expect_argument_error(remove_with(t), "tool.length");
  t = ToolParams{};
  t.axis_sign = 0;
  expect_argument_error(remove_with(t), "tool.axis_sign");
  Pose bad_pose = upright_pose(0, 0);
  bad_pose.translation().x() = nan;
  expect_argument_error([&] { remove_material(ToolParams{}, grid, bad_pose); }, "X_CT");

  const StepRemoval s;
  auto force_with = [&](ForceParams f, double dt) {
    return [=] { grinding_force(f, ToolParams{}, s, dt, Pose::Identity(), Vec3::Zero()); };
  };
  ForceParams f;
  f.specific_energy = nan;
  expect_argument_error(force_with(f, 1e-3), "specific_energy");
  f = ForceParams{};
  f.spindle_rpm = 0;
  expect_argument_error(force_with(f, 1e-3), "spindle_rpm");
  f = ForceParams{};
  f.contact_stiffness = -1;
  expect_argument_error(force_with(f, 1e-3), "contact_stiffness");
  expect_argument_error(force_with(ForceParams{}, 0), "dt");
  expect_argument_error(force_with(ForceParams{}, nan), "dt");
}
