#include "flashtwin/core/robot.hpp"

#include <urdf_parser/urdf_parser.h>

#include <cmath>
#include <cstdio>
#include <sstream>

#include "flashtwin/core/config.hpp"
#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"

namespace flashtwin {

Vector6 RobotModel::lower() const {
  Vector6 v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits[i].lower;
  return v;
}

Vector6 RobotModel::upper() const {
  Vector6 v;
  for (int i = 0; i < kNumJoints; ++i) v[i] = limits[i].upper;
  return v;
}

bool RobotModel::within_limits(const Vector6& q, double tol) const {
  for (int i = 0; i < kNumJoints; ++i)
    if (!limits[i].contains(q[i], tol)) return false;
  return true;
}

Pose dh_constant(const DhRow& row) {
  Pose X = Pose::Identity();
  X.translation() = Vec3(row.a, 0.0, row.d);
  X.linear() = Eigen::AngleAxisd(row.alpha, Vec3::UnitX()).toRotationMatrix();
  return X;
}

namespace {

bool near_exact(double v, double t) { return std::abs(v - t) < 1e-12; }

}  // namespace

ArmGeometry arm_geometry(const RobotModel& r) {
  const double h = M_PI / 2;
  const auto& dh = r.dh;
  const auto alphas = [&](double a1, double a2, double a3) {
    return near_exact(dh[0].alpha, a1) && near_exact(dh[1].alpha, 0) &&
           near_exact(dh[2].alpha, a2) && near_exact(dh[3].alpha, a3) &&
           near_exact(dh[4].alpha, -h) && near_exact(dh[5].alpha, 0);
  };
  // Both types: no common-normal length after joint 4 (a4 = a5 = a6 = 0), an upper arm a2.
  const bool wrist_a = near_exact(dh[3].a, 0) && near_exact(dh[4].a, 0) &&
                       near_exact(dh[5].a, 0) && std::abs(dh[1].a) > 1e-9;
  if (alphas(-h, -h, h) && wrist_a && near_exact(dh[4].d, 0) && std::hypot(dh[2].a, dh[3].d) > 1e-9)
    return ArmGeometry::kSphericalWrist;
  const bool offset_wrist = alphas(h, 0, h) && wrist_a && std::abs(dh[2].a) > 1e-9;
  return offset_wrist ? ArmGeometry::kOffsetWrist : ArmGeometry::kUnsupported;
}

namespace {

Inertial parse_inertial(const ConfigNode& n) {
  Inertial in;
  in.mass = n.get_double("mass", 1e-6, 1e4);
  in.com = n.get_vec3("com", Vec3::Zero());
  const ConfigNode inertia = n.at("inertia");
  in.inertia = inertia.as_vec3();
  const Vec3& I = in.inertia;
  if (I.minCoeff() <= 0) inertia.fail("expected three positive principal moments [kg m^2]");
  // Principal moments of a real body satisfy the triangle inequality.
  if (I.x() + I.y() < I.z() * (1 - 1e-9) || I.y() + I.z() < I.x() * (1 - 1e-9) ||
      I.x() + I.z() < I.y() * (1 - 1e-9))
    inertia.fail("expected moments satisfying the triangle inequality (Ixx+Iyy >= Izz, ...)");
  return in;
}

}  // namespace

RobotModel parse_robot(const std::string& yaml_text, const std::string& name) {
  const ConfigNode root = ConfigNode::load_string(yaml_text, name);
  RobotModel r;
  r.source = name;
  r.name = root.get_string("name");
  if (root.has("description")) root.at("description").as_string();

  const ConfigNode dh = root.at("dh");
  if (!dh.is_sequence() || dh.size() != kNumJoints)
    dh.fail("expected a list of 6 D-H rows {alpha, a, d}, got " +
            (dh.is_sequence() ? std::to_string(dh.size()) + " rows" : std::string("no list")));
  const ConfigNode joints = root.at("joints");
  if (!joints.is_sequence() || joints.size() != kNumJoints)
    joints.fail("expected a list of 6 joints, got " +
                (joints.is_sequence() ? std::to_string(joints.size()) : std::string("no list")));
  const ConfigNode links = root.at("links");
  if (!links.is_sequence() || links.size() != kNumJoints)
    links.fail("expected a list of 6 link inertials, got " +
               (links.is_sequence() ? std::to_string(links.size()) : std::string("no list")));

  for (int i = 0; i < kNumJoints; ++i) {
    const ConfigNode row = dh[i];
    r.dh[i].alpha = row.get_double("alpha", -2 * M_PI, 2 * M_PI);
    r.dh[i].a = row.get_double("a", -10, 10);
    r.dh[i].d = row.get_double("d", -10, 10);

    const ConfigNode j = joints[i];
    const std::string expected = "joint" + std::to_string(i + 1);
    const std::string jname = j.get_string("name", expected);
    if (jname != expected) j.at("name").fail("expected '" + expected + "', got '" + jname + "'");
    JointLimits& L = r.limits[i];
    L.lower = j.get_double("lower", -4 * M_PI, 4 * M_PI);
    L.upper = j.get_double("upper", -4 * M_PI, 4 * M_PI);
    if (L.lower >= L.upper)
      j.at("upper").fail("expected upper > lower (" + std::to_string(L.lower) + "), got " +
                         std::to_string(L.upper));
    L.velocity = j.get_double("velocity", 1e-6, 1e3);
    L.acceleration = j.get_double("acceleration", 1e-6, 1e5);
    L.torque = j.get_double("torque", 1e-6, 1e6);

    r.links[i] = parse_inertial(links[i]);
  }
  r.base = parse_inertial(root.at("base"));

  const ConfigNode tool = root.at("tool");
  r.tool.name = tool.get_string("name", "tool");
  r.tool.X_ET = tool.get_pose("X_ET", Pose::Identity());
  r.tool.inertial = parse_inertial(tool.at("inertial"));
  r.tool.radius = tool.get_double("radius", 1e-4, 0.5, r.tool.radius);
  r.tool.length = tool.get_double("length", 1e-4, 0.5, r.tool.length);
  r.tool.shank_radius = tool.get_double("shank_radius", 1e-4, 0.05, r.tool.shank_radius);
  r.tool.shank_length = tool.get_double("shank_length", 0.0, 0.3, r.tool.shank_length);
  r.tool.collet_radius = tool.get_double("collet_radius", 1e-4, 0.1, r.tool.collet_radius);
  r.tool.collet_length = tool.get_double("collet_length", 0.0, 0.3, r.tool.collet_length);
  r.tool.rack_collet_radius = tool.get_double("rack_collet_radius", 1e-4, 0.1, r.tool.rack_collet_radius);
  if (r.tool.length + r.tool.shank_length + r.tool.collet_length > r.tool.X_ET.translation().norm())
    tool.fail("expected length + shank_length + collet_length within the tool's reach |X_ET| = " +
              std::to_string(r.tool.X_ET.translation().norm()) + " m");

  if (root.has("home")) {
    const ConfigNode home = root.at("home");
    const auto v = home.as_doubles(kNumJoints);
    for (int i = 0; i < kNumJoints; ++i) r.home[i] = v[i];
    if (!r.within_limits(r.home)) home.fail("expected a configuration within the joint limits");
  }

  if (root.has("controller")) {
    const ConfigNode c = root.at("controller");
    r.controller.language = c.get_string("language", r.controller.language);
    if (r.controller.language != "krl" && r.controller.language != "rapid" &&
        r.controller.language != "urscript" && r.controller.language != "none")
      c.at("language").fail("expected krl, rapid, urscript or none, got '" +
                            r.controller.language + "'");
    if (c.has("sign")) {
      const auto v = c.at("sign").as_doubles(kNumJoints);
      for (int i = 0; i < kNumJoints; ++i) {
        if (v[i] != 1.0 && v[i] != -1.0)
          c.at("sign").fail("expected six signs, each 1 or -1, got " + std::to_string(v[i]));
        r.controller.sign[i] = v[i];
      }
    }
    if (c.has("offset")) {
      const auto v = c.at("offset").as_doubles(kNumJoints);
      for (int i = 0; i < kNumJoints; ++i) {
        if (!(std::abs(v[i]) <= 2 * M_PI))
          c.at("offset").fail("expected six offsets within [-2pi, 2pi] [rad]");
        r.controller.offset[i] = v[i];
      }
    }
  }

  if (root.has("servo")) {
    const ConfigNode sv = root.at("servo");
    const auto kp = sv.at("kp").as_doubles(kNumJoints);
    const auto damping = sv.at("damping").as_doubles(kNumJoints);
    for (int i = 0; i < kNumJoints; ++i) {
      if (!(kp[i] > 0 && kp[i] <= 1e7)) sv.at("kp").fail("expected six stiffnesses in (0, 1e7] N m/rad");
      if (!(damping[i] >= 0 && damping[i] <= 1e5))
        sv.at("damping").fail("expected six dampings in [0, 1e5] N m s/rad");
      r.servo_kp[i] = kp[i];
      r.servo_damping[i] = damping[i];
    }
  }

  root.check_all_used();
  return r;
}

RobotModel load_robot(const std::string& path) {
  const bool urdf = path.size() > 5 && path.compare(path.size() - 5, 5, ".urdf") == 0;
  const std::string text = read_text_file(path);
  return urdf ? robot_from_urdf(text, path) : parse_robot(text, path);
}

namespace {

std::string num(double v) { return exact_number(v); }

std::string origin_xml(const Pose& X) {
  const Vec3 t = X.translation();
  const Vec3 rpy = rpy_from_rotation(X.linear());
  return "<origin xyz=\"" + num(t.x()) + " " + num(t.y()) + " " + num(t.z()) + "\" rpy=\"" +
         num(rpy.x()) + " " + num(rpy.y()) + " " + num(rpy.z()) + "\"/>";
}

std::string inertial_xml(const Inertial& in, const Pose& X_frame_body) {
  Pose X = X_frame_body;
  X.translation() = X_frame_body * in.com;
  std::ostringstream os;
  os << "    <inertial>" << origin_xml(X) << "<mass value=\"" << num(in.mass) << "\"/>"
     << "<inertia ixx=\"" << num(in.inertia.x()) << "\" ixy=\"0\" ixz=\"0\" iyy=\""
     << num(in.inertia.y()) << "\" iyz=\"0\" izz=\"" << num(in.inertia.z()) << "\"/>"
     << "</inertial>\n";
  return os.str();
}

// Cylinder visuals along the D-H offsets: d along z, then a along x (link frame F_i').
std::string link_visual_xml(const DhRow& row, double radius) {
  std::ostringstream os;
  const double eps = 1e-6;
  if (std::abs(row.d) > eps) {
    Pose X = Pose::Identity();
    X.translation() = Vec3(0, 0, row.d / 2);
    os << "    <visual>" << origin_xml(X) << "<geometry><cylinder radius=\"" << num(radius)
       << "\" length=\"" << num(std::abs(row.d)) << "\"/></geometry></visual>\n";
  }
  if (std::abs(row.a) > eps) {
    const Pose X = pose_from_xyz_rpy(Vec3(row.a / 2, 0, row.d), Vec3(0, M_PI / 2, 0));
    os << "    <visual>" << origin_xml(X) << "<geometry><cylinder radius=\"" << num(radius)
       << "\" length=\"" << num(std::abs(row.a)) << "\"/></geometry></visual>\n";
  }
  os << "    <visual><origin xyz=\"0 0 0\" rpy=\"0 0 0\"/><geometry><sphere radius=\""
     << num(radius * 1.2) << "\"/></geometry></visual>\n";
  return os.str();
}

}  // namespace

std::string robot_urdf(const RobotModel& robot) {
  std::ostringstream os;
  os << "<?xml version=\"1.0\"?>\n"
     << "<!-- Generated by flashtwin from " << robot.source
     << ". Joint zero equals the standard D-H theta zero. -->\n"
     << "<robot name=\"" << robot.name << "\">\n";
  os << "  <link name=\"base_link\">\n" << inertial_xml(robot.base, Pose::Identity())
     << "  </link>\n";
  const auto& radii = kLinkDrawRadii;
  for (int i = 0; i < kNumJoints; ++i) {
    const std::string link = "link" + std::to_string(i + 1);
    const std::string parent = i == 0 ? "base_link" : "link" + std::to_string(i);
    const Pose X_parent = i == 0 ? Pose::Identity() : dh_constant(robot.dh[i - 1]);
    const JointLimits& L = robot.limits[i];
    // Link i's inertial is given in D-H frame {i} = F_i' * C_i, with F_i' the joint frame.
    os << "  <link name=\"" << link << "\">\n"
       << inertial_xml(robot.links[i], dh_constant(robot.dh[i]))
       << link_visual_xml(robot.dh[i], radii[i]) << "  </link>\n";
    os << "  <joint name=\"joint" << i + 1 << "\" type=\"revolute\">\n"
       << "    <parent link=\"" << parent << "\"/><child link=\"" << link << "\"/>\n"
       << "    " << origin_xml(X_parent) << "<axis xyz=\"0 0 1\"/>\n"
       << "    <limit lower=\"" << num(L.lower) << "\" upper=\"" << num(L.upper)
       << "\" velocity=\"" << num(L.velocity) << "\" effort=\"" << num(L.torque) << "\"/>\n"
       << "  </joint>\n";
  }
  os << "  <link name=\"flange\">\n" << inertial_xml(robot.tool.inertial, Pose::Identity())
     << "  </link>\n"
     << "  <joint name=\"flange_joint\" type=\"fixed\"><parent link=\"link6\"/>"
     << "<child link=\"flange\"/>" << origin_xml(dh_constant(robot.dh[5])) << "</joint>\n"
     << "  <link name=\"tcp\"/>\n"
     << "  <joint name=\"tool_joint\" type=\"fixed\"><parent link=\"flange\"/>"
     << "<child link=\"tcp\"/>" << origin_xml(robot.tool.X_ET) << "</joint>\n"
     << "</robot>\n";
  const std::string xml = os.str();
  // The output must be readable by urdfdom (what ROS/MoveIt use); anything else is our bug.
  FT_ASSERT(urdf::parseURDF(xml) != nullptr);
  return xml;
}

}  // namespace flashtwin
