// Voxel-grid downsampling: the plain centroid version against the thesis's improved version
// (§3.4: keep the original point nearest each voxel's centroid), on boundary-like points.
#include <benchmark/benchmark.h>

#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "flashtwin/sim/casting.hpp"

using namespace flashtwin;

namespace {

// ~2,600 points along a flash root of the default-family casting, with 30 µm noise: the
// thesis's boundary point count.
const PointCloud& boundary_points() {
  static const PointCloud cloud = [] {
    sim::CastingParams p;
    p.flash.root_spacing = 0.0002;
    const sim::Casting c = sim::make_casting(p);
    PointCloud out;
    Rng rng(3);
    for (const auto& fin : c.fins)
      for (const auto& q : fin.root) {
        if (out.size() >= 2600) break;
        out.points.push_back((q + Vec3(rng.normal(), rng.normal(), rng.normal()) * 30e-6).cast<float>());
      }
    return out;
  }();
  return cloud;
}

void BM_VoxelCentroid(benchmark::State& state) {
  const PointCloud& c = boundary_points();
  std::size_t out = 0;
  for (auto _ : state) out = perception::voxel_downsample(c, 0.001).size();
  state.counters["points_in"] = static_cast<double>(c.size());
  state.counters["points_out"] = static_cast<double>(out);
}
BENCHMARK(BM_VoxelCentroid)->Unit(benchmark::kMicrosecond);

void BM_VoxelNearestOriginal(benchmark::State& state) {
  const PointCloud& c = boundary_points();
  std::size_t out = 0;
  for (auto _ : state) out = perception::voxel_downsample_nearest(c, 0.001).size();
  state.counters["points_in"] = static_cast<double>(c.size());
  state.counters["points_out"] = static_cast<double>(out);
}
BENCHMARK(BM_VoxelNearestOriginal)->Unit(benchmark::kMicrosecond);

}  // namespace
