#include "core/query/exact_landmarks.h"

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <set>
#include <thread>

#include "absl/synchronization/mutex.h"
#include "core/query/exact_landmarks_file.h"
#include "gmock/gmock.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using testing::MustBuild;
using testing::NoisyTorus;
using testing::PlanarGrid;
using testing::TempDir;

std::vector<VertexId> SpreadVertices(const Mesh& mesh, int count) {
  std::vector<VertexId> out;
  for (int k = 0; k < count; ++k) out.push_back(mesh.num_vertices() * k / count);
  return out;
}

// The floor is a lower bound on the exact distance to the goal at every
// vertex, for a vertex, an edge and a face goal, and it is tighter than the
// straight line on much of a curved surface (else it would buy nothing).
TEST(ExactLandmarksTest, FloorNeverExceedsTheExactDistance) {
  const Mesh mesh = NoisyTorus(48, 24, 2.0, 5);
  auto landmarks = ExactLandmarks::Compute(mesh, SpreadVertices(mesh, 6));
  ASSERT_OK(landmarks);
  EXPECT_EQ((*landmarks)->count(), 6);
  EXPECT_EQ((*landmarks)->byte_size(),
            mesh.num_vertices() * 6 * sizeof(float) + mesh.num_halfedges() * sizeof(FaceFrame));
  ASSERT_NE((*landmarks)->frames(), nullptr);
  const SurfacePoint goals[] = {SurfacePoint::Vertex(17), SurfacePoint::Edge(101, 0.3),
                                SurfacePoint::Face(257, 0.2, 0.5, 0.3)};
  ExactGeodesic exact(mesh);
  for (const SurfacePoint& goal : goals) {
    SCOPED_TRACE(FormatSurfacePoint(goal));
    auto field = exact.Distances(goal);
    ASSERT_OK(field);
    const ExactLandmarks::Floor floor = (*landmarks)->FloorFor(mesh, goal);
    const Vec3 at = PositionOf(mesh, goal);
    size_t tighter = 0;
    for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
      const double d = (*field)[v];
      ASSERT_TRUE(std::isfinite(d)) << "vertex " << v;
      const double f = floor.At(v);
      ASSERT_GE(f, 0) << "vertex " << v;
      ASSERT_LE(f, d) << "vertex " << v;
      if (f > Distance(mesh.position(v), at)) ++tighter;
    }
    EXPECT_GT(tighter, mesh.num_vertices() / 4);
  }
}

// Two pieces: the floor is +inf on the piece without the goal (no route
// exists) and finite on the goal's own, whichever piece each landmark lies
// on (six of them: the floor takes four at a time, then the rest).
TEST(ExactLandmarksTest, FloorIsInfiniteAcrossComponents) {
  const Mesh grid = PlanarGrid(6, 6, 0.1);
  TriangleSoup soup;
  for (int copy = 0; copy < 2; ++copy) {
    const VertexId base = soup.positions.size();
    for (const Vec3& p : grid.positions()) soup.positions.push_back(p + Vec3{3.0 * copy, 0, 0});
    for (FaceId f = 0; f < grid.num_faces(); ++f) {
      soup.triangles.push_back({base + grid.face_vertex(f, 0), base + grid.face_vertex(f, 1),
                                base + grid.face_vertex(f, 2)});
    }
  }
  const Mesh mesh = MustBuild(std::move(soup));
  const VertexId per_piece = grid.num_vertices();
  const std::vector<VertexId> marks = {0, per_piece + 5, 20, per_piece + 30, per_piece + 11, 33};
  auto landmarks = ExactLandmarks::Compute(mesh, marks);
  ASSERT_OK(landmarks);
  const ExactLandmarks::Floor floor = (*landmarks)->FloorFor(mesh, SurfacePoint::Vertex(3));
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
    if (v < per_piece) {
      EXPECT_TRUE(std::isfinite(floor.At(v))) << "vertex " << v;
    } else {
      EXPECT_EQ(floor.At(v), std::numeric_limits<double>::infinity()) << "vertex " << v;
    }
  }
}

// A daemon computes them on a build worker, with a build's threads: asked
// for one thread, every propagation runs on the caller's (which polls the
// cancel callback), not on every core.
TEST(ExactLandmarksTest, ComputeKeepsToTheThreadsItIsGiven) {
  const Mesh mesh = NoisyTorus(48, 24, 2.0, 5);
  absl::Mutex mu;
  std::set<std::thread::id> seen;
  auto polled = [&] {
    absl::MutexLock lock(&mu);
    seen.insert(std::this_thread::get_id());
    return false;
  };
  auto landmarks = ExactLandmarks::Compute(mesh, SpreadVertices(mesh, 16), polled, /*threads=*/1);
  ASSERT_OK(landmarks);
  EXPECT_EQ((*landmarks)->count(), 16);
  absl::MutexLock lock(&mu);
  EXPECT_THAT(seen, ::testing::ElementsAre(std::this_thread::get_id()));
}

