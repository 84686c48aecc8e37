// Certified graphs: the certificate a build publishes holds where nobody
// measured it, from other sources on the bundled mesh and against the
// independent exact solver's fields on the shared meshes.
#include "core/query/certified_graph.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <memory>
#include <mutex>
#include <set>
#include <string>

#include "core/mesh/mesh_io.h"
#include "core/query/accuracy_check.h"
#include "core/query/geodesic_engine.h"
#include "gmock/gmock.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

std::shared_ptr<const Mesh> LoadShared(const std::string& path) {
  auto loaded = LoadMesh(path);
  EXPECT_TRUE(loaded.ok()) << loaded.status();
  return loaded.ok() ? std::make_shared<const Mesh>(*std::move(loaded)) : nullptr;
}

CertifyOptions TwoThreads() {
  CertifyOptions options;
  options.build.threads = 2;
  return options;
}

// The certificate says what was measured, and what it says holds from
// sources it did not measure: another seed's, checked the same way.
TEST(CertifiedGraphTest, BundledMeshKeepsTheBoundFromUnmeasuredSources) {
  auto mesh = LoadShared(testing::SourcePath("data/spot.obj"));
  ASSERT_NE(mesh, nullptr);
  const double bound = 1e-2;
  auto certified = BuildCertifiedGraph(mesh, bound, TwoThreads());
  ASSERT_OK(certified);
  const GraphCertificate& c = certified->certificate;
  EXPECT_EQ(c.max_error_bound, bound);
  EXPECT_EQ(c.epsilon, certified->graph->params().epsilon);
  EXPECT_LE(c.epsilon, kCertifyEpsilonFactor * bound);
  EXPECT_GT(c.measured_max_error, 0);
  EXPECT_LE(c.measured_max_error, bound / kCertifySafetyFactor);
  EXPECT_GT(c.measured_mean_error, 0);
  EXPECT_LT(c.measured_mean_error, c.measured_max_error);
  EXPECT_EQ(c.sources, 16u);
  EXPECT_EQ(c.seed, 1u + c.builds - 1);
  EXPECT_TRUE(c.sound);
  EXPECT_GE(c.builds, 1u);

  std::vector<SurfacePoint> unseen;
  const std::vector<VertexId> seen = RandomSurfaceVertices(*mesh, c.sources, c.seed);
  for (VertexId v : RandomSurfaceVertices(*mesh, 24, 9001)) {
    if (std::count(seen.begin(), seen.end(), v) == 0) unseen.push_back(SurfacePoint::Vertex(v));
  }
  ASSERT_GE(unseen.size(), 20u);
  AccuracyCheckOptions check;
  check.threads = 2;
  auto checks = CheckAgainstExact(mesh, certified->graph, unseen, check);
  ASSERT_OK(checks);
  for (const SourceCheck& s : *checks) {
    SCOPED_TRACE(FormatSurfacePoint(s.source));
    EXPECT_TRUE(s.comparison.sound());
    EXPECT_LE(s.comparison.max_error, bound);
  }
}

TEST(CertifiedGraphTest, BoundOutsideZeroOneAndNoSourcesAreRefused) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(4, 4, 1.0));
  for (double bound : {0.0, -1e-3, 1.0, 2.0, std::nan("")}) {
    auto certified = BuildCertifiedGraph(mesh, bound, TwoThreads());
    EXPECT_EQ(certified.status().code(), absl::StatusCode::kInvalidArgument) << bound;
  }
  CertifyOptions none = TwoThreads();
  none.sources = 0;
  EXPECT_EQ(BuildCertifiedGraph(mesh, 1e-2, none).status().code(),
            absl::StatusCode::kInvalidArgument);
}

// A flat grid's graph is exact up to float rounding: certified at once,
// and progress reports the build's phases and then the check up to 1.
TEST(CertifiedGraphTest, ProgressCoversBuildThenCheck) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(12, 12, 1.0));
  CertifyOptions options = TwoThreads();
  std::mutex mu;
  std::set<std::string> phases;
  double last_check = 0;
  options.progress = [&](uint32_t build, std::string_view phase, double fraction) {
    std::lock_guard<std::mutex> lock(mu);
    EXPECT_EQ(build, 1u);
    EXPECT_GE(fraction, 0);
    EXPECT_LE(fraction, 1);
    phases.insert(std::string(phase));
    if (phase == "check") last_check = std::max(last_check, fraction);
    return true;
  };
  auto certified = BuildCertifiedGraph(mesh, 1e-2, options);
  ASSERT_OK(certified);
  EXPECT_EQ(certified->certificate.builds, 1u);
  EXPECT_TRUE(phases.count("candidates"));
  EXPECT_TRUE(phases.count("check"));
  EXPECT_DOUBLE_EQ(last_check, 1.0);
}

