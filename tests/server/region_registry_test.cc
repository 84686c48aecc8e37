// Regions in the registry (MeshRegistry::RegisterRegion): ids kept once
// each, refusals before any work, and a region's memory counted as a mesh's
// is, against --memory-limit too.
#include <cstdint>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/meshes/mesh_registry.h"

namespace geodesic::server {
namespace {

using ::testing::HasSubstr;

// An n x n grid of squares, two triangles each, as RegisterArrays takes it.
struct Grid {
  std::vector<double> vertices;
  std::vector<uint32_t> faces;
};

Grid GridOf(uint32_t n) {
  Grid g;
  for (uint32_t j = 0; j <= n; ++j) {
    for (uint32_t i = 0; i <= n; ++i) g.vertices.insert(g.vertices.end(), {1.0 * i, 1.0 * j, 0});
  }
  auto id = [n](uint32_t i, uint32_t j) { return j * (n + 1) + i; };
  for (uint32_t j = 0; j < n; ++j) {
    for (uint32_t i = 0; i < n; ++i) {
      g.faces.insert(g.faces.end(), {id(i, j), id(i + 1, j), id(i + 1, j + 1)});
      g.faces.insert(g.faces.end(), {id(i, j), id(i + 1, j + 1), id(i, j + 1)});
    }
  }
  return g;
}

class RegionRegistryTest : public ::testing::Test {
 protected:
  void Register(MeshRegistry& registry, uint32_t n) {
    const Grid grid = GridOf(n);
    auto parent = registry.RegisterArrays("grid", grid.vertices, grid.faces);
    ASSERT_TRUE(parent.ok()) << parent.status();
    parent_ = *parent;
  }
  std::shared_ptr<const RegisteredMesh> parent_;
};

// Each id a thousand times over, backwards: the region of the ids once, and
// recorded (for the catalog) once each, in increasing order.
TEST_F(RegionRegistryTest, RepeatedIdsAreKeptOnceEachInOrder) {
  MeshRegistry registry("");
  Register(registry, 100);
  std::vector<uint32_t> plain, repeated;
  for (uint32_t f = 0; f < 20; ++f) plain.push_back(f);  // a strip of ten squares
  for (int k = 0; k < 1000; ++k) repeated.insert(repeated.end(), plain.rbegin(), plain.rend());
  auto once = registry.RegisterRegion("once", "grid", RegionMask::kFaces, plain);
  ASSERT_TRUE(once.ok()) << once.status();
  auto many = registry.RegisterRegion("many", "grid", RegionMask::kFaces, repeated);
  ASSERT_TRUE(many.ok()) << many.status();
  EXPECT_EQ((*many)->fingerprint, (*once)->fingerprint);
  EXPECT_EQ((*many)->region_ids, plain);
  EXPECT_EQ((*many)->region_ids.capacity(), plain.size());
}

TEST_F(RegionRegistryTest, IdsPastTheParentOrRepeatedPastReasonAreRefusedByName) {
  MeshRegistry registry("");
  Register(registry, 10);  // 121 vertices, 200 faces
  auto past = registry.RegisterRegion("r", "grid", RegionMask::kVertices, {0, 1, 11, 12, 121});
  EXPECT_EQ(past.status().code(), absl::StatusCode::kOutOfRange) << past.status();
  EXPECT_THAT(past.status().message(), HasSubstr("vertex id 121"));
  EXPECT_THAT(past.status().message(), HasSubstr("121 vertices"));

  const std::vector<uint32_t> flood(4 * 200 + 1, 7);
  auto refused = registry.RegisterRegion("r", "grid", RegionMask::kFaces, flood);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kInvalidArgument) << refused.status();
  EXPECT_THAT(refused.status().message(), HasSubstr("801 face ids for a mesh of 200 faces"));
  EXPECT_THAT(refused.status().message(), HasSubstr("list each id once"));
  // At the bound, repeats are only work.
  const std::vector<uint32_t> bound(4 * 200, 7);
  EXPECT_TRUE(registry.RegisterRegion("r", "grid", RegionMask::kFaces, bound).ok());
}

// A region's maps and ids count in resident_bytes; they are region-sized:
// a hundred one-face regions of a 250K-vertex mesh add little more than
// their own meshes.
TEST_F(RegionRegistryTest, RegionsCountTheirMapsAndStaySmall) {
  MeshRegistry registry("");
  Register(registry, 500);
  const uint64_t parent_bytes = registry.resident_bytes();
  for (uint32_t k = 0; k < 100; ++k) {
    auto r = registry.RegisterRegion(absl::StrCat("r", k), "grid", RegionMask::kFaces, {k * 997});
    ASSERT_TRUE(r.ok()) << r.status();
    EXPECT_GT((*r)->extra_bytes(), 0u);
    EXPECT_LT((*r)->extra_bytes(), 64u);
  }
  uint64_t regions = 0;
  for (const auto& m : registry.List()) {
    if (m->region) regions += m->mesh->memory_bytes() + m->extra_bytes();
  }
  EXPECT_EQ(registry.resident_bytes(), parent_bytes + regions);
  EXPECT_LT(regions, 100u * 4096);
}

// Refused as a mesh is when it would not fit --memory-limit, before it is
// built, and named.
TEST_F(RegionRegistryTest, ARegionPastTheMemoryLimitIsRefusedNamingIt) {
  MeshRegistry registry("");
  Register(registry, 100);
  // Room for the parent and a query on it, not for a region of most of it.
  registry.SetMemoryLimit(2 * parent_->mesh->memory_bytes() + 10'000);
  std::vector<uint32_t> most;
  for (uint32_t f = 0; f < 18'000; ++f) most.push_back(f);
  auto refused = registry.RegisterRegion("big", "grid", RegionMask::kFaces, most);
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kResourceExhausted) << refused.status();
  EXPECT_THAT(refused.status().message(), HasSubstr("'big'"));
  EXPECT_THAT(refused.status().message(), HasSubstr("--memory-limit"));
  EXPECT_THAT(refused.status().message(), HasSubstr("before it is built"));
  EXPECT_FALSE(registry.Get("big").ok());
  EXPECT_TRUE(registry.RegisterRegion("small", "grid", RegionMask::kFaces, {0}).ok());
}

}  // namespace
}  // namespace geodesic::server