// Landmarks written to a file come back with the same fields and slack, so
// the same bounds, and frames made again from the mesh.
TEST(ExactLandmarksFileTest, WrittenLandmarksReadBackGiveTheSameBounds) {
  const Mesh mesh = NoisyTorus(48, 24, 2.0, 5);
  auto landmarks = ExactLandmarks::Compute(mesh, SpreadVertices(mesh, 6));
  ASSERT_OK(landmarks);
  TempDir dir;
  const std::string path = dir.path() + "/g.dgg.exact-landmarks";
  ASSERT_OK(WriteExactLandmarks(**landmarks, mesh, path));
  EXPECT_EQ(std::filesystem::file_size(path), ExactLandmarksFileBytes(**landmarks));
  auto read = ReadExactLandmarks(path, mesh, 6);
  ASSERT_OK(read);
  ASSERT_EQ((*read)->fields().size(), (*landmarks)->fields().size());
  ASSERT_FALSE((*read)->fields().empty());
  EXPECT_TRUE(std::equal((*read)->fields().begin(), (*read)->fields().end(),
                         (*landmarks)->fields().begin()));
  EXPECT_EQ((*read)->slack(), (*landmarks)->slack());
  EXPECT_EQ((*read)->byte_size(), (*landmarks)->byte_size());
  const SurfacePoint goal = SurfacePoint::Face(257, 0.2, 0.5, 0.3);
  const ExactLandmarks::Floor before = (*landmarks)->FloorFor(mesh, goal);
  const ExactLandmarks::Floor after = (*read)->FloorFor(mesh, goal);
  int positive = 0;
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
    ASSERT_EQ(after.At(v), before.At(v)) << v;
    positive += before.At(v) > 0;
  }
  EXPECT_GT(positive, 0);
}

// A file for another mesh or count is refused naming what differs; a
// damaged one is DATA_LOSS; no file is NOT_FOUND (compute them then).
TEST(ExactLandmarksFileTest, ReadRefusesOtherMeshesCountsAndDamage) {
  const Mesh mesh = NoisyTorus(48, 24, 2.0, 5);
  auto landmarks = ExactLandmarks::Compute(mesh, SpreadVertices(mesh, 4));
  ASSERT_OK(landmarks);
  TempDir dir;
  const std::string path = dir.path() + "/g.dgg.exact-landmarks";
  EXPECT_EQ(ReadExactLandmarks(path, mesh, 4).status().code(), absl::StatusCode::kNotFound);
  ASSERT_OK(WriteExactLandmarks(**landmarks, mesh, path));

  const Mesh other = NoisyTorus(48, 24, 2.0, 6);
  auto wrong_mesh = ReadExactLandmarks(path, other, 4);
  EXPECT_EQ(wrong_mesh.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(wrong_mesh.status().message(),
              ::testing::AllOf(::testing::HasSubstr(path), ::testing::HasSubstr("another mesh")));
  auto wrong_count = ReadExactLandmarks(path, mesh, 8);
  EXPECT_EQ(wrong_count.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(wrong_count.status().message(), ::testing::HasSubstr("4 landmarks"));

  const uint64_t size = std::filesystem::file_size(path);
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    f.seekg(size - 3);
    const char byte = static_cast<char>(f.get());
    f.seekp(size - 3);
    f.put(static_cast<char>(byte ^ 0x55));
  }
  auto damaged = ReadExactLandmarks(path, mesh, 4);
  EXPECT_EQ(damaged.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(damaged.status().message(), ::testing::HasSubstr("checksum"));
  std::filesystem::resize_file(path, size / 2);
  EXPECT_EQ(ReadExactLandmarks(path, mesh, 4).status().code(), absl::StatusCode::kDataLoss);
}

TEST(ExactLandmarksTest, RefusesNoVerticesOrOnePastTheMeshAndStopsWhenCancelled) {
  const Mesh mesh = PlanarGrid(4, 4, 0.1);
  const std::vector<VertexId> past = {0, static_cast<VertexId>(mesh.num_vertices())};
  auto refused = ExactLandmarks::Compute(mesh, past);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_NE(refused.status().message().find(std::to_string(mesh.num_vertices())), std::string::npos)
      << refused.status();
  EXPECT_EQ(ExactLandmarks::Compute(mesh, {}).status().code(), absl::StatusCode::kInvalidArgument);
  auto cancelled = ExactLandmarks::Compute(mesh, SpreadVertices(mesh, 2), [] { return true; });
  EXPECT_EQ(cancelled.status().code(), absl::StatusCode::kCancelled);
}

}  // namespace
}  // namespace geodesic
