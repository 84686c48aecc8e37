// Mesh loading: the shared meshes load with their manifest's counts and the
// file's vertex order; diagnostics match the manifest; broken files get
// precise errors; the half-edge structure is consistent.
#include "core/mesh/mesh_io.h"

#include <cmath>
#include <filesystem>
#include <fstream>
#include <numbers>
#include <random>
#include <sstream>

#include "core/mesh/surface_locator.h"
#include "core/mesh/surface_point.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::SharedDataAvailable;
using testing::SharedPath;
using testing::TempDir;

struct ManifestRow {
  const char* file;
  uint64_t vertices, faces, edges, components, boundary_loops;
  int64_t genus;
  uint64_t isolated;
  double bbox_diagonal;
};

// From ../shared/meshes/MANIFEST.md.
const ManifestRow kManifest[] = {
    {"eight.off", 766, 1536, 2304, 1, 0, 2, 0, 2.898},
    {"spot.obj", 2930, 5856, 8784, 1, 0, 0, 0, 2.5881},
    {"blade_aniso.off", 8231, 16222, 24453, 1, 2, 0, 0, 129.57},
    {"camelhead.off", 11381, 22704, 34084, 1, 1, 0, 0, 1.2477},
    {"fertility.off", 17827, 35666, 53499, 1, 0, 4, 0, 1.289},
    {"bunny.ply", 35947, 69451, 104288, 1, 5, 0, 1113, 0.25025},
    {"armadillo.obj", 49990, 99976, 149964, 1, 0, 0, 0, 228.79},
    {"igea.ply", 134345, 268686, 403029, 1, 0, 0, 0, 0.1564},
};

class ManifestTest : public ::testing::TestWithParam<ManifestRow> {};

TEST_P(ManifestTest, LoadsWithManifestCountsAndDiagnostics) {
  ASSERT_TRUE(SharedDataAvailable());
  const ManifestRow& row = GetParam();
  MeshDiagnostics d;
  auto mesh = LoadMesh(SharedPath(std::string("meshes/") + row.file), {}, &d);
  ASSERT_OK(mesh);
  EXPECT_EQ(mesh->num_vertices(), row.vertices);
  EXPECT_EQ(mesh->num_faces(), row.faces);
  EXPECT_EQ(mesh->num_edges(), row.edges);
  EXPECT_EQ(d.vertices, row.vertices);
  EXPECT_EQ(d.faces, row.faces);
  EXPECT_EQ(d.edges, row.edges);
  EXPECT_EQ(d.components, row.components);
  EXPECT_EQ(d.boundary_loops, row.boundary_loops);
  EXPECT_EQ(d.genus, row.genus);
  EXPECT_EQ(d.isolated_vertices, row.isolated);
  EXPECT_EQ(d.non_manifold_edges, 0u);
  EXPECT_EQ(d.non_manifold_vertices, 0u);
  EXPECT_EQ(d.duplicate_vertices, 0u);
  EXPECT_EQ(d.zero_area_faces, 0u);
  EXPECT_TRUE(d.manifold);
  EXPECT_NEAR(d.bbox_diagonal, row.bbox_diagonal, 1e-3 * row.bbox_diagonal);
  EXPECT_OK(mesh->CheckConsistency());
  // Interior vertices that are not saddles have angle sums of at most 2 pi.
  for (VertexId v = 0; v < mesh->num_vertices(); v += 101) {
    if (mesh->is_isolated(v) || mesh->is_boundary(v)) continue;
    EXPECT_EQ(mesh->is_saddle(v), mesh->total_angle(v) > 2 * std::numbers::pi * (1 + 1e-10));
  }
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, ManifestTest, ::testing::ValuesIn(kManifest),
                         [](const auto& info) {
                           std::string name = info.param.file;
                           for (char& c : name) c = std::isalnum(c) ? c : '_';
                           return name;
                         });

// The first and last vertex lines of an OBJ/OFF file, read as text.
TEST(MeshIoOnSharedMeshes, VertexOrderIsTheFileOrder) {
  ASSERT_TRUE(SharedDataAvailable());
  auto mesh = LoadMesh(SharedPath("meshes/armadillo.obj"));
  ASSERT_OK(mesh);
  std::ifstream in(SharedPath("meshes/armadillo.obj"));
  std::string line;
  std::vector<Vec3> listed;
  while (std::getline(in, line)) {
    if (line.rfind("v ", 0) == 0) {
      std::istringstream f(line.substr(2));
      Vec3 p;
      f >> p.x >> p.y >> p.z;
      listed.push_back(p);
    }
  }
  ASSERT_EQ(listed.size(), mesh->num_vertices());
  for (VertexId v : {VertexId{0}, VertexId{1}, VertexId{12345}, VertexId(listed.size() - 1)}) {
    // Exactly: coordinates are read in double precision.
    EXPECT_EQ(mesh->position(v), listed[v]) << "vertex " << v;
  }
}

