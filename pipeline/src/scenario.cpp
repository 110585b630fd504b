#include "flashtwin/pipeline/scenario.hpp"

#include "flashtwin/core/config.hpp"
#include "flashtwin/core/errors.hpp"

namespace flashtwin::pipeline {

Scenario load_scenario(const std::string& path) {
  const ConfigNode root = ConfigNode::load_file(path);
  Scenario sc;
  sc.file = path;
  sc.name = root.get_string("name");
  sc.description = root.get_string("description", "");
  sc.seed = static_cast<std::uint64_t>(root.get_int("seed", 0, (1LL << 62), 1));

  const ConfigNode robot = root.at("robot");
  const std::string robot_file = resolve_relative(path, robot.as_string());
  try {
    sc.robot = load_robot(robot_file);
  } catch (const IoError&) {
    robot.fail("expected a robot description file, got '" + robot.as_string() +
               "' (resolved to " + robot_file + ", not found)");
  }

  sim::CellSpec& cell = sc.cell;
  if (root.has("cell")) {
    const ConfigNode c = root.at("cell");
    cell.X_WB = c.get_pose("robot_base", cell.X_WB);
    cell.base_height = c.get_double("base_height", 0.0, 3.0, cell.base_height);
    if (cell.X_WB.translation().z() < cell.base_height)
      c.fail("expected the robot base at least base_height (" +
             std::to_string(cell.base_height) + " m) above the floor");
    if (c.has("table")) {
      const ConfigNode t = c.at("table");
      cell.X_WTable = t.get_pose("pose", cell.X_WTable);
      if (t.has("size")) {
        cell.table_size = t.get_vec3("size");
        if (cell.table_size.minCoeff() <= 0)
          t.at("size").fail("expected three positive extents [m]");
      }
      if (cell.X_WTable.translation().z() <= cell.table_size.z())
        t.fail("expected the table top above the floor by more than its thickness");
    }
    cell.timestep = c.get_double("timestep", 1e-5, 0.001, cell.timestep);
  }

  const ConfigNode casting = root.at("casting");
  if (casting.has("placeholder")) {
    const ConfigNode p = casting.at("placeholder");
    cell.casting_size = p.get_vec3("size");
    if (cell.casting_size.minCoeff() <= 0)
      p.at("size").fail("expected three positive extents [m]");
  } else {
    casting.fail("expected a casting description (for now: placeholder: {size: [x, y, z]})");
  }
  // The casting pose is given on the table: relative to the table top centre.
  const Pose X_TableC = casting.get_pose("pose", Pose::Identity());
  cell.X_WC = cell.X_WTable * X_TableC;

  root.check_all_used();
  return sc;
}

}  // namespace flashtwin::pipeline
