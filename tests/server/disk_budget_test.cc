// The graph directory's byte budget: what goes first, and what never goes.
#include "server/store/disk_budget.h"

#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <map>

#include "absl/strings/str_cat.h"
#include "core/base/atomic_file.h"
#include "core/dgg/graph_file.h"
#include "core/mesh/mesh_snapshot.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {
namespace {

namespace fs = std::filesystem;
using ::testing::ElementsAre;
using ::testing::IsEmpty;
using ::testing::UnorderedElementsAre;

class DiskBudgetTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           absl::StrCat("disk_budget_test.", getpid(), ".",
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }

  // A file of `bytes` bytes last used `age_s` seconds ago.
  void Add(const std::string& name, size_t bytes, int age_s, FileRole role) {
    std::ofstream(dir_ / name) << std::string(bytes, 'x');
    fs::last_write_time(dir_ / name,
                        fs::file_time_type::clock::now() - std::chrono::seconds(age_s));
    roles_[name] = role;
  }
  absl::StatusOr<DiskReport> Enforce(uint64_t limit) {
    return EnforceDiskLimit(dir_, limit, [&](const std::string& name) {
      auto it = roles_.find(name);
      EXPECT_NE(it, roles_.end()) << "asked about " << name;
      return it == roles_.end() ? FileRole::kInUse : it->second;
    });
  }
  bool Exists(const std::string& name) const { return fs::exists(dir_ / name); }

  fs::path dir_;
  std::map<std::string, FileRole> roles_;
};

TEST_F(DiskBudgetTest, SpareFilesGoFirstLeastRecentlyUsedFirst) {
  Add("old-spare.dgg", 100, 300, FileRole::kSpare);
  Add("new-spare.mesh", 100, 10, FileRole::kSpare);
  Add("oldest-cataloged.dgg", 100, 900, FileRole::kCataloged);
  Add("in-use.dgg", 100, 1000, FileRole::kInUse);
  std::ofstream(dir_ / "catalog.json") << std::string(50, 'c');
  auto report = Enforce(320);  // 450 bytes: two files must go
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_EQ(report->bytes_before, 450u);
  EXPECT_THAT(report->removed, ElementsAre("old-spare.dgg", "new-spare.mesh"));
  EXPECT_EQ(report->bytes_after, 250u);
  EXPECT_FALSE(report->over_limit);
  EXPECT_TRUE(Exists("oldest-cataloged.dgg"));
  EXPECT_TRUE(Exists("in-use.dgg"));
}

// A certificate and exact landmarks are a graph's sidecars: counted, and
// removed with it.
TEST_F(DiskBudgetTest, AGraphsSidecarsGoWithItAndCountInTheTotal) {
  Add("old.dgg", 100, 300, FileRole::kSpare);
  Add("kept.dgg", 100, 10, FileRole::kSpare);
  for (const std::string graph : {"old.dgg", "kept.dgg"}) {
    std::ofstream(dir_ / (graph + ".certificate.json")) << std::string(20, 'j');
    std::ofstream(dir_ / (graph + ".exact-landmarks")) << std::string(40, 'l');
  }
  auto report = Enforce(170);  // 320 bytes: the older graph goes, and its sidecars
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_EQ(report->bytes_before, 320u);
  EXPECT_THAT(report->removed,
              ElementsAre("old.dgg", "old.dgg.certificate.json", "old.dgg.exact-landmarks"));
  EXPECT_EQ(report->bytes_after, 160u);
  EXPECT_FALSE(Exists("old.dgg.certificate.json"));
  EXPECT_FALSE(Exists("old.dgg.exact-landmarks"));
  EXPECT_TRUE(Exists("kept.dgg.certificate.json"));
  EXPECT_TRUE(Exists("kept.dgg.exact-landmarks"));
}