// The estimate a registration is refused by before the build: within a few
// percent of what the built mesh holds (the edge array's spare capacity).
TEST(MeshIoOnSharedMeshes, MemoryEstimateFromCountsIsNearTheBuiltMesh) {
  ASSERT_TRUE(SharedDataAvailable());
  auto mesh = LoadMesh(SharedPath("meshes/armadillo.obj"));
  ASSERT_OK(mesh);
  const uint64_t built = mesh->memory_bytes();
  const uint64_t estimate = Mesh::EstimateMemoryBytes(mesh->num_vertices(), mesh->num_faces());
  ASSERT_GT(built, 0u);
  EXPECT_LE(estimate, built);
  EXPECT_GE(estimate, built * 0.9) << "estimate " << estimate << ", built " << built;
}

TEST(MeshIoOnSharedMeshes, MessyOgreDiagnosticsMatchTheManifest) {
  ASSERT_TRUE(SharedDataAvailable());
  MeshDiagnostics d;
  auto mesh = LoadMesh(SharedPath("meshes/ogre_messy.obj"), {}, &d);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(mesh.status().message()), HasSubstr("non-manifold"));
  EXPECT_EQ(d.vertices, 62194u);
  EXPECT_EQ(d.faces, 124008u);
  EXPECT_EQ(d.edges, 186130u);
  EXPECT_EQ(d.components, 44u);
  EXPECT_EQ(d.boundary_loops, 12u);
  EXPECT_EQ(d.non_manifold_vertices, 3u);
  EXPECT_EQ(d.duplicate_vertices, 9u);
  EXPECT_EQ(d.zero_area_faces, 4u);
  EXPECT_FALSE(d.manifold);
  LoadOptions repair;
  repair.repair_non_manifold = true;
  auto repaired = LoadMesh(SharedPath("meshes/ogre_messy.obj"), repair);
  ASSERT_OK(repaired);
  EXPECT_GT(repaired->num_vertices(), 62194u);  // split copies appended
  EXPECT_OK(repaired->CheckConsistency());
}

class BrokenFilesTest : public ::testing::Test {
 protected:
  std::string Write(const std::string& name, const std::string& content) {
    std::string path = dir_.File(name);
    std::ofstream(path, std::ios::binary) << content;
    return path;
  }
  absl::Status Load(const std::string& path) { return LoadMesh(path).status(); }
  TempDir dir_;
};

TEST_F(BrokenFilesTest, EachGetsAClearError) {
  const std::string tri = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  ASSERT_OK(Load(Write("ok.off", tri)));

  absl::Status missing = Load(dir_.File("missing.off"));
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound);
  EXPECT_THAT(std::string(missing.message()), HasSubstr("missing.off"));

  EXPECT_EQ(Load(Write("empty.off", "")).code(), absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(Load(Write("mesh.xyz", tri)).code(), absl::StatusCode::kInvalidArgument);

  absl::Status truncated = Load(Write("cut.off", "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n"));
  EXPECT_EQ(truncated.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(truncated.message()), HasSubstr("cut.off"));

  absl::Status nan = Load(Write("nan.obj", "v 0 0 0\nv nan 0 0\nv 0 1 0\nf 1 2 3\n"));
  EXPECT_EQ(nan.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(nan.message()), HasSubstr("vertex 1"));

  absl::Status range = Load(Write("range.off", "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n"));
  EXPECT_EQ(range.code(), absl::StatusCode::kInvalidArgument);

  absl::Status huge = Load(Write("huge.off", "OFF\n999999999999 1 0\n0 0 0\n"));
  EXPECT_EQ(huge.code(), absl::StatusCode::kInvalidArgument);

  // Three faces on one edge.
  absl::Status fin = Load(Write(
      "fin.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n"));
  EXPECT_EQ(fin.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(fin.message()), HasSubstr("non-manifold"));

  // Bow tie: two triangles sharing only a vertex.
  absl::Status bowtie = Load(
      Write("bowtie.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nv -1 0 0\nv 0 -1 0\nf 1 2 3\nf 1 4 5\n"));
  EXPECT_EQ(bowtie.code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(bowtie.message()), HasSubstr("vertex 0"));

  // Binary PLY cut short.
  std::string ply =
      "ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float "
      "y\nproperty float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n";
  ply += std::string(20, '\0');
  EXPECT_EQ(Load(Write("cut.ply", ply)).code(), absl::StatusCode::kInvalidArgument);
}

