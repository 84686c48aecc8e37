// The pieces that bound a build's memory: the in-place edge array, candidate
// runs that spill to disk, and merges that load one part at a time. Each
// must leave the graph exactly as the plain in-memory build makes it.
#include <atomic>
#include <cstring>
#include <mutex>
#include <thread>
#include <vector>

#include "absl/strings/str_cat.h"
#include "core/base/large_array.h"
#include "core/dgg/candidate_runs.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using ::testing::HasSubstr;
using testing::SourcePath;
using testing::TempDir;

TEST(LargeArrayTest, GrowsWithZerosAfterShrinkingAndConvertsInPlace) {
  LargeArray<DggHalfEdge> a;
  EXPECT_TRUE(a.empty());
  a.resize(3000);  // more than a page
  for (uint32_t i = 0; i < a.size(); ++i) EXPECT_EQ(a[i].to, 0u);
  for (uint32_t i = 0; i < a.size(); ++i) a[i] = {i, float(i), 1, 2};
  a.resize(10);  // the rest of the last page held data
  a.resize(3000);
  EXPECT_EQ(a[9].to, 9u);
  for (uint32_t i = 10; i < a.size(); ++i) ASSERT_EQ(a[i].to, 0u) << i;
  for (uint32_t i = 0; i < 100000; ++i) a.push_back({i, 0, 0, 0});
  EXPECT_EQ(a.size(), 103000u);
  EXPECT_EQ(a[102999].to, 99999u);
  const DggHalfEdge* before = a.data();
  LargeArray<DggEdge> b = std::move(a).TransformInPlace<DggEdge>([](const DggHalfEdge& h) {
    return DggEdge{h.to + 1, h.weight, {7, 8}};
  });
  EXPECT_TRUE(a.empty());
  EXPECT_EQ(static_cast<const void*>(b.data()), static_cast<const void*>(before));
  ASSERT_EQ(b.size(), 103000u);
  EXPECT_EQ(b[5].target, 6u);
  EXPECT_EQ(b[5].weight, 5.0f);
  EXPECT_EQ(b[102999].target, 100000u);
  EXPECT_EQ(b[102999].fan.count, 8u);
}

// Lists of a few hundred edges from many threads, against a budget of one
// byte: every sealed chunk goes to disk, and each list comes back once,
// unchanged.
TEST(CandidateRunsTest, SpillsBeyondTheBudgetAndDrainsEveryListOnce) {
  TempDir dir;
  constexpr uint32_t kSources = 4000;
  auto list_of = [](uint32_t s) {
    std::vector<DggHalfEdge> edges(s % 300);
    for (uint32_t i = 0; i < edges.size(); ++i)
      edges[i] = {s + i, float(s) * 0.5f, 0.25f, float(i)};
    return edges;
  };
  CandidateRuns runs(kSources, /*memory_budget=*/1, dir.path());
  std::atomic<int> failures{0};
  // Two plain threads, whatever the machine (and visible to TSan, which
  // cannot see inside Debian's TBB): the ~9.6 MB of lists fill several 1 MB
  // chunks per thread, so chunks are sealed and spilled.
  std::vector<std::thread> threads;
  for (uint32_t t = 0; t < 2; ++t) {
    threads.emplace_back([&, t] {
      for (uint32_t s = t; s < kSources; s += 2) {
        if (!runs.Add(s, list_of(s)).ok()) ++failures;
      }
    });
  }
  for (std::thread& thread : threads) thread.join();
  ASSERT_EQ(failures, 0);
  EXPECT_GT(runs.spilled_bytes(), 0u);
  for (uint32_t s = 0; s < kSources; ++s) ASSERT_EQ(runs.counts()[s], s % 300) << s;
  // Drain visits from several threads at once: count in atomics.
  std::vector<std::atomic<int>> seen(kSources);
  ASSERT_OK(runs.Drain([&](uint32_t s, std::span<const DggHalfEdge> edges) {
    ASSERT_LT(s, kSources);
    ++seen[s];
    const auto want = list_of(s);
    ASSERT_EQ(edges.size(), want.size()) << s;
    if (!want.empty()) {
      EXPECT_EQ(std::memcmp(edges.data(), want.data(), edges.size_bytes()), 0) << s;
    }
  }));
  for (uint32_t s = 0; s < kSources; ++s) EXPECT_EQ(seen[s], 1) << s;
}