TEST_F(DiskBudgetTest, CatalogedFilesGoOnlyWhenSpareOnesAreNotEnough) {
  Add("spare.dgg", 100, 10, FileRole::kSpare);
  Add("cataloged-old.dgg", 100, 500, FileRole::kCataloged);
  Add("cataloged-new.dgg", 100, 50, FileRole::kCataloged);
  auto report = Enforce(150);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_THAT(report->removed, ElementsAre("spare.dgg", "cataloged-old.dgg"));
  EXPECT_TRUE(Exists("cataloged-new.dgg"));
}

TEST_F(DiskBudgetTest, FilesInUseAndOtherFilesAreNeverRemoved) {
  Add("mapped.dgg", 300, 1000, FileRole::kInUse);
  Add("registered.mesh", 300, 1000, FileRole::kInUse);
  std::ofstream(dir_ / "x.dgg.tmp.1.abc") << std::string(300, 't');  // being written
  auto report = Enforce(100);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_THAT(report->removed, IsEmpty());
  EXPECT_TRUE(report->over_limit);
  EXPECT_EQ(report->bytes_after, 900u);
  EXPECT_TRUE(Exists("mapped.dgg"));
  EXPECT_TRUE(Exists("registered.mesh"));
  EXPECT_TRUE(Exists("x.dgg.tmp.1.abc"));
}

// A file that comes into use after the listing (mapped meanwhile) stays.
TEST_F(DiskBudgetTest, AFileTakenIntoUseDuringTheSweepStays) {
  Add("a.dgg", 100, 100, FileRole::kSpare);
  Add("b.dgg", 100, 50, FileRole::kSpare);
  int asked_about_a = 0;
  auto report = EnforceDiskLimit(dir_, 50, [&](const std::string& name) {
    if (name == "a.dgg" && ++asked_about_a > 1) return FileRole::kInUse;
    return FileRole::kSpare;
  });
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_THAT(report->removed, ElementsAre("b.dgg"));
  EXPECT_TRUE(Exists("a.dgg"));
  EXPECT_TRUE(report->over_limit);
}

TEST_F(DiskBudgetTest, UnderTheLimitOrNoLimitRemovesNothing) {
  Add("a.dgg", 100, 100, FileRole::kSpare);
  for (uint64_t limit : {uint64_t{0}, uint64_t{100}, uint64_t{1} << 40}) {
    auto report = Enforce(limit);
    ASSERT_TRUE(report.ok()) << report.status();
    EXPECT_THAT(report->removed, IsEmpty()) << limit;
  }
  EXPECT_TRUE(Exists("a.dgg"));
  auto bytes = DirectoryBytes(dir_);
  ASSERT_TRUE(bytes.ok());
  EXPECT_EQ(*bytes, 100u);
}

TEST_F(DiskBudgetTest, MarkFileUsedMovesAFileToTheBackOfTheLine) {
  Add("a.dgg", 100, 500, FileRole::kSpare);
  Add("b.dgg", 100, 100, FileRole::kSpare);
  MarkFileUsed(dir_ / "a.dgg");
  MarkFileUsed(dir_ / "no-such-file.dgg");  // best effort: no crash, no error
  auto report = Enforce(150);
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_THAT(report->removed, ElementsAre("b.dgg"));
}

TEST_F(DiskBudgetTest, AWriteThatWouldPassTheLimitIsRefusedNamingTheSizes) {
  Add("a.dgg", 600, 100, FileRole::kInUse);
  std::ofstream(dir_ / Catalog::kReserveFileName) << std::string(5000, 'r');  // not counted
  DiskBudget budget(dir_, 1000);
  ASSERT_TRUE(budget.Scan().ok());
  EXPECT_EQ(budget.used(), 600u);
  EXPECT_TRUE(budget.Reserve(300).ok());
  EXPECT_EQ(budget.used(), 900u);
  absl::Status refused = budget.Reserve(200);  // 600 + 300 admitted + 200 > 1000
  EXPECT_EQ(refused.code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(refused.message()),
              ::testing::AllOf(::testing::HasSubstr("200 bytes"), ::testing::HasSubstr("600"),
                               ::testing::HasSubstr("1000"), ::testing::HasSubstr("--disk-limit")));
  budget.Done(300, 0);  // that write failed: nothing on disk
  EXPECT_EQ(budget.used(), 600u);
  EXPECT_TRUE(budget.Reserve(400).ok());
  budget.Done(400, 400);
  EXPECT_EQ(budget.used(), 1000u);
  EXPECT_FALSE(budget.Reserve(1).ok());
  EXPECT_TRUE(DiskBudget(dir_, 0).Reserve(uint64_t{1} << 50).ok());  // no limit
}

