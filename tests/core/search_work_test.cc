// The work the query searches do on the bundled mesh, pinned: a change that
// makes a search relax more edges, queue more nodes or read more of the
// graph fails here, even where the clock on a shared machine cannot tell.
// The counts are deterministic (a single-threaded build, fixed queries),
// not machine-dependent; the margin is for changes that move the work a
// little on purpose, and anything beyond it must be re-pinned by hand.
#include "core/query/search_work.h"

#include <cmath>
#include <memory>
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/mesh/mesh_io.h"
#include "core/query/augmented_graph.h"
#include "core/query/build_dgg.h"
#include "core/query/field_lanes.h"
#include "core/query/geodesic_engine.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

// Each pinned count may move by this share before the test fails. A search
// that relaxed every edge of every node (FieldMethod::kDijkstra) relaxes
// several times the edges the fans let the DGG solver relax (the test
// checks that this margin tells the two apart), and any change that doubles
// a search's work is far outside it.
constexpr double kWorkMargin = 0.15;
constexpr double kWorkEpsilon = 1e-3;

// Counts on data/spot.obj (2930 vertices) with its DGG built at epsilon
// 1e-3 on one thread, for the queries below, summed over each group.
// Re-pin from the values a failure prints (see ExpectPinned).
// Four fields (FieldSources) by the DGG label-correcting solver.
constexpr SearchWork kFieldsWork = {
    .relaxed = 38362, .improved = 18368, .pushes = 18368, .pops = 12264, .graph_bytes = 810016};
// One field from FieldSources()[0] by Dijkstra's rule: every edge of the
// graph's 287246, some nodes twice (the bucket queue takes a node out again
// when it improves after), 45 times the 6774 the DGG solver relaxed from
// that source; a solver that lost its fans would fail far past the margin.
constexpr SearchWork kDijkstraFieldWork = {
    .relaxed = 305069, .improved = 13319, .pushes = 13319, .pops = 3118, .graph_bytes = 4930992};
// Four point-to-point pairs (bidirectional A*, straight-line bounds).
constexpr SearchWork kPairsWork = {
    .relaxed = 8217, .improved = 4450, .pushes = 2780, .pops = 1395, .graph_bytes = 153792};
// One matrix sweep of kFieldLanes sources, by the x86 kernels (AVX2 and
// AVX-512 alike). The portable kernel (other machines, and the TSan build)
// covers a node's lanes' fans another way and relaxed 248 edges fewer
// (48102): inside the margin, so one pin serves every kernel.
constexpr SearchWork kLanesWork = {
    .relaxed = 48350, .improved = 74701, .pushes = 18188, .pops = 3652, .graph_bytes = 832032};

std::string FormatWork(const SearchWork& w) {
  return absl::StrFormat(
      "{.relaxed = %u, .improved = %u, .pushes = %u, .pops = %u, .graph_bytes = %u}", w.relaxed,
      w.improved, w.pushes, w.pops, w.graph_bytes);
}

// Every count is non-zero and within kWorkMargin of its pinned value.
void ExpectPinned(const char* name, const SearchWork& measured, const SearchWork& pinned) {
  const std::pair<const char*, std::pair<uint64_t, uint64_t>> counts[] = {
      {"relaxed", {measured.relaxed, pinned.relaxed}},
      {"improved", {measured.improved, pinned.improved}},
      {"pushes", {measured.pushes, pinned.pushes}},
      {"pops", {measured.pops, pinned.pops}},
      {"graph_bytes", {measured.graph_bytes, pinned.graph_bytes}},
  };
  bool within = true;
  for (const auto& [what, values] : counts) {
    const auto [got, want] = values;
    EXPECT_GT(got, 0u) << name << ": no " << what << " counted";
    const double off = std::abs(double(got) - double(want));
    if (off > kWorkMargin * double(want)) {
      within = false;
      ADD_FAILURE() << name << ": " << what << " " << got << ", pinned " << want << " (off by "
                    << (want ? 100 * off / double(want) : 100.0) << "%, more than "
                    << 100 * kWorkMargin << "%)";
    }
  }
  if (!within) {
    ADD_FAILURE() << name << " measured " << FormatWork(measured) << "\n"
                  << "If the change in work is intended, re-pin: copy the measured value into "
                     "the constant for "
                  << name
                  << " in tests/core/search_work_test.cc (from build/bin/core_tests "
                     "--gtest_filter='SearchWorkTest.*'), and say why in the commit.";
  }
}

