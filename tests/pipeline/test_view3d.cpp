// DIR/view3d.html opened as a reviewer opens it: from file://, in Debian's Chromium and
// Firefox ESR, headless (software WebGL). The default scenario runs with its report; the page
// must load without a console error, list every layer with items, and each layer shown alone
// must draw something (not all background).
#include <gtest/gtest.h>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <sstream>
#include <string>

#define STB_IMAGE_IMPLEMENTATION
#include <stb/stb_image.h>

#include "test_util.hpp"

using ftest::shell;
using ftest::slurp;

namespace {

// Headless Chromium as root in a container: no sandbox; WebGL on SwiftShader (no GPU here).
std::string chromium(const std::string& what, const std::string& url, const std::string& err) {
  return "chromium --headless --no-sandbox --disable-gpu --use-angle=swiftshader "
         "--enable-unsafe-swiftshader --hide-scrollbars --window-size=1280,800 "
         "--virtual-time-budget=15000 " + what + " '" + url + "' 2>" + err;
}

// The page's #ft-status JSON from a DOM dump (its text is HTML-escaped).
nlohmann::json page_status(const std::string& dom) {
  const std::string open = "id=\"ft-status\"";
  auto at = dom.find(open);
  if (at == std::string::npos) return {};
  at = dom.find('>', at) + 1;
  std::string text = dom.substr(at, dom.find("</pre>", at) - at);
  for (const auto& [from, to] : {std::pair<std::string, std::string>{"&quot;", "\""},
                                 {"&lt;", "<"}, {"&gt;", ">"}, {"&amp;", "&"}}) {
    for (auto p = text.find(from); p != std::string::npos; p = text.find(from, p + to.size()))
      text.replace(p, from.size(), to);
  }
  return nlohmann::json::parse(text, nullptr, false);
}

// Share of the 3D area's pixels (left of the 270 px panel, above the 44 px timeline) that
// differ from the background colour.
double drawn_fraction(const std::string& png) {
  int w = 0, h = 0, n = 0;
  unsigned char* px = stbi_load(png.c_str(), &w, &h, &n, 3);
  if (!px) return -1;
  std::size_t drawn = 0, all = 0;
  for (int y = 0; y < h - 44; ++y)
    for (int x = 0; x < w - 270; ++x) {
      const unsigned char* p = px + 3 * (static_cast<std::size_t>(y) * w + x);
      ++all;
      drawn += std::abs(p[0] - 0xf4) + std::abs(p[1] - 0xf5) + std::abs(p[2] - 0xf7) > 12;
    }
  stbi_image_free(px);
  return all ? static_cast<double>(drawn) / static_cast<double>(all) : -1;
}

const char* const kLayers[] = {"cad", "scan", "roots", "paths", "toolpath", "residual", "gouges", "robot"};

// Runs the default scenario with its report into `dir`; "" on success, else the log.
std::string run_default(const std::string& dir) {
  const std::string sc = ftest::source_path("scenarios/default.yaml");
  if (shell(std::string(FLASHTWIN_CLI) + " -q run " + sc + " -o " + dir + " >" + dir +
            "/run.log 2>&1") != 0)
    return "flashtwin run failed: " + slurp(dir + "/run.log");
  return std::filesystem::exists(dir + "/view3d.html") ? "" : "no view3d.html in " + dir;
}

// Headless Firefox ESR with software WebGL: Mesa's EGL without a display (the GLX path needs
// an X server), and WebGL allowed on a software renderer (Firefox blocks it there by default).
// Its headless mode dumps no DOM and its screenshots do not show WebGL, so the page logs its
// status (#log) and counts its own drawn pixels (#pixels); console output goes to stdout by
// the profile's preference. --screenshot makes Firefox quit once the page has loaded.
nlohmann::json firefox_status(const std::string& url, const std::string& dir, const std::string& tag) {
  const std::string profile = dir + "/firefox_profile";
  std::filesystem::create_directories(profile);
  std::ofstream(profile + "/user.js") << "user_pref(\"devtools.console.stdout.content\", true);\n"
                                         "user_pref(\"webgl.force-enabled\", true);\n";
  const std::string out = dir + "/firefox_" + tag + ".log";
  shell("MOZ_WEBGL_FORCE_EGL=1 EGL_PLATFORM=surfaceless timeout 120 firefox-esr --headless "
        "--profile " + profile + " --window-size=1280,800 --screenshot " + dir + "/firefox.png '" +
        url + "' >" + out + " 2>&1");
  // The last status line: console.log: "ft-status {...}" with the JSON's quotes escaped.
  std::istringstream log(slurp(out));
  std::string line, last;
  while (std::getline(log, line))
    if (line.find("console.log: \"ft-status ") == 0) last = line;
  if (last.empty()) return {{"log", slurp(out)}};
  std::string text = last.substr(std::string("console.log: \"ft-status ").size());
  if (!text.empty() && text.back() == '"') text.pop_back();
  std::string json;
  for (std::size_t i = 0; i < text.size(); ++i) {
    if (text[i] == '\\' && i + 1 < text.size()) ++i;
    json += text[i];
  }
  return nlohmann::json::parse(json, nullptr, false);
}

}  // namespace

