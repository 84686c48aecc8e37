// Numbers are scale-free or refused: the bundled mesh scaled across the
// usable range answers the unscaled distances times the factor (exact to
// 1e-9, the graph within its bound), and scaled past it is refused at
// Mesh::Build, naming the measure and the range.
#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "core/mesh/mesh.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "gmock/gmock.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;

TriangleSoup ScaledSpotSoup(double factor) {
  auto soup = ReadTriangleSoup(testing::SourcePath("data/spot.obj"));
  EXPECT_TRUE(soup.ok()) << soup.status();
  for (Vec3& p : soup->positions) p = {p.x * factor, p.y * factor, p.z * factor};
  return *std::move(soup);
}

struct ScaledAnswers {
  std::vector<double> exact, graph;
};

constexpr double kScaleTestEpsilon = 1e-2;

// Exact and graph distances of a fixed spread of vertex pairs, on the graph
// at `epsilon`, with pseudo vertices if asked.
ScaledAnswers MeasureScaledSpot(double factor, bool pseudo = false,
                                double epsilon = kScaleTestEpsilon) {
  auto mesh = Mesh::Build(ScaledSpotSoup(factor), "spot.obj");
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  auto shared = std::make_shared<const Mesh>(*std::move(mesh));
  DggBuildOptions options;
  options.params.epsilon = epsilon;
  options.params.pseudo_vertices = pseudo;
  auto graph = BuildDgg(*shared, options);
  EXPECT_TRUE(graph.ok()) << graph.status();
  GeodesicEngine engine(shared, *graph);
  ScaledAnswers out;
  const VertexId n = static_cast<VertexId>(shared->num_vertices());
  PairOptions exact;
  exact.exact = true;
  for (VertexId i = 0; i < 6; ++i) {
    const SurfacePoint a = SurfacePoint::Vertex(i * 7 % n);
    const SurfacePoint b = SurfacePoint::Vertex((i * 977 + n / 2) % n);
    auto e = engine.Distance(a, b, exact);
    auto g = engine.Distance(a, b, PairOptions());
    EXPECT_TRUE(e.ok() && g.ok());
    out.exact.push_back(e.ok() ? e->distance : NAN);
    out.graph.push_back(g.ok() ? g->distance : NAN);
  }
  return out;
}

TEST(MeshScaleTest, AnswersScaleWithTheMeshAcrossTheUsableRange) {
  const ScaledAnswers unit = MeasureScaledSpot(1);
  for (double factor : {1e-20, 1e-6, 1e6, 1e20}) {
    const ScaledAnswers scaled = MeasureScaledSpot(factor);
    for (size_t i = 0; i < unit.exact.size(); ++i) {
      const double want = unit.exact[i] * factor;
      ASSERT_GT(unit.exact[i], 0);
      EXPECT_NEAR(scaled.exact[i], want, 1e-9 * want) << "pair " << i << " at " << factor;
      // The graph's bound: never below the exact distance, at most epsilon
      // (and float32 rounding) above it.
      EXPECT_GE(scaled.graph[i], scaled.exact[i] * (1 - 1e-9)) << "pair " << i << " at " << factor;
      EXPECT_LE(scaled.graph[i], scaled.exact[i] * (1 + 1.5 * kScaleTestEpsilon))
          << "pair " << i << " at " << factor;
      EXPECT_NEAR(scaled.graph[i], unit.graph[i] * factor, 1e-5 * unit.graph[i] * factor)
          << "pair " << i << " at " << factor;
    }
  }
}

// Pseudo vertices come from geodesics shot across faces, whose steps are
// lengths in the mesh's units too.
TEST(MeshScaleTest, PseudoVertexGraphsScaleWithTheMeshToo) {
  // A coarse graph: the pseudo vertices' build is the slow part, and its
  // steps scale or not whatever epsilon is.
  constexpr double kEpsilon = 0.05;
  const ScaledAnswers unit = MeasureScaledSpot(1, /*pseudo=*/true, kEpsilon);
  const double factor = 1e-20;
  const ScaledAnswers scaled = MeasureScaledSpot(factor, /*pseudo=*/true, kEpsilon);
  for (size_t i = 0; i < unit.graph.size(); ++i) {
    EXPECT_NEAR(scaled.graph[i], unit.graph[i] * factor, 1e-5 * unit.graph[i] * factor)
        << "pair " << i;
  }
}

TEST(MeshScaleTest, RefusesMeshesOutsideTheUsableRangeNamingIt) {
  for (double factor : {1e-160, 1e-50}) {
    auto mesh = Mesh::Build(ScaledSpotSoup(factor), "spot.obj");
    ASSERT_FALSE(mesh.ok()) << factor;
    EXPECT_EQ(mesh.status().code(), absl::StatusCode::kInvalidArgument);
    EXPECT_THAT(mesh.status().message(), HasSubstr("spot.obj: edge "));
    EXPECT_THAT(mesh.status().message(), HasSubstr("too short"));
    EXPECT_THAT(mesh.status().message(), HasSubstr("at least 1e-30"));
  }
  for (double factor : {1e50, 1e160}) {
    auto mesh = Mesh::Build(ScaledSpotSoup(factor), "spot.obj");
    ASSERT_FALSE(mesh.ok()) << factor;
    EXPECT_THAT(mesh.status().message(), HasSubstr("spot.obj: bounding-box diagonal"));
    EXPECT_THAT(mesh.status().message(), HasSubstr("at most 1e+30"));
  }
}

TEST(MeshScaleTest, LoadMeshRefusesTheSameWayForTheOfflineCommands) {
  // 1e35: past the range, yet within float, which the OBJ reader parses
  // positions as.
  const std::string path = ::testing::TempDir() + "/spot_1e35.obj";
  {
    std::FILE* f = std::fopen(path.c_str(), "w");
    ASSERT_NE(f, nullptr);
    const TriangleSoup soup = ScaledSpotSoup(1e35);
    for (const Vec3& p : soup.positions) std::fprintf(f, "v %.9g %.9g %.9g\n", p.x, p.y, p.z);
    for (const auto& t : soup.triangles) {
      std::fprintf(f, "f %u %u %u\n", t[0] + 1, t[1] + 1, t[2] + 1);
    }
    std::fclose(f);
  }
  auto mesh = LoadMesh(path);
  ASSERT_FALSE(mesh.ok());
  EXPECT_THAT(mesh.status().message(), HasSubstr(path));
  EXPECT_THAT(mesh.status().message(), HasSubstr("usable range"));
}

}  // namespace
}  // namespace geodesic
