// The rules that keep a daemon in step with the shared catalog, with fake
// hooks standing for the registry and the graph cache.
#include "server/store/catalog_sync.h"

#include <unistd.h>

#include <filesystem>
#include <fstream>
#include <mutex>
#include <set>
#include <thread>

#include "absl/strings/str_cat.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::HasSubstr;
using ::testing::IsEmpty;
using ::testing::Not;
using ::testing::Pair;

// What one daemon holds, as the hooks change it.
struct FakeDaemon {
  std::map<std::string, uint64_t> meshes;              // name -> fingerprint
  std::set<std::pair<std::string, double>> graphs;     // mesh, epsilon
  std::set<std::pair<std::string, double>> certified;  // mesh, max_error
  std::set<std::string> unrestorable;
  int restores = 0;

  CatalogSync::Hooks Hooks() {
    return {
        .restore_mesh =
            [this](const CatalogMesh& m) {
              ++restores;
              if (unrestorable.contains(m.name)) return absl::DataLossError("snapshot damaged");
              if (!m.parent.empty() && !meshes.contains(m.parent)) {
                return absl::NotFoundError("no mesh named '" + m.parent + "'");
              }
              meshes[m.name] = m.fingerprint;
              return absl::OkStatus();
            },
        .drop_mesh =
            [this](const std::string& name) {
              meshes.erase(name);
              std::erase_if(graphs, [&](const auto& g) { return g.first == name; });
            },
        .request_graph =
            [this](const std::string& mesh, const DggParams& p, double max_error) {
              if (max_error > 0) {
                certified.insert({mesh, max_error});
              } else {
                graphs.insert({mesh, p.epsilon});
              }
            },
        .cancel_graph =
            [this](const std::string& mesh, const DggParams& p, double max_error) {
              if (max_error > 0) {
                certified.erase({mesh, max_error});
              } else {
                graphs.erase({mesh, p.epsilon});
              }
            },
    };
  }
};

CatalogMesh MeshNamed(const std::string& name, uint64_t fingerprint = 7) {
  return {name, "upload", "obj", 42, fingerprint, false};
}

CatalogMesh RegionNamed(const std::string& name, const std::string& parent) {
  CatalogMesh m{name, "region", "region", 0, 11, false};
  m.parent = parent;
  m.region_ids = {0, 1, 2};
  return m;
}

DggParams ParamsAt(double e) {
  DggParams p;
  p.epsilon = e;
  return p;
}

class CatalogSyncTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           absl::StrCat("catalog_sync_test.", getpid(), ".",
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

// Two replicas on one directory: what one records, the other restores; what
// one forgets, the other drops.
TEST_F(CatalogSyncTest, AReplicaFollowsWhatAnotherRecords) {
  Catalog catalog_a(dir_), catalog_b(dir_);
  FakeDaemon a, b;
  CatalogSync sync_a(&catalog_a, a.Hooks()), sync_b(&catalog_b, b.Hooks());

  a.meshes["kitten"] = 7;  // registered by a client on replica a
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten")).ok());
  a.graphs.insert({"kitten", 1e-3});
  auto recorded = sync_a.RecordGraph("kitten", ParamsAt(1e-3));
  ASSERT_TRUE(recorded.ok() && *recorded) << recorded.status();
  EXPECT_EQ(a.restores, 0);  // loaded there already

  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.meshes, ElementsAre(Pair("kitten", 7u)));
  EXPECT_THAT(b.graphs, ElementsAre(Pair("kitten", 1e-3)));
  EXPECT_TRUE(sync_b.Catalogued("kitten"));
  ASSERT_TRUE(sync_b.Reconcile().ok());  // nothing new: nothing done again
  EXPECT_EQ(b.restores, 1);

  auto forgot = sync_a.ForgetGraph("kitten", ParamsAt(1e-3));
  ASSERT_TRUE(forgot.ok() && *forgot);
  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.graphs, IsEmpty());

  auto unloaded = sync_a.ForgetMesh("kitten");
  ASSERT_TRUE(unloaded.ok() && *unloaded);
  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.meshes, IsEmpty());
  EXPECT_FALSE(sync_b.Catalogued("kitten"));
}

