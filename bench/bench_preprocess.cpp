// Voxel-grid downsampling: the plain centroid version against the thesis's improved version
// (§3.4: keep the original point nearest each voxel's centroid), on boundary-like points.
#include <benchmark/benchmark.h>

#include <algorithm>
#include <cmath>

#include "flashtwin/core/random.hpp"
#include "flashtwin/perception/preprocess.hpp"
#include "flashtwin/sim/casting.hpp"

using namespace flashtwin;

namespace {

// ~2,600 points along flash roots of the default-family casting (the thesis's boundary point
// count) with isotropic noise `sigma`, and the true root polylines for the reconstruction error.
struct Boundary {
  PointCloud cloud;
  std::vector<std::vector<Vec3>> roots;
};

Boundary make_boundary(double sigma) {
  sim::CastingParams p;
  p.flash.root_spacing = 0.0002;
  const sim::Casting c = sim::make_casting(p);
  Boundary b;
  Rng rng(3);
  for (const auto& fin : c.fins) {
    if (b.cloud.size() >= 2600) break;
    b.roots.push_back(fin.root);
    if (fin.closed) b.roots.back().push_back(fin.root.front());
    for (const auto& q : fin.root) {
      if (b.cloud.size() >= 2600) break;
      b.cloud.points.push_back((q + Vec3(rng.normal(), rng.normal(), rng.normal()) * sigma).cast<float>());
    }
  }
  return b;
}

const Boundary& boundary(int sigma_um) {
  static const Boundary b30 = make_boundary(30e-6);
  static const Boundary b100 = make_boundary(100e-6);
  return sigma_um <= 30 ? b30 : b100;
}

// Reconstruction error: distance of every kept point to the true root polylines.
void reconstruction(const PointCloud& kept, const Boundary& b, benchmark::State& state) {
  double s2 = 0, mx = 0;
  for (const auto& pf : kept.points) {
    const Vec3 p = pf.cast<double>();
    double best = 1e9;
    for (const auto& r : b.roots)
      for (std::size_t i = 1; i < r.size(); ++i) {
        const Vec3 d = r[i] - r[i - 1];
        const double t = std::clamp((p - r[i - 1]).dot(d) / std::max(d.squaredNorm(), 1e-30), 0.0, 1.0);
        best = std::min(best, (r[i - 1] + t * d - p).norm());
      }
    s2 += best * best;
    mx = std::max(mx, best);
  }
  state.counters["points_in"] = static_cast<double>(b.cloud.size());
  state.counters["points_out"] = static_cast<double>(kept.size());
  state.counters["rmse_um"] = kept.empty() ? 0 : std::sqrt(s2 / kept.size()) * 1e6;
  state.counters["max_um"] = mx * 1e6;
}

// Args: voxel size [µm], noise sigma [µm]; `grid` is the downsampler under test.
void BM_Voxel(benchmark::State& state, PointCloud (*grid)(const PointCloud&, double)) {
  const Boundary& b = boundary(static_cast<int>(state.range(1)));
  const double voxel = state.range(0) * 1e-6;
  PointCloud out;
  for (auto _ : state) out = grid(b.cloud, voxel);
  reconstruction(out, b, state);
}
BENCHMARK_CAPTURE(BM_Voxel, centroid, &perception::voxel_downsample)
    ->Args({1000, 30})->Args({400, 30})->Args({1000, 100})->Args({400, 100})
    ->Unit(benchmark::kMicrosecond);
BENCHMARK_CAPTURE(BM_Voxel, nearest_original, &perception::voxel_downsample_nearest)
    ->Args({1000, 30})->Args({400, 30})->Args({1000, 100})->Args({400, 100})
    ->Unit(benchmark::kMicrosecond);

}  // namespace
