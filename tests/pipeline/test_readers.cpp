// Hostile input to the readers: each case was found by the fuzzers in fuzz/ (or by reading the
// reader while writing them) and must now end as the project's InputError (exit 2).
#include <gtest/gtest.h>

#include <fstream>
#include <string>

#include "flashtwin/core/config.hpp"
#include "flashtwin/core/errors.hpp"
#include "flashtwin/core/mesh.hpp"
#include "flashtwin/core/robot.hpp"
#include "flashtwin/pipeline/paths_io.hpp"
#include "flashtwin/pipeline/pose_json.hpp"
#include "flashtwin/pipeline/scenario.hpp"
#include "test_util.hpp"

using namespace flashtwin;

namespace {

std::string write(const std::string& dir, const std::string& name, const std::string& text) {
  const std::string p = dir + "/" + name;
  std::ofstream(p, std::ios::binary) << text;
  return p;
}

}  // namespace

TEST(Readers, NumbersBeyondDoubleRangeAreInputErrors) {
  // nlohmann throws out_of_range for 1e999; it used to escape as an internal failure (exit 1).
  EXPECT_THROW(pipeline::read_paths_from_string(R"({"paths":[{"points":[[1e999,0,0]]}]})", "p.json"),
               InputError);
  EXPECT_THROW(pipeline::read_pose_from_string("[1e999,0,0,0, 0,1,0,0, 0,0,1,0, 0,0,0,1]", "x.json"),
               InputError);
}

TEST(Readers, PathsClosedMustBeABoolean) {
  for (const char* v : {"\"yes\"", "1", "null"}) {
    const std::string text =
        std::string(R"({"paths":[{"points":[[0,0,0],[0.01,0,0]],"closed":)") + v + "}]}";
    EXPECT_THROW(pipeline::read_paths_from_string(text, "p.json"), InputError) << v;
  }
}

TEST(Readers, DeeplyNestedPoseIsRefusedNotARecursionCrash) {
  const std::string deep = std::string(100000, '[') + std::string(100000, ']');
  EXPECT_THROW(pipeline::read_pose_from_string(deep, "x.json"), InputError);
}

TEST(Readers, YamlKeysThatAreListsOrMapsAreConfigErrors) {
  EXPECT_THROW(ConfigNode::load_string("[1]: 2\n", "a.yaml").keys(), ConfigError);
  EXPECT_THROW(ConfigNode::load_string("a: {{x: 1}: 2}\n", "b.yaml"), ConfigError);
  EXPECT_THROW(parse_robot("? [1, 2]\n: 3\n", "robot.yaml"), ConfigError);
}

TEST(Readers, YamlAliasCyclesAndExpansionBombsAreConfigErrors) {
  EXPECT_THROW(ConfigNode::load_string("a: &v [*v]\n", "cycle.yaml"), ConfigError);
  // Nine levels of nine-fold aliases expand to 9^9 nodes.
  std::string bomb = "l0: &a0 [x, x, x, x, x, x, x, x, x]\n";
  for (int i = 1; i <= 9; ++i) {
    const std::string p = "*a" + std::to_string(i - 1);
    bomb.append("l").append(std::to_string(i)).append(": &a").append(std::to_string(i));
    bomb.append(" [").append(p);
    for (int k = 1; k < 9; ++k) bomb.append(", ").append(p);
    bomb += "]\n";
  }
  EXPECT_THROW(ConfigNode::load_string(bomb, "bomb.yaml"), ConfigError);
}

TEST(Readers, ScanViewThatIsNotAMappingIsAConfigError) {
  const std::string dir = ftest::temp_dir("readers_views");
  const std::string robot = ftest::source_path("models/robots/ft6.yaml");
  for (const char* views : {"[1]", "[[]]", "[line]"}) {
    const std::string sc = write(dir, "s.yaml",
                                 "name: v\nrobot: " + robot + "\ncasting: {family: flanged_plate}\nscanner: {views: " + views + "}\n");
    try {
      pipeline::load_scenario(sc);
      ADD_FAILURE() << views << ": accepted";
    } catch (const ConfigError& e) {
      EXPECT_NE(std::string(e.what()).find("scanner.views[0]"), std::string::npos) << e.what();
    }
  }
}