// A restart is a new daemon on the same directory.
TEST_F(CatalogSyncTest, ARestartRestoresMeshesAndThenTheirGraphs) {
  {
    Catalog catalog(dir_);
    FakeDaemon before;
    CatalogSync sync(&catalog, before.Hooks());
    before.meshes["a"] = 1;
    before.meshes["b"] = 2;
    ASSERT_TRUE(sync.RecordMesh(MeshNamed("a", 1)).ok());
    ASSERT_TRUE(sync.RecordMesh(MeshNamed("b", 2)).ok());
    ASSERT_TRUE(sync.RecordGraph("a", ParamsAt(1e-2)).ok());
    ASSERT_TRUE(sync.RecordGraph("b", ParamsAt(1e-3)).ok());
  }
  Catalog catalog(dir_);
  FakeDaemon after;
  after.unrestorable = {"b"};
  CatalogSync sync(&catalog, after.Hooks());
  ASSERT_TRUE(sync.Reconcile().ok());
  EXPECT_THAT(after.meshes, ElementsAre(Pair("a", 1u)));
  // A graph waits for its mesh; the failure is reported and retried.
  EXPECT_THAT(after.graphs, ElementsAre(Pair("a", 1e-2)));
  EXPECT_THAT(sync.failures(), ElementsAre(Pair("b", ::testing::HasSubstr("snapshot damaged"))));
  after.unrestorable.clear();
  ASSERT_TRUE(sync.Reconcile().ok());
  EXPECT_THAT(after.meshes, ElementsAre(Pair("a", 1u), Pair("b", 2u)));
  EXPECT_THAT(after.graphs, ElementsAre(Pair("a", 1e-2), Pair("b", 1e-3)));
  EXPECT_THAT(sync.failures(), IsEmpty());
}

// A certified graph is restored certified, with its bound, and is a graph
// apart from the plain graph of its key's epsilon: forgetting one leaves
// the other.
TEST_F(CatalogSyncTest, ACertifiedGraphIsRestoredWithItsBound) {
  Catalog catalog_a(dir_);
  FakeDaemon a;
  CatalogSync sync_a(&catalog_a, a.Hooks());
  a.meshes["kitten"] = 7;
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten")).ok());
  ASSERT_TRUE(sync_a.RecordGraph("kitten", ParamsAt(4e-3)).ok());
  auto recorded = sync_a.RecordGraph("kitten", ParamsAt(4e-3), 1e-2);
  ASSERT_TRUE(recorded.ok() && *recorded) << recorded.status();

  // A restart: a new daemon on the directory.
  Catalog catalog_b(dir_);
  FakeDaemon b;
  CatalogSync sync_b(&catalog_b, b.Hooks());
  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.graphs, ElementsAre(Pair("kitten", 4e-3)));
  EXPECT_THAT(b.certified, ElementsAre(Pair("kitten", 1e-2)));

  auto forgot = sync_a.ForgetGraph("kitten", ParamsAt(4e-3), 1e-2);
  ASSERT_TRUE(forgot.ok() && *forgot);
  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.certified, IsEmpty());
  EXPECT_THAT(b.graphs, ElementsAre(Pair("kitten", 4e-3)));
}

