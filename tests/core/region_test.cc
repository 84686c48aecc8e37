// Regions of a mesh (core/mesh/region.h): extraction, the maps back to the
// parent, and geodesics on a region that must stay inside it.
#include "core/mesh/region.h"

#include <algorithm>
#include <cmath>

#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;

// A 2 x 1 grid of squares: vertices 0 1 2 / 3 4 5, four triangles.
Mesh TwoSquares() { return testing::PlanarGrid(2, 1, 1.0); }

TEST(RegionTest, VertexMaskKeepsFacesWithAllThreeVertices) {
  const Mesh parent = TwoSquares();
  ASSERT_EQ(parent.num_vertices(), 6u);
  ASSERT_EQ(parent.num_faces(), 4u);
  // Dropping a corner loses the faces that use it (the middle vertices
  // would leave two squares touching at a vertex, or nothing).
  for (VertexId dropped : {0u, 2u, 3u, 5u}) {
    std::vector<uint32_t> mask;
    for (VertexId v = 0; v < 6; ++v) {
      if (v != dropped) mask.push_back(v);
    }
    auto region = ExtractRegion(parent, RegionMask::kVertices, mask, "test");
    ASSERT_OK(region);
    for (FaceId f = 0; f < parent.num_faces(); ++f) {
      const bool uses = parent.face_vertex(f, 0) == dropped ||
                        parent.face_vertex(f, 1) == dropped || parent.face_vertex(f, 2) == dropped;
      EXPECT_EQ(region->region_face[f] == kNone, uses) << "dropped " << dropped << " face " << f;
    }
    EXPECT_EQ(region->mesh->num_faces(), region->parent_face.size());
    EXPECT_EQ(region->region_vertex[dropped], kNone);
  }
}

TEST(RegionTest, RenumbersInParentOrderAndMapsBothWays) {
  const Mesh parent = TwoSquares();
  // The right square's two faces, listed backwards and once twice.
  std::vector<uint32_t> faces;
  for (FaceId f = 0; f < parent.num_faces(); ++f) {
    const bool right = parent.position(parent.face_vertex(f, 0)).x +
                           parent.position(parent.face_vertex(f, 1)).x +
                           parent.position(parent.face_vertex(f, 2)).x >
                       3.0;
    if (right) faces.insert(faces.begin(), f);
  }
  ASSERT_EQ(faces.size(), 2u);
  faces.push_back(faces.front());
  auto region = ExtractRegion(parent, RegionMask::kFaces, faces, "test");
  ASSERT_OK(region);
  ASSERT_EQ(region->mesh->num_vertices(), 4u);
  ASSERT_EQ(region->mesh->num_faces(), 2u);
  EXPECT_TRUE(std::is_sorted(region->parent_vertex.begin(), region->parent_vertex.end()));
  EXPECT_TRUE(std::is_sorted(region->parent_face.begin(), region->parent_face.end()));
  for (VertexId v = 0; v < region->mesh->num_vertices(); ++v) {
    const VertexId p = region->parent_vertex[v];
    EXPECT_EQ(region->region_vertex[p], v);
    EXPECT_EQ(region->mesh->position(v), parent.position(p));
  }
  for (FaceId f = 0; f < region->mesh->num_faces(); ++f) {
    const FaceId p = region->parent_face[f];
    EXPECT_EQ(region->region_face[p], f);
    for (int k = 0; k < 3; ++k) {
      EXPECT_EQ(region->parent_vertex[region->mesh->face_vertex(f, k)], parent.face_vertex(p, k));
    }
  }
  // Another mesh: a graph built for the parent must not open on it.
  EXPECT_NE(MeshFingerprint(*region->mesh), MeshFingerprint(parent));
}

