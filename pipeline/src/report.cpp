#include "flashtwin/pipeline/report.hpp"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <filesystem>
#include <iomanip>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/plot.hpp"
#include "flashtwin/pipeline/run.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "flashtwin/pipeline/view3d.hpp"
#include "flashtwin/sim/cell.hpp"
#include "flashtwin/sim/process.hpp"
#include "flashtwin/sim/views.hpp"

namespace flashtwin::pipeline {

namespace fs = std::filesystem;

namespace {

std::string html_escape(const std::string& s) {
  std::string o;
  o.reserve(s.size());
  for (char c : s) {
    switch (c) {
      case '&': o += "&amp;"; break;
      case '<': o += "&lt;"; break;
      case '>': o += "&gt;"; break;
      case '"': o += "&quot;"; break;
      default: o += c;
    }
  }
  return o;
}

// One figure of the page: an image (embedded) or the reason it is missing.
struct Figure {
  std::string caption;
  std::string png;    ///< file path, or empty
  std::string error;  ///< why there is no image
};

std::string figure_html(const Figure& f) {
  std::ostringstream os;
  os << "<figure>";
  if (!f.png.empty()) {
    os << "<img src=\"data:image/png;base64," << base64_encode(read_text_file(f.png)) << "\" alt=\""
       << html_escape(f.caption) << "\">";
  } else {
    os << "<div class=\"missing\">not available: " << html_escape(f.error) << "</div>";
  }
  os << "<figcaption>" << html_escape(f.caption) << "</figcaption></figure>\n";
  return os.str();
}

const Rgb kPalette[8] = {{31, 119, 180}, {255, 127, 14}, {44, 160, 44},  {214, 39, 40},
                         {148, 103, 189}, {140, 86, 75}, {227, 119, 194}, {23, 190, 207}};

// Top view (x, y of {C}) of the true roots and the detected paths, in mm.
Image path_plot(const ReportInputs& in) {
  PlotSpec spec;
  spec.title = "Grinding paths, top view of the casting {C}";
  spec.xlabel = "x [mm]";
  spec.ylabel = "y [mm]";
  spec.equal_aspect = true;
  for (std::size_t f = 0; f < in.scan.setup.casting.fins.size(); ++f) {
    const auto& fin = in.scan.setup.casting.fins[f];
    Series s;
    s.color = {170, 170, 170};
    s.size = 5;
    if (f == 0) s.label = "true flash root";
    for (const auto& p : fin.root) {
      s.x.push_back(p.x() * 1e3);
      s.y.push_back(p.y() * 1e3);
    }
    if (fin.closed && !fin.root.empty()) {
      s.x.push_back(fin.root.front().x() * 1e3);
      s.y.push_back(fin.root.front().y() * 1e3);
    }
    spec.series.push_back(std::move(s));
  }
  const auto& paths = in.result.detection.paths;
  for (std::size_t k = 0; k < paths.size(); ++k) {
    Series s;
    s.color = kPalette[k % 8];
    s.size = 2;
    if (k == 0) s.label = "detected paths";
    for (const auto& p : paths[k].points_C) {
      s.x.push_back(p.x() * 1e3);
      s.y.push_back(p.y() * 1e3);
    }
    if (paths[k].closed && !paths[k].points_C.empty()) {
      s.x.push_back(paths[k].points_C.front().x() * 1e3);
      s.y.push_back(paths[k].points_C.front().y() * 1e3);
    }
    spec.series.push_back(std::move(s));
  }
  return render_plot(spec, 900, 700);
}

// Residual flash (truth: voxels left) by height, gouges, over the roots; top view, mm.
Image residual_plot(const ReportInputs& in) {
  const auto& ex = in.execution;
  PlotSpec spec;
  spec.title = "Residual flash and gouges after grinding (top view, {C})";
  spec.xlabel = "x [mm]";
  spec.ylabel = "y [mm]";
  spec.equal_aspect = true;
  Series roots;
  roots.color = {210, 210, 210};
  roots.size = 3;
  roots.label = "flash root (before)";
  for (const auto& fin : in.scan.setup.casting.fins) {
    for (const auto& p : fin.root) {
      roots.x.push_back(p.x() * 1e3);
      roots.y.push_back(p.y() * 1e3);
    }
    roots.x.push_back(NAN);
    roots.y.push_back(NAN);
  }
  spec.series.push_back(std::move(roots));
  // Maps of the material after grinding (ground truth): remaining flash by height above the
  // nominal surface, and the removed body.
  const sim::RemainingFlash remaining = sim::split_remaining_flash(*ex.grid);
  const std::vector<Vec3>& residual = remaining.attached;
  const std::vector<Vec3>& loose = remaining.loose;
  const std::vector<Vec3> gouge = sim::voxel_points(*ex.grid, sim::VoxelLabel::kGouge);
  const double bins[3] = {0.1e-3, 0.2e-3, 1e300};
  const char* labels[3] = {"flash left <= 0.1 mm high", "0.1-0.2 mm", "> 0.2 mm"};
  const Rgb colors[3] = {{240, 200, 40}, {255, 127, 14}, {214, 39, 40}};
  Series bin[3];
  for (int b = 0; b < 3; ++b) {
    bin[b].points = true;
    bin[b].size = 2;
    bin[b].color = colors[b];
    bin[b].label = labels[b];
  }
  const std::size_t stride = std::max<std::size_t>(1, residual.size() / 60000);
  for (std::size_t i = 0; i < residual.size(); i += stride) {
    // Only the bin matters: search no farther than its upper edge.
    const auto cp = ex.grid->nominal().closest(residual[i], bins[1]);
    const int b = cp.triangle < 0 ? 2 : (cp.distance <= bins[0] ? 0 : (cp.distance <= bins[1] ? 1 : 2));
    bin[b].x.push_back(residual[i].x() * 1e3);
    bin[b].y.push_back(residual[i].y() * 1e3);
  }
  for (auto& b : bin) spec.series.push_back(std::move(b));
  if (!loose.empty()) {
    Series l;
    l.points = true;
    l.size = 2;
    l.color = {127, 127, 127};
    l.label = "chip cut loose (falls off)";
    for (const auto& p : loose) {
      l.x.push_back(p.x() * 1e3);
      l.y.push_back(p.y() * 1e3);
    }
    spec.series.push_back(std::move(l));
  }
  Series g;
  g.points = true;
  g.size = 2;
  g.color = {148, 103, 189};
  g.label = "gouge (body removed)";
  const std::size_t gs = std::max<std::size_t>(1, gouge.size() / 30000);
  for (std::size_t i = 0; i < gouge.size(); i += gs) {
    g.x.push_back(gouge[i].x() * 1e3);
    g.y.push_back(gouge[i].y() * 1e3);
  }
  spec.series.push_back(std::move(g));
  if (!ex.rescan_flash_C.empty()) {
    Series r;
    r.points = true;
    r.size = 3;
    r.color = {0, 0, 0};
    r.label = "re-scan: points still called flash";
    for (const auto& p : ex.rescan_flash_C) {
      r.x.push_back(p.x() * 1e3);
      r.y.push_back(p.y() * 1e3);
    }
    spec.series.push_back(std::move(r));
  }
  return render_plot(spec, 900, 700);
}

Image time_plot(const std::string& title, const std::string& ylabel, const std::vector<double>& t,
                const std::vector<std::pair<std::string, const std::vector<double>*>>& lines,
                double scale, double hline) {
  PlotSpec spec;
  spec.title = title;
  spec.xlabel = "simulated time [s]";
  spec.ylabel = ylabel;
  const std::size_t stride = std::max<std::size_t>(1, t.size() / 6000);
  for (std::size_t l = 0; l < lines.size(); ++l) {
    Series s;
    s.label = lines[l].first;
    s.color = kPalette[l % 8];
    for (std::size_t i = 0; i < t.size(); i += stride) {
      s.x.push_back(t[i]);
      s.y.push_back((*lines[l].second)[i] * scale);
    }
    spec.series.push_back(std::move(s));
  }
  if (hline > 0) spec.hlines.push_back({hline, {214, 39, 40}});
  return render_plot(spec, 900, 420);
}

std::string metric_value(const nlohmann::ordered_json& v) {
  if (v.is_number_float()) {
    std::ostringstream os;
    const double x = v.get<double>();
    os.precision(std::abs(x) >= 1000 ? 8 : 4);
    os << x;
    return os.str();
  }
  if (v.is_string()) return v.get<std::string>();
  return v.dump();
}

}  // namespace

std::string base64_encode(const std::string& in) {
  static const char* k = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((in.size() + 2) / 3 * 4);
  std::size_t i = 0;
  for (; i + 2 < in.size(); i += 3) {
    const unsigned v = (static_cast<unsigned char>(in[i]) << 16) |
                       (static_cast<unsigned char>(in[i + 1]) << 8) |
                       static_cast<unsigned char>(in[i + 2]);
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += k[(v >> 6) & 63];
    out += k[v & 63];
  }
  if (i < in.size()) {
    unsigned v = static_cast<unsigned char>(in[i]) << 16;
    if (i + 1 < in.size()) v |= static_cast<unsigned char>(in[i + 1]) << 8;
    out += k[(v >> 18) & 63];
    out += k[(v >> 12) & 63];
    out += i + 1 < in.size() ? k[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

std::string write_report(const std::string& dir, const ReportInputs& in) {
  const fs::path img_dir = fs::path(dir) / "report";
  ensure_directory(img_dir.string());
  const auto& sc = in.scenario;
  const auto& res = in.result;
  const auto& m = res.metrics;
  const auto& ex = in.execution;
  const fs::path cell_dir = fs::path(in.scan.files.mjcf).parent_path();
  std::vector<Figure> renders, plots;

  // Renders: the cell before grinding, the scan coloured by perception's labels, after.
  const auto render = [&](const std::string& mjcf, sim::RenderRequest req, const std::string& prefix,
                          const std::string& what) {
    try {
      const auto files = sim::render_views(mjcf, req, img_dir.string(), prefix);
      for (std::size_t i = 0; i < files.size(); ++i)
        renders.push_back({what + " (" + req.cameras[i] + " camera)", files[i], ""});
    } catch (const std::exception& e) {
      spdlog::warn("report: {} render failed: {}", what, e.what());
      renders.push_back({what, "", e.what()});
    }
  };
  using Clock = std::chrono::steady_clock;
  const auto t_renders = Clock::now();
  sim::RenderRequest req;
  req.cameras = {"overview", "casting_closeup"};
  render(in.scan.files.mjcf, req, "before_", "Before grinding");
  if (res.detection.ran) {
    sim::RenderRequest sreq;
    sreq.cameras = {"casting_closeup"};
    const auto& cloud = in.scan.scan.result.cloud_M;
    const Pose X_WM = in.scan.scan.X_WM_nominal;
    std::vector<std::size_t> idx;
    for (std::size_t i = 0; i < cloud.size(); ++i)
      if (res.detection.labels[i] != 2) idx.push_back(i);
    const double step = std::max(1.0, static_cast<double>(idx.size()) / 8000.0);
    for (double f = 0; f < static_cast<double>(idx.size()); f += step) {
      const std::size_t i = idx[static_cast<std::size_t>(f)];
      sreq.points_W.push_back(X_WM * cloud.points[i].cast<double>());
      sreq.colors.push_back(res.detection.labels[i] == 1 ? Rgb{255, 90, 0} : Rgb{40, 170, 220});
    }
    sreq.point_radius = 0.0005;
    sreq.cubes = true;  // 8000 spheres took ~1.6 s of software rendering
    render(in.scan.files.mjcf, sreq, "scan_",
           "Scan as perception labelled it: flash orange, casting blue");
  }
  if (ex.ran) {
    try {
      const std::string after = sim::write_cell_variant(sc.robot, in.scan.setup.spec,
                                                        in.scan.setup.casting.nominal,
                                                        ex.remaining_flash_C, cell_dir.string(),
                                                        "cell_after");
      render(after, req, "after_", "After grinding");
    } catch (const std::exception& e) {
      renders.push_back({"After grinding", "", e.what()});
    }
  }

  const auto t_plots = Clock::now();
  const auto plot = [&](const std::string& name, const std::string& caption, const Image& img) {
    const std::string p = (img_dir / name).string();
    write_png(p, img);
    plots.push_back({caption, p, ""});
  };
  if (res.detection.ran && !res.detection.paths.empty())
    plot("paths.png", "Detected grinding paths (colours) over the true flash roots (grey)",
         path_plot(in));
  if (!in.plans.empty()) {
    const auto& g = in.plans.front().second;
    const std::string which = "path " + std::to_string(in.plans.front().first);
    plot("joint_positions.png", "Joint angles, " + which,
         planner::plot_joint_trajectory(g.trajectory, planner::JointQuantity::kPosition));
    plot("joint_velocities.png", "Joint velocities, " + which,
         planner::plot_joint_trajectory(g.trajectory, planner::JointQuantity::kVelocity));
    plot("joint_accelerations.png", "Joint accelerations, " + which,
         planner::plot_joint_trajectory(g.trajectory, planner::JointQuantity::kAcceleration));
  }
  if (ex.ran && !ex.t.empty()) {
    plot("force.png", "Grinding forces on the tool over the run (all paths back to back)",
         time_plot("Grinding force", "force [N]", ex.t,
                   {{"normal (incl. contact penalty)", &ex.normal_force},
                    {"tangential", &ex.tangential_force},
                    {"flange F/T sensor |F|", &ex.sensor_force}},
                   1.0, sc.execution.exec.force_control.enabled ? ex.target_force : 0.0));
    plot("tracking.png", "TCP tracking error, executed vs planned",
         time_plot("TCP tracking error", "error [mm]", ex.t, {{"|p_exec - p_plan|", &ex.tracking_error}},
                   1e3, 0));
    plot("residual.png", "Residual flash map (ground truth voxels) and the re-scan's flash points",
         residual_plot(in));
  }

  spdlog::debug("report: renders {:.2f} s, plots {:.2f} s",
                std::chrono::duration<double>(t_plots - t_renders).count(),
                std::chrono::duration<double>(Clock::now() - t_plots).count());
  // The page.
  std::ostringstream h;
  const bool ok = res.exit_code == 0;
  h << "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">\n<title>flashtwin: "
    << html_escape(sc.name) << "</title>\n<style>\n"
    << "body{font-family:sans-serif;max-width:1900px;margin:1em auto;padding:0 1em;color:#222}\n"
    << ".verdict{padding:.6em 1em;border-radius:6px;font-size:1.15em}\n"
    << ".ok{background:#dff5e1;border:1px solid #3a3}.bad{background:#fbe3e3;border:1px solid #c33}\n"
    << "figure{display:inline-block;margin:.5em;vertical-align:top}figure img{max-width:900px;"
       "border:1px solid #ccc}\nfigcaption{font-size:.9em;color:#555;max-width:900px}\n"
    << "table{border-collapse:collapse;font-size:.9em}td,th{border:1px solid #ccc;padding:2px 8px;"
       "text-align:left}td.n{text-align:right;font-family:monospace}\n"
    << ".missing{width:400px;padding:2em;background:#eee}.fail{color:#c33;font-weight:bold}\n"
    << "iframe.view3d{width:100%;height:760px;border:1px solid #ccc}\n"
    << ".summary{display:flex;gap:1em;align-items:flex-start;flex-wrap:wrap}\n"
    << "table.five{font-size:1.2em;margin-top:.6em}table.five td{font-family:monospace;"
       "text-align:right;padding:4px 12px}table.five th{font-weight:normal}\n"
    << "</style></head><body>\n";
  h << "<h1>flashtwin run: " << html_escape(sc.name) << "</h1>\n<p>"
    << html_escape(sc.description) << " &mdash; seed " << sc.seed << ", scenario file <code>"
    << html_escape(sc.file) << "</code></p>\n";
  h << "<p class=\"verdict " << (ok ? "ok" : "bad") << "\"><b>Verdict (exit " << res.exit_code
    << "):</b> " << html_escape(res.verdict) << "</p>\n";
  // One screen: the five numbers that matter and the top view of what is left.
  {
    const auto num = [&](const char* key, double scale, int digits, const char* unit) {
      if (!m.contains(key) || !m[key].is_number()) return std::string("n/a");
      std::ostringstream os;
      os << std::fixed << std::setprecision(digits) << m[key].get<double>() * scale << unit;
      return os.str();
    };
    h << "<div class=\"summary\"><table class=\"five\">"
      << "<tr><th>flash removed</th><td>" << num("removal.flash_removed_fraction", 100, 1, " %")
      << "</td></tr><tr><th>highest residual flash</th><td>"
      << num("removal.residual_flash_max_mm", 1, 2, " mm")
      << "</td></tr><tr><th>deepest gouge</th><td>" << num("removal.gouge_max_mm", 1, 2, " mm")
      << "</td></tr><tr><th>grinding program time<br><small>(the paths; moves between them are "
         "not planned yet)</small></th><td>"
      << num("trajectory.total_time_s", 1, 0, " s") << "</td></tr><tr><th>normal force RMS error"
      << "<br><small>(vs the " << num("force.target_n", 1, 0, " N") << " target)</small></th><td>"
      << num("force.rmse_n", 1, 1, " N") << "</td></tr></table>\n";
    for (auto it = plots.begin(); it != plots.end(); ++it)
      if (it->png.find("residual.png") != std::string::npos) {
        h << figure_html(*it);
        plots.erase(it);
        break;
      }
    h << "</div>\n";
  }
  const auto bad = check_expectations(sc, m);
  if (!sc.expect.empty()) {
    h << "<h2>Expectations</h2>\n<p>" << sc.expect.size() - bad.size() << " of "
      << sc.expect.size() << " bounds of the scenario's <code>expect:</code> block hold.</p>\n";
    if (!bad.empty()) {
      h << "<ul>";
      for (const auto& b : bad) h << "<li class=\"fail\">" << html_escape(b) << "</li>";
      h << "</ul>\n";
    }
  }
  // The interactive 3D view: also DIR/view3d.html; here the same page inside the report.
  const std::string view3d = view3d_html(in);
  write_text_file((fs::path(dir) / "view3d.html").string(), view3d);
  h << "<h2>3D view</h2>\n<p>Turn the part, switch layers, click a point to measure it; "
       "the same view on its own: <code>view3d.html</code>.</p>\n"
    << "<iframe class=\"view3d\" title=\"3D view\" srcdoc=\"" << html_escape(view3d)
    << "\"></iframe>\n";
  h << "<h2>Renders</h2>\n";
  for (const auto& f : renders) h << figure_html(f);
  h << "<h2>Paths, motion, forces, residual</h2>\n";
  for (const auto& f : plots) h << figure_html(f);
  h << "<h2>Metrics</h2>\n<table><tr><th>key</th><th>value</th></tr>\n";
  for (auto it = m.begin(); it != m.end(); ++it)
    h << "<tr><td>" << html_escape(it.key()) << "</td><td class=\"n\">"
      << html_escape(metric_value(it.value())) << "</td></tr>\n";
  h << "</table>\n<p>Files next to this report: <code>metrics.json</code>, <code>scan.ply</code>, "
       "<code>scan_detected_C.ply</code>, <code>paths.json</code>/<code>.ply</code>, "
       "<code>plans.json</code>, <code>trajectory.csv</code>, <code>plan/path_*/</code>, "
       "<code>cell/cell.xml</code> (open with <code>mujoco-simulate</code>), "
       "<code>cell/cell_after.xml</code>.</p>\n</body></html>\n";
  const std::string path = (fs::path(dir) / "report.html").string();
  write_text_file(path, h.str());
  return path;
}

}  // namespace flashtwin::pipeline