TEST_F(BrokenFilesTest, PolygonsAreTriangulatedAndIsolatedVerticesKept) {
  MeshDiagnostics d;
  auto mesh = LoadMesh(
      Write("quad.obj", "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nv 5 5 5\nf 1 2 3 4\n"), {}, &d);
  ASSERT_OK(mesh);
  EXPECT_EQ(mesh->num_faces(), 2u);
  EXPECT_EQ(d.polygons_triangulated, 1u);
  EXPECT_EQ(d.isolated_vertices, 1u);
  EXPECT_TRUE(mesh->is_isolated(4));
}

TEST_F(BrokenFilesTest, AMeshWithNoFacesIsRefusedWithItsDiagnostics) {
  MeshDiagnostics d;
  auto mesh = LoadMesh(Write("points.obj", "v 0 0 0\nv 1 0 0\n"), {}, &d);
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(mesh.status().message()), HasSubstr("no faces"));
  EXPECT_EQ(d.vertices, 2u);
  EXPECT_EQ(d.faces, 0u);
  EXPECT_THAT(d.mesh_error, HasSubstr("no faces"));
}

TEST(MeshBuildTest, SameDirectionEdgeNamesTheFirstClashInFaceOrder) {
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {0, -1, 0},
                    {1, 1, 1}, {2, 0, 0}, {2, 1, 0}, {3, 0, 0}};
  // Faces 0 and 1 share edge (0, 1) properly; face 2 walks (0, 1) again in
  // face 0's direction, face 4 walks (5, 6) in face 3's direction.
  soup.triangles = {{0, 1, 2}, {1, 0, 3}, {0, 1, 4}, {5, 6, 7}, {5, 6, 2}};
  auto mesh = Mesh::Build(soup, "clash");
  ASSERT_FALSE(mesh.ok());
  EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(std::string(mesh.status().message()),
              HasSubstr("edge (0, 1) is used in the same direction by faces 0 and 2"));
  // Consistent orientation: twins pair up and edge ids follow first use.
  soup.triangles = {{0, 1, 2}, {1, 0, 3}, {5, 6, 7}, {6, 5, 4}};
  auto good = Mesh::Build(soup, "good");
  ASSERT_OK(good);
  EXPECT_EQ(good->num_edges(), 10u);
  for (HalfedgeId h = 0; h < 12; ++h) {
    const HalfedgeId t = good->twin(h);
    if (t == kNone) continue;
    EXPECT_EQ(good->twin(t), h);
    EXPECT_EQ(good->tail(t), good->head(h));
    EXPECT_EQ(good->edge(t), good->edge(h));
  }
  EXPECT_EQ(good->twin(0), 3u);  // (0 -> 1) and (1 -> 0)
  EXPECT_EQ(good->edge(0), 0u);
  EXPECT_EQ(good->edge(1), 1u);
  EXPECT_EQ(good->edge(3), 0u);
}

TEST_F(BrokenFilesTest, UploadedBytesLoadLikeFiles) {
  const std::string tri = "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  auto soup = ReadTriangleSoupFromMemory(tri, "off", "upload");
  ASSERT_OK(soup);
  EXPECT_EQ(soup->positions.size(), 3u);
  EXPECT_EQ(ReadTriangleSoupFromMemory(tri, "exe", "upload").status().code(),
            absl::StatusCode::kInvalidArgument);
}