TEST_F(DiskBudgetTest, AWriteEvictsWhatTheRuleAllowsBeforeItIsRefused) {
  Add("spare.dgg", 500, 100, FileRole::kSpare);
  Add("in-use.dgg", 400, 100, FileRole::kInUse);
  std::vector<uint64_t> targets;
  DiskBudget budget(dir_, 1000, [&](uint64_t target) -> absl::StatusOr<uint64_t> {
    targets.push_back(target);
    auto report = Enforce(target);
    if (!report.ok()) return report.status();
    return report->bytes_after;
  });
  ASSERT_TRUE(budget.Scan().ok());
  EXPECT_TRUE(budget.Reserve(300).ok());  // spare.dgg goes
  EXPECT_THAT(targets, ElementsAre(700u));
  EXPECT_FALSE(Exists("spare.dgg"));
  EXPECT_EQ(budget.used(), 700u);
  EXPECT_EQ(budget.Reserve(400).code(), absl::StatusCode::kResourceExhausted);  // only in use left
  EXPECT_TRUE(Exists("in-use.dgg"));
  EXPECT_EQ(budget.Reserve(2000).code(), absl::StatusCode::kResourceExhausted);  // never fits
}

TEST(TemporaryFilesTest, OnlyOldTemporariesOfAtomicWritesAreRemoved) {
  const fs::path dir = fs::temp_directory_path() / absl::StrCat("temporaries.", getpid());
  fs::remove_all(dir);
  fs::create_directories(dir);
  auto add = [&](const std::string& name, int age_s) {
    std::ofstream(dir / name) << "x";
    fs::last_write_time(dir / name, fs::file_time_type::clock::now() - std::chrono::seconds(age_s));
  };
  add("catalog.json.tmp.123.abc0", 600);
  add("0123-eps0.01-r2.dgg.tmp.77.ffffffff", 600);
  add("00aa.mesh.tmp.9.1", 600);
  add("0123-eps0.02-r2.dgg.tmp.78.beef", 10);  // a live writer's, perhaps
  add("catalog.json", 600);
  add("notes.tmp.txt", 600);
  add("x.tmp.12.xyz", 600);
  add("0123-eps0.01-r2.dgg", 600);
  EXPECT_TRUE(IsAtomicTemporaryName("a.tmp.1.f"));
  EXPECT_FALSE(IsAtomicTemporaryName(".tmp.1.f"));
  EXPECT_FALSE(IsAtomicTemporaryName("a.tmp..f"));
  auto removed = RemoveStaleTemporaries(dir, std::chrono::seconds(120));
  EXPECT_THAT(removed,
              UnorderedElementsAre("catalog.json.tmp.123.abc0",
                                   "0123-eps0.01-r2.dgg.tmp.77.ffffffff", "00aa.mesh.tmp.9.1"));
  for (const char* kept : {"0123-eps0.02-r2.dgg.tmp.78.beef", "catalog.json", "notes.tmp.txt",
                           "x.tmp.12.xyz", "0123-eps0.01-r2.dgg"}) {
    EXPECT_TRUE(fs::exists(dir / kept)) << kept;
  }
  fs::remove_all(dir);
}

