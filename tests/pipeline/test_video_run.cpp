// `flashtwin run --video` as a user runs it: the follow camera's MP4 of a whole run, with the
// scenario's video: block (length, size) and the overlay on every frame; a bad video: block is
// refused before anything runs.
#include <gtest/gtest.h>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>
#include <vector>

#include "test_util.hpp"

using ftest::shell;
using ftest::slurp;

TEST(VideoRun, FollowCameraFilmsTheRunWithItsOverlay) {
  const std::string dir = ftest::temp_dir("video_run");
  const std::string sc = ftest::source_path("scenarios/user_mesh.yaml");
  const int code = shell(std::string(FLASHTWIN_CLI) + " -q run " + sc + " -o " + dir +
                         " --no-report --video --set video.length=3 --set video.width=320"
                         " --set video.height=240 --set video.fps=10 >" + dir + "/run.log 2>&1");
  const auto m = nlohmann::json::parse(slurp(dir + "/metrics.json"));
  // The video's time is no quality: the exit code is the part's verdict alone (seed 11's collet
  // touches the bracket's leg, a failed part: README "The whole job").
  EXPECT_EQ(code, m["quality.pass"].get<bool>() ? 0 : 1) << slurp(dir + "/run.log");
  // 3 s at 10 frames/s (the last frame or two may fall after the run's end).
  EXPECT_GE(m["video.frames"].get<int>(), 28);
  EXPECT_LE(m["video.frames"].get<int>(), 32);
  // One decoded frame, raw RGB: 320 x 240, and the overlay's darkened band with white text in
  // the top-left corner (the scene there, floor or part, is neither: RGB sums ~440 for the floor;
  // the band measured ~240 with its text ~760).
  const std::string raw = dir + "/frame.rgb";
  ASSERT_EQ(shell("ffmpeg -loglevel error -y -ss 1 -i " + dir + "/run.mp4 -frames:v 1 -f rawvideo "
                  "-pix_fmt rgb24 " + raw),
            0);
  const std::string px = slurp(raw);
  ASSERT_EQ(px.size(), 320u * 240u * 3u);
  int dark = 0, white = 0;
  for (int y = 0; y < 50; ++y)
    for (int x = 0; x < 100; ++x) {
      const auto* p = reinterpret_cast<const unsigned char*>(px.data()) + 3 * (y * 320 + x);
      const int sum = p[0] + p[1] + p[2];
      dark += sum < 380;
      white += sum > 650;
    }
  EXPECT_GT(dark, 3000) << "no overlay band";
  EXPECT_GT(white, 100) << "no overlay text";
}

TEST(VideoRun, OddVideoSizeIsRefusedNamingTheKey) {
  const std::string dir = ftest::temp_dir("video_bad");
  const std::string sc = ftest::source_path("scenarios/user_mesh.yaml");
  EXPECT_EQ(shell(std::string(FLASHTWIN_CLI) + " -q run " + sc + " -o " + dir +
                  " --no-report --video --set video.width=321 >" + dir + "/out 2>" + dir + "/err"),
            2);
  const std::string err = slurp(dir + "/err");
  EXPECT_NE(err.find("video"), std::string::npos) << err;
  EXPECT_NE(err.find("width"), std::string::npos) << err;
  EXPECT_FALSE(std::filesystem::exists(dir + "/run.mp4"));
}