// Queries naming what a daemon lacks reconcile only when the catalog
// changed: a mesh that failed to restore is not loaded again per query.
TEST_F(CatalogSyncTest, ReconcileIfChangedRetriesNothingUntilTheCatalogChanges) {
  Catalog catalog_a(dir_), catalog_b(dir_);
  FakeDaemon a, b;
  b.unrestorable = {"broken"};
  CatalogSync sync_a(&catalog_a, a.Hooks()), sync_b(&catalog_b, b.Hooks());
  a.meshes["broken"] = 1;
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("broken", 1)).ok());

  ASSERT_TRUE(sync_b.ReconcileIfChanged().ok());
  EXPECT_EQ(b.restores, 1);
  EXPECT_THAT(sync_b.Failure("broken"), ::testing::Optional(::testing::HasSubstr("damaged")));
  EXPECT_EQ(sync_b.Failure("other"), std::nullopt);
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sync_b.ReconcileIfChanged().ok());
  EXPECT_EQ(b.restores, 1);

  a.meshes["fine"] = 2;  // a change: applied, and the failed restore tried again
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("fine", 2)).ok());
  ASSERT_TRUE(sync_b.ReconcileIfChanged().ok());
  EXPECT_THAT(b.meshes, ElementsAre(Pair("fine", 2u)));
  EXPECT_EQ(b.restores, 3);
  ASSERT_TRUE(sync_b.Reconcile().ok());  // the follower's Reconcile always retries
  EXPECT_EQ(b.restores, 4);

  // Unloaded elsewhere: its failure is forgotten with it.
  ASSERT_TRUE(sync_a.ForgetMesh("broken").ok());
  ASSERT_TRUE(sync_b.ReconcileIfChanged().ok());
  EXPECT_EQ(sync_b.Failure("broken"), std::nullopt);
  EXPECT_THAT(sync_b.failures(), IsEmpty());
}

TEST_F(CatalogSyncTest, ANameTakenElsewhereWithOtherContentsIsRefused) {
  Catalog catalog_a(dir_), catalog_b(dir_);
  FakeDaemon a, b;
  CatalogSync sync_a(&catalog_a, a.Hooks()), sync_b(&catalog_b, b.Hooks());
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten", 7)).ok());
  absl::Status s = sync_b.RecordMesh(MeshNamed("kitten", 8));
  EXPECT_EQ(s.code(), absl::StatusCode::kAlreadyExists) << s;
  // The same contents again is fine (a client retrying on another replica).
  EXPECT_TRUE(sync_b.RecordMesh(MeshNamed("kitten", 7)).ok());
}

// A mesh replaced under the same name elsewhere is dropped and restored.
TEST_F(CatalogSyncTest, AMeshReplacedElsewhereIsRestoredAgain) {
  Catalog catalog_a(dir_), catalog_b(dir_);
  FakeDaemon a, b;
  CatalogSync sync_a(&catalog_a, a.Hooks()), sync_b(&catalog_b, b.Hooks());
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten", 7)).ok());
  ASSERT_TRUE(sync_a.RecordGraph("kitten", ParamsAt(1e-3)).ok());
  ASSERT_TRUE(sync_b.Reconcile().ok());
  ASSERT_TRUE(sync_a.ForgetMesh("kitten").ok());
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten", 9)).ok());
  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_THAT(b.meshes, ElementsAre(Pair("kitten", 9u)));
  EXPECT_THAT(b.graphs, IsEmpty());  // the old mesh's graph went with it
}

// Reconcile racing Record*: whatever order they run in, a graph just
// recorded is never cancelled by a catalog read before it was written.
TEST_F(CatalogSyncTest, ReconcileNeverUndoesAConcurrentRecord) {
  Catalog catalog(dir_);
  FakeDaemon d;
  std::mutex hooks_mu;
  CatalogSync::Hooks hooks = d.Hooks();
  auto locked = [&](auto f) {
    return [&, f](auto&&... args) {
      std::lock_guard<std::mutex> lock(hooks_mu);
      return f(args...);
    };
  };
  hooks.restore_mesh = locked(hooks.restore_mesh);
  hooks.drop_mesh = locked(hooks.drop_mesh);
  hooks.request_graph = locked(hooks.request_graph);
  int cancels = 0;
  hooks.cancel_graph = [&](const std::string&, const DggParams&, double) {
    std::lock_guard<std::mutex> lock(hooks_mu);
    ++cancels;
  };
  CatalogSync sync(&catalog, hooks);
  std::atomic<bool> done{false};
  std::thread follower([&] {
    while (!done) EXPECT_TRUE(sync.Reconcile().ok());
  });
  for (int i = 0; i < 200; ++i) {
    const std::string name = absl::StrCat("m", i % 3);
    ASSERT_TRUE(sync.RecordMesh(MeshNamed(name)).ok());
    ASSERT_TRUE(sync.RecordGraph(name, ParamsAt(1e-2)).ok());
    auto forgot = sync.ForgetMesh(name);
    ASSERT_TRUE(forgot.ok() && *forgot);
  }
  done = true;
  follower.join();
  EXPECT_EQ(cancels, 0);
}

