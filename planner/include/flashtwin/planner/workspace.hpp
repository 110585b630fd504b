#pragma once
// Monte Carlo workspace: random joint samples within limits → reachable points.
#include <cstdint>
#include <vector>

#include "flashtwin/core/plot.hpp"
#include "flashtwin/core/robot.hpp"

namespace flashtwin::planner {

struct WorkspaceParams {
  int samples = 100000;     ///< joint-space samples, uniform within the position limits
  std::uint64_t seed = 1;   ///< random seed (same seed → same points)
  bool tool_point = false;  ///< sample the TCP {T} instead of the flange {E}
};

struct WorkspaceResult {
  std::vector<Vec3> points;          ///< reachable points in {B} [m]
  double max_reach = 0;              ///< max distance from the base origin (shoulder) [m]
  double max_horizontal_reach = 0;   ///< max distance from the axis of joint 1 [m]
  Vec3 min = Vec3::Zero(), max = Vec3::Zero();  ///< axis-aligned bounds [m]
};

/// @throws ArgumentError when samples < 1.
WorkspaceResult sample_workspace(const RobotModel& robot, const WorkspaceParams& params);

/// Top (x-y) and side (horizontal radius-z) scatter views, one image.
Image plot_workspace(const WorkspaceResult& ws, const std::string& title);

}  // namespace flashtwin::planner
