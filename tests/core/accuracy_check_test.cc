// The accuracy check: each broken inequality is counted where it happens,
// errors are measured as the DGG contract states them, and a real graph on
// real meshes passes with the contract's margins.
#include "core/query/accuracy_check.h"

#include <algorithm>
#include <cmath>
#include <memory>
#include <set>

#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "gmock/gmock.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

// A flat grid's exact field from a vertex is the straight line.
struct FlatField {
  std::shared_ptr<const Mesh> mesh = std::make_shared<const Mesh>(testing::PlanarGrid(6, 5, 1.0));
  SurfacePoint source = SurfacePoint::Vertex(8);
  std::vector<double> exact;
  FlatField() {
    for (VertexId v = 0; v < mesh->num_vertices(); ++v) {
      exact.push_back(Distance(mesh->position(source.id), mesh->position(v)));
    }
  }
};

TEST(CompareFieldsTest, MeasuresRelativeErrorsOverReachedVertices) {
  FlatField f;
  std::vector<double> graph = f.exact;
  graph[3] *= 1.02;  // the worst
  graph[20] *= 1.01;
  const FieldComparison c = CompareFields(*f.mesh, f.source, f.exact, graph);
  EXPECT_TRUE(c.sound());
  EXPECT_EQ(c.compared, f.mesh->num_vertices() - 1);  // all but the source
  EXPECT_NEAR(c.max_error, 0.02, 1e-12);
  EXPECT_EQ(c.worst_vertex, 3u);
  EXPECT_EQ(c.min_error, 0);
  EXPECT_NEAR(c.mean_error, 0.03 / c.compared, 1e-12);
}

TEST(CompareFieldsTest, CountsEveryBrokenInequality) {
  FlatField f;
  std::vector<double> exact = f.exact, graph = f.exact;
  graph[5] *= 0.999;  // a graph distance below the exact one
  graph[7] *= 0.5;
  exact[11] = kInfinity;  // only the graph reaches it
  graph[12] = kInfinity;  // only the exact engine reaches it
  exact[14] *= 0.9;       // shorter than the straight line (graph stays above)
  graph[f.source.id] = 1e-9;
  const FieldComparison c = CompareFields(*f.mesh, f.source, exact, graph);
  EXPECT_FALSE(c.sound());
  EXPECT_EQ(c.below_exact, 2u);
  EXPECT_EQ(c.first_below_exact, 5u);
  EXPECT_EQ(c.exact_unreached, 1u);
  EXPECT_EQ(c.graph_unreached, 1u);
  EXPECT_EQ(c.below_straight, 1u);
  EXPECT_TRUE(c.source_nonzero);
  // Rounding alone is not a violation.
  graph = f.exact;
  graph[5] *= 1 - kCheckRoundingSlack / 2;
  EXPECT_TRUE(CompareFields(*f.mesh, f.source, f.exact, graph).sound());
}

TEST(CompareFieldsTest, BothUnreachedIsAnotherComponentNotAnError) {
  FlatField f;
  std::vector<double> exact = f.exact, graph = f.exact;
  exact[9] = graph[9] = kInfinity;
  const FieldComparison c = CompareFields(*f.mesh, f.source, exact, graph);
  EXPECT_TRUE(c.sound());
  EXPECT_EQ(c.compared, f.mesh->num_vertices() - 2);
}

TEST(RandomSurfaceVerticesTest, DistinctSeededAndOnFaces) {
  // Two triangles and an isolated vertex (3), which is never drawn.
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {0, 1, 0}, {5, 5, 5}, {1, 1, 0}};
  soup.triangles = {{0, 1, 2}, {1, 4, 2}};
  const Mesh mesh = testing::MustBuild(soup);
  for (uint64_t seed : {1u, 2u, 3u}) {
    const std::vector<VertexId> drawn = RandomSurfaceVertices(mesh, 10, seed);
    EXPECT_EQ(drawn.size(), 4u);
    EXPECT_EQ(std::set<VertexId>(drawn.begin(), drawn.end()).size(), 4u);
    EXPECT_EQ(std::count(drawn.begin(), drawn.end(), 3u), 0);
  }
  const Mesh grid = testing::PlanarGrid(20, 20, 1.0);
  EXPECT_EQ(RandomSurfaceVertices(grid, 5, 7), RandomSurfaceVertices(grid, 5, 7));
  EXPECT_NE(RandomSurfaceVertices(grid, 5, 7), RandomSurfaceVertices(grid, 5, 8));
  EXPECT_TRUE(RandomSurfaceVertices(grid, 0, 7).empty());
}