TEST_F(CatalogSyncTest, LocalOnlyMeshesAreLeftAlone) {
  Catalog catalog(dir_);
  FakeDaemon d;
  CatalogSync sync(&catalog, d.Hooks());
  d.meshes["sample"] = 3;  // registered by serve itself, never catalogued
  ASSERT_TRUE(sync.Reconcile().ok());
  EXPECT_THAT(d.meshes, ElementsAre(Pair("sample", 3u)));
  auto graph = sync.RecordGraph("sample", ParamsAt(1e-3));
  ASSERT_TRUE(graph.ok());
  EXPECT_FALSE(*graph);
  auto forgot = sync.ForgetMesh("sample");
  ASSERT_TRUE(forgot.ok());
  EXPECT_FALSE(*forgot);
}

// The follower reconciles every few seconds: a catalog unchanged since it
// was applied is not parsed, nor applied, again, however often it is asked.
TEST_F(CatalogSyncTest, AnUnchangedCatalogIsNeitherParsedNorAppliedAgain) {
  Catalog catalog_a(dir_), catalog_b(dir_);
  FakeDaemon a, b;
  CatalogSync sync_a(&catalog_a, a.Hooks()), sync_b(&catalog_b, b.Hooks());
  a.meshes["kitten"] = 7;
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("kitten")).ok());
  ASSERT_TRUE(sync_a.RecordGraph("kitten", ParamsAt(1e-3)).ok());

  ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_EQ(catalog_b.parses(), 1u);
  for (int i = 0; i < 20; ++i) {
    ASSERT_TRUE(sync_b.Reconcile().ok());
    ASSERT_TRUE(sync_b.ReconcileIfChanged().ok());
  }
  EXPECT_EQ(catalog_b.parses(), 1u);
  EXPECT_EQ(b.restores, 1);
  EXPECT_THAT(b.graphs, ElementsAre(Pair("kitten", 1e-3)));
  // What a daemon wrote itself it need not read back.
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sync_a.Reconcile().ok());
  EXPECT_EQ(catalog_a.parses(), 0u);

  a.meshes["puppy"] = 8;  // a change: parsed once, applied once
  ASSERT_TRUE(sync_a.RecordMesh(MeshNamed("puppy", 8)).ok());
  for (int i = 0; i < 3; ++i) ASSERT_TRUE(sync_b.Reconcile().ok());
  EXPECT_EQ(catalog_b.parses(), 2u);
  EXPECT_EQ(b.restores, 2);
  EXPECT_THAT(b.meshes, ElementsAre(Pair("kitten", 7u), Pair("puppy", 8u)));
}

