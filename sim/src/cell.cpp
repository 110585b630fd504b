#include "flashtwin/sim/cell.hpp"

#include <algorithm>
#include <array>
#include <cctype>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <limits>
#include <map>
#include <sstream>

#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/io.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/mesh_query.hpp"
#include "flashtwin/sim/mujoco_handles.hpp"

namespace flashtwin::sim {

namespace {

// Robot base and scanner head as cell_mjcf draws them (check_cell_layout tests the same boxes).
constexpr double kPedestalHalfWidth = 0.2;   // [m] square pedestal from the floor up
constexpr double kBaseHousingRadius = 0.11;  // [m] cylinder about z_B from base_height below {B}
constexpr double kBaseHousingTop = 0.09;     // [m] ... up to this far below {B}
constexpr double kSpindleRadius = 0.035;      // [m] the spindle body's cylinder
const Vec3 kScannerHeadCentre_M(0.0, 0.0, -0.04);  // [m] box centre in {M}
const Vec3 kScannerHeadHalfSize(0.06, 0.09, 0.035);
// Fixture blocks: half extents and the clearance to the casting they are laid out with.
const Vec3 kFixtureHalfSize(0.012, 0.03, 0.0125);
// The gap leaves the flash and the burr grinding it clear, as a fixture designer would (blocks
// locate on datum faces, never on flash): fins stand up to 8 mm out of the parting line (the
// generator's bound), the burr beside a fin's tip takes up to its 12 mm diameter (the robot
// file's burr), 2 mm to spare.
constexpr double kFixtureGap = 0.022;     // [m] clear of the casting
constexpr double kFixtureOffset = kFixtureGap + 0.012;  // [m] centre outside the bounds: + half width

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

// The fixture blocks' axes {F} in {W}: the table's, turned with the casting's x axis (its yaw
// about the table normal only).
Mat3 fixture_axes_W(const CellSpec& spec) {
  const Vec3 x_T = spec.X_WTable.inverse().linear() * spec.X_WC.linear().col(0);
  const double yaw = std::atan2(x_T.y(), x_T.x());
  return spec.X_WTable.linear() * Eigen::AngleAxisd(yaw, Vec3::UnitZ()).toRotationMatrix();
}

// The locating blocks beside the casting's bounds [lo, hi] in {C}: standing flat on the table
// top, turned with the casting's x axis, centred on its y extent, kFixtureGap outside its x
// extent; tall enough to reach kFixtureHalfSize's height up the casting standing on a riser.
std::vector<FixtureBlock> fixture_blocks_from_bounds(const CellSpec& spec, const Vec3& lo,
                                                     const Vec3& hi) {
  const Pose X_TableW = spec.X_WTable.inverse();
  const Mat3 R_WF = fixture_axes_W(spec);
  const double half_z = kFixtureHalfSize.z() + 0.5 * spec.riser_height;
  std::vector<FixtureBlock> blocks;
  for (int sx = -1; sx <= 1; sx += 2) {
    const Vec3 p_C(sx > 0 ? hi.x() + kFixtureOffset : lo.x() - kFixtureOffset,
                   0.5 * (lo.y() + hi.y()), 0);
    Vec3 p_T = X_TableW * (spec.X_WC * p_C);
    p_T.z() = half_z;
    FixtureBlock b;
    b.name = sx > 0 ? "fixture_right" : "fixture_left";
    b.X_WF.linear() = R_WF;
    b.X_WF.translation() = spec.X_WTable * p_T;
    b.half_size = Vec3(kFixtureHalfSize.x(), kFixtureHalfSize.y(), half_z);
    blocks.push_back(b);
  }
  return blocks;
}

// Does the segment [a, b] meet the rectangle [lo, hi]? (Liang–Barsky: clip the segment's
// parameter range to each slab; touching counts.)
bool segment_meets_rect(const Eigen::Vector2d& a, const Eigen::Vector2d& b,
                        const Eigen::Vector2d& lo, const Eigen::Vector2d& hi) {
  double t0 = 0, t1 = 1;
  const Eigen::Vector2d d = b - a;
  for (int k = 0; k < 2; ++k) {
    if (std::abs(d[k]) < 1e-15) {
      if (a[k] < lo[k] || a[k] > hi[k]) return false;
      continue;
    }
    double ta = (lo[k] - a[k]) / d[k], tb = (hi[k] - a[k]) / d[k];
    if (ta > tb) std::swap(ta, tb);
    t0 = std::max(t0, ta);
    t1 = std::min(t1, tb);
    if (t0 > t1) return false;
  }
  return true;
}

// The edges that bound the face made of `face` triangles (indices into q, 2-D points): its
// outline and the rims of the openings in it. An edge is on the boundary when one face triangle
// alone has it; vertices are matched by position to 1 µm, so an unwelded STL works alike.
std::vector<std::array<Eigen::Vector2d, 2>> face_boundary(
    const std::vector<Eigen::Vector2d>& q, const std::vector<Eigen::Vector3i>& face) {
  using Key = std::array<long long, 2>;
  const auto key = [&](int i) {
    return Key{std::llround(q[static_cast<std::size_t>(i)].x() * 1e6),
               std::llround(q[static_cast<std::size_t>(i)].y() * 1e6)};
  };
  std::map<std::pair<Key, Key>, std::pair<int, std::array<int, 2>>> count;
  for (const auto& t : face)
    for (int e = 0; e < 3; ++e) {
      const int i = t[e], j = t[(e + 1) % 3];
      Key a = key(i), b = key(j);
      if (a == b) continue;  // a sliver's collapsed edge
      if (b < a) std::swap(a, b);
      auto& c = count[{a, b}];
      ++c.first;
      c.second = {i, j};
    }
  std::vector<std::array<Eigen::Vector2d, 2>> edges;
  for (const auto& [k, c] : count)
    if (c.first == 1)
      edges.push_back({q[static_cast<std::size_t>(c.second[0])], q[static_cast<std::size_t>(c.second[1])]});
  return edges;
}

// The riser under a casting whose points (vertices, or its bounds' corners) in {W} are p_W:
// the footprint, in the fixture's axes, of those within 1 mm of the lowest, shrunk by the
// inset (at least kRiserMinHalf about its centre), from the table top to the lowest point.
// Given the mesh's triangles as well, a fixture designer's riser: it stands on solid material,
// kRiserEdgeRoom inside every edge of the lowest face (its outline and the openings in it),
// shrunk about its centre as far as that needs. A riser under a bolt hole closes the hole's
// lower end: the burr grinding the hole's core-print flash low in it has no room beneath
// (housing 7320 and 7349: every pose of the 6 mm rack burr 0.25 mm from the riser's top).
// None without a riser height.
std::vector<FixtureBlock> riser_block(const CellSpec& spec, const std::vector<Vec3>& p_W,
                                      const std::vector<Eigen::Vector3i>& triangles = {}) {
  if (!(spec.riser_height > 0) || p_W.empty()) return {};
  constexpr double kLowBand = 1e-3;       // [m] points this near the lowest bear on the riser
  constexpr double kRiserMinHalf = 0.01;  // [m] a pin of 20 x 20 mm at least
  // [m] the riser's edge inside the face's edges: the burr's end and lean past a hole's rim,
  // and the casting's placement on the fixture (a few mm).
  constexpr double kRiserEdgeRoom = 0.005;
  const Mat3 R_WF = fixture_axes_W(spec);
  const Mat3 R_TF = spec.X_WTable.linear().transpose() * R_WF;  // about the table normal
  const Pose X_TableW = spec.X_WTable.inverse();
  double low = std::numeric_limits<double>::infinity();
  for (const Vec3& p : p_W) low = std::min(low, (X_TableW * p).z());
  if (!(low > 1e-6)) return {};  // the casting is not raised (check_cell_layout says so)
  std::vector<Eigen::Vector2d> q(p_W.size());
  std::vector<bool> in_band(p_W.size());
  Eigen::Vector2d lo = Eigen::Vector2d::Constant(std::numeric_limits<double>::infinity()), hi = -lo;
  for (std::size_t i = 0; i < p_W.size(); ++i) {
    const Vec3 q_T = X_TableW * p_W[i];
    q[i] = (R_TF.transpose() * q_T).head<2>();  // in-plane coordinates along the fixture's axes
    in_band[i] = q_T.z() <= low + kLowBand;
    if (!in_band[i]) continue;
    lo = lo.cwiseMin(q[i]);
    hi = hi.cwiseMax(q[i]);
  }
  const Eigen::Vector2d centre = 0.5 * (lo + hi);
  const Eigen::Vector2d min_half = Eigen::Vector2d::Constant(kRiserMinHalf);
  const Eigen::Vector2d half0 =
      (0.5 * (hi - lo) - Eigen::Vector2d::Constant(spec.riser_inset)).cwiseMax(min_half);
  Eigen::Vector2d half = half0;
  std::vector<Eigen::Vector3i> face;
  for (const auto& t : triangles)
    if (in_band[static_cast<std::size_t>(t[0])] && in_band[static_cast<std::size_t>(t[1])] &&
        in_band[static_cast<std::size_t>(t[2])])
      face.push_back(t);
  const auto edges = face_boundary(q, face);
  const auto clear = [&](const Eigen::Vector2d& h) {
    const Eigen::Vector2d room = h + Eigen::Vector2d::Constant(kRiserEdgeRoom);
    for (const auto& e : edges)
      if (segment_meets_rect(e[0], e[1], centre - room, centre + room)) return false;
    return true;
  };
  // The centre over the face itself (not over an opening, as under a frame-like bottom).
  const auto over_face = [&](const Eigen::Vector2d& c) {
    for (const auto& t : face) {
      const Eigen::Vector2d &a = q[static_cast<std::size_t>(t[0])],
                            &b = q[static_cast<std::size_t>(t[1])],
                            &d = q[static_cast<std::size_t>(t[2])];
      const auto cross = [](const Eigen::Vector2d& u, const Eigen::Vector2d& v) {
        return u.x() * v.y() - u.y() * v.x();
      };
      const double w0 = cross(b - a, c - a), w1 = cross(d - b, c - b), w2 = cross(a - d, c - d);
      if ((w0 >= 0 && w1 >= 0 && w2 >= 0) || (w0 <= 0 && w1 <= 0 && w2 <= 0)) return true;
    }
    return false;
  };
  if (!face.empty() && over_face(centre) && !clear(half0)) {
    // The largest scale of the inset footprint that is clear (clear from larger to smaller: a
    // smaller box meets a subset of the edges a larger one meets); the pin when none is.
    double ok = 0, bad = 1;
    for (int it = 0; it < 40; ++it) {
      const double mid = 0.5 * (ok + bad);
      (clear((mid * half0).cwiseMax(min_half)) ? ok : bad) = mid;
    }
    half = (ok * half0).cwiseMax(min_half);
  }
  FixtureBlock b;
  b.name = "riser";
  b.X_WF.linear() = R_WF;
  b.X_WF.translation() = spec.X_WTable * (R_TF * Vec3(centre.x(), centre.y(), 0) +
                                          Vec3(0, 0, 0.5 * low));
  b.half_size = Vec3(half.x(), half.y(), 0.5 * low);
  return {b};
}

// The locating blocks and the riser of a casting known only by its bounds in {C}.
std::vector<FixtureBlock> fixture_from_bounds(const CellSpec& spec, const Vec3& lo, const Vec3& hi) {
  std::vector<FixtureBlock> blocks = fixture_blocks_from_bounds(spec, lo, hi);
  std::vector<Vec3> corners_W;
  for (int k = 0; k < 8; ++k)
    corners_W.push_back(spec.X_WC * Vec3(k & 1 ? hi.x() : lo.x(), k & 2 ? hi.y() : lo.y(), k & 4 ? hi.z() : lo.z()));
  for (FixtureBlock& r : riser_block(spec, corners_W)) blocks.push_back(r);
  return blocks;
}

// A cylinder of the tool about the flange's z axis from z0 to z1 (none when not longer than 0).
std::string tool_cylinder(const char* name, double z0, double z1, double radius,
                          const std::string& indent) {
  if (!(z1 > z0)) return "";
  return indent + "  <geom name=\"" + name + "\" type=\"cylinder\" fromto=\"0 0 " + num(z0) +
         " 0 0 " + num(z1) + "\" size=\"" + num(radius) +
         "\" contype=\"0\" conaffinity=\"0\" group=\"1\" material=\"spindle\"/>\n";
}

// ---- exact geometric tests for the layout (boxes and triangle meshes)

// Does triangle (a, b, c) meet the box |x| <= h (all in the box frame)? Separating axis
// theorem (Akenine-Möller): the box's axes, the triangle's normal, their 9 edge cross products.
// Touching counts as meeting.
bool triangle_meets_box(const Vec3& h, const Vec3& a, const Vec3& b, const Vec3& c) {
  for (int i = 0; i < 3; ++i)
    if (std::min({a[i], b[i], c[i]}) > h[i] || std::max({a[i], b[i], c[i]}) < -h[i]) return false;
  const auto separates = [&](const Vec3& n) {
    const double pa = n.dot(a), pb = n.dot(b), pc = n.dot(c);
    const double r = h.x() * std::abs(n.x()) + h.y() * std::abs(n.y()) + h.z() * std::abs(n.z());
    return std::min({pa, pb, pc}) > r || std::max({pa, pb, pc}) < -r;
  };
  const Vec3 e[3] = {b - a, c - b, a - c};
  const Vec3 n = e[0].cross(e[1]);
  if (n.squaredNorm() > 0 && separates(n)) return false;
  for (int i = 0; i < 3; ++i)
    for (const Vec3& ej : e) {
      const Vec3 axis = Vec3::Unit(i).cross(ej);
      if (axis.squaredNorm() > 1e-30 && separates(axis)) return false;
    }
  return true;
}

// Generalised winding number of a closed, outward-oriented mesh about p: 1 inside, 0 outside
// (sum of the triangles' signed solid angles, Van Oosterom and Strackee).
double winding_number(const TriangleMesh& mesh, const Vec3& p) {
  double sum = 0;
  for (const auto& t : mesh.triangles) {
    const Vec3 a = mesh.vertices[t[0]] - p, b = mesh.vertices[t[1]] - p,
               c = mesh.vertices[t[2]] - p;
    const double la = a.norm(), lb = b.norm(), lc = c.norm();
    const double det = a.dot(b.cross(c));
    const double div = la * lb * lc + a.dot(b) * lc + b.dot(c) * la + c.dot(a) * lb;
    sum += 2.0 * std::atan2(det, div);
  }
  return sum / (4.0 * M_PI);
}

// The mesh (in {W}) in the frame of a box at X_WF.
TriangleMesh in_box_frame(const TriangleMesh& mesh_W, const Pose& X_WF) {
  return mesh_W.transformed(X_WF.inverse());
}

// Does the solid bounded by a closed mesh (given in the box frame) meet the box |x| <= h? Either
// a triangle meets the box, or the box lies wholly inside the solid.
bool solid_meets_box(const TriangleMesh& mesh_F, const Vec3& h) {
  for (const auto& t : mesh_F.triangles)
    if (triangle_meets_box(h, mesh_F.vertices[t[0]], mesh_F.vertices[t[1]], mesh_F.vertices[t[2]]))
      return true;
  return winding_number(mesh_F, Vec3::Zero()) > 0.5;
}

// How deep a box |x| <= h and the solid of mesh_F overlap, estimated from the mesh's vertices
// inside the box (their depth below the box's faces) and from 3 x 3 x 3 points of the box
// (corners, edge and face centres, centre) inside the solid (their distance to its surface)
// [m]; 0 when no such point is inside (only edges crossing). For messages only.
double overlap_depth(const TriangleMesh& mesh_F, const Vec3& h) {
  double depth = 0;
  for (const Vec3& v : mesh_F.vertices)
    if ((v.cwiseAbs() - h).maxCoeff() < 0) depth = std::max(depth, (h - v.cwiseAbs()).minCoeff());
  // The box's points on a 9 x 9 x 9 grid inside the mesh: a tall block beside a thin raised
  // plate meets it only between its corners' heights.
  const MeshBvh bvh(mesh_F);
  constexpr int kSteps = 4;
  for (int i = -kSteps; i <= kSteps; ++i)
    for (int j = -kSteps; j <= kSteps; ++j)
      for (int k = -kSteps; k <= kSteps; ++k) {
        const Vec3 p = Vec3(i, j, k).cwiseProduct(h) / kSteps;
        if (winding_number(mesh_F, p) > 0.5) depth = std::max(depth, bvh.closest(p).distance);
      }
  return depth;
}

// Overlap of two boxes (centres and axes X_WA, X_WB, half extents ha, hb) along the axis of
// least overlap among the 15 separating-axis candidates [m]: <= 0 when they are apart.
double box_box_overlap(const Pose& X_WA, const Vec3& ha, const Pose& X_WB, const Vec3& hb) {
  const Mat3 A = X_WA.linear(), B = X_WB.linear();
  const Vec3 d = X_WB.translation() - X_WA.translation();
  std::vector<Vec3> axes;
  for (int i = 0; i < 3; ++i) {
    axes.push_back(A.col(i));
    axes.push_back(B.col(i));
    for (int j = 0; j < 3; ++j) {
      const Vec3 n = A.col(i).cross(B.col(j));
      if (n.norm() > 1e-9) axes.push_back(n.normalized());
    }
  }
  double least = std::numeric_limits<double>::infinity();
  for (const Vec3& n : axes) {
    double ra = 0, rb = 0;
    for (int i = 0; i < 3; ++i) {
      ra += ha[i] * std::abs(n.dot(A.col(i)));
      rb += hb[i] * std::abs(n.dot(B.col(i)));
    }
    least = std::min(least, ra + rb - std::abs(n.dot(d)));
  }
  return least;
}

// Range along x of the part of triangle (a, b, c) inside the slab |y| <= h.y, |z| <= h.z
// (Sutherland-Hodgman clipping); false when no part of it is inside.
bool clipped_x_range(const Vec3& a, const Vec3& b, const Vec3& c, const Vec3& h, double& lo,
                     double& hi) {
  std::vector<Vec3> poly{a, b, c}, next;
  for (int axis = 1; axis <= 2; ++axis)
    for (double sign : {1.0, -1.0}) {
      // Keep sign * p[axis] <= h[axis].
      next.clear();
      for (std::size_t i = 0; i < poly.size(); ++i) {
        const Vec3& p = poly[i];
        const Vec3& q = poly[(i + 1) % poly.size()];
        const double fp = sign * p[axis] - h[axis], fq = sign * q[axis] - h[axis];
        if (fp <= 0) next.push_back(p);
        if ((fp < 0 && fq > 0) || (fp > 0 && fq < 0))
          next.push_back(p + (q - p) * (fp / (fp - fq)));
      }
      poly.swap(next);
      if (poly.empty()) return false;
    }
  lo = std::numeric_limits<double>::infinity();
  hi = -lo;
  for (const Vec3& p : poly) {
    lo = std::min(lo, p.x());
    hi = std::max(hi, p.x());
  }
  return true;
}

// A length for messages: millimetres below 0.1 m ("4.2 mm"), else metres ("0.210 m").
std::string length_text(double v) {
  char buf[48];
  if (std::abs(v) < 0.1)
    std::snprintf(buf, sizeof buf, "%.1f mm", v * 1e3);
  else
    std::snprintf(buf, sizeof buf, "%.3f m", v);
  return buf;
}

// Metres with 3 decimals, no unit.
std::string m3(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.3f", v);
  return buf;
}

// The mesh files of one mesh for MuJoCo: DIR/meshes/<stem>.stl, or its parts <stem>.stl,
// <stem>_part1.stl, ... when it has more faces than MuJoCo takes. Returns the paths relative
// to DIR.
std::vector<std::string> save_mujoco_mesh(const std::string& dir, const std::string& stem,
                                          const TriangleMesh& mesh) {
  std::vector<std::string> files;
  const std::vector<TriangleMesh> parts = split_mesh(mesh);
  for (std::size_t k = 0; k < parts.size(); ++k) {
    files.push_back("meshes/" + mesh_part_name(stem, k) + ".stl");
    save_mesh((std::filesystem::path(dir) / files.back()).string(), parts[k]);
  }
  return files;
}

}  // namespace

std::string arm_mjcf(const RobotModel& robot, const Pose& X_WB, const CellSpec& spec) {
  std::ostringstream os;
  os << "    <body name=\"base\" " << pose_attrs(X_WB) << ">\n"
     << "      " << inertial_xml(robot.base, Pose::Identity()) << "\n";
  // The housing below {B} (an arm whose {B} is at its shoulder, as the FT6's); an arm whose {B}
  // is its mounting face (base_height 0) draws its base as link 1.
  if (spec.base_height > kBaseHousingTop)
    os << "      <geom type=\"cylinder\" fromto=\"0 0 " << num(-spec.base_height) << " 0 0 "
       << num(-kBaseHousingTop) << "\" size=\"" << num(kBaseHousingRadius)
       << "\" material=\"robot\" group=\"1\"/>\n";
  std::string indent = "      ";
  for (int i = 0; i < kNumJoints; ++i) {
    // Body i is D-H frame {i-1} turned by joint i about its z axis; it sits at the constant
    // part of the previous link's transform.
    const Pose X_parent = i == 0 ? Pose::Identity() : dh_constant(robot.dh[i - 1]);
    const JointLimits& L = robot.limits[i];
    os << indent << "<body name=\"link" << i + 1 << "\" " << pose_attrs(X_parent) << ">\n"
       << indent << "  <joint name=\"joint" << i + 1 << "\" type=\"hinge\" axis=\"0 0 1\" "
       << "limited=\"true\" range=\"" << num(L.lower) << " " << num(L.upper) << "\" damping=\""
       << num(robot.servo_kp[i] > 0 ? robot.servo_damping[i] : spec.damping[i])
       << "\" armature=\"0.05\"/>\n"
       << indent << "  " << inertial_xml(robot.links[i], dh_constant(robot.dh[i])) << "\n"
       << indent << "  " << link_geoms(robot.dh[i], kLinkDrawRadii[i], i % 2 ? "robot" : "robot_dark")
       << "\n";
    indent += "  ";
  }
  const Pose C6 = dh_constant(robot.dh[5]);
  const ToolDescription& tool = robot.tool;
  const double tool_len = tool.X_ET.translation().norm();
  // Along the tool axis from the flange: spindle body, collet nut, exposed shank, burr.
  const double burr_top = std::max(0.0, tool_len - tool.length);
  const double collet_end = std::max(0.0, burr_top - tool.shank_length);
  const double spindle_end = std::max(0.0, collet_end - tool.collet_length);
  // The tool body sits at the flange {E}; its frame is {E}. The flange site (the F/T sensor's
  // frame) is on the tool body, so the sensor measures the wrist's wrench on the tool alone.
  os << indent << "<body name=\"tool\" " << pose_attrs(C6) << ">\n"
     << indent << "  " << inertial_xml(tool.inertial, Pose::Identity()) << "\n"
     << indent << "  <site name=\"flange\" pos=\"0 0 0\" size=\"0.01\" rgba=\"0.9 0.1 0.1 1\" "
     << "group=\"3\"/>\n"
     << tool_cylinder("spindle", 0, spindle_end, kSpindleRadius, indent)
     << tool_cylinder("collet", spindle_end, collet_end, tool.collet_radius, indent)
     << tool_cylinder("shank", collet_end, burr_top, shank_radius_for(tool, tool.radius), indent)
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
     // No convex hulls: no mesh geom collides in MuJoCo (the process model is the tool's
     // contact), and qhull over a ground part's voxel-face flash mesh took half a second.
     << "  <compiler angle=\"radian\" autolimits=\"true\" convexhull=\"false\"/>\n"
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
    // One mesh asset per part (split_mesh): MuJoCo 2.2.2 caps a mesh at kMaxMeshFaces faces.
    for (std::size_t k = 0; k < ca.nominal_stl.size(); ++k)
      os << "    <mesh name=\"" << mesh_part_name("casting_nominal", k) << "\" file=\""
         << ca.nominal_stl[k] << "\"/>\n";
    for (std::size_t k = 0; k < ca.flash_stl.size(); ++k)
      os << "    <mesh name=\"" << mesh_part_name("casting_flash", k) << "\" file=\""
         << ca.flash_stl[k] << "\"/>\n";
  }
  os << "  </asset>\n"
     << "  <worldbody>\n"
     << "    <light name=\"key\" directional=\"true\" pos=\"1 -1 3\" dir=\"-0.3 0.3 -1\" "
        "diffuse=\"0.6 0.6 0.6\" castshadow=\"true\"/>\n"
     << "    <light name=\"fill\" directional=\"true\" pos=\"-1 1 3\" dir=\"0.3 -0.2 -1\" "
        "diffuse=\"0.3 0.3 0.3\" castshadow=\"false\"/>\n"
     << "    <geom name=\"floor\" type=\"plane\" size=\"3 3 0.1\" material=\"floor\"/>\n";
  if (pedestal_top > 1e-6)  // none for an arm standing on the floor
    os << "    <geom name=\"pedestal\" type=\"box\" pos=\"" << num(b.x()) << " " << num(b.y())
       << " " << num(pedestal_top / 2) << "\" size=\"" << num(kPedestalHalfWidth) << " "
       << num(kPedestalHalfWidth) << " " << num(pedestal_top / 2) << "\" material=\"table\"/>\n";
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
    // A split mesh is one geom per part, all alike. contype = conaffinity = 0: MuJoCo neither
    // collides them nor builds their convex hulls, so splitting changes no dynamics.
    for (std::size_t k = 0; k < ca.nominal_stl.size(); ++k)
      os << "      <geom name=\"" << mesh_part_name("casting_body", k)
         << "\" type=\"mesh\" mesh=\"" << mesh_part_name("casting_nominal", k)
         << "\" material=\"casting\" contype=\"0\" conaffinity=\"0\"/>\n";
    for (std::size_t k = 0; k < ca.flash_stl.size(); ++k)
      os << "      <geom name=\"" << mesh_part_name("casting_flash", k)
         << "\" type=\"mesh\" mesh=\"" << mesh_part_name("casting_flash", k)
         << "\" material=\"flash\" contype=\"0\" conaffinity=\"0\"/>\n";
  } else {
    const Vec3 c = 0.5 * (ca.lo + ca.hi), h = 0.5 * (ca.hi - ca.lo);
    os << "      <geom name=\"casting_body\" type=\"box\" pos=\"" << vec3_string(c) << "\" size=\""
       << vec3_string(h) << "\" material=\"casting\"/>\n";
  }
  os << "    </body>\n";
  // Fixture: the given blocks, or two locating blocks beside the casting's bounds.
  for (const FixtureBlock& f :
       spec.fixtures.empty() ? fixture_from_bounds(spec, ca.lo, ca.hi) : spec.fixtures)
    os << "    <geom name=\"" << f.name << "\" type=\"box\" size=\"" << vec3_string(f.half_size)
       << "\" pos=\"" << vec3_string(f.X_WF.translation()) << "\" quat=\""
       << quat_wxyz_string(f.X_WF.linear()) << "\" material=\"fixture\" contype=\"0\" "
       << "conaffinity=\"0\"/>\n";
  // The scanner head at its mount {M} (z_M is its viewing direction) and its camera.
  os << "    <body name=\"scanner\" " << pose_attrs(spec.X_WM) << ">\n"
     << "      <geom name=\"scanner_head\" type=\"box\" pos=\"" << vec3_string(kScannerHeadCentre_M)
     << "\" size=\"" << vec3_string(kScannerHeadHalfSize)
     << "\" material=\"scanner\" contype=\"0\" conaffinity=\"0\"/>\n"
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
       << num(robot.servo_kp[i] > 0 ? robot.servo_kp[i] : spec.kp[i]) << "\" ctrlrange=\"" << num(L.lower) << " " << num(L.upper)
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
  X_TC.translation() = Vec3(x, y, std::max(0.0, spec.riser_height) - min_z);
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
  assets.nominal_stl = save_mujoco_mesh(dir, "casting_nominal", casting.nominal);
  const TriangleMesh flash = casting.flash_mesh();
  if (!flash.triangles.empty()) assets.flash_stl = save_mujoco_mesh(dir, "casting_flash", flash);
  casting.nominal.bounds(assets.lo, assets.hi);
  save_mesh(f.cad, casting.nominal);
  write_ground_truth(casting, spec.X_WC, f.truth);
  CellSpec laid_out = spec;
  if (laid_out.fixtures.empty()) laid_out.fixtures = fixture_blocks(spec, casting.nominal);
  write_text_file(f.mjcf, cell_mjcf(robot, laid_out, &assets));
  write_text_file(f.urdf, robot_urdf(robot));
  f.model = check_mjcf(f.mjcf);
  return f;
}

