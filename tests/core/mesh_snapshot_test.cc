#include "core/mesh/mesh_snapshot.h"

#include <filesystem>
#include <fstream>
#include <sstream>

#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh_io.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::ReadBytes;
using testing::SourcePath;
using testing::TempDir;
using testing::WriteBytes;

template <typename T>
bool SameBytes(const std::vector<T>& a, const std::vector<T>& b) {
  return a.size() == b.size() && std::memcmp(a.data(), b.data(), a.size() * sizeof(T)) == 0;
}

void ExpectSameArrays(const Mesh& a, const Mesh& b) {
  const Mesh::Arrays &x = a.arrays(), &y = b.arrays();
  EXPECT_TRUE(SameBytes(x.positions, y.positions));
  EXPECT_TRUE(SameBytes(x.corners, y.corners));
  EXPECT_TRUE(SameBytes(x.twin, y.twin));
  EXPECT_TRUE(SameBytes(x.edge, y.edge));
  EXPECT_TRUE(SameBytes(x.edge_halfedge, y.edge_halfedge));
  EXPECT_TRUE(SameBytes(x.length, y.length));
  EXPECT_TRUE(SameBytes(x.corner_angle, y.corner_angle));
  EXPECT_TRUE(SameBytes(x.polar_angle, y.polar_angle));
  EXPECT_TRUE(SameBytes(x.vertex_halfedge, y.vertex_halfedge));
  EXPECT_TRUE(SameBytes(x.total_angle, y.total_angle));
  EXPECT_TRUE(SameBytes(x.flags, y.flags));
}

class MeshSnapshotTest : public ::testing::Test {
 protected:
  void SetUp() override {
    source_ = SourcePath("data/spot.obj");
    auto mesh = LoadMesh(source_, {}, &diagnostics_);
    ASSERT_TRUE(mesh.ok()) << mesh.status();
    mesh_ = std::move(mesh).value();
    auto key = SourceHashOfFile(source_);
    ASSERT_TRUE(key.ok()) << key.status();
    key_ = *key;
    path_ = dir_.File(MeshSnapshotName(key_));
    ASSERT_TRUE(WriteMeshSnapshot(mesh_, diagnostics_, key_, path_).ok());
  }

  TempDir dir_;
  std::string source_, path_;
  Mesh mesh_;
  MeshDiagnostics diagnostics_;
  uint64_t key_ = 0;
};

TEST_F(MeshSnapshotTest, RestoresTheMeshAndItsDiagnosticsExactly) {
  auto restored = ReadMeshSnapshot(path_, key_);
  ASSERT_TRUE(restored.ok()) << restored.status();
  ExpectSameArrays(mesh_, restored->mesh);
  EXPECT_EQ(MeshFingerprint(restored->mesh), MeshFingerprint(mesh_));
  EXPECT_EQ(restored->fingerprint, MeshFingerprint(mesh_));
  // Everything but the per-load facts (path, time) comes back.
  MeshDiagnostics expected = diagnostics_;
  expected.path = restored->diagnostics.path;
  expected.load_seconds = restored->diagnostics.load_seconds;
  EXPECT_EQ(restored->diagnostics.ToJson(), expected.ToJson());
  EXPECT_EQ(restored->diagnostics.format, "obj");
  EXPECT_GT(restored->diagnostics.faces, 0u);
}

TEST_F(MeshSnapshotTest, KeyDependsOnBytesAndFormat) {
  const std::string bytes = ReadBytes(source_);
  EXPECT_EQ(SourceHash(bytes, "obj"), key_);
  EXPECT_NE(SourceHash(bytes, "off"), key_);
  EXPECT_NE(SourceHash(bytes + "\n", "obj"), key_);
  EXPECT_EQ(MeshSnapshotName(0x1234), "0000000000001234.mesh");
}

TEST_F(MeshSnapshotTest, RefusesOtherBytesMissingFilesAndDamage) {
  EXPECT_EQ(ReadMeshSnapshot(path_, key_ ^ 1).status().code(),
            absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(ReadMeshSnapshot(dir_.File("absent.mesh"), key_).status().code(),
            absl::StatusCode::kNotFound);

  const std::string good = ReadBytes(path_);
  const std::string damaged = dir_.File("damaged.mesh");
  // One flipped byte anywhere that matters: the header, the first array
  // (positions), the middle of the file, its last array (flags).
  for (size_t at : {size_t{20}, size_t{4096 + 7}, good.size() / 2, good.size() - 70}) {
    std::string bytes = good;
    bytes[at] ^= 0x10;
    WriteBytes(damaged, bytes);
    auto r = ReadMeshSnapshot(damaged, key_);
    EXPECT_EQ(r.status().code(), absl::StatusCode::kDataLoss)
        << "byte " << at << ": " << r.status();
    EXPECT_THAT(r.status().message(), HasSubstr(damaged));
  }
  WriteBytes(damaged, good.substr(0, good.size() - 64));
  EXPECT_EQ(ReadMeshSnapshot(damaged, key_).status().code(), absl::StatusCode::kDataLoss);
  WriteBytes(damaged, good.substr(0, 100));
  EXPECT_EQ(ReadMeshSnapshot(damaged, key_).status().code(), absl::StatusCode::kDataLoss);
  WriteBytes(damaged, std::string(8192, 'x'));
  EXPECT_THAT(ReadMeshSnapshot(damaged, key_).status().message(),
              HasSubstr("not a geodesicd mesh snapshot"));
}

TEST(MeshFromArraysTest, RefusesArraysThatWouldReadOutOfBounds) {
  const Mesh grid = testing::PlanarGrid(3, 2, 1.0);  // has boundary half-edges
  auto same = Mesh::FromArrays(grid.arrays(), "grid");
  ASSERT_TRUE(same.ok()) << same.status();
  ExpectSameArrays(grid, *same);

  auto expect_damaged = [](Mesh::Arrays a, const std::string& what) {
    auto m = Mesh::FromArrays(std::move(a), "grid");
    EXPECT_EQ(m.status().code(), absl::StatusCode::kDataLoss) << what;
    EXPECT_THAT(m.status().message(), HasSubstr("grid")) << what;
  };
  Mesh::Arrays a = grid.arrays();
  a.twin[0] = static_cast<HalfedgeId>(a.corners.size());
  expect_damaged(a, "twin out of range");
  a = grid.arrays();
  a.corners[4] = static_cast<VertexId>(a.positions.size());
  expect_damaged(a, "corner out of range");
  a = grid.arrays();
  a.edge.pop_back();
  expect_damaged(a, "short edge array");
  a = grid.arrays();
  a.edge_halfedge[0] = kNone;
  expect_damaged(a, "edge without a half-edge");
  a = grid.arrays();
  // A twin pointing at a half-edge that does not point back: in range, but
  // not a mesh.
  HalfedgeId inner = 0;
  while (a.twin[inner] == kNone) ++inner;
  a.twin[inner] = a.twin[inner] == 1 ? 2 : 1;
  expect_damaged(a, "inconsistent twins");
}

}  // namespace
}  // namespace geodesic