// A region whose parent the catalog no longer lists (an older build, an
// unload racing the region's registration elsewhere) could never be cut
// again: the restore removes it from the catalog, with a warning, instead of
// failing on it at every poll. A region of a start-up mesh stays, as does one
// whose catalogued parent failed to restore here (a failure, retried).
TEST_F(CatalogSyncTest, ARegionWhoseParentIsGoneIsRemovedFromTheCatalogWithAWarning) {
  Catalog catalog(dir_);
  ASSERT_TRUE(catalog
                  .Update([](CatalogState& s) {
                    s.PutMesh(MeshNamed("broken", 1));
                    s.PutMesh(RegionNamed("orphan", "gone"));
                    s.PutMesh(RegionNamed("lobe", "sample"));
                    s.PutMesh(RegionNamed("part", "broken"));
                    s.PutGraph({"orphan", ParamsAt(1e-3)});
                    return absl::OkStatus();
                  })
                  .ok());
  FakeDaemon d;
  d.unrestorable = {"broken"};
  d.meshes["sample"] = 3;  // registered by serve itself
  CatalogSync sync(&catalog, d.Hooks());
  sync.AddStartupMesh("sample");
  ::testing::internal::CaptureStderr();
  ASSERT_TRUE(sync.Reconcile().ok());
  const std::string log = ::testing::internal::GetCapturedStderr();
  EXPECT_THAT(log, HasSubstr("warning catalog_region_orphaned mesh=orphan parent=gone"));
  EXPECT_THAT(log, Not(HasSubstr("orphaned mesh=lobe")));
  EXPECT_THAT(log, Not(HasSubstr("orphaned mesh=part")));
  EXPECT_THAT(d.meshes, ElementsAre(Pair("lobe", 11u), Pair("sample", 3u)));
  EXPECT_THAT(sync.failures(), ElementsAre(Pair("broken", HasSubstr("damaged")),
                                           Pair("part", HasSubstr("no mesh named 'broken'"))));
  auto state = Catalog(dir_).Read();
  ASSERT_TRUE(state.ok()) << state.status();
  EXPECT_EQ(state->FindMesh("orphan"), nullptr);
  EXPECT_TRUE(state->graphs.empty());
  EXPECT_NE(state->FindMesh("lobe"), nullptr);
  EXPECT_NE(state->FindMesh("part"), nullptr);
  EXPECT_FALSE(sync.Catalogued("orphan"));

  ::testing::internal::CaptureStderr();
  ASSERT_TRUE(sync.Reconcile().ok());
  EXPECT_THAT(::testing::internal::GetCapturedStderr(), Not(HasSubstr("orphaned")));
  EXPECT_EQ(Catalog(dir_).Read()->generation, state->generation);
}

// Nor is such a region recorded: its parent was unloaded (elsewhere) after
// this daemon found it.
TEST_F(CatalogSyncTest, ARegionOfAParentNoLongerCataloguedIsNotRecorded) {
  Catalog catalog(dir_);
  FakeDaemon d;
  CatalogSync sync(&catalog, d.Hooks());
  sync.AddStartupMesh("sample");
  absl::Status s = sync.RecordMesh(RegionNamed("late", "unloaded"));
  EXPECT_EQ(s.code(), absl::StatusCode::kFailedPrecondition) << s;
  EXPECT_THAT(s.message(), HasSubstr("'unloaded'"));
  EXPECT_FALSE(sync.Catalogued("late"));
  EXPECT_TRUE(sync.RecordMesh(RegionNamed("lobe", "sample")).ok());
  ASSERT_TRUE(sync.RecordMesh(MeshNamed("kitten")).ok());
  EXPECT_TRUE(sync.RecordMesh(RegionNamed("ear", "kitten")).ok());
}

TEST_F(CatalogSyncTest, ADamagedCatalogIsAnErrorAndChangesNothing) {
  Catalog catalog(dir_);
  FakeDaemon d;
  CatalogSync sync(&catalog, d.Hooks());
  d.meshes["kitten"] = 7;
  ASSERT_TRUE(sync.RecordMesh(MeshNamed("kitten")).ok());
  std::ofstream(catalog.path()) << "{ not json";
  EXPECT_EQ(sync.Reconcile().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(d.meshes, ElementsAre(Pair("kitten", 7u)));
  EXPECT_EQ(sync.RecordMesh(MeshNamed("other")).code(), absl::StatusCode::kDataLoss);
}

}  // namespace
}  // namespace geodesic::server
