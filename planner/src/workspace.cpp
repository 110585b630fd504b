#include "flashtwin/planner/workspace.hpp"

#include <algorithm>
#include <cmath>
#include <cstdio>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/random.hpp"
#include "flashtwin/planner/kinematics.hpp"

namespace flashtwin::planner {

WorkspaceResult sample_workspace(const RobotModel& robot, const WorkspaceParams& params) {
  if (params.samples < 1)
    throw ArgumentError("samples: expected a positive count, got " +
                        std::to_string(params.samples));
  WorkspaceResult ws;
  ws.points.reserve(params.samples);
  Rng rng(params.seed);
  ws.min = Vec3::Constant(1e300);
  ws.max = Vec3::Constant(-1e300);
  for (int s = 0; s < params.samples; ++s) {
    Vector6 q;
    for (int i = 0; i < kNumJoints; ++i)
      q[i] = rng.uniform(robot.limits[i].lower, robot.limits[i].upper);
    const Pose X = params.tool_point ? fk_tool(robot, q) : fk_flange(robot, q);
    const Vec3 p = X.translation();
    ws.points.push_back(p);
    ws.max_reach = std::max(ws.max_reach, p.norm());
    ws.max_horizontal_reach = std::max(ws.max_horizontal_reach, std::hypot(p.x(), p.y()));
    ws.min = ws.min.cwiseMin(p);
    ws.max = ws.max.cwiseMax(p);
  }
  return ws;
}

Image plot_workspace(const WorkspaceResult& ws, const std::string& title) {
  PlotSpec top, side;
  Series st, ss;
  st.points = ss.points = true;
  st.size = ss.size = 1;
  st.alpha = ss.alpha = 0.15;
  for (const Vec3& p : ws.points) {
    st.x.push_back(p.x());
    st.y.push_back(p.y());
    ss.x.push_back(std::hypot(p.x(), p.y()));
    ss.y.push_back(p.z());
  }
  // The circle of the measured reach, for reading the plot.
  Series circle_t, circle_s;
  circle_t.color = circle_s.color = Rgb{214, 39, 40};
  circle_t.label = circle_s.label = "max reach";
  for (int k = 0; k <= 360; ++k) {
    const double a = k * M_PI / 180;
    circle_t.x.push_back(ws.max_reach * std::cos(a));
    circle_t.y.push_back(ws.max_reach * std::sin(a));
    if (k <= 180) {
      circle_s.x.push_back(ws.max_reach * std::sin(a));
      circle_s.y.push_back(ws.max_reach * std::cos(a));
    }
  }
  char buf[160];
  std::snprintf(buf, sizeof buf, "%s: top view (max reach %.3f m)", title.c_str(), ws.max_reach);
  top.title = buf;
  top.xlabel = "x [m]";
  top.ylabel = "y [m]";
  top.equal_aspect = true;
  top.series = {st, circle_t};
  std::snprintf(buf, sizeof buf, "side view (%zu samples)", ws.points.size());
  side.title = buf;
  side.xlabel = "distance from axis 1 [m]";
  side.ylabel = "z [m]";
  side.equal_aspect = true;
  side.series = {ss, circle_s};
  return render_grid({top, side}, 2, 700, 640);
}

}  // namespace flashtwin::planner