TEST(CertifiedGraphTest, ProgressReturningFalseOrCancelledStops) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(12, 12, 1.0));
  CertifyOptions stop_in_check = TwoThreads();
  stop_in_check.progress = [](uint32_t, std::string_view phase, double) {
    return phase != "check";
  };
  EXPECT_EQ(BuildCertifiedGraph(mesh, 1e-2, stop_in_check).status().code(),
            absl::StatusCode::kCancelled);
  CertifyOptions cancelled = TwoThreads();
  cancelled.cancelled = [] { return true; };
  EXPECT_EQ(BuildCertifiedGraph(mesh, 1e-2, cancelled).status().code(),
            absl::StatusCode::kCancelled);
}

TEST(CertifiedGraphTest, RebuildEpsilonShrinksWithTheMissWithinLimits) {
  const double bound = 1e-3, target = bound / kCertifySafetyFactor;
  EXPECT_DOUBLE_EQ(NextCertifyEpsilon(bound, 0, 0), kCertifyEpsilonFactor * bound);
  // A near miss still shrinks by the largest step: maxima fall in steps.
  EXPECT_DOUBLE_EQ(NextCertifyEpsilon(bound, 5e-4, target * 1.01), 5e-4 * kCertifyMaxRebuildScale);
  // A larger miss shrinks in proportion, with the margin.
  EXPECT_NEAR(NextCertifyEpsilon(bound, 5e-4, target * 1.5), 5e-4 / 1.5 * kCertifyRebuildMargin,
              1e-15);
  // A far miss is not chased down to nothing.
  EXPECT_GE(NextCertifyEpsilon(bound, 5e-4, target * 100), 5e-4 / 4);
}

// On real meshes, the certified graph keeps the bound against the
// independent exact solver's fields, from sources the certificate never saw.
class CertifiedOnSharedMeshesTest : public ::testing::TestWithParam<std::string> {};

TEST_P(CertifiedOnSharedMeshesTest, TruthFieldsWithinTheBound) {
  ASSERT_TRUE(testing::SharedDataAvailable());
  const std::string name = GetParam();
  auto mesh = LoadShared(testing::SharedMeshPath(name));
  ASSERT_NE(mesh, nullptr);
  const double bound = 1e-3;
  auto certified = BuildCertifiedGraph(mesh, bound, TwoThreads());
  ASSERT_OK(certified);
  EXPECT_LE(certified->certificate.measured_max_error, bound / kCertifySafetyFactor);
  GeodesicEngine engine(mesh, certified->graph);
  const VertexId n = mesh->num_vertices();
  for (VertexId s : {VertexId{0}, n / 3, 2 * n / 3}) {
    auto truth = testing::ReadF64(
        testing::SharedPath("truth/" + name + ".exact.s" + std::to_string(s) + ".f64"));
    ASSERT_EQ(truth.size(), n);
    const SurfacePoint source = SurfacePoint::Vertex(s);
    auto field = engine.Field(absl::MakeConstSpan(&source, 1), {});
    ASSERT_OK(field);
    double worst = 0;
    for (VertexId v = 0; v < n; ++v) {
      if (!std::isfinite(truth[v]) || truth[v] == 0) continue;
      worst = std::max(worst, (field->distance[v] - truth[v]) / truth[v]);
    }
    EXPECT_GT(worst, 0) << name << " source " << s;
    EXPECT_LE(worst, bound) << name << " source " << s;
  }
}

INSTANTIATE_TEST_SUITE_P(SharedMeshes, CertifiedOnSharedMeshesTest,
                         ::testing::Values("camelhead", "fertility"),
                         [](const auto& info) { return std::string(info.param); });

}  // namespace
}  // namespace geodesic