std::string write_cell_variant(const RobotModel& robot, const CellSpec& spec,
                               const TriangleMesh& nominal, const TriangleMesh& flash_C,
                               const std::string& dir, const std::string& name) {
  namespace fs = std::filesystem;
  CastingAssets assets;
  // The nominal mesh files of write_cell, split the same way (split_mesh depends on the face
  // count only).
  const std::size_t parts =
      std::max<std::size_t>(1, (nominal.triangles.size() + kMaxMeshFaces - 1) / kMaxMeshFaces);
  for (std::size_t k = 0; k < parts; ++k) {
    assets.nominal_stl.push_back("meshes/" + mesh_part_name("casting_nominal", k) + ".stl");
    if (!fs::exists(fs::path(dir) / assets.nominal_stl.back()))
      throw IoError(dir + ": expected a cell written by write_cell (" + assets.nominal_stl.back() +
                    ")");
  }
  if (!flash_C.triangles.empty())
    assets.flash_stl = save_mujoco_mesh(dir, name + "_flash", flash_C);
  nominal.bounds(assets.lo, assets.hi);
  CellSpec laid_out = spec;
  if (laid_out.fixtures.empty()) laid_out.fixtures = fixture_blocks(spec, nominal);
  const std::string path = (fs::path(dir) / (name + ".xml")).string();
  write_text_file(path, cell_mjcf(robot, laid_out, &assets));
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

std::vector<TriangleMesh> split_mesh(const TriangleMesh& mesh, std::size_t max_faces) {
  FT_ASSERT(max_faces > 0);
  const std::size_t n = mesh.triangles.size();
  if (n <= max_faces) return {mesh};
  const std::size_t parts = (n + max_faces - 1) / max_faces;
  std::vector<TriangleMesh> out(parts);
  std::vector<int> index(mesh.vertices.size());
  for (std::size_t k = 0; k < parts; ++k) {
    // Round robin: part k takes triangles k, k + parts, ...; each part indexes its own vertices.
    TriangleMesh& part = out[k];
    std::fill(index.begin(), index.end(), -1);
    part.triangles.reserve(n / parts + 1);
    for (std::size_t t = k; t < n; t += parts) {
      Eigen::Vector3i tri;
      for (int c = 0; c < 3; ++c) {
        const int v = mesh.triangles[t][c];
        if (index[v] < 0) {
          index[v] = static_cast<int>(part.vertices.size());
          part.vertices.push_back(mesh.vertices[v]);
        }
        tri[c] = index[v];
      }
      part.triangles.push_back(tri);
    }
  }
  return out;
}

std::string mesh_part_name(const std::string& base, std::size_t k) {
  return k == 0 ? base : base + "_part" + std::to_string(k);
}

bool is_mesh_part(const std::string& name, const std::string& base) {
  if (name == base) return true;
  const std::string prefix = base + "_part";
  if (name.size() <= prefix.size() || name.compare(0, prefix.size(), prefix) != 0) return false;
  return std::all_of(name.begin() + static_cast<std::ptrdiff_t>(prefix.size()), name.end(),
                     [](unsigned char ch) { return std::isdigit(ch) != 0; });
}

double shank_radius_for(const ToolDescription& tool, double burr_radius) {
  return std::max(1e-4, std::min(tool.shank_radius, burr_radius - 1e-3));
}

BurrHolder holder_for(const ToolDescription& tool, double burr_radius) {
  const bool from_rack = burr_radius < tool.radius;
  return {shank_radius_for(tool, burr_radius), from_rack ? tool.rack_collet_radius : tool.collet_radius};
}

std::vector<FixtureBlock> fixture_blocks(const CellSpec& spec, const TriangleMesh& nominal_C) {
  Vec3 lo, hi;
  nominal_C.bounds(lo, hi);
  std::vector<FixtureBlock> blocks = fixture_blocks_from_bounds(spec, lo, hi);
  if (nominal_C.triangles.empty()) return blocks;
  const TriangleMesh mesh_W = nominal_C.transformed(spec.X_WC);
  for (std::size_t i = 0; i < blocks.size(); ++i) {
    // Blocks beside the bounds are clear of an upright casting; a tilted one may reach over or
    // under them. Then slide the block outward along its x axis past everything of the casting
    // within its width and height, plus the gap (blocks[0] is on the -x side).
    FixtureBlock& b = blocks[i];
    const TriangleMesh mesh_F = in_box_frame(mesh_W, b.X_WF);
    if (!solid_meets_box(mesh_F, b.half_size)) continue;
    double lo_x = std::numeric_limits<double>::infinity(), hi_x = -lo_x;
    for (const auto& t : mesh_F.triangles) {
      double t_lo = 0, t_hi = 0;
      if (clipped_x_range(mesh_F.vertices[t[0]], mesh_F.vertices[t[1]], mesh_F.vertices[t[2]],
                          b.half_size, t_lo, t_hi)) {
        lo_x = std::min(lo_x, t_lo);
        hi_x = std::max(hi_x, t_hi);
      }
    }
    // A closed mesh always crosses the band (the band leaves the part somewhere).
    if (!(hi_x >= lo_x)) continue;
    const double shift = i > 0 ? hi_x + kFixtureGap + b.half_size.x()
                               : lo_x - kFixtureGap - b.half_size.x();
    b.X_WF.translation() += b.X_WF.linear().col(0) * shift;
  }
  for (FixtureBlock& r : riser_block(spec, mesh_W.vertices, mesh_W.triangles)) blocks.push_back(r);
  return blocks;
}

void check_cell_layout(const CellSpec& spec, const TriangleMesh& nominal_C,
                       const CellCheckParams& params) {
  if (nominal_C.triangles.empty())
    throw ArgumentError("check_cell_layout: expected the casting's nominal mesh, got no triangles");
  const double tol = params.tolerance;
  const Pose X_TableW = spec.X_WTable.inverse();
  const Vec3& ts = spec.table_size;
  const double ax = ts.x() / 2, ay = ts.y() / 2;
  const std::string table_top =
      "the table top (" + m3(ts.x()) + " x " + m3(ts.y()) + " m)";

  // The casting's footprint: its placed mesh in the table frame {Table} (z up from the top).
  const TriangleMesh mesh_W = nominal_C.transformed(spec.X_WC);
  Vec3 lo_T = Vec3::Constant(std::numeric_limits<double>::infinity()), hi_T = -lo_T;
  for (const Vec3& v : mesh_W.vertices) {
    const Vec3 p = X_TableW * v;
    lo_T = lo_T.cwiseMin(p);
    hi_T = hi_T.cwiseMax(p);
  }
  const double overhang = std::max({-ax - lo_T.x(), hi_T.x() - ax, -ay - lo_T.y(), hi_T.y() - ay});
  if (overhang > tol) {
    const Vec3 ext = hi_T - lo_T;
    const std::string footprint = "the casting's footprint (" + m3(ext.x()) + " x " +
                                  m3(ext.y()) + " m at its placement, x " + m3(lo_T.x()) +
                                  ".." + m3(hi_T.x()) + ", y " + m3(lo_T.y()) + ".." +
                                  m3(hi_T.y()) + " m from the table's centre)";
    if (ext.x() > ts.x() + tol || ext.y() > ts.y() + tol)
      throw ConfigError("cell.table.size: expected " + footprint + " to fit on " + table_top +
                        ", got it over the edge by " + length_text(overhang));
    throw ConfigError("casting.placement: expected " + footprint + " within " + table_top +
                      ", got it over the edge by " + length_text(overhang) +
                      " (move the casting towards the centre)");
  }
  const double rest = std::max(0.0, spec.riser_height);
  if (std::abs(lo_T.z() - rest) > tol)
    throw ConfigError(std::string("casting.placement: expected the casting resting on ") +
                      (rest > 0 ? "the riser (" + length_text(rest) + " over the table top)"
                                : std::string("the table top")) +
                      ", got its lowest point " + length_text(std::abs(lo_T.z() - rest)) +
                      (lo_T.z() > rest ? " above" : " below") + " that surface");

  // Fixture blocks: on the table top, clear of the casting.
  const std::vector<FixtureBlock> blocks =
      spec.fixtures.empty() ? fixture_blocks(spec, nominal_C) : spec.fixtures;
  for (const FixtureBlock& b : blocks) {
    const Pose X_TableF = X_TableW * b.X_WF;
    const Vec3 c_T = X_TableF.translation();
    double bottom = std::numeric_limits<double>::infinity();
    for (int k = 0; k < 8; ++k) {
      const Vec3 corner(k & 1 ? b.half_size.x() : -b.half_size.x(),
                        k & 2 ? b.half_size.y() : -b.half_size.y(),
                        k & 4 ? b.half_size.z() : -b.half_size.z());
      bottom = std::min(bottom, (X_TableF * corner).z());
    }
    const std::string what = "fixture block '" + b.name + "' (centre " + m3(c_T.x()) + " " +
                             m3(c_T.y()) + " m from the table's centre)";
    if (bottom > tol)
      throw ConfigError("casting.placement: expected " + what +
                        " standing on the table top, got it floating " + length_text(bottom) +
                        " above it");
    if (bottom < -tol)
      throw ConfigError("casting.placement: expected " + what +
                        " standing on the table top, got it " + length_text(-bottom) +
                        " into the table");
    if (std::abs(c_T.x()) > ax + tol || std::abs(c_T.y()) > ay + tol)
      throw ConfigError("casting.placement: expected " + what + " over " + table_top +
                        ", got it off the table's edge (it would float; move the casting towards "
                        "the centre or enlarge cell.table.size)");
    const Vec3 shrunk = (b.half_size - Vec3::Constant(tol)).cwiseMax(0.0);
    const TriangleMesh mesh_F = in_box_frame(mesh_W, b.X_WF);
    if (solid_meets_box(mesh_F, shrunk)) {
      const double depth = overlap_depth(mesh_F, b.half_size);
      throw ConfigError("casting.placement: expected " + what +
                        " clear of the casting's nominal mesh (tolerance " + length_text(tol) +
                        "), got them overlapping" +
                        (depth > tol ? " by " + length_text(depth) : std::string()));
    }
  }

  // Robot base and scanner head against the table's volume: its top's footprint from the floor
  // up to the top surface (plate and legs).
  const double table_height = spec.X_WTable.translation().z();
  Pose X_WTableBox = spec.X_WTable;
  X_WTableBox.translation() = spec.X_WTable * Vec3(0, 0, -table_height / 2);
  const Vec3 table_half(ax, ay, table_height / 2);
  const Vec3 p_WB = spec.X_WB.translation();
  const double pedestal_top = p_WB.z() - spec.base_height;
  const Pose X_WPedestal(Eigen::Translation3d(p_WB.x(), p_WB.y(), pedestal_top / 2));
  const double pedestal =
      pedestal_top > 1e-6
          ? box_box_overlap(X_WPedestal,
                            Vec3(kPedestalHalfWidth, kPedestalHalfWidth, pedestal_top / 2),
                            X_WTableBox, table_half)
          : 0.0;
  if (pedestal > tol)
    throw ConfigError("cell.robot_base: expected the robot's pedestal (" +
                      m3(2 * kPedestalHalfWidth) + " x " + m3(2 * kPedestalHalfWidth) +
                      " m under the base at x " + m3(p_WB.x()) + ", y " + m3(p_WB.y()) +
                      " m) clear of the worktable (cell.table), got them overlapping by " +
                      length_text(pedestal));
  // The base housing (a cylinder about z_B) by its bounding box.
  const double housing_len = std::abs(spec.base_height - kBaseHousingTop);
  const Pose X_WHousing =
      spec.X_WB * Pose(Eigen::Translation3d(0, 0, -(spec.base_height + kBaseHousingTop) / 2));
  const double housing =
      spec.base_height > kBaseHousingTop
          ? box_box_overlap(X_WHousing,
                            Vec3(kBaseHousingRadius, kBaseHousingRadius, housing_len / 2),
                            X_WTableBox, table_half)
          : 0.0;
  if (housing > tol)
    throw ConfigError("cell.robot_base: expected the robot's base housing (d" +
                      m3(2 * kBaseHousingRadius) + " m, " + m3(housing_len) +
                      " m tall) clear of the worktable (cell.table), got them overlapping by " +
                      length_text(housing));
  const Pose X_WHead = spec.X_WM * Pose(Eigen::Translation3d(kScannerHeadCentre_M));
  const double head = box_box_overlap(X_WHead, kScannerHeadHalfSize, X_WTableBox, table_half);
  if (head > tol)
    throw ConfigError("cell.scanner_mount: expected the scanner head (" +
                      m3(2 * kScannerHeadHalfSize.x()) + " x " + m3(2 * kScannerHeadHalfSize.y()) +
                      " x " + m3(2 * kScannerHeadHalfSize.z()) +
                      " m) clear of the worktable (cell.table), got them overlapping by " +
                      length_text(head));
}

// The arm at its home pose (the pose it scans in) against the scanner head: each link's capsules
// along its D-H offsets and the spindle, sampled every 5 mm, against the head's box grown by the
// capsule's radius.
void check_arm_clear_of_scanner(const RobotModel& robot, const CellSpec& spec) {
  const Pose X_WHead = spec.X_WM * Pose(Eigen::Translation3d(kScannerHeadCentre_M));
  const auto depth_inside = [&](const Vec3& p_W, double radius) {
    const Vec3 p = X_WHead.inverse() * p_W;
    const Vec3 h = kScannerHeadHalfSize + Vec3::Constant(radius);
    return std::min({h.x() - std::abs(p.x()), h.y() - std::abs(p.y()), h.z() - std::abs(p.z())});
  };
  std::string worst_part;
  double worst = 0;
  const auto segment = [&](const Vec3& a, const Vec3& b, double radius, const std::string& part) {
    const int n = 1 + static_cast<int>((b - a).norm() / 0.005);
    for (int k = 0; k <= n; ++k) {
      const double d = depth_inside(a + (b - a) * (static_cast<double>(k) / n), radius);
      if (d > worst) {
        worst = d;
        worst_part = part;
      }
    }
  };
  Pose X = spec.X_WB;
  for (int i = 0; i < kNumJoints; ++i) {
    X = X * Pose(Eigen::AngleAxisd(robot.home[i], Vec3::UnitZ()));
    const Vec3 o = X.translation(), z_end = X * Vec3(0, 0, robot.dh[i].d);
    const Vec3 a_end = X * Vec3(robot.dh[i].a, 0, robot.dh[i].d);
    segment(o, z_end, kLinkDrawRadii[i], "link " + std::to_string(i + 1));
    segment(z_end, a_end, kLinkDrawRadii[i], "link " + std::to_string(i + 1));
    X = X * dh_constant(robot.dh[i]);
  }
  segment(X.translation(), X * robot.tool.X_ET.translation(), kSpindleRadius, "the spindle");
  if (worst > 1e-4)
    throw ConfigError(
        "cell.scanner_mount: expected the scanner head clear of the arm at its home pose (the "
        "pose it scans in; robot " + robot.name + "), got " + worst_part + " " +
        length_text(worst) + " into it: move the scanner or the robot base, or give the robot "
        "file a home away from the scanner");
}

}  // namespace flashtwin::sim
