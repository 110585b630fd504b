#pragma once
// DIR/view3d.html: a self-contained interactive 3D review of a run (three.js vendored into the
// build from the npm registry, the run's data embedded; opens from file:// without a server).
// Layers, each switchable: the casting CAD, the scan coloured by perception's labels, the true
// flash roots, the detected paths, the planned tool path, the residual flash and the gouges
// (coloured by height / depth in mm) and the robot along the executed motion with a timeline.
// Everything is drawn in the casting frame {C}, in millimetres.
#include <cstddef>
#include <string>

#include "flashtwin/pipeline/report.hpp"

namespace flashtwin::pipeline {

/// What goes into the page: point layers are evenly decimated to these counts and stored in a
/// shuffled order; the page draws a prefix of each (its density control; the default keeps it
/// fluid: ≥ 20 frames/s orbiting the default run at 1280×800 in headless Chromium's software
/// renderer, README "3D view").
struct View3dParams {
  std::size_t scan_points = 150000;  ///< scan points stored at most
  std::size_t map_points = 60000;    ///< residual flash / gouge voxels stored at most, each
  std::size_t robot_frames = 1500;   ///< keyframes of the executed motion at most
  /// The page's title after "flashtwin 3D view: "; empty: the scenario's name and seed.
  std::string title;
};

/// The page as one HTML string (write_report writes it to DIR/view3d.html and embeds it).
std::string view3d_html(const ReportInputs& in, const View3dParams& params = {});

}  // namespace flashtwin::pipeline
