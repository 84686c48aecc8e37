#include "core/exact/geodesic_shooting.h"

#include <cmath>

#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "gtest/gtest.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

Mesh Spot() {
  auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  return *std::move(mesh);
}

// A shot's strip bounds distances to its end point from above (the pseudo
// vertices' cheap serve test relies on it): never below the exact distance,
// and equal to it from the corners of the face the shot ends in, where the
// segment is the straight line of one face.
TEST(ShotStripTest, BoundsDistancesToTheEndFromAboveAndExactlyInTheLastFace) {
  const Mesh mesh = Spot();
  ExactGeodesic engine(mesh);
  int last_face_checked = 0, across_faces_checked = 0;
  for (VertexId s : {VertexId{0}, VertexId{250}, VertexId{1200}, VertexId{2700}}) {
    for (int k = 0; k < 7; ++k) {
      const double angle = mesh.total_angle(s) * (k + 0.37) / 7;
      ShotStrip strip;
      auto end = ShootGeodesic(mesh, s, angle, 0.15, &strip);
      ASSERT_TRUE(end.ok()) << end.status();
      if (end->hit_vertex) continue;
      auto exact = engine.Distances(end->point, {});
      ASSERT_TRUE(exact.ok()) << exact.status();
      for (VertexId w : strip.Vertices(s)) {
        ASSERT_NE(w, s);
        const double bound = strip.StraightDistanceToEnd(w), truth = (*exact)[w];
        ASSERT_TRUE(std::isfinite(truth)) << "vertex " << w;
        if (!std::isfinite(bound)) continue;
        EXPECT_GE(bound, truth * (1 - 1e-12)) << "shot from " << s << " to vertex " << w;
        const bool in_last_face =
            std::find(strip.last_face.begin(), strip.last_face.end(), w) != strip.last_face.end();
        if (in_last_face) {
          EXPECT_NEAR(bound, truth, 1e-12 * truth) << "shot from " << s << " to vertex " << w;
          ++last_face_checked;
        } else {
          ++across_faces_checked;
        }
      }
    }
  }
  EXPECT_GT(last_face_checked, 20);
  EXPECT_GT(across_faces_checked, 20);
}

// Past the limit on pseudo vertices per mesh vertex the build is refused,
// giving the estimate, before the propagations of all of them are spent.
TEST(PseudoVertexLimitTest, RefusesWithTheEstimate) {
  const Mesh mesh = Spot();
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  options.params.pseudo_vertices = true;
  options.pseudo_vertex_limit = 0.1;
  DggBuildStats stats;
  auto refused = BuildDgg(mesh, options, &stats);
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition);
  for (const char* part : {"pseudo vertices at eps 0.01", "per mesh vertex", "limit of 0.1", "MB",
                           "--pseudo-vertex-limit"}) {
    EXPECT_NE(refused.status().message().find(part), std::string::npos)
        << part << " not in: " << refused.status().message();
  }
  EXPECT_GT(stats.pseudo_shots, 0u);
  EXPECT_GT(stats.pseudo_propagations, 0u);
  EXPECT_LT(stats.pseudo_propagations, stats.pseudo_shots / 4);
}

}  // namespace
}  // namespace geodesic