TEST(CandidateRunsTest, ASpillDirectoryThatCannotBeWrittenIsNamed) {
  CandidateRuns runs(2, /*memory_budget=*/1, "/nonexistent/spill");
  std::vector<DggHalfEdge> big(70000, DggHalfEdge{1, 1, 0, 0});  // over a 1 MB chunk
  ASSERT_OK(runs.Add(0, big));
  const absl::Status s = runs.Add(1, big);  // seals the first: must spill
  EXPECT_FALSE(s.ok());
  EXPECT_THAT(std::string(s.message()), HasSubstr("/nonexistent/spill"));
}

// A caller keeping the spill directory within a disk budget is asked before
// every growth of the spill file, with its size in all, and told once it is
// gone; a refusal stops the runs with it, before anything is written.
TEST(CandidateRunsTest, EachSpillIsAdmittedBeforeItIsWrittenAndGivenBackOnceRead) {
  TempDir dir;
  std::vector<uint64_t> asked;
  CandidateRuns runs(3, /*memory_budget=*/1, dir.path(), [&](uint64_t bytes) {
    asked.push_back(bytes);
    return absl::OkStatus();
  });
  std::vector<DggHalfEdge> big(70000, DggHalfEdge{1, 1, 0, 0});  // over a 1 MB chunk
  for (uint32_t s = 0; s < 3; ++s) ASSERT_OK(runs.Add(s, big));  // two seals
  ASSERT_EQ(asked.size(), 2u);
  EXPECT_GT(asked[0], big.size() * sizeof(DggHalfEdge));
  EXPECT_EQ(asked[1], 2 * asked[0]);
  EXPECT_EQ(runs.spilled_bytes(), asked[1]);
  int lists = 0;
  ASSERT_OK(runs.Drain([&](uint32_t, std::span<const DggHalfEdge> edges) {
    EXPECT_EQ(edges.size(), big.size());
    ++lists;
  }));
  EXPECT_EQ(lists, 3);
  ASSERT_EQ(asked.size(), 3u);
  EXPECT_EQ(asked[2], 0u);
}

TEST(CandidateRunsTest, ARefusedSpillStopsTheRunsWithTheRefusal) {
  TempDir dir;
  CandidateRuns runs(2, /*memory_budget=*/1, dir.path(), [](uint64_t bytes) {
    return absl::ResourceExhaustedError(absl::StrCat("no room for ", bytes));
  });
  std::vector<DggHalfEdge> big(70000, DggHalfEdge{1, 1, 0, 0});
  ASSERT_OK(runs.Add(0, big));
  const absl::Status s = runs.Add(1, big);
  EXPECT_TRUE(absl::IsResourceExhausted(s)) << s;
  EXPECT_THAT(std::string(s.message()), HasSubstr("no room for"));
  EXPECT_EQ(runs.spilled_bytes(), 0u);
}

std::vector<char> Bytes(const DggGraph& g) {
  std::vector<char> out;
  auto add = [&](auto span) {
    const char* p = reinterpret_cast<const char*>(span.data());
    out.insert(out.end(), p, p + span.size_bytes());
  };
  add(g.offsets());
  add(g.edges());
  add(g.angles());
  add(g.node_of_vertex());
  return out;
}