// The daemon's rule (serve --disk-limit) on a catalog with a mesh from a
// path, an uploaded one and graphs (one certified), against the files
// actually there.
class GraphDirRuleTest : public DiskBudgetTest {
 protected:
  void SetUp() override {
    DiskBudgetTest::SetUp();
    DggParams params;
    params.epsilon = 1e-2;
    state_.meshes = {{"scan", "scan.obj", "obj", 1, 10, false},
                     {"sent", "upload", "ply", 2, 20, false}};
    state_.graphs = {{"scan", params}, {"scan", params, 1e-2}, {"unloaded", params}};
    files_ = FilesOf(state_);
    scan_graph_ = GraphFileName(10, params);
    scan_certified_ = CachedGraphFileName(10, params, 1e-2);
  }
  FileRole Role(const std::string& name, bool in_use = false) {
    return GraphDirFileRole(dir_, name, files_, in_use, kGrace);
  }

  static constexpr std::chrono::seconds kGrace{120};
  CatalogState state_;
  CatalogFiles files_;
  std::string scan_graph_, scan_certified_;
};

TEST_F(GraphDirRuleTest, TheCatalogNamesSnapshotsAndGraphsAndUploadsApart) {
  EXPECT_THAT(files_.catalogued, UnorderedElementsAre(MeshSnapshotName(1), MeshSnapshotName(2),
                                                      scan_graph_, scan_certified_));
  EXPECT_THAT(files_.uploads, ElementsAre(MeshSnapshotName(2)));
}

TEST_F(GraphDirRuleTest, UploadsRecentFilesAndFilesInUseAreNeverRemoved) {
  Add(MeshSnapshotName(1), 100, 900, FileRole::kCataloged);
  Add(MeshSnapshotName(2), 100, 900, FileRole::kInUse);  // an upload: the only copy
  Add(scan_graph_, 100, 800, FileRole::kCataloged);
  Add("mapped.dgg", 100, 900, FileRole::kInUse);
  Add("from-a-replica.dgg", 100, 30, FileRole::kInUse);  // younger than the grace
  Add("forgotten.dgg", 100, 700, FileRole::kSpare);
  for (const auto& [name, role] : roles_) {
    EXPECT_EQ(Role(name, name == "mapped.dgg"), role) << name;
  }
  EXPECT_EQ(Role("vanished.dgg"), FileRole::kInUse);  // no time to go by

  auto report = EnforceDiskLimit(
      dir_, 1, [&](const std::string& name) { return Role(name, name == "mapped.dgg"); });
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_THAT(report->removed, ElementsAre("forgotten.dgg", MeshSnapshotName(1), scan_graph_));
  EXPECT_TRUE(report->over_limit);
  EXPECT_TRUE(Exists(MeshSnapshotName(2)));
  EXPECT_TRUE(Exists("mapped.dgg"));
  EXPECT_TRUE(Exists("from-a-replica.dgg"));
}

// The grace is for files the catalog does not know yet: a graph it names is
// another user's finished graph, however young, and gives way like any other
// rather than fail the build that needs its room.
TEST_F(GraphDirRuleTest, AYoungGraphTheCatalogNamesIsRemovedWhenNotInUse) {
  Add(scan_graph_, 100, 5, FileRole::kCataloged);
  Add(MeshSnapshotName(1), 100, 5, FileRole::kCataloged);
  Add("from-a-replica.dgg", 100, 5, FileRole::kInUse);
  for (const auto& [name, role] : roles_) EXPECT_EQ(Role(name), role) << name;

  auto report = EnforceDiskLimit(dir_, 150, [&](const std::string& name) { return Role(name); });
  ASSERT_TRUE(report.ok()) << report.status();
  EXPECT_EQ(report->removed.size(), 2u);
  EXPECT_FALSE(report->over_limit);
  EXPECT_TRUE(Exists("from-a-replica.dgg"));
}

}  // namespace
}  // namespace geodesic::server