TEST(View3d, EveryLayerOfTheDefaultRunDrawsInHeadlessChromium) {
  const std::string dir = ftest::temp_dir("view3d");
  const std::string failed = run_default(dir);
  ASSERT_EQ(failed, "");
  const std::string page = dir + "/view3d.html";
  const auto bytes = std::filesystem::file_size(page);
  EXPECT_LT(bytes, 15u << 20) << "view3d.html is " << bytes << " bytes";
  // The report carries the same view.
  EXPECT_NE(slurp(dir + "/report.html").find("<iframe class=\"view3d\""), std::string::npos);

  const std::string url = "file://" + page;
  ASSERT_EQ(shell(chromium("--dump-dom", url, dir + "/dom.err") + " >" + dir + "/dom.html"), 0)
      << slurp(dir + "/dom.err");
  const nlohmann::json st = page_status(slurp(dir + "/dom.html"));
  ASSERT_TRUE(st.is_object()) << "no #ft-status in the page's DOM: " << slurp(dir + "/dom.err");
  EXPECT_TRUE(st.value("ready", false)) << st.dump();
  EXPECT_TRUE(st["errors"].empty()) << st["errors"].dump();
  // "Deepest gouge" in one click: the view goes to the deepest gouge voxel and the measuring
  // tool, which finds the distance to the CAD over its triangles in the page, gives its depth
  // as the run computed it (metrics: removal.gouge_voxel_max_mm; float mm, voxel centre; the
  // exact CAD check's gouges where the voxels hold no steel are not drawn).
  const auto metrics = nlohmann::json::parse(slurp(dir + "/metrics.json"));
  ASSERT_EQ(shell(chromium("--dump-dom", url + "#go=gouges", dir + "/go.err") + " >" + dir +
                  "/go.html"), 0);
  const nlohmann::json go = page_status(slurp(dir + "/go.html"));
  ASSERT_TRUE(go.contains("measure")) << go.dump();
  EXPECT_NEAR(go["measure"]["distance_to_cad"].get<double>(),
              metrics["removal.gouge_voxel_max_mm"].get<double>(), 2e-3);
  EXPECT_NE(go["measure"]["what"].get<std::string>().find("gouge"), std::string::npos);
  for (const char* layer : kLayers) {
    SCOPED_TRACE(layer);
    ASSERT_TRUE(st["layers"].contains(layer)) << st.dump();
    EXPECT_GT(st["layers"][layer]["count"].get<int>(), 0);
    const std::string png = dir + "/layer_" + layer + ".png";
    ASSERT_EQ(shell(chromium("--screenshot=" + png, url + "#only=" + layer,
                             dir + "/shot_" + layer + ".err")), 0)
        << slurp(dir + "/shot_" + layer + ".err");
    // Points and lines of a layer cover little of the view; blank would be 0.
    EXPECT_GT(drawn_fraction(png), 0.0005) << png;
  }
}

TEST(View3d, EveryLayerOfTheDefaultRunDrawsInHeadlessFirefox) {
  const std::string dir = ftest::temp_dir("view3d_firefox");
  const std::string failed = run_default(dir);
  ASSERT_EQ(failed, "");
  const std::string url = "file://" + dir + "/view3d.html";
  const nlohmann::json st = firefox_status(url + "#log", dir, "all");
  ASSERT_TRUE(st.contains("ready")) << st.dump();
  EXPECT_TRUE(st["ready"].get<bool>()) << st.dump();
  EXPECT_TRUE(st["errors"].empty()) << st["errors"].dump();
  for (const char* layer : kLayers) {
    SCOPED_TRACE(layer);
    ASSERT_TRUE(st["layers"].contains(layer)) << st.dump();
    EXPECT_GT(st["layers"][layer]["count"].get<int>(), 0);
    const nlohmann::json one = firefox_status(url + "#only=" + layer + "&pixels&log", dir, layer);
    ASSERT_TRUE(one.contains("drawn_fraction")) << one.dump();
    EXPECT_TRUE(one["errors"].empty()) << one["errors"].dump();
    EXPECT_GT(one["drawn_fraction"].get<double>(), 0.0005);
  }
  // A layer that does not exist draws nothing: the pixel count can fail.
  const nlohmann::json none = firefox_status(url + "#only=nothing&pixels&log", dir, "none");
  ASSERT_TRUE(none.contains("drawn_fraction")) << none.dump();
  EXPECT_LT(none["drawn_fraction"].get<double>(), 0.0005);
}
