// Query scratch: the point-to-point hash table and the engine's pool.
#include "core/query/query_scratch.h"

#include <random>
#include <set>

#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

// Many more nodes than the records kept between queries: every record
// survives the growth, and a new query forgets them all.
TEST(PairTableTest, RecordsSurviveGrowthAndResetForgetsThem) {
  PairTable table;
  table.Reset(200000);
  std::vector<uint32_t> nodes;
  for (uint32_t i = 0; i < 20000; ++i) nodes.push_back((i * 7919) % 200000);
  for (uint32_t node : nodes) {
    bool inserted = false;
    PairTable::Record& r = table.FindOrInsert(node, &inserted);
    ASSERT_TRUE(inserted) << node;
    r.dist[0] = node * 0.5;
    r.pred[1] = node + 1;
  }
  EXPECT_EQ(table.touched(), nodes.size());
  for (uint32_t node : nodes) {
    PairTable::Record* r = table.Find(node);
    ASSERT_NE(r, nullptr) << node;
    EXPECT_EQ(r->node, node);
    EXPECT_EQ(r->dist[0], node * 0.5);
    EXPECT_EQ(r->pred[1], node + 1);
    bool inserted = true;
    EXPECT_EQ(&table.FindOrInsert(node, &inserted), r);
    EXPECT_FALSE(inserted);
  }
  EXPECT_EQ(table.Find(3), nullptr);  // 3 is no multiple of 7919 below 200000
  table.Reset(200000);
  EXPECT_EQ(table.touched(), 0u);
  for (uint32_t node : nodes) ASSERT_EQ(table.Find(node), nullptr) << node;
  // The large query's records are not kept: 4 bytes per node and a few
  // thousand records remain.
  EXPECT_LT(table.bytes(), 200000 * 4 + 5000 * sizeof(PairTable::Record));
  bool inserted = false;
  PairTable::Record& r = table.FindOrInsert(nodes[5], &inserted);
  EXPECT_TRUE(inserted);
  EXPECT_FALSE(r.done(0) || r.done(1));
}

TEST(ScratchPoolTest, LeasesAreDistinctAndIdleOnesAreKeptUpToTheLimit) {
  ScratchPool pool(1);
  {
    ScratchPool::Lease a = pool.Acquire();
    ScratchPool::Lease b = pool.Acquire();
    EXPECT_NE(&*a, &*b);
    EXPECT_EQ(pool.in_use(), 2);
    // A field without nearest sources needs no labels, and packed fans no
    // whole ones.
    a->PrepareField(1000, /*labels=*/false, LaneFanLayout::kPacked);
    EXPECT_TRUE(a->label.empty());
    EXPECT_TRUE(a->fan.empty());
    EXPECT_GE(a->fan_packed.size(), 1000u);
    a->PrepareField(1000, /*labels=*/true, LaneFanLayout::kWhole);
    b->PrepareField(1000, /*labels=*/true, LaneFanLayout::kWhole);
  }
  EXPECT_EQ(pool.in_use(), 0);
  EXPECT_EQ(pool.idle(), 1);  // the second one released was freed
  const uint64_t kept = pool.bytes();
  EXPECT_GE(kept, 1000 * (sizeof(double) + sizeof(FanRange) + sizeof(uint32_t)));
  // The kept one is reused, not a new one made.
  ScratchPool::Lease c = pool.Acquire();
  EXPECT_GE(c->dist.size(), 1000u);
  EXPECT_EQ(pool.idle(), 0);
  EXPECT_EQ(pool.bytes(), kept);  // counted while in use
}

// The engine's scratch is counted, and a pair query's stays near what it
// touches rather than growing with the graph.
TEST(ScratchPoolTest, EngineScratchIsCountedAndPairsStaySmall) {
  auto mesh = std::make_shared<const Mesh>(testing::PlanarGrid(120, 120, 0.1));
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  GeodesicEngine pairs_only(mesh, *graph);
  ASSERT_OK(pairs_only.Distance(SurfacePoint::Vertex(0), SurfacePoint::Vertex(300), {}));
  // No field arrays: 4 bytes per node and the records a query touches.
  EXPECT_LT(pairs_only.scratch_bytes(), mesh->num_vertices() * 4u + 300 * 1024u);
  EXPECT_GT(pairs_only.scratch_bytes(), 0u);
  // A face point joins the graph by exact propagation: the engine's
  // per-vertex state (distances, angles, provenance: over 40 bytes a vertex)
  // is counted as it is, not estimated.
  const SurfacePoint inside = SurfacePoint::Face(100, 0.2, 0.3, 0.5);
  ASSERT_OK(pairs_only.Distance(inside, SurfacePoint::Vertex(300), {}));
  EXPECT_GE(pairs_only.scratch_bytes(), mesh->num_vertices() * 40u);
  GeodesicEngine fields(mesh, *graph);
  const SurfacePoint source = SurfacePoint::Vertex(7);
  ASSERT_OK(fields.Field(absl::MakeConstSpan(&source, 1), {}));
  // A label and a packed fan per node (this graph's nodes have fewer than
  // 2^16 edges); each node's nearest source only when asked.
  const uint64_t plain = fields.scratch_bytes();
  EXPECT_GE(plain, mesh->num_vertices() * 12u);
  FieldOptions nearest;
  nearest.nearest_source = true;
  ASSERT_OK(fields.Field(absl::MakeConstSpan(&source, 1), nearest));
  EXPECT_GE(fields.scratch_bytes(), plain + mesh->num_vertices() * 4u);
}

}  // namespace
}  // namespace geodesic