class BuildMemoryTest : public ::testing::Test {
 protected:
  void SetUp() override {
    auto mesh = LoadMesh(SourcePath("data/spot.obj"));
    ASSERT_OK(mesh);
    mesh_ = std::make_unique<Mesh>(*std::move(mesh));
    options_.params.epsilon = 1e-3;
    options_.threads = 2;
  }
  std::unique_ptr<Mesh> mesh_;
  DggBuildOptions options_;
};

TEST_F(BuildMemoryTest, SpilledCandidatesGiveTheSameGraph) {
  auto plain = BuildDgg(*mesh_, options_);
  ASSERT_OK(plain);
  TempDir dir;
  DggBuildOptions spilling = options_;
  spilling.candidate_memory_limit = 1;
  spilling.spill_dir = dir.path();
  DggBuildStats stats;
  auto spilled = BuildDgg(*mesh_, spilling, &stats);
  ASSERT_OK(spilled);
  EXPECT_GT(stats.spilled_bytes, 0u);
  EXPECT_TRUE(Bytes(**plain) == Bytes(**spilled));
}

// The build passes its admit_spill to its runs: the spill is admitted in
// full before it is written and given back before the build ends.
TEST_F(BuildMemoryTest, ABuildAdmitsItsSpillAndGivesItBack) {
  TempDir dir;
  DggBuildOptions spilling = options_;
  spilling.candidate_memory_limit = 1;
  spilling.spill_dir = dir.path();
  std::mutex mu;
  std::vector<uint64_t> asked;
  spilling.admit_spill = [&](uint64_t bytes) {
    std::lock_guard<std::mutex> lock(mu);
    asked.push_back(bytes);
    return absl::OkStatus();
  };
  DggBuildStats stats;
  ASSERT_OK(BuildDgg(*mesh_, spilling, &stats));
  ASSERT_GE(asked.size(), 2u);
  EXPECT_EQ(asked[asked.size() - 2], stats.spilled_bytes);
  EXPECT_EQ(asked.back(), 0u);
}

TEST_F(BuildMemoryTest, PartsLoadedOneAtATimeMergeToTheSameGraph) {
  auto plain = BuildDgg(*mesh_, options_);
  ASSERT_OK(plain);
  std::vector<DggPartSource> sources;
  int loaded = 0;
  for (uint32_t i = 0; i < 3; ++i) {
    auto part = BuildDggCandidatePart(*mesh_, options_, i, 3);
    ASSERT_OK(part);
    DggCandidatePart index = *part;
    index.edges.clear();
    sources.push_back(
        {absl::StrCat("part", i), index, [&, whole = *part]() -> absl::StatusOr<DggCandidatePart> {
           ++loaded;
           return whole;
         }});
  }
  EXPECT_EQ(loaded, 0);  // the merge checks the indexes before loading any
  auto merged = MergeDggParts(*mesh_, std::move(sources), options_);
  ASSERT_OK(merged);
  EXPECT_EQ(loaded, 3);
  EXPECT_TRUE(Bytes(**plain) == Bytes(**merged));
}

TEST_F(BuildMemoryTest, APartThatChangesBeforeItIsLoadedIsRefusedByName) {
  std::vector<DggPartSource> sources;
  for (uint32_t i = 0; i < 2; ++i) {
    auto part = BuildDggCandidatePart(*mesh_, options_, i, 2);
    ASSERT_OK(part);
    DggCandidatePart index = *part;
    index.edges.clear();
    DggCandidatePart changed = *part;
    if (i == 1) {
      changed.offsets[1] += 1;  // another file took its place
      changed.edges.push_back(changed.edges.back());
    }
    sources.push_back({absl::StrCat("/parts/p", i, ".part"), index,
                       [changed]() -> absl::StatusOr<DggCandidatePart> { return changed; }});
  }
  auto merged = MergeDggParts(*mesh_, std::move(sources), options_);
  ASSERT_FALSE(merged.ok());
  EXPECT_EQ(merged.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(merged.status().message()), HasSubstr("/parts/p1.part changed"));
}

}  // namespace
}  // namespace geodesic