// A graph built at 1e-2 on the bundled sample mesh, from vertices, an edge
// point and a face point: sound, and within the contract (mean <= 0.3 eps,
// max <= 1.5 eps) with room to spare on the mean.
TEST(CheckAgainstExactTest, BundledMeshIsSoundAndWithinContract) {
  auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(loaded);
  auto mesh = std::make_shared<const Mesh>(std::move(loaded).value());
  DggBuildOptions build;
  build.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, build);
  ASSERT_OK(graph);
  std::vector<SurfacePoint> sources;
  for (VertexId v : RandomSurfaceVertices(*mesh, 3, 1)) sources.push_back(SurfacePoint::Vertex(v));
  sources.push_back(SurfacePoint::Edge(5, 0.25));
  sources.push_back(SurfacePoint::Face(10, 0.2, 0.3, 0.5));
  AccuracyCheckOptions options;
  options.threads = 2;
  auto checks = CheckAgainstExact(mesh, *graph, sources, options);
  ASSERT_OK(checks);
  ASSERT_EQ(checks->size(), sources.size());
  for (const SourceCheck& c : *checks) {
    SCOPED_TRACE(FormatSurfacePoint(c.source));
    EXPECT_TRUE(c.comparison.sound());
    EXPECT_GE(c.comparison.compared, mesh->num_vertices() - 1);
    EXPECT_GT(c.comparison.max_error, 0);
    EXPECT_LE(c.comparison.max_error, 1.5e-2);
    EXPECT_LE(c.comparison.mean_error, 0.3e-2);
  }
}

// A graph whose edges are too short is caught at every vertex: one built on
// a copy of the mesh scaled by 0.9 answers about 10% short.
TEST(CheckAgainstExactTest, GraphOfAShrunkenMeshIsCaughtBelowExact) {
  const Mesh flat = testing::PlanarGrid(8, 8, 1.0);
  const Mesh shrunk = testing::PlanarGrid(8, 8, 0.9);
  DggBuildOptions build;
  build.params.epsilon = 1e-2;
  auto graph = BuildDgg(shrunk, build);
  ASSERT_OK(graph);
  auto mesh = std::make_shared<const Mesh>(flat);
  auto checks = CheckAgainstExact(mesh, *graph, {SurfacePoint::Vertex(0)});
  ASSERT_OK(checks);
  const FieldComparison& c = (*checks)[0].comparison;
  EXPECT_FALSE(c.sound());
  EXPECT_EQ(c.below_exact, c.compared);
  EXPECT_NEAR(c.min_error, -0.1, 1e-6);  // where the graph path is straight
  // Every graph distance is 0.9 of one within 1.5% of exact: -10% to -8.6%.
  EXPECT_GE(c.max_error, -0.1 - 1e-9);
  EXPECT_LE(c.max_error, -0.086);
}

TEST(CheckAgainstExactTest, BadSourceIsNamed) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(3, 3, 1.0));
  DggBuildOptions build;
  build.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, build);
  ASSERT_OK(graph);
  auto checks =
      CheckAgainstExact(mesh, *graph, {SurfacePoint::Vertex(0), SurfacePoint::Vertex(1000)});
  EXPECT_EQ(checks.status().code(), absl::StatusCode::kOutOfRange);
  EXPECT_THAT(std::string(checks.status().message()), ::testing::HasSubstr("source 1 (v:1000)"));
}

}  // namespace
}  // namespace geodesic
