// Video frames of `flashtwin run --video` on the default scenario: rendering (OSMesa, the
// video's default 800×600 close-up with the remaining flash drawn from the voxel grid) and H.264
// encoding by ffmpeg, per frame. Goal: ≥ 15 frames/s.
#include <benchmark/benchmark.h>

#include <filesystem>
#include <string>

#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/pipeline/video.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"
#include "flashtwin/sim/process.hpp"

using namespace flashtwin;

namespace {

void BM_VideoFrames(benchmark::State& state) {
  const auto sc =
      pipeline::load_scenario(std::string(FLASHTWIN_SOURCE_DIR) + "/scenarios/default.yaml");
  const auto tmp = std::filesystem::temp_directory_path() / "flashtwin_bench_video";
  const auto scan = pipeline::scan_scenario(sc, tmp.string(), 2);
  const sim::MjModelPtr model = sim::load_mjcf_file(scan.files.mjcf);
  const sim::MjDataPtr data = sim::make_data(model.get());
  mj_forward(model.get(), data.get());
  const sim::MaterialGrid grid = sim::make_material_grid(scan.setup.casting);
  pipeline::VideoOptions vo;
  vo.path = (tmp / "bench.mp4").string();
  const int frames = 60;
  for (auto _ : state) {
    // One recorder per iteration: `frames` frames, one every simulated frame interval.
    pipeline::VideoRecorder rec(vo, vo.length);
    const double dt = rec.speedup() / vo.fps;
    for (int k = 0; k < frames; ++k) rec.on_step(model.get(), data.get(), k * dt, grid);
    benchmark::DoNotOptimize(rec.finish());
  }
  state.counters["frames_per_s"] = benchmark::Counter(static_cast<double>(frames) *
                                                          static_cast<double>(state.iterations()),
                                                      benchmark::Counter::kIsRate);
}
BENCHMARK(BM_VideoFrames)->Unit(benchmark::kSecond)->Iterations(1)->Repetitions(2)->UseRealTime();

}  // namespace
