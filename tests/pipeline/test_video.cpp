// The video pipe: ffmpeg started from an argument vector, never through a shell.
#include <gtest/gtest.h>

#include <filesystem>
#include <string>
#include <vector>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/subprocess.hpp"
#include "flashtwin/pipeline/video.hpp"
#include "test_util.hpp"

using namespace flashtwin;
namespace fs = std::filesystem;

TEST(Video, OutputPathWithQuotesSpacesAndShellSyntaxIsOneArgument) {
  const std::string dir = ftest::temp_dir("video_quotes");
  pipeline::VideoOptions o;
  o.width = 64;
  o.height = 48;
  o.fps = 10;
  // Under `sh -c '... 'PATH''` this would end the quoting and run `touch`.
  o.path = dir + "/it's a \"cut\"; touch pwned; .mp4";
  PipedProcess ffmpeg(pipeline::ffmpeg_arguments(o));
  const std::vector<unsigned char> frame(3 * o.width * o.height, 128);
  for (int i = 0; i < 10; ++i) ASSERT_TRUE(ffmpeg.write(frame.data(), frame.size()));
  EXPECT_EQ(ffmpeg.finish(), 0);
  EXPECT_TRUE(fs::exists(o.path));
  EXPECT_GT(fs::file_size(o.path), 0u);
  EXPECT_FALSE(fs::exists("pwned"));
  std::size_t files = 0;
  for ([[maybe_unused]] const auto& e : fs::directory_iterator(dir)) ++files;
  EXPECT_EQ(files, 1u);
}

TEST(Video, MissingProgramIsAnIoErrorNamingIt) {
  try {
    PipedProcess p({"flashtwin-no-such-program", "x"});
    FAIL() << "expected IoError";
  } catch (const IoError& e) {
    EXPECT_NE(std::string(e.what()).find("flashtwin-no-such-program"), std::string::npos);
  }
}

TEST(Video, WritingToAChildThatStoppedReadingFailsWithoutSignal) {
  PipedProcess p({"true"});
  const std::vector<char> chunk(1 << 16, 'x');
  bool ok = true;
  // The pipe buffer takes the first writes; once `true` has exited a write must fail (EPIPE)
  // and return false instead of ending the test process with SIGPIPE.
  for (int i = 0; i < 64 && ok; ++i) ok = p.write(chunk.data(), chunk.size());
  EXPECT_FALSE(ok);
  EXPECT_EQ(p.finish(), 0);
  EXPECT_EQ(p.finish(), 0);
}

TEST(Video, ExitStatusOfTheChildIsReported) {
  PipedProcess p({"false"});
  EXPECT_EQ(p.finish(), 1);
}