class SearchWorkTest : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    auto loaded = LoadMesh(testing::SourcePath("data/spot.obj"));
    ASSERT_OK(loaded);
    mesh_ = new std::shared_ptr<const Mesh>(std::make_shared<const Mesh>(*std::move(loaded)));
    DggBuildOptions options;
    options.params.epsilon = kWorkEpsilon;
    // One thread: the counts are of one graph, whatever the machine (two
    // threads built the same graph when these were pinned).
    options.threads = 1;
    auto graph = BuildDgg(**mesh_, options);
    ASSERT_OK(graph);
    graph_ = new std::shared_ptr<const DggGraph>(*std::move(graph));
  }
  static void TearDownTestSuite() {
    delete mesh_;
    delete graph_;
    mesh_ = nullptr;
    graph_ = nullptr;
  }
  void SetUp() override {
    ASSERT_NE(graph_, nullptr);
    ASSERT_EQ((*mesh_)->num_vertices(), 2930u) << "the pinned counts are of the bundled spot";
  }

  const Mesh& mesh() const { return **mesh_; }
  const DggGraph& graph() const { return **graph_; }
  GeodesicEngine Engine() const { return GeodesicEngine(*mesh_, *graph_); }

  // Fixed sources spread over the mesh: vertices and points inside faces.
  static std::vector<SurfacePoint> FieldSources() {
    return {SurfacePoint::Vertex(0), SurfacePoint::Vertex(1234), SurfacePoint::Vertex(2900),
            SurfacePoint::Face(777, 0.2, 0.3, 0.5)};
  }

  static std::shared_ptr<const Mesh>* mesh_;
  static std::shared_ptr<const DggGraph>* graph_;
};

std::shared_ptr<const Mesh>* SearchWorkTest::mesh_ = nullptr;
std::shared_ptr<const DggGraph>* SearchWorkTest::graph_ = nullptr;

// A field reaches every vertex of spot (one component) at a finite distance.
void ExpectWholeField(const FieldResult& field, uint32_t vertices) {
  ASSERT_EQ(field.distance.size(), vertices);
  for (double d : field.distance) ASSERT_TRUE(std::isfinite(d));
}

TEST_F(SearchWorkTest, FieldsDoThePinnedWork) {
  const GeodesicEngine engine = Engine();
  SearchWork work;
  for (const SurfacePoint& source : FieldSources()) {
    auto field = engine.Field({&source, 1}, FieldOptions{});
    ASSERT_OK(field);
    ExpectWholeField(*field, mesh().num_vertices());
    EXPECT_EQ(field->work.relaxed, field->relaxed);
    work += field->work;
  }
  ExpectPinned("kFieldsWork", work, kFieldsWork);

  // Dijkstra's rule from the first source: every edge of every node.
  FieldOptions every_edge;
  every_edge.method = FieldMethod::kDijkstra;
  const SurfacePoint source = FieldSources()[0];
  auto dijkstra = engine.Field({&source, 1}, every_edge);
  ASSERT_OK(dijkstra);
  ExpectWholeField(*dijkstra, mesh().num_vertices());
  ExpectPinned("kDijkstraFieldWork", dijkstra->work, kDijkstraFieldWork);
  // That margin would catch the DGG solver turning into this one.
  auto fans = engine.Field({&source, 1}, FieldOptions{});
  ASSERT_OK(fans);
  EXPECT_GT(double(dijkstra->work.relaxed), (1 + 2 * kWorkMargin) * double(fans->work.relaxed));
  EXPECT_GT(double(dijkstra->work.graph_bytes),
            (1 + 2 * kWorkMargin) * double(fans->work.graph_bytes));
}