TEST(RegionTest, ScattersIntoParentIdsWithAFill) {
  const Mesh parent = TwoSquares();
  auto region = ExtractRegion(parent, RegionMask::kVertices, {1, 2, 4, 5}, "test");
  ASSERT_OK(region);
  ASSERT_EQ(region->parent_vertex, (std::vector<VertexId>{1, 2, 4, 5}));
  const std::vector<double> inf =
      ScatterToParent(*region, absl::Span<const double>({10, 20, 40, 50}));
  ASSERT_EQ(inf.size(), 6u);
  EXPECT_EQ(inf, (std::vector<double>{kInfinity, 10, 20, kInfinity, 40, 50}));
  const std::vector<double> nan = ScatterToParent<double>(*region, {10, 20, 40, 50}, std::nan(""));
  ASSERT_EQ(nan.size(), 6u);
  EXPECT_TRUE(std::isnan(nan[0]) && std::isnan(nan[3]));
  EXPECT_EQ(nan[5], 50);
}

TEST(RegionTest, MapsParentPointsIntoTheRegion) {
  const Mesh parent = TwoSquares();
  auto region = ExtractRegion(parent, RegionMask::kVertices, {1, 2, 4, 5}, "test");
  ASSERT_OK(region);
  auto v = PointInRegion(parent, *region, SurfacePoint::Vertex(4));
  ASSERT_OK(v);
  EXPECT_EQ(v->id, 2u);
  auto out = PointInRegion(parent, *region, SurfacePoint::Vertex(3));
  EXPECT_EQ(out.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_THAT(out.status().message(), HasSubstr("v:3"));
  // Every parent point on a kept face lands at the same position, edges
  // whichever way the region runs them.
  for (FaceId f = 0; f < parent.num_faces(); ++f) {
    const SurfacePoint face = SurfacePoint::Face(f, 0.2, 0.3, 0.5);
    auto mapped = PointInRegion(parent, *region, face);
    if (region->region_face[f] == kNone) {
      EXPECT_FALSE(mapped.ok());
      continue;
    }
    ASSERT_OK(mapped);
    EXPECT_LT(Distance(PositionOf(*region->mesh, *mapped), PositionOf(parent, face)), 1e-15);
  }
  size_t edges_inside = 0;
  for (EdgeId e = 0; e < parent.num_edges(); ++e) {
    const SurfacePoint edge = SurfacePoint::Edge(e, 0.25);
    auto mapped = PointInRegion(parent, *region, edge);
    if (!mapped.ok()) continue;
    ++edges_inside;
    EXPECT_LT(Distance(PositionOf(*region->mesh, *mapped), PositionOf(parent, edge)), 1e-15);
  }
  EXPECT_EQ(edges_inside, region->mesh->num_edges());
}

TEST(RegionTest, RefusesBadMasksNamingTheProblem) {
  const Mesh parent = TwoSquares();
  auto vertex = ExtractRegion(parent, RegionMask::kVertices, {0, 9}, "mask.txt");
  EXPECT_EQ(vertex.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_THAT(vertex.status().message(), HasSubstr("mask.txt: vertex id 9"));
  EXPECT_THAT(vertex.status().message(), HasSubstr("6 vertices"));
  auto face = ExtractRegion(parent, RegionMask::kFaces, {4}, "mask.txt");
  EXPECT_EQ(face.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_THAT(face.status().message(), HasSubstr("face id 4"));
  EXPECT_THAT(face.status().message(), HasSubstr("4 faces"));
  auto none = ExtractRegion(parent, RegionMask::kFaces, {}, "mask.txt");
  EXPECT_EQ(none.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(none.status().message(), HasSubstr("empty"));
  // Two vertices share no face.
  auto no_face = ExtractRegion(parent, RegionMask::kVertices, {0, 5}, "mask.txt");
  EXPECT_EQ(no_face.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(no_face.status().message(), HasSubstr("empty"));
}

// Order and repeats never change a region: each id once, increasing, cuts
// the same mesh as the ids repeated a thousand times in reverse.
TEST(RegionTest, RepeatedIdsCutTheRegionOfTheDistinctIds) {
  const Mesh parent = testing::PlanarGrid(6, 6, 1.0);
  const std::vector<uint32_t> plain = {0, 1, 2, 3, 4, 5, 6, 7};  // a strip of four squares
  std::vector<uint32_t> repeated;
  for (int k = 0; k < 1000; ++k) repeated.insert(repeated.end(), plain.rbegin(), plain.rend());
  auto distinct = DistinctRegionIds(parent, RegionMask::kFaces, repeated, "test");
  ASSERT_OK(distinct);
  EXPECT_EQ(*distinct, plain);
  auto once = ExtractRegion(parent, RegionMask::kFaces, plain, "test");
  auto many = ExtractRegion(parent, RegionMask::kFaces, repeated, "test");
  ASSERT_OK(once);
  ASSERT_OK(many);
  EXPECT_EQ(MeshFingerprint(*many->mesh), MeshFingerprint(*once->mesh));
  EXPECT_EQ(many->parent_face, once->parent_face);
  EXPECT_EQ(many->parent_vertex, once->parent_vertex);

  auto past = DistinctRegionIds(parent, RegionMask::kVertices, {1, 49, 2, 50}, "mask.txt");
  EXPECT_EQ(past.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_THAT(past.status().message(), HasSubstr("vertex id 49"));
  EXPECT_THAT(past.status().message(), HasSubstr("49 vertices"));
}

// The maps back to the parent hold the region's ids, not a table of the
// parent's size: one face of a 250K-vertex mesh keeps a few bytes, and still
// maps (and walks) every parent id as the table did.
TEST(RegionTest, ARegionOfOneFaceOfABigMeshHoldsRegionSizedMaps) {
  const Mesh parent = testing::PlanarGrid(500, 500, 1.0);
  ASSERT_GT(parent.num_vertices(), 250'000u);
  const FaceId face = 123'456;
  auto region = ExtractRegion(parent, RegionMask::kFaces, {face}, "test");
  ASSERT_OK(region);
  EXPECT_LT(region->map_bytes(), 64u);
  EXPECT_LT(region->map_bytes() + region->mesh->memory_bytes(), 4096u);
  EXPECT_EQ(region->region_vertex.size(), parent.num_vertices());
  EXPECT_EQ(region->region_face.size(), parent.num_faces());
  EXPECT_EQ(region->region_face[face], 0u);
  EXPECT_EQ(region->region_face[face + 1], kNone);
  std::vector<VertexId> inside;
  VertexId v = 0;
  for (VertexId r : region->region_vertex) {
    if (r != kNone) {
      EXPECT_EQ(r, inside.size());
      inside.push_back(v);
    }
    EXPECT_EQ(region->region_vertex[v], r);
    ++v;
  }
  EXPECT_EQ(v, parent.num_vertices());
  EXPECT_EQ(inside, region->parent_vertex);
  EXPECT_EQ(inside.size(), 3u);
}

// The room asked for is the region's, before its mesh is built; a refusal
// refuses the region.
TEST(RegionTest, AsksForRoomWithTheRegionsCountsBeforeBuilding) {
  const Mesh parent = TwoSquares();
  std::vector<std::pair<uint64_t, uint64_t>> asked;
  auto region = ExtractRegion(parent, RegionMask::kFaces, {0, 1}, "test",
                              [&](uint64_t vertices, uint64_t faces) {
                                asked.push_back({vertices, faces});
                                return absl::OkStatus();
                              });
  ASSERT_OK(region);
  EXPECT_EQ(asked, (std::vector<std::pair<uint64_t, uint64_t>>{{4, 2}}));
  auto refused = ExtractRegion(parent, RegionMask::kFaces, {0, 1}, "test", [](uint64_t, uint64_t) {
    return absl::ResourceExhaustedError("no room");
  });
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kResourceExhausted);
}

TEST(RegionTest, RefusesARegionThatTouchesItselfAtAVertex) {
  // A 2 x 2 grid's two diagonally opposite squares meet only at the centre.
  const Mesh parent = testing::PlanarGrid(2, 2, 1.0);
  std::vector<uint32_t> faces;
  for (FaceId f = 0; f < parent.num_faces(); ++f) {
    Vec3 c =
        (parent.position(parent.face_vertex(f, 0)) + parent.position(parent.face_vertex(f, 1)) +
         parent.position(parent.face_vertex(f, 2))) *
        (1.0 / 3);
    if ((c.x < 1) == (c.y < 1)) faces.push_back(f);
  }
  ASSERT_EQ(faces.size(), 4u);
  auto region = ExtractRegion(parent, RegionMask::kFaces, faces, "test");
  EXPECT_EQ(region.status().code(), absl::StatusCode::kInvalidArgument);
  EXPECT_THAT(region.status().message(), HasSubstr("non-manifold at parent vertex 4"));
}

// Twice the area of triangle abc.
double TwiceArea(const Vec3& a, const Vec3& b, const Vec3& c) { return Norm(Cross(b - a, c - a)); }

// Whether p lies in triangle f of `mesh` (on its plane, within its sides):
// the three triangles p makes with the sides then tile it exactly.
bool InFace(const Mesh& mesh, FaceId f, const Vec3& p) {
  const Vec3 &a = mesh.position(mesh.face_vertex(f, 0)), &b = mesh.position(mesh.face_vertex(f, 1)),
             &c = mesh.position(mesh.face_vertex(f, 2));
  const double whole = TwiceArea(a, b, c);
  const double parts = TwiceArea(p, b, c) + TwiceArea(a, p, c) + TwiceArea(a, b, p);
  return parts - whole <= 1e-9 * std::max(whole, 1e-12);
}

// The bundled cow with the right half of a horizontal band through its body
// removed: from above the band to below it on the right, geodesics must go
// round by the left.
class SpotWithoutBandTest : public ::testing::Test {
 protected:
  static constexpr double kEps = 1e-2;

  void SetUp() override {
    auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
    ASSERT_OK(loaded);
    parent_ = std::make_shared<const Mesh>(*std::move(loaded));
    std::vector<uint32_t> kept;
    for (VertexId v = 0; v < parent_->num_vertices(); ++v) {
      const Vec3& p = parent_->position(v);
      if (!(std::abs(p.y - 0.1) < 0.08 && p.x > 0)) kept.push_back(v);
    }
    ASSERT_GT(kept.size(), 0u);
    ASSERT_LT(kept.size(), parent_->num_vertices());
    auto region = ExtractRegion(*parent_, RegionMask::kVertices, kept, "spot without band");
    ASSERT_OK(region);
    region_ = *std::move(region);
    region_mesh_ = region_.mesh;
    DggBuildOptions options;
    options.params.epsilon = kEps;
    auto parent_graph = BuildDgg(*parent_, options);
    ASSERT_OK(parent_graph);
    auto region_graph = BuildDgg(*region_mesh_, options);
    ASSERT_OK(region_graph);
    parent_engine_ = std::make_unique<GeodesicEngine>(parent_, *parent_graph);
    region_engine_ = std::make_unique<GeodesicEngine>(region_mesh_, *region_graph);
  }

  // The region vertex nearest to `target` among those with x > 0.
  VertexId NearestRight(const Vec3& target) const {
    VertexId best = kNone;
    double best_distance = kInfinity;
    for (VertexId v = 0; v < region_mesh_->num_vertices(); ++v) {
      const Vec3& p = region_mesh_->position(v);
      const double d = Distance(p, target);
      if (p.x > 0 && d < best_distance) best = v, best_distance = d;
    }
    return best;
  }

  std::shared_ptr<const Mesh> parent_, region_mesh_;
  Region region_;
  std::unique_ptr<GeodesicEngine> parent_engine_, region_engine_;
};

TEST_F(SpotWithoutBandTest, RegionDistancesAreNeverShorter) {
  ASSERT_NE(region_engine_, nullptr);
  const VertexId above = NearestRight({0.3, 0.3, 0.1}), below = NearestRight({0.3, -0.1, 0.1});
  ASSERT_NE(above, kNone);
  ASSERT_NE(below, kNone);
  size_t compared = 0, longer = 0;
  for (VertexId source : {above, below}) {
    const SurfacePoint in_region = SurfacePoint::Vertex(source);
    const SurfacePoint in_parent = SurfacePoint::Vertex(region_.parent_vertex[source]);
    auto r = region_engine_->Field({&in_region, 1}, FieldOptions{});
    auto p = parent_engine_->Field({&in_parent, 1}, FieldOptions{});
    ASSERT_OK(r);
    ASSERT_OK(p);
    ASSERT_EQ(r->distance.size(), region_mesh_->num_vertices());
    ASSERT_EQ(p->distance.size(), parent_->num_vertices());
    for (VertexId v = 0; v < region_mesh_->num_vertices(); ++v) {
      const double dr = r->distance[v], dp = p->distance[region_.parent_vertex[v]];
      ASSERT_TRUE(std::isfinite(dr)) << "region vertex " << v << " unreached";
      ASSERT_TRUE(std::isfinite(dp)) << "parent vertex " << region_.parent_vertex[v];
      // Graph distances are within (1 + eps) of exact ones, and the exact
      // distance in the region is at least the parent's.
      EXPECT_GE(dr * (1 + kEps), dp) << "region vertex " << v;
      ++compared;
      longer += dr > 1.2 * dp;
    }
  }
  EXPECT_EQ(compared, 2 * region_mesh_->num_vertices());
  EXPECT_GT(longer, 0u) << "the band forced no detour";
}

TEST_F(SpotWithoutBandTest, RegionPathsStayInside) {
  ASSERT_NE(region_engine_, nullptr);
  const VertexId above = NearestRight({0.3, 0.3, 0.1}), below = NearestRight({0.3, -0.1, 0.1});
  ASSERT_NE(above, kNone);
  ASSERT_NE(below, kNone);
  PairOptions options;
  options.want_path = true;
  auto pair =
      region_engine_->Distance(SurfacePoint::Vertex(above), SurfacePoint::Vertex(below), options);
  ASSERT_OK(pair);
  auto direct =
      parent_engine_->Distance(SurfacePoint::Vertex(region_.parent_vertex[above]),
                               SurfacePoint::Vertex(region_.parent_vertex[below]), options);
  ASSERT_OK(direct);
  ASSERT_TRUE(std::isfinite(pair->distance));
  ASSERT_TRUE(std::isfinite(direct->distance));
  EXPECT_GT(pair->distance, 1.2 * direct->distance) << "this pair was chosen to need a detour";
  ASSERT_TRUE(pair->path.has_value());
  const std::vector<PathPoint>& points = pair->path->points;
  ASSERT_GE(points.size(), 2u);
  const std::vector<FaceId>& kept = region_.parent_face;
  // Whether a segment lies in one kept face of the parent: checked on
  // positions alone, not on the region's own ids.
  auto segment_inside = [&](const Vec3& a, const Vec3& b) {
    return std::any_of(kept.begin(), kept.end(),
                       [&](FaceId f) { return InFace(*parent_, f, a) && InFace(*parent_, f, b); });
  };
  for (size_t i = 1; i < points.size(); ++i) {
    EXPECT_TRUE(segment_inside(points[i - 1].xyz, points[i].xyz))
        << "segment " << i << " leaves the region";
  }
  // The check can fail: the whole mesh's path crosses the band.
  ASSERT_TRUE(direct->path.has_value());
  const std::vector<PathPoint>& across = direct->path->points;
  ASSERT_GE(across.size(), 2u);
  bool leaves = false;
  for (size_t i = 1; i < across.size(); ++i) {
    leaves |= !segment_inside(across[i - 1].xyz, across[i].xyz);
  }
  EXPECT_TRUE(leaves) << "the whole mesh's path stays out of the band too";
}

}  // namespace
}  // namespace geodesic