TEST(Readers, MillimetreMeshAtScaleOneWeldsLikeAMetreMesh) {
  // Coordinates of several hundred units overflowed the 32-bit weld grid (undefined behaviour;
  // in practice every vertex fell into one cell and welding went quadratic).
  const std::string dir = ftest::temp_dir("readers_mm");
  const TriangleMesh box_m = box_mesh(Vec3::Zero(), Vec3(0.2, 0.1, 0.05));
  TriangleMesh box_mm = box_m;
  for (auto& v : box_mm.vertices) v = 1000.0 * v + Vec3(300, -250, 40);
  save_mesh(dir + "/box_mm.stl", box_mm);
  const TriangleMesh loaded = load_mesh(dir + "/box_mm.stl");
  EXPECT_EQ(loaded.vertices.size(), box_m.vertices.size());
  EXPECT_EQ(loaded.triangles.size(), box_m.triangles.size());
}

TEST(Readers, ObjFaceIndexBeyondTheVerticesIsAnInputError) {
  const std::string dir = ftest::temp_dir("readers_obj");
  const std::string p = write(dir, "bad.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  EXPECT_THROW(load_mesh(p), InputError);
}

TEST(Readers, FuzzFindingsAreInputErrorsOrClouds) {
  // fuzz_pcd: a PCD whose TYPE line is mangled made PCL return a blob with 4 points and no
  // data; converting it bound a reference to a null point (UBSan). Now an InputError.
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/pcd_mangled_type_line.pcd")),
               InputError);
  // fuzz_pcd: a PCD with a mangled TYPE line among blank lines crashed inside PCL's reader
  // (SEGV); fuzz_ply: a PLY whose end_header is misspelt kept assimp busy for over 10 s. Both
  // are refused by the header checks now, before PCL or assimp see them.
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/pcd_pcl_segv.pcd")), InputError);
  EXPECT_THROW(load_mesh(ftest::source_path("tests/data/fuzz/ply_assimp_timeout.ply")), InputError);
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/ply_assimp_timeout.ply")), InputError);
  // fuzz_pcd: a binary_compressed block whose sizes disagree with the header overflowed PCL's
  // buffer (ASan); fuzz_ply: a binary PLY with face indices past its two vertices made
  // assimp's triangulation abort on an internal assert. Refused before PCL / by assimp's own
  // validation step now.
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/pcd_pcl_compressed_overflow.pcd")),
               InputError);
  EXPECT_THROW(load_mesh(ftest::source_path("tests/data/fuzz/ply_assimp_abort.ply")), InputError);
  // fuzz_pcd: an ASCII body of garbage made PCL's reader crash (SEGV).
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/pcd_pcl_ascii_segv.pcd")), InputError);
  // fuzz_pcd: a field list without z made PCL throw std::length_error; fuzz_ply: a garbled
  // ASCII value ("0..01") made assimp ask for 29 GB.
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/pcd_pcl_length_error.pcd")), InputError);
  EXPECT_THROW(load_mesh(ftest::source_path("tests/data/fuzz/ply_assimp_huge_alloc.ply")), InputError);
  // fuzz_ply, on our own reader: two 'vertex' elements made it read one element's values by
  // the other's layout (ASan heap-buffer-overflow). A repeated element is refused.
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/ply_two_vertex_elements.ply")), InputError);
  // fuzz_ply, 10-minute run: an element named by 75 digits made assimp ask for 100 GB. PLY
  // meshes are read by our own parser now.
  EXPECT_THROW(load_mesh(ftest::source_path("tests/data/fuzz/ply_assimp_oom.ply")), InputError);
  EXPECT_THROW(load_cloud(ftest::source_path("tests/data/fuzz/ply_assimp_oom.ply")), InputError);
  // fuzz_ply / fuzz_obj: inputs on which assimp leaks its partial scene (suppressed as a
  // third-party leak in scripts/sanitizers/lsan.supp); the readers must still end cleanly.
  for (const char* f : {"tests/data/fuzz/ply_assimp_leak.ply", "tests/data/fuzz/obj_assimp_leak.obj"}) {
    try {
      load_mesh(ftest::source_path(f));
    } catch (const InputError&) {
    }
  }
  try {
    load_cloud(ftest::source_path("tests/data/fuzz/ply_assimp_leak.ply"));
  } catch (const InputError&) {
  }
}