TEST(SurfacePointTest, ParseValidateCanonicalize) {
  Mesh grid = testing::PlanarGrid(3, 3, 1.0);
  auto v = ParseSurfacePointSpec("v:5");
  ASSERT_OK(v);
  EXPECT_EQ(v->point.kind, SurfacePoint::Kind::kVertex);
  auto f = ParseSurfacePointSpec("f:2:0.2,0.3,0.5");
  ASSERT_OK(f);
  EXPECT_EQ(f->point.id, 2u);
  EXPECT_DOUBLE_EQ(f->point.bary[2], 0.5);
  auto x = ParseSurfacePointSpec("xyz:1,2.5,-3");
  ASSERT_OK(x);
  EXPECT_TRUE(x->is_position);
  for (const char* bad : {"v:", "v:-1", "f:1:0.2,0.3", "q:1", "e:1", "xyz:1,2,nan", ""}) {
    EXPECT_EQ(ParseSurfacePointSpec(bad).status().code(), absl::StatusCode::kInvalidArgument)
        << bad;
  }
  EXPECT_EQ(ValidateSurfacePoint(grid, SurfacePoint::Vertex(16)).code(),
            absl::StatusCode::kOutOfRange);
  EXPECT_EQ(ValidateSurfacePoint(grid, SurfacePoint::Face(0, 0.5, 0.6, 0.1)).code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(ValidateSurfacePoint(grid, SurfacePoint::Edge(0, 1.5)).code(),
            absl::StatusCode::kInvalidArgument);
  // A face point on a corner is that vertex; on an edge, that edge point.
  SurfacePoint corner = CanonicalizeSurfacePoint(grid, SurfacePoint::Face(3, 0, 1, 0));
  EXPECT_EQ(corner.kind, SurfacePoint::Kind::kVertex);
  EXPECT_EQ(corner.id, grid.face_vertex(3, 1));
  SurfacePoint edge = CanonicalizeSurfacePoint(grid, SurfacePoint::Face(3, 0.25, 0.75, 0));
  EXPECT_EQ(edge.kind, SurfacePoint::Kind::kEdge);
  EXPECT_LT(
      Distance(PositionOf(grid, edge), PositionOf(grid, SurfacePoint::Face(3, 0.25, 0.75, 0))),
      1e-15);
}

TEST(SurfaceLocatorTest, SnapsToTheClosestPointLikeBruteForce) {
  auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(mesh);
  auto locator = SurfaceLocator::Build(*mesh);
  ASSERT_OK(locator);
  auto at_vertex = locator->Snap(mesh->position(123));
  ASSERT_OK(at_vertex);
  EXPECT_LT(Distance(PositionOf(*mesh, *at_vertex), mesh->position(123)), 1e-12);
  std::mt19937 rng(11);
  std::uniform_real_distribution<double> coord(-1, 1);
  for (int i = 0; i < 50; ++i) {
    Vec3 q{coord(rng), coord(rng), coord(rng)};
    auto snapped = locator->Snap(q);
    ASSERT_OK(snapped);
    double best = INFINITY;
    for (FaceId f = 0; f < mesh->num_faces(); ++f) {
      // Dense sampling of each face bounds the true distance from above.
      for (double a = 0; a <= 1; a += 0.25)
        for (double b = 0; a + b <= 1; b += 0.25)
          best = std::min(best,
                          Distance(q, PositionOf(*mesh, SurfacePoint::Face(f, a, b, 1 - a - b))));
    }
    EXPECT_LE(Distance(q, PositionOf(*mesh, *snapped)), best + 1e-12);
  }
}

}  // namespace
}  // namespace geodesic

