#include "flashtwin/sim/cell.hpp"

#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"

namespace flashtwin::sim {

namespace {

std::string num(double v) { return exact_number(v); }

std::string pose_attrs(const Pose& X) {
  return "pos=\"" + vec3_string(X.translation()) + "\" quat=\"" + quat_wxyz_string(X.linear()) +
         "\"";
}

std::string inertial_xml(const Inertial& in, const Pose& X_body_frame) {
  // The inertial is given in a frame fixed to the body; MJCF wants it in the body frame.
  return "<inertial pos=\"" + vec3_string(X_body_frame * in.com) + "\" quat=\"" +
         quat_wxyz_string(X_body_frame.linear()) + "\" mass=\"" + num(in.mass) +
         "\" diaginertia=\"" + vec3_string(in.inertia) + "\"/>";
}

// Visual capsules along the D-H offsets of a link (d along the joint axis z, then a along x),
// and a motor housing around the joint axis. Visual only: the process model does contact.
std::string link_geoms(const DhRow& row, double radius, const char* material) {
  std::ostringstream os;
  const std::string common = std::string(" contype=\"0\" conaffinity=\"0\" group=\"1\" material=\"") +
                             material + "\"";
  os << "<geom type=\"cylinder\" size=\"" << num(radius * 1.15) << " "
     << num(radius * 1.1) << "\" " << common << "/>";
  if (std::abs(row.d) > 1e-6)
    os << "<geom type=\"capsule\" fromto=\"0 0 0 0 0 " << num(row.d) << "\" size=\""
       << num(radius) << "\"" << common << "/>";
  if (std::abs(row.a) > 1e-6)
    os << "<geom type=\"capsule\" fromto=\"0 0 " << num(row.d) << " " << num(row.a) << " 0 "
       << num(row.d) << "\" size=\"" << num(radius) << "\"" << common << "/>";
  return os.str();
}

}  // namespace

std::string arm_mjcf(const RobotModel& robot, const Pose& X_WB, const CellSpec& spec) {
  std::ostringstream os;
  const double radii[kNumJoints] = {0.08, 0.07, 0.06, 0.05, 0.045, 0.04};
  os << "    <body name=\"base\" " << pose_attrs(X_WB) << ">\n"
     << "      " << inertial_xml(robot.base, Pose::Identity()) << "\n"
     << "      <geom type=\"cylinder\" fromto=\"0 0 " << num(-spec.base_height) << " 0 0 -0.09\" "
     << "size=\"0.11\" material=\"robot\" group=\"1\"/>\n";
  std::string indent = "      ";
  for (int i = 0; i < kNumJoints; ++i) {
    // Body i is D-H frame {i-1} turned by joint i about its z axis; it sits at the constant
    // part of the previous link's transform.
    const Pose X_parent = i == 0 ? Pose::Identity() : dh_constant(robot.dh[i - 1]);
    const JointLimits& L = robot.limits[i];
    os << indent << "<body name=\"link" << i + 1 << "\" " << pose_attrs(X_parent) << ">\n"
       << indent << "  <joint name=\"joint" << i + 1 << "\" type=\"hinge\" axis=\"0 0 1\" "
       << "limited=\"true\" range=\"" << num(L.lower) << " " << num(L.upper) << "\" damping=\""
       << num(spec.damping[i]) << "\" armature=\"0.05\"/>\n"
       << indent << "  " << inertial_xml(robot.links[i], dh_constant(robot.dh[i])) << "\n"
       << indent << "  " << link_geoms(robot.dh[i], radii[i], i % 2 ? "robot" : "robot_dark")
       << "\n";
    indent += "  ";
  }
  const Pose C6 = dh_constant(robot.dh[5]);
  const ToolDescription& tool = robot.tool;
  const double tool_len = tool.X_ET.translation().norm();
  // The tool body sits at the flange {E}; its frame is {E}.
  os << indent << "<site name=\"flange\" " << pose_attrs(C6)
     << " size=\"0.01\" rgba=\"0.9 0.1 0.1 1\" group=\"3\"/>\n"
     << indent << "<body name=\"tool\" " << pose_attrs(C6) << ">\n"
     << indent << "  " << inertial_xml(tool.inertial, Pose::Identity()) << "\n"
     << indent << "  <geom name=\"spindle\" type=\"cylinder\" fromto=\"0 0 0 0 0 "
     << num(std::max(0.0, tool_len - tool.length)) << "\" size=\"0.035\" contype=\"0\" "
     << "conaffinity=\"0\" group=\"1\" material=\"spindle\"/>\n"
     << indent << "  <geom name=\"burr\" type=\"capsule\" fromto=\"" << vec3_string(tool.X_ET * Vec3(0, 0, -tool.length)) << " "
     << vec3_string(tool.X_ET * Vec3(0, 0, -tool.radius)) << "\" size=\"" << num(tool.radius)
     << "\" contype=\"0\" conaffinity=\"0\" group=\"1\" material=\"burr\"/>\n"
     << indent << "  <site name=\"tcp\" " << pose_attrs(tool.X_ET)
     << " size=\"0.006\" rgba=\"0.1 0.9 0.1 1\" group=\"3\"/>\n"
     << indent << "</body>\n";
  for (int i = kNumJoints - 1; i >= 0; --i) {
    indent.resize(indent.size() - 2);
    os << indent << "</body>\n";
  }
  os << "    </body>\n";
  return os.str();
}

std::string cell_mjcf(const RobotModel& robot, const CellSpec& spec, const CastingAssets* casting) {
  const CastingAssets fallback;
  const CastingAssets& ca = casting ? *casting : fallback;
  std::ostringstream os;
  const Vec3 t = spec.X_WTable.translation();
  const Vec3& ts = spec.table_size;
  const Vec3 b = spec.X_WB.translation();
  const double pedestal_top = b.z() - spec.base_height;
  os << "<mujoco model=\"flashtwin_cell\">\n"
     << "  <!-- Generated by flashtwin from robot " << robot.source
     << ". Frames: world {W}; robot base {B} = body base; flange {E} = site flange; tool {T} = "
        "site tcp; casting {C} = body casting. -->\n"
     << "  <compiler angle=\"radian\" autolimits=\"true\"/>\n"
     << "  <option timestep=\"" << num(spec.timestep) << "\" gravity=\"0 0 -9.81\"/>\n"
     << "  <visual><global offwidth=\"1920\" offheight=\"1080\"/>"
     << "<quality shadowsize=\"4096\"/><headlight ambient=\"0.35 0.35 0.35\"/></visual>\n"
     << "  <asset>\n"
     << "    <texture name=\"sky\" type=\"skybox\" builtin=\"gradient\" rgb1=\"0.55 0.65 0.75\" "
        "rgb2=\"0.15 0.17 0.2\" width=\"256\" height=\"256\"/>\n"
     << "    <texture name=\"floor\" type=\"2d\" builtin=\"checker\" rgb1=\"0.55 0.57 0.6\" "
        "rgb2=\"0.45 0.47 0.5\" width=\"512\" height=\"512\"/>\n"
     << "    <material name=\"floor\" texture=\"floor\" texrepeat=\"8 8\" reflectance=\"0.05\"/>\n"
     << "    <material name=\"robot\" rgba=\"0.95 0.55 0.1 1\"/>\n"
     << "    <material name=\"robot_dark\" rgba=\"0.25 0.25 0.28 1\"/>\n"
     << "    <material name=\"spindle\" rgba=\"0.7 0.72 0.75 1\"/>\n"
     << "    <material name=\"burr\" rgba=\"0.85 0.8 0.3 1\"/>\n"
     << "    <material name=\"table\" rgba=\"0.35 0.4 0.45 1\"/>\n"
     << "    <material name=\"casting\" rgba=\"0.42 0.4 0.38 1\"/>\n"
     << "    <material name=\"flash\" rgba=\"0.85 0.35 0.1 1\"/>\n"
     << "    <material name=\"fixture\" rgba=\"0.2 0.45 0.25 1\"/>\n"
     << "    <material name=\"scanner\" rgba=\"0.15 0.3 0.6 1\"/>\n";
  if (casting) {
    os << "    <mesh name=\"casting_nominal\" file=\"" << ca.nominal_stl << "\"/>\n";
    if (!ca.flash_stl.empty())
      os << "    <mesh name=\"casting_flash\" file=\"" << ca.flash_stl << "\"/>\n";
  }
  os << "  </asset>\n"
     << "  <worldbody>\n"
     << "    <light name=\"key\" directional=\"true\" pos=\"1 -1 3\" dir=\"-0.3 0.3 -1\" "
        "diffuse=\"0.6 0.6 0.6\" castshadow=\"true\"/>\n"
     << "    <light name=\"fill\" directional=\"true\" pos=\"-1 1 3\" dir=\"0.3 -0.2 -1\" "
        "diffuse=\"0.3 0.3 0.3\" castshadow=\"false\"/>\n"
     << "    <geom name=\"floor\" type=\"plane\" size=\"3 3 0.1\" material=\"floor\"/>\n"
     << "    <geom name=\"pedestal\" type=\"box\" pos=\"" << num(b.x()) << " " << num(b.y()) << " "
     << num(pedestal_top / 2) << "\" size=\"0.2 0.2 " << num(pedestal_top / 2)
     << "\" material=\"table\"/>\n";
  os << arm_mjcf(robot, spec.X_WB, spec);
  os << "    <body name=\"worktable\" " << pose_attrs(spec.X_WTable) << ">\n"
     << "      <geom name=\"table_top\" type=\"box\" pos=\"0 0 " << num(-ts.z() / 2)
     << "\" size=\"" << num(ts.x() / 2) << " " << num(ts.y() / 2) << " " << num(ts.z() / 2)
     << "\" material=\"table\"/>\n";
  // Four legs down to the floor.
  const double leg_h = t.z() - ts.z();
  for (int sx = -1; sx <= 1; sx += 2)
    for (int sy = -1; sy <= 1; sy += 2)
      os << "      <geom type=\"box\" pos=\"" << num(sx * (ts.x() / 2 - 0.04)) << " "
         << num(sy * (ts.y() / 2 - 0.04)) << " " << num(-ts.z() - leg_h / 2)
         << "\" size=\"0.03 0.03 " << num(leg_h / 2) << "\" material=\"table\"/>\n";
  os << "    </body>\n";
  // The casting: the nominal body and its flashes, visual only (the process model does contact).
  os << "    <body name=\"casting\" " << pose_attrs(spec.X_WC) << ">\n";
  if (casting) {
    os << "      <geom name=\"casting_body\" type=\"mesh\" mesh=\"casting_nominal\" "
          "material=\"casting\" contype=\"0\" conaffinity=\"0\"/>\n";
    if (!ca.flash_stl.empty())
      os << "      <geom name=\"casting_flash\" type=\"mesh\" mesh=\"casting_flash\" "
            "material=\"flash\" contype=\"0\" conaffinity=\"0\"/>\n";
  } else {
    const Vec3 c = 0.5 * (ca.lo + ca.hi), h = 0.5 * (ca.hi - ca.lo);
    os << "      <geom name=\"casting_body\" type=\"box\" pos=\"" << vec3_string(c) << "\" size=\""
       << vec3_string(h) << "\" material=\"casting\"/>\n";
  }
  os << "    </body>\n";
  // Fixture: two locating blocks on the table beside the casting's footprint along its x axis.
  {
    const Pose X_TableW = spec.X_WTable.inverse();
    // Blocks stand flat on the table, turned with the casting's x axis (its yaw only).
    const Vec3 x_T = X_TableW.linear() * spec.X_WC.linear().col(0);
    const double yaw = std::atan2(x_T.y(), x_T.x());
    const Mat3 R_W_fixture =
        spec.X_WTable.linear() * Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
    for (int sx = -1; sx <= 1; sx += 2) {
      const Vec3 p_C(sx > 0 ? ca.hi.x() + 0.02 : ca.lo.x() - 0.02, 0.5 * (ca.lo.y() + ca.hi.y()), 0);
      Vec3 p_T = X_TableW * (spec.X_WC * p_C);
      p_T.z() = 0.0125;
      const Vec3 p_W = spec.X_WTable * p_T;
      os << "    <geom name=\"fixture_" << (sx > 0 ? "right" : "left")
         << "\" type=\"box\" size=\"0.012 0.03 0.0125\" pos=\"" << vec3_string(p_W) << "\" quat=\""
         << quat_wxyz_string(R_W_fixture) << "\" material=\"fixture\" contype=\"0\" "
         << "conaffinity=\"0\"/>\n";
    }
  }
  // The scanner head at its mount {M} (z_M is its viewing direction) and its camera.
  os << "    <body name=\"scanner\" " << pose_attrs(spec.X_WM) << ">\n"
     << "      <geom name=\"scanner_head\" type=\"box\" pos=\"0 0 -0.04\" size=\"0.06 0.09 0.035\" "
        "material=\"scanner\" contype=\"0\" conaffinity=\"0\"/>\n"
     << "      <camera name=\"scanner_view\" quat=\"0 1 0 0\" fovy=\"50\"/>\n"
     << "    </body>\n";
  // Named cameras aimed at the casting (targetbody keeps them aimed when it moves).
  const Vec3 c = spec.X_WC.translation();
  auto camera = [&](const char* name, const Vec3& offset) {
    os << "    <camera name=\"" << name << "\" mode=\"targetbody\" target=\"casting\" pos=\""
       << vec3_string(c + offset) << "\" fovy=\"45\"/>\n";
  };
  camera("overview", Vec3(1.2, -1.4, 1.0));
  camera("front", Vec3(1.1, 0.0, 0.5));
  camera("top", Vec3(0.0, -0.01, 1.2));
  camera("casting_closeup", Vec3(0.16, -0.24, 0.20));
  os << "  </worldbody>\n"
     << "  <actuator>\n";
  for (int i = 0; i < kNumJoints; ++i) {
    const JointLimits& L = robot.limits[i];
    os << "    <position name=\"act" << i + 1 << "\" joint=\"joint" << i + 1 << "\" kp=\""
       << num(spec.kp[i]) << "\" ctrlrange=\"" << num(L.lower) << " " << num(L.upper)
       << "\" forcerange=\"" << num(-L.torque) << " " << num(L.torque) << "\"/>\n";
  }
  os << "  </actuator>\n";
  // Keyframe: the arm parked clear of the table, servos holding it there.
  std::string home;
  for (int i = 0; i < kNumJoints; ++i) home += (i ? " " : "") + num(robot.home[i]);
  os << "  <keyframe><key name=\"home\" qpos=\"" << home << "\" ctrl=\"" << home
     << "\"/></keyframe>\n"
     << "  <sensor>\n"
     << "    <force name=\"flange_force\" site=\"flange\"/>\n"
     << "    <torque name=\"flange_torque\" site=\"flange\"/>\n"
     << "  </sensor>\n"
     << "</mujoco>\n";
  return os.str();
}

ModelSummary check_mjcf(const std::string& path) {
  const MjModelPtr m = load_mjcf_file(path);
  ModelSummary s;
  s.nbody = m->nbody;
  s.njnt = m->njnt;
  s.nu = m->nu;
  s.ngeom = m->ngeom;
  s.nsite = m->nsite;
  s.ncam = m->ncam;
  s.timestep = m->opt.timestep;
  return s;
}

Pose rest_on_table(const CellSpec& spec, const TriangleMesh& nominal, double x, double y,
                   const Mat3& R_TC) {
  double min_z = std::numeric_limits<double>::infinity();
  for (const Vec3& v : nominal.vertices) min_z = std::min(min_z, (R_TC * v).z());
  Pose X_TC = Pose::Identity();
  X_TC.linear() = R_TC;
  X_TC.translation() = Vec3(x, y, -min_z);
  return spec.X_WTable * X_TC;
}

CellFiles write_cell(const RobotModel& robot, const CellSpec& spec, const Casting& casting,
                     const std::string& dir) {
  namespace fs = std::filesystem;
  ensure_directory(dir);
  ensure_directory((fs::path(dir) / "meshes").string());
  ensure_directory((fs::path(dir) / "truth").string());
  CellFiles f;
  f.mjcf = (fs::path(dir) / "cell.xml").string();
  f.urdf = (fs::path(dir) / "robot.urdf").string();
  f.cad = (fs::path(dir) / "casting_cad.stl").string();
  f.truth = (fs::path(dir) / "truth").string();

  CastingAssets assets;
  assets.nominal_stl = "meshes/casting_nominal.stl";
  save_mesh((fs::path(dir) / assets.nominal_stl).string(), casting.nominal);
  const TriangleMesh flash = casting.flash_mesh();
  if (!flash.triangles.empty()) {
    assets.flash_stl = "meshes/casting_flash.stl";
    save_mesh((fs::path(dir) / assets.flash_stl).string(), flash);
  }
  casting.nominal.bounds(assets.lo, assets.hi);
  save_mesh(f.cad, casting.nominal);
  write_ground_truth(casting, spec.X_WC, f.truth);
  write_text_file(f.mjcf, cell_mjcf(robot, spec, &assets));
  write_text_file(f.urdf, robot_urdf(robot));
  f.model = check_mjcf(f.mjcf);
  return f;
}

std::string write_cell_variant(const RobotModel& robot, const CellSpec& spec,
                               const TriangleMesh& nominal, const TriangleMesh& flash_C,
                               const std::string& dir, const std::string& name) {
  namespace fs = std::filesystem;
  CastingAssets assets;
  assets.nominal_stl = "meshes/casting_nominal.stl";
  if (!fs::exists(fs::path(dir) / assets.nominal_stl))
    throw IoError(dir + ": expected a cell written by write_cell (meshes/casting_nominal.stl)");
  if (!flash_C.triangles.empty()) {
    assets.flash_stl = "meshes/" + name + "_flash.stl";
    save_mesh((fs::path(dir) / assets.flash_stl).string(), flash_C);
  }
  nominal.bounds(assets.lo, assets.hi);
  const std::string path = (fs::path(dir) / (name + ".xml")).string();
  write_text_file(path, cell_mjcf(robot, spec, &assets));
  check_mjcf(path);
  return path;
}

void write_ground_truth(const Casting& casting, const Pose& X_WC, const std::string& dir) {
  namespace fs = std::filesystem;
  ensure_directory(dir);
  const TriangleMesh flash = casting.flash_mesh();
  if (!flash.triangles.empty()) save_mesh((fs::path(dir) / "fins.stl").string(), flash);
  std::ostringstream os;
  os.precision(17);
  os << "{\n  \"note\": \"ground truth for scoring only; frames: C = casting, W = world\",\n"
     << "  \"family\": \"" << to_string(casting.family) << "\",\n"
     << "  \"description\": \"" << casting.description << "\",\n"
     << "  \"parting_height_m\": " << casting.parting_height << ",\n"
     << "  \"nominal_volume_m3\": " << casting.nominal.volume() << ",\n"
     << "  \"flash_volume_m3\": " << casting.flash_volume() << ",\n"
     << "  \"X_WC\": [";
  const auto m = to_row_major(X_WC);
  for (int i = 0; i < 16; ++i) os << (i ? ", " : "") << m[i];
  os << "],\n  \"fins\": [";
  for (std::size_t i = 0; i < casting.fins.size(); ++i) {
    const Fin& fin = casting.fins[i];
    os << (i ? "," : "") << "\n    {\"kind\": \"" << fin.kind << "\", \"closed\": "
       << (fin.closed ? "true" : "false") << ", \"volume_m3\": " << fin.volume
       << ", \"thickness_m\": " << fin.thickness << ", \"max_height_m\": " << fin.max_height
       << ", \"root_C\": [";
    for (std::size_t k = 0; k < fin.root.size(); ++k) {
      const Vec3& p = fin.root[k];
      os << (k ? ", " : "") << "[" << p.x() << ", " << p.y() << ", " << p.z() << "]";
    }
    os << "]}";
  }
  os << "\n  ]\n}\n";
  write_text_file((fs::path(dir) / "flash_truth.json").string(), os.str());
}

}  // namespace flashtwin::sim