TEST(Readers, CloudFormatsPclWritesAreReadByOurOwnParser) {
  // The seed corpus holds clouds in every layout PCL writes (ascii, binary, LZF-compressed PCD;
  // ascii and big-endian double PLY): the same four points, with normals where stored.
  struct Case {
    const char* file;
    std::size_t points;
    bool normals;
  };
  for (const Case& c : {Case{"fuzz/corpus/pcd/ascii_xyz.pcd", 4, false},
                        Case{"fuzz/corpus/pcd/binary_compressed_xyz.pcd", 4, false},
                        Case{"fuzz/corpus/pcd/binary_xyz_normals_label.pcd", 4, true},
                        Case{"fuzz/corpus/ply/cloud_binary_be_double.ply", 3, false},
                        Case{"fuzz/corpus/ply/cloud_ascii_normals_rgb.ply", 3, true}}) {
    const PointCloud pc = load_cloud(ftest::source_path(c.file));
    EXPECT_EQ(pc.size(), c.points) << c.file;
    EXPECT_EQ(pc.normals.size(), c.normals ? c.points : 0u) << c.file;
    for (const auto& p : pc.points) EXPECT_LT(p.norm(), 1.0f) << c.file;  // metres, near the origin
  }
  // The compressed and the plain binary PCD hold the same coordinates.
  const PointCloud a = load_cloud(ftest::source_path("fuzz/corpus/pcd/ascii_xyz.pcd"));
  const PointCloud b = load_cloud(ftest::source_path("fuzz/corpus/pcd/binary_compressed_xyz.pcd"));
  ASSERT_EQ(a.size(), b.size());
  for (std::size_t i = 0; i < a.size(); ++i) EXPECT_TRUE(a.points[i].isApprox(b.points[i], 1e-6f)) << i;
}

TEST(Readers, PlyMeshesAreReadByOurOwnParser) {
  // A box written as binary PLY and a hand-written ASCII quad (a polygon, split as a fan) load
  // with their triangles; a face index past the vertices is refused naming the face.
  const std::string dir = ftest::temp_dir("readers_ply_mesh");
  const TriangleMesh box = box_mesh(Vec3::Zero(), Vec3(0.2, 0.1, 0.05));
  save_mesh(dir + "/box.ply", box);
  const TriangleMesh b = load_mesh(dir + "/box.ply");
  EXPECT_EQ(b.vertices.size(), box.vertices.size());
  EXPECT_EQ(b.triangles.size(), box.triangles.size());
  const std::string quad =
      "ply\nformat ascii 1.0\nelement vertex 4\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n"
      "0 0 0\n1 0 0\n1 1 0\n0 1 0\n4 0 1 2 3\n";
  std::ofstream(dir + "/quad.ply") << quad;
  const TriangleMesh q = load_mesh(dir + "/quad.ply", 0.001);
  EXPECT_EQ(q.triangles.size(), 2u);
  EXPECT_NEAR(q.vertices[2].x(), 0.001, 1e-12);
  std::string bad = quad;
  bad.replace(bad.rfind("4 0 1 2 3"), 9, "3 0 1 7");
  std::ofstream(dir + "/bad.ply") << bad;
  try {
    load_mesh(dir + "/bad.ply");
    ADD_FAILURE() << "accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("face 0"), std::string::npos) << e.what();
  }
}

// The plan stops in free air before the finishing pass (for the sensor's zero) by default when
// the controller reads the F/T sensor for the tool's position, not with the oracle
// compensation; the scenario's planning block decides when it says so, and a non-boolean is a
// config error naming the key.
TEST(Readers, StopsInFreeAirFollowWhetherTheControllerReadsTheSensor) {
  const std::string path = ftest::source_path("scenarios/default.yaml");
  EXPECT_FALSE(pipeline::load_scenario(path).grind.retare_before_finish);
  EXPECT_TRUE(
      pipeline::load_scenario(path, {"execution.compensation=sensor"}).grind.retare_before_finish);
  EXPECT_TRUE(pipeline::load_scenario(path, {"execution.force_control.enabled=true"})
                  .grind.retare_before_finish);
  EXPECT_FALSE(pipeline::load_scenario(
                   path, {"execution.compensation=sensor", "planning.retare_before_finish=false"})
                   .grind.retare_before_finish);
  const auto sc = pipeline::load_scenario(
      path, {"planning.retare_before_finish=true", "planning.retare_length=0.05"});
  EXPECT_TRUE(sc.grind.retare_before_finish);
  EXPECT_EQ(sc.grind.retare_length, 0.05);
  try {
    pipeline::load_scenario(path, {"planning.retare_before_finish=often"});
    ADD_FAILURE() << "a non-boolean was accepted";
  } catch (const InputError& e) {
    EXPECT_NE(std::string(e.what()).find("retare_before_finish"), std::string::npos) << e.what();
  }
}