TEST_F(SearchWorkTest, PointToPointPairsDoThePinnedWork) {
  const GeodesicEngine engine = Engine();
  // Vertex to vertex, vertex to face point, face point to face point and
  // back to a vertex, across the mesh and nearby. A* with straight-line
  // bounds only: no landmarks are prepared.
  const std::pair<SurfacePoint, SurfacePoint> pairs[] = {
      {SurfacePoint::Vertex(0), SurfacePoint::Vertex(2900)},
      {SurfacePoint::Vertex(1234), SurfacePoint::Face(3000, 0.6, 0.2, 0.2)},
      {SurfacePoint::Face(777, 0.2, 0.3, 0.5), SurfacePoint::Face(5500, 0.1, 0.1, 0.8)},
      {SurfacePoint::Face(42, 0.3, 0.3, 0.4), SurfacePoint::Vertex(17)},
  };
  SearchWork work;
  for (const auto& [a, b] : pairs) {
    auto pair = engine.Distance(a, b, PairOptions{});
    ASSERT_OK(pair);
    EXPECT_TRUE(std::isfinite(pair->distance) && pair->distance > 0)
        << FormatSurfacePoint(a) << " to " << FormatSurfacePoint(b) << ": " << pair->distance;
    EXPECT_EQ(pair->work.relaxed, pair->relaxed);
    EXPECT_EQ(pair->work.pushes, pair->queued);
    work += pair->work;
  }
  ExpectPinned("kPairsWork", work, kPairsWork);
}

TEST_F(SearchWorkTest, AMatrixSweepDoesThePinnedWork) {
  const DggGraph& g = graph();
  QueryScratch sc;
  // A matrix's rows from kFieldLanes sources close together, as a matrix
  // groups them, one of them inside a face.
  std::vector<query_internal::Endpoint> sources;
  for (uint32_t k = 0; k + 1 < kFieldLanes; ++k) {
    const SurfacePoint p = SurfacePoint::Vertex(g.vertex_of_node(1000 + k));
    auto end = query_internal::JoinToGraph(mesh(), g, sc, p, false);
    ASSERT_OK(end);
    sources.push_back(*std::move(end));
  }
  auto face =
      query_internal::JoinToGraph(mesh(), g, sc, SurfacePoint::Face(777, 0.2, 0.3, 0.5), false);
  ASSERT_OK(face);
  sources.push_back(*std::move(face));
  auto sweep = [&](query_internal::LaneKernel kernel) -> SearchWork {
    auto stats = query_internal::SolveFieldLanes(g, BucketShapeOf(g), LaneFanLayoutFor(g), nullptr,
                                                 sc, sources, kInfinity, nullptr, kernel);
    EXPECT_OK(stats);
    if (!stats.ok()) return {};
    EXPECT_EQ(stats->work.relaxed, stats->relaxed);
    EXPECT_EQ(stats->work.pops, stats->queue_pops);
    for (uint32_t u = 0; u < g.num_nodes(); ++u) {
      for (int k = 0; k < kFieldLanes; ++k) {
        EXPECT_TRUE(std::isfinite(sc.lane_dist[u].dist[k])) << "node " << u << " lane " << k;
      }
    }
    return stats->work;
  };
  ExpectPinned("kLanesWork (portable kernel)", sweep(query_internal::LaneKernel::kPortable),
               kLanesWork);
  if (!query_internal::LaneKernelRuns(query_internal::LaneKernel::kAvx2)) return;
  const SearchWork avx2 = sweep(query_internal::LaneKernel::kAvx2);
  ExpectPinned("kLanesWork (AVX2 kernel)", avx2, kLanesWork);
  if (!query_internal::LaneKernelRuns(query_internal::LaneKernel::kAvx512)) return;
  EXPECT_EQ(FormatWork(sweep(query_internal::LaneKernel::kAvx512)), FormatWork(avx2))
      << "the x86 kernels cover fans alike, so they do the same work";
}

}  // namespace
}  // namespace geodesic