namespace geodesic {
namespace {

// Found by tests/fuzz/mesh_reader_fuzzer: OpenMesh's PLY reader never
// returned on this header (an unknown line before end_header).
TEST(MeshIoTest, MalformedPlyHeadersAreRefusedNotHung) {
  const std::string body = "0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n";
  const std::string start =
      "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
      "property float z\nelement face 1\nproperty list uchar int vertex_indices\n";
  for (const std::string& header :
       {start + std::string("en\x0e\0\0\0ader\n", 10), start, "plx\n" + start.substr(4),
        // Found by the fuzzer: OpenMesh hung on a version other than 1.0.
        "ply\nformat ascii '.0" + start.substr(start.find('\n', 4)) + "end_header\n",
        // Found by the fuzzer: OpenMesh hung on a form feed inside a word.
        "ply\nformat ascii 1.0\nelement ver\f\ftex 3\n" + start.substr(start.find("property")),
        // Found by the fuzzer: OpenMesh crashed on a property before any element.
        "ply\nformat ascii 1.0\nproperty list uchar int vertex_indices\n" + start.substr(4) +
            "end_header\n"}) {
    auto soup = ReadTriangleSoupFromMemory(header + body, "ply", "bad.ply");
    ASSERT_FALSE(soup.ok());
    EXPECT_EQ(soup.status().code(), absl::StatusCode::kInvalidArgument) << soup.status();
    EXPECT_NE(soup.status().message().find("bad.ply"), std::string::npos) << soup.status();
  }
  EXPECT_TRUE(ReadTriangleSoupFromMemory(start + "end_header\n" + body, "ply", "good.ply").ok());
  // And OpenMesh's OFF reader read vertices without end when the counts
  // line was garbled.
  auto off = ReadTriangleSoupFromMemory(
      "OFF\n555555555555555555555\xff\x14 4 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "off", "bad.off");
  ASSERT_FALSE(off.ok());
  EXPECT_NE(off.status().message().find("counts"), std::string::npos) << off.status();
  // NUL bytes where the counts belong: OpenMesh looped on faces.
  auto nul =
      ReadTriangleSoupFromMemory(std::string("OFF\n\0\0\x01 \0]\n0 0 0\n", 16), "off", "nul.off");
  ASSERT_FALSE(nul.ok());
  EXPECT_NE(nul.status().message().find("counts"), std::string::npos) << nul.status();
  // A word that is two numbers to OpenMesh, the second a negative count.
  auto glued = ReadTriangleSoupFromMemory(
      "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n3 0 1 2\n3 0 2 3-3 0 3 1\n", "off", "glued.off");
  ASSERT_FALSE(glued.ok());
  EXPECT_NE(glued.status().message().find("line 8: '3-3' in the faces is not a number"),
            std::string::npos)
      << glued.status();
  // Fewer vertex lines than declared.
  auto short_list = ReadTriangleSoupFromMemory("OFF 3 1 0\n0 0 0\n1 0 0\n", "off", "short.off");
  ASSERT_FALSE(short_list.ok());
  EXPECT_NE(short_list.status().message().find("declares 3 vertices, but 2 vertex lines follow"),
            std::string::npos)
      << short_list.status();
  // An edge count past int: OpenMesh's stream failed and it looped.
  auto edges = ReadTriangleSoupFromMemory(
      "OFF 3\n3   " + std::string(40, '2') + " 1 \n0 0 0\n1 0 0\n0 1 0\n", "off", "edges.off");
  ASSERT_FALSE(edges.ok());
  EXPECT_NE(edges.status().message().find("counts"), std::string::npos) << edges.status();
  // Garbage containing "OFF" where the counts belong: OpenMesh read it as
  // a vertex count of 555555555.
  auto keyword = ReadTriangleSoupFromMemory(
      "OFF\xff\n555555555%OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "off", "kw.off");
  ASSERT_FALSE(keyword.ok());
  EXPECT_NE(keyword.status().message().find("counts"), std::string::npos) << keyword.status();
  // A face whose corner count is garbled (the fuzzer's had 355555555).
  auto corners = ReadTriangleSoupFromMemory(
      "OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n100000 0 1 2\n", "off", "corners.off");
  ASSERT_FALSE(corners.ok());
  EXPECT_NE(
      corners.status().message().find("line 7: a face with 100000 corners, but the file has 4"),
      std::string::npos)
      << corners.status();
  // Or negative, which OpenMesh reads as about 2^32 (found by the fuzzer).
  auto negative = ReadTriangleSoupFromMemory("OFF\n4 1 0\n0 0 0\n1 0 0\n0 1 0\n0 0 1\n-3 0 1 2\n",
                                             "off", "negative.off");
  ASSERT_FALSE(negative.ok());
  EXPECT_NE(negative.status().message().find("line 7: a face with -3 corners"), std::string::npos)
      << negative.status();
}

// Found by the fuzzer in CI: OpenMesh's OBJ reader aborts on an assertion
// when a corner has no vertex index.
TEST(MeshIoTest, MalformedObjFaceCornersAreRefused) {
  const std::string vertices = "v 0 0 0\nv 1 0 0\nv 0 1 0\nvt 0 0\nvn 0 0 1\n";
  for (const char* face :
       {"f /1 2 3", "f 1 2 3 # comment", "f 1 2 x3", "f 1/1/1/1 2 3", "f 99999999999 2 3"}) {
    auto soup = ReadTriangleSoupFromMemory(vertices + face + "\n", "obj", "bad.obj");
    ASSERT_FALSE(soup.ok()) << face;
    EXPECT_EQ(soup.status().code(), absl::StatusCode::kInvalidArgument) << soup.status();
    EXPECT_NE(soup.status().message().find("bad.obj line 6: face corner"), std::string::npos)
        << soup.status();
  }
  for (const char* face : {"f 1 2 3", "f 1/1 2/1 3/1", "f 1//1 2//1 3//1", "f 1/1/1 2/1/1 3/1/1",
                           "f -3 -2 -1", "f 1 2 3 \r"}) {
    auto soup = ReadTriangleSoupFromMemory(vertices + face + "\n", "obj", "good.obj");
    ASSERT_TRUE(soup.ok()) << face << ": " << soup.status();
    EXPECT_EQ(soup->triangles.size(), 1u) << face;
  }
}

// OFF comments ('#' to the end of a line) anywhere: the same mesh as without
// them. OpenMesh alone failed on a comment after the header, with a
// different message on each run, and loaded a comment among the vertices as
// wrong faces without a word.
TEST(MeshIoTest, OffCommentsAnywhereReadAsWithoutThem) {
  const std::string plain = "OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n";
  auto want = ReadTriangleSoupFromMemory(plain, "off", "plain.off");
  ASSERT_OK(want);
  for (const char* text :
       {"OFF\n# a comment\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n3 1 3 2\n",
        "OFF # keyword\n4 2 0 # counts\n# vertices\n0 0 0\n1 0 0 # second\n0 1 0\n1 1 "
        "0\n#faces\n3 0 1 2\n3 1 3 2 # last\n# end",
        "# made by hand\nOFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n\n3 1 3 2\n"}) {
    for (int run = 0; run < 3; ++run) {  // once failed differently on each run
      auto got = ReadTriangleSoupFromMemory(text, "off", "commented.off");
      ASSERT_TRUE(got.ok()) << text << ": " << got.status();
      EXPECT_EQ(got->positions.size(), want->positions.size()) << text;
      for (size_t v = 0; v < want->positions.size(); ++v) {
        EXPECT_EQ(Distance(got->positions[v], want->positions[v]), 0) << text << " vertex " << v;
      }
      EXPECT_EQ(got->triangles, want->triangles) << text;
    }
  }
}

// Found by tests/fuzz/mesh_reader_fuzzer: garbage after the counts on the
// header's line ran OpenMesh out of memory (the face check reads only the
// lines after the header), and a variant's faces went unchecked, so a
// garbled corner count there did the same. A keyword with anything but
// [ST][C][N][4][n] before "OFF" is not OFF.
TEST(MeshIoTest, OffHeadersAndVariantFacesAreCheckedBeforeOpenMeshReadsThem) {
  const std::string garbage_after_counts(
      "OFF 0  2  0 \x1d\0\0@\x01\x08\0\0 2 3\x02"
      "2\n",
      27);
  auto refused = ReadTriangleSoupFromMemory(garbage_after_counts, "off", "garbage.off");
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find(
                "garbage.off line 1: '\\x1d\\x00\\x00@\\x01\\x08\\x00\\x00' after the OFF "
                "header's vertex, face and edge counts"),
            std::string::npos)
      << refused.status();
  const std::string noff_vertices = "0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n";
  auto variant = ReadTriangleSoupFromMemory("NOFF\n3 1 0\n" + noff_vertices + "-3 0 1 2\n", "off",
                                            "variant.off");
  ASSERT_FALSE(variant.ok());
  EXPECT_NE(variant.status().message().find("variant.off line 6: a face with -3 corners"),
            std::string::npos)
      << variant.status();
  auto good = ReadTriangleSoupFromMemory("NOFF\n3 1 0\n" + noff_vertices + "3 0 1 2\n", "off",
                                         "variant.off");
  ASSERT_TRUE(good.ok()) << good.status();
  EXPECT_EQ(good->triangles.size(), 1u);
  auto keyword = ReadTriangleSoupFromMemory("\x01OFF 3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "off",
                                            "keyword.off");
  EXPECT_FALSE(keyword.ok());
}

// The radix sort of edge uses gives exactly what std::sort gives the same
// pairs, for small and for 32-bit vertex counts.
TEST(MeshIoTest, SortEdgeUsesMatchesSortingThePairs) {
  std::mt19937 rng(5);
  for (uint64_t nv :
       {uint64_t{1}, uint64_t{2}, uint64_t{7}, uint64_t{3000}, uint64_t{4000000000}}) {
    std::vector<std::pair<uint64_t, uint32_t>> uses;
    for (uint32_t i = 0; i < 5000; ++i) {
      const VertexId a = rng() % nv, b = rng() % std::min<uint64_t>(nv, 40);
      uses.push_back({UndirectedEdgeKey(a, b), i});
    }
    auto expected = uses;
    std::sort(expected.begin(), expected.end());
    SortEdgeUses(uses, nv);
    EXPECT_EQ(uses, expected) << nv << " vertices";
  }
}

}  // namespace
}  // namespace geodesic
