// The durable catalog: round trips, refusals of damaged files, and updates
// from many threads and processes at once that lose nothing.
#include "server/store/catalog.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "absl/strings/str_cat.h"
#include "core/base/atomic_file.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"

namespace geodesic::server {
namespace {

class CatalogTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::temp_directory_path() /
           absl::StrCat("catalog_test.", getpid(), ".",
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    std::filesystem::remove_all(dir_);
    std::filesystem::create_directories(dir_);
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }
  void WriteCatalogText(const std::string& text) { std::ofstream(dir_ / "catalog.json") << text; }

  std::filesystem::path dir_;
};

CatalogMesh Kitten() {
  return {"kitten", "scans/kitten.off", "off", 0x0123456789abcdefULL, 0xfedcba9876543210ULL, true};
}

TEST_F(CatalogTest, MissingFileIsTheEmptyState) {
  Catalog catalog(dir_);
  auto state = catalog.Read();
  ASSERT_TRUE(state.ok()) << state.status();
  EXPECT_EQ(state->generation, 0u);
  EXPECT_TRUE(state->meshes.empty());
  EXPECT_TRUE(state->graphs.empty());
}

TEST_F(CatalogTest, UpdatesRoundTripEveryField) {
  Catalog catalog(dir_);
  DggParams pseudo;
  pseudo.epsilon = 1e-3;
  pseudo.pseudo_vertices = true;
  pseudo.prune_redundant = true;
  pseudo.exact_fans = true;
  pseudo.candidate_rule = 1;
  DggParams plain;
  plain.epsilon = 0.1 + 0.2;  // not a short decimal: must round-trip exactly
  auto written = catalog.Update([&](CatalogState& s) {
    s.PutMesh(Kitten());
    s.PutGraph({"kitten", pseudo});
    s.PutGraph({"kitten", plain});
    s.PutGraph({"kitten", plain});  // twice is once
    return absl::OkStatus();
  });
  ASSERT_TRUE(written.ok()) << written.status();
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->generation, 1u);
  ASSERT_EQ(read->meshes.size(), 1u);
  const CatalogMesh& m = read->meshes[0];
  EXPECT_EQ(m.name, "kitten");
  EXPECT_EQ(m.source, "scans/kitten.off");
  EXPECT_EQ(m.format, "off");
  EXPECT_EQ(m.source_hash, 0x0123456789abcdefULL);
  EXPECT_EQ(m.fingerprint, 0xfedcba9876543210ULL);
  EXPECT_TRUE(m.repair_non_manifold);
  ASSERT_EQ(read->graphs.size(), 2u);
  EXPECT_TRUE(read->HasGraph("kitten", pseudo));
  EXPECT_TRUE(read->HasGraph("kitten", plain));
  EXPECT_FALSE(read->HasGraph("kitten", DggParams{}));
  EXPECT_EQ(CatalogToJson(*read), CatalogToJson(*written));
}

// A certified graph keeps its bound, and is not the plain graph of its
// key's epsilon. A catalog holding one is format version 2; one without is
// still written as version 1, which earlier builds read.
TEST_F(CatalogTest, CertifiedGraphsRoundTripAsVersion2) {
  Catalog catalog(dir_);
  DggParams key;
  key.epsilon = 4e-3;
  key.pseudo_vertices = true;
  auto plain = catalog.Update([&](CatalogState& s) {
    s.PutMesh(Kitten());
    s.PutGraph({"kitten", key});
    return absl::OkStatus();
  });
  ASSERT_TRUE(plain.ok()) << plain.status();
  EXPECT_THAT(CatalogToJson(*plain), ::testing::HasSubstr("\"version\": 1\n"));
  EXPECT_THAT(CatalogToJson(*plain), ::testing::Not(::testing::HasSubstr("max_error")));

  auto written = catalog.Update([&](CatalogState& s) {
    s.PutGraph({"kitten", key, 1e-2});
    s.PutGraph({"kitten", key, 1e-2});  // twice is once
    return absl::OkStatus();
  });
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_THAT(CatalogToJson(*written), ::testing::HasSubstr("\"version\": 2\n"));
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_EQ(read->graphs.size(), 2u);
  EXPECT_TRUE(read->HasGraph("kitten", key));
  EXPECT_TRUE(read->HasGraph("kitten", key, 1e-2));
  EXPECT_FALSE(read->HasGraph("kitten", key, 2e-2));
  EXPECT_EQ(CatalogToJson(*read), CatalogToJson(*written));

  // Cancelled: the plain graph stays, and the catalog is version 1 again.
  auto after = catalog.Update([&](CatalogState& s) {
    EXPECT_TRUE(s.RemoveGraph("kitten", key, 1e-2));
    EXPECT_FALSE(s.RemoveGraph("kitten", key, 1e-2));
    return absl::OkStatus();
  });
  ASSERT_TRUE(after.ok()) << after.status();
  ASSERT_EQ(after->graphs.size(), 1u);
  EXPECT_EQ(after->graphs[0].max_error, 0);
  EXPECT_THAT(CatalogToJson(*after), ::testing::HasSubstr("\"version\": 1\n"));
}

// Regions are written as version 4, their ids once each in increasing
// order, as runs or as a bitmap.
TEST_F(CatalogTest, RegionsRoundTripAsVersion4) {
  Catalog catalog(dir_);
  CatalogMesh region{"cortex", "region", "region", 0, 0x1111222233334444ULL, false};
  region.parent = "kitten";
  region.region_faces = true;
  region.region_ids = {7, 3, 3, 4000000000u};
  auto written = catalog.Update([&](CatalogState& s) {
    s.PutMesh(Kitten());
    s.PutMesh(region);
    return absl::OkStatus();
  });
  ASSERT_TRUE(written.ok()) << written.status();
  const std::string text = CatalogToJson(*written);
  EXPECT_THAT(text, ::testing::HasSubstr("\"version\": 4\n"));
  EXPECT_THAT(text, ::testing::HasSubstr("\"ranges\": \"3,7,4000000000\""));
  const std::vector<uint32_t> distinct = {3, 7, 4000000000u};
  for (const CatalogState& read : {*Catalog(dir_).Read(), *written}) {
    const CatalogMesh* m = read.FindMesh("cortex");
    ASSERT_NE(m, nullptr);
    EXPECT_EQ(m->parent, "kitten");
    EXPECT_TRUE(m->region_faces);
    EXPECT_EQ(m->region_ids, distinct);
    EXPECT_EQ(m->fingerprint, region.fingerprint);
    const CatalogMesh* whole = read.FindMesh("kitten");
    ASSERT_NE(whole, nullptr);
    EXPECT_TRUE(whole->parent.empty());
    EXPECT_TRUE(whole->region_ids.empty());
    EXPECT_EQ(CatalogToJson(read), text);
  }

  // Gone: the catalog is version 1 again.
  auto after = catalog.Update([&](CatalogState& s) {
    EXPECT_TRUE(s.RemoveMesh("cortex"));
    return absl::OkStatus();
  });
  ASSERT_TRUE(after.ok()) << after.status();
  EXPECT_THAT(CatalogToJson(*after), ::testing::HasSubstr("\"version\": 1\n"));

  WriteCatalogText(R"({"format": "geodesicd-catalog", "version": 3, "generation": 1,
    "meshes": [{"name": "r", "source": "region", "format": "region",
      "source_hash": "0000000000000000", "fingerprint": "0000000000000001",
      "repair_non_manifold": false, "region": {"parent": "p", "mask": "edges", "ids": []}}],
    "graphs": []})");
  auto bad = catalog.Read();
  EXPECT_EQ(bad.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_THAT(bad.status().message(), ::testing::HasSubstr("meshes[0].region.mask"));
}

CatalogMesh RegionOf(std::vector<uint32_t> ids) {
  CatalogMesh region{"part", "region", "region", 0, 0x1111222233334444ULL, false};
  region.parent = "kitten";
  region.region_ids = std::move(ids);
  return region;
}

// The text of the one region in `text`: what its ids take in the file.
std::string RegionText(const std::string& text) {
  const size_t at = text.find("\"region\"");
  return at == std::string::npos ? "" : text.substr(at, text.find('}', at) - at);
}

// What the catalog holds of a region is about the size of its runs or of
// a bitmap of its ids, whichever is smaller, not a line per id: a million
// ids in one run take a few bytes, every other id of 200,000 a 25 KB bitmap.
TEST_F(CatalogTest, RegionIdsAreStoredCompactlyAndReadBack) {
  std::vector<uint32_t> run, alternate, scattered;
  for (uint32_t id = 0; id < 1'000'000; ++id) run.push_back(id);
  for (uint32_t id = 0; id < 200'000; id += 2) alternate.push_back(id);
  for (uint32_t id = 5; id < 40'000'000; id += 400'037) scattered.push_back(id);
  struct Case {
    std::vector<uint32_t> ids;
    const char* form;
    size_t at_most;
  };
  for (const Case& c : {Case{run, "ranges", 200}, Case{alternate, "bitmap", 34'000},
                        Case{scattered, "ranges", 1'200}, Case{{}, "ranges", 200}}) {
    CatalogState state;
    state.PutMesh(Kitten());
    state.PutMesh(RegionOf(c.ids));
    const std::string text = CatalogToJson(state);
    const std::string region = RegionText(text);
    EXPECT_THAT(region, ::testing::HasSubstr(absl::StrCat("\"", c.form, "\"")));
    EXPECT_LE(region.size(), c.at_most) << c.form << " of " << c.ids.size();
    auto read = CatalogFromJson(text, "catalog.json");
    ASSERT_TRUE(read.ok()) << read.status();
    ASSERT_NE(read->FindMesh("part"), nullptr);
    EXPECT_EQ(read->FindMesh("part")->region_ids, c.ids) << c.form << " of " << c.ids.size();
  }
}

// Version 3's list of ids, as earlier builds wrote it, still loads (once
// each, in order); written again, it is version 4.
TEST_F(CatalogTest, AVersion3RegionListStillLoads) {
  WriteCatalogText(R"({"format": "geodesicd-catalog", "version": 3, "generation": 4,
    "meshes": [{"name": "r", "source": "region", "format": "region",
      "source_hash": "0000000000000000", "fingerprint": "0000000000000001",
      "repair_non_manifold": false,
      "region": {"parent": "p", "mask": "vertices", "ids": [900, 2, 2, 500, 900]}}],
    "graphs": []})");
  Catalog catalog(dir_);
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  ASSERT_NE(read->FindMesh("r"), nullptr);
  EXPECT_EQ(read->FindMesh("r")->region_ids, (std::vector<uint32_t>{2, 500, 900}));
  EXPECT_FALSE(read->FindMesh("r")->region_faces);
  auto written = catalog.Update([](CatalogState&) { return absl::OkStatus(); });
  ASSERT_TRUE(written.ok()) << written.status();
  std::ifstream in(catalog.path());
  const std::string text(std::istreambuf_iterator<char>(in), {});
  EXPECT_THAT(text, ::testing::HasSubstr("\"version\": 4\n"));
  EXPECT_THAT(text, ::testing::HasSubstr("\"ranges\": \"2,500,900\""));
}

TEST_F(CatalogTest, DamagedRegionIdsAreRefusedByName) {
  Catalog catalog(dir_);
  const std::string head = R"({"format": "geodesicd-catalog", "version": 4, "generation": 1,
    "meshes": [{"name": "r", "source": "region", "format": "region",
      "source_hash": "0000000000000000", "fingerprint": "0000000000000001",
      "repair_non_manifold": false, "region": {"parent": "p", "mask": "faces", )";
  const std::string tail = "}}], \"graphs\": []}";
  for (const auto& [ids, says] : std::vector<std::pair<std::string, std::string>>{
           {R"("count": 2, "ranges": "5-3")", "'5-3' is not a run"},
           {R"("count": 2, "ranges": "1,1")", "'1' is not a run"},
           {R"("count": 2, "ranges": "1,x")", "'x' is not an id"},
           {R"("count": 1, "ranges": "1,")", "ends with a comma"},
           {R"("count": 1, "ranges": "99999999999")", "is not an id"},
           {R"("count": 3, "ranges": "0-9")", "more than the 3 ids of its count"},
           {R"("count": 3, "ranges": "0-1")", "lists 2 ids, not the 3 of its count"},
           {R"("count": 1, "bitmap": "%%%")", "is not base64"},
           {R"("ranges": "0-1")", "region.count is missing"},
       }) {
    WriteCatalogText(head + ids + tail);
    auto read = catalog.Read();
    EXPECT_EQ(read.status().code(), absl::StatusCode::kDataLoss) << ids << ": " << read.status();
    EXPECT_THAT(read.status().message(), ::testing::HasSubstr("meshes[0].region")) << ids;
    EXPECT_THAT(read.status().message(), ::testing::HasSubstr(says)) << ids;
  }
}

// The file is parsed again only when it changed: a follower polling an
// unchanged catalog reads a few bytes, whatever its size.
TEST_F(CatalogTest, AnUnchangedCatalogIsNotParsedAgain) {
  Catalog catalog(dir_), other(dir_);
  ASSERT_TRUE(catalog.Read().ok());  // no file: nothing to parse
  EXPECT_EQ(catalog.parses(), 0u);
  ASSERT_TRUE(catalog
                  .Update([](CatalogState& s) {
                    s.PutMesh(Kitten());
                    return absl::OkStatus();
                  })
                  .ok());
  auto first = catalog.ReadShared();
  ASSERT_TRUE(first.ok()) << first.status();
  for (int i = 0; i < 5; ++i) {
    auto again = catalog.ReadShared();
    ASSERT_TRUE(again.ok());
    EXPECT_EQ(*again, *first);  // the same object
  }
  EXPECT_EQ(catalog.parses(), 0u);  // what it wrote, it knows

  // Changed elsewhere (another replica): parsed once.
  ASSERT_TRUE(other
                  .Update([](CatalogState& s) {
                    CatalogMesh m = Kitten();
                    m.name = "other";
                    s.PutMesh(m);
                    return absl::OkStatus();
                  })
                  .ok());
  for (int i = 0; i < 3; ++i) {
    auto read = catalog.Read();
    ASSERT_TRUE(read.ok());
    EXPECT_NE(read->FindMesh("other"), nullptr);
  }
  EXPECT_EQ(catalog.parses(), 1u);

  // Rewritten in place by hand, to the same size, a while later: parsed
  // again. (Within the same tick of the file system's clock, only an
  // Update's new generation would tell.)
  std::string text = CatalogToJson(*catalog.Read());
  text.replace(text.find("\"other\""), 7, "\"third\"");
  const auto before = std::filesystem::last_write_time(catalog.path());
  WriteCatalogText(text);
  std::filesystem::last_write_time(catalog.path(), before + std::chrono::seconds(5));
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_NE(read->FindMesh("third"), nullptr);
  EXPECT_EQ(catalog.parses(), 2u);
  // Gone: the empty state.
  std::filesystem::remove(catalog.path());
  EXPECT_EQ(catalog.Read()->generation, 0u);
}

// A catalog as builds before certified graphs wrote it still loads, its
// graphs plain.
TEST_F(CatalogTest, AVersion1CatalogStillLoads) {
  WriteCatalogText(R"({
  "format": "geodesicd-catalog",
  "generation": 5,
  "graphs": [
    {
      "candidate_rule": 0,
      "epsilon": 0.001,
      "exact_fans": false,
      "mesh": "kitten",
      "prune_redundant": false,
      "pseudo_vertices": false
    }
  ],
  "meshes": [
    {
      "fingerprint": "fedcba9876543210",
      "format": "off",
      "name": "kitten",
      "repair_non_manifold": true,
      "source": "scans/kitten.off",
      "source_hash": "0123456789abcdef"
    }
  ],
  "version": 1
}
)");
  Catalog catalog(dir_);
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->generation, 5u);
  ASSERT_EQ(read->graphs.size(), 1u);
  EXPECT_EQ(read->graphs[0].mesh, "kitten");
  EXPECT_EQ(read->graphs[0].params.epsilon, 1e-3);
  EXPECT_EQ(read->graphs[0].max_error, 0);
  ASSERT_NE(read->FindMesh("kitten"), nullptr);
}

TEST_F(CatalogTest, RemovingAMeshRemovesItsGraphs) {
  Catalog catalog(dir_);
  ASSERT_TRUE(catalog
                  .Update([](CatalogState& s) {
                    s.PutMesh(Kitten());
                    CatalogMesh other = Kitten();
                    other.name = "other";
                    s.PutMesh(other);
                    s.PutGraph({"kitten", DggParams{}});
                    s.PutGraph({"other", DggParams{}});
                    return absl::OkStatus();
                  })
                  .ok());
  auto after = catalog.Update([](CatalogState& s) {
    EXPECT_TRUE(s.RemoveMesh("kitten"));
    EXPECT_FALSE(s.RemoveMesh("kitten"));
    return absl::OkStatus();
  });
  ASSERT_TRUE(after.ok()) << after.status();
  EXPECT_EQ(after->FindMesh("kitten"), nullptr);
  ASSERT_NE(after->FindMesh("other"), nullptr);
  ASSERT_EQ(after->graphs.size(), 1u);
  EXPECT_EQ(after->graphs[0].mesh, "other");
}

TEST_F(CatalogTest, AFailedChangeWritesNothing) {
  Catalog catalog(dir_);
  ASSERT_TRUE(catalog
                  .Update([](CatalogState& s) {
                    s.PutMesh(Kitten());
                    return absl::OkStatus();
                  })
                  .ok());
  auto failed = catalog.Update([](CatalogState& s) {
    s.RemoveMesh("kitten");
    return absl::AlreadyExistsError("no");
  });
  EXPECT_EQ(failed.status().code(), absl::StatusCode::kAlreadyExists);
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok());
  EXPECT_EQ(read->generation, 1u);
  EXPECT_NE(read->FindMesh("kitten"), nullptr);
}

TEST_F(CatalogTest, DamagedFilesAreRefusedByName) {
  Catalog catalog(dir_);
  struct Case {
    std::string text;
    absl::StatusCode code;
    std::string says;
  };
  const std::string valid = CatalogToJson([] {
    CatalogState s;
    s.generation = 3;
    s.PutMesh(Kitten());
    return s;
  }());
  std::string bad_bound = CatalogToJson([] {
    CatalogState s;
    s.PutMesh(Kitten());
    s.PutGraph({"kitten", DggParams{}, 1e-2});
    return s;
  }());
  const std::string bound = "\"max_error\": 0.01";
  bad_bound.replace(bad_bound.find(bound), bound.size(), "\"max_error\": -0.01");
  std::string bad_hex = valid;
  bad_hex.replace(bad_hex.find("0123456789abcdef"), 16, "0123456789abcdeg");
  std::string newer = valid;
  newer.replace(newer.find("\"version\": 1"), 12, "\"version\": 9");
  std::string wrong_type = valid;
  wrong_type.replace(wrong_type.find("true"), 4, "\"yes\"");
  const std::vector<Case> cases = {
      {valid.substr(0, valid.size() / 2), absl::StatusCode::kDataLoss, "not a JSON object"},
      {"{\"format\": \"something else\"}", absl::StatusCode::kDataLoss, "not a geodesicd catalog"},
      {bad_hex, absl::StatusCode::kDataLoss, "0123456789abcdeg"},
      {newer, absl::StatusCode::kFailedPrecondition, "format version 9"},
      {bad_bound, absl::StatusCode::kDataLoss, "graphs[0].max_error: -0.01"},
      {wrong_type, absl::StatusCode::kDataLoss, "repair_non_manifold"},
  };
  for (const Case& c : cases) {
    WriteCatalogText(c.text);
    auto read = catalog.Read();
    ASSERT_FALSE(read.ok()) << c.text;
    EXPECT_EQ(read.status().code(), c.code) << read.status();
    EXPECT_THAT(std::string(read.status().message()), ::testing::HasSubstr(catalog.path()));
    EXPECT_THAT(std::string(read.status().message()), ::testing::HasSubstr(c.says));
    // An update never replaces a catalog it cannot read.
    EXPECT_FALSE(catalog.Update([](CatalogState&) { return absl::OkStatus(); }).ok());
    std::ifstream in(catalog.path());
    EXPECT_EQ(std::string(std::istreambuf_iterator<char>(in), {}), c.text);
  }
}

// Replicas sharing a directory update it from several processes, each with
// several threads: every change must survive, and no temporary file stays.
TEST_F(CatalogTest, ConcurrentUpdatesFromProcessesAndThreadsLoseNothing) {
  constexpr int kProcesses = 3, kThreads = 3, kUpdates = 15;
  auto work = [&](int process) {
    std::vector<std::thread> threads;
    for (int t = 0; t < kThreads; ++t) {
      threads.emplace_back([&, t] {
        Catalog catalog(dir_);  // each its own object, as separate daemons
        for (int k = 0; k < kUpdates; ++k) {
          auto s = catalog.Update([&](CatalogState& s) {
            CatalogMesh m = Kitten();
            m.name = absl::StrCat("m", process, "_", t, "_", k);
            s.PutMesh(m);
            return absl::OkStatus();
          });
          if (!s.ok()) ADD_FAILURE() << s.status();
        }
      });
    }
    for (auto& t : threads) t.join();
  };
  std::vector<pid_t> children;
  for (int p = 1; p < kProcesses; ++p) {
    const pid_t pid = fork();
    ASSERT_GE(pid, 0);
    if (pid == 0) {
      work(p);
      _exit(::testing::Test::HasFailure() ? 1 : 0);
    }
    children.push_back(pid);
  }
  work(0);
  for (pid_t pid : children) {
    int status = 0;
    ASSERT_EQ(waitpid(pid, &status, 0), pid);
    EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
  }
  auto read = Catalog(dir_).Read();
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->meshes.size(), size_t{kProcesses * kThreads * kUpdates});
  EXPECT_EQ(read->generation, uint64_t{kProcesses * kThreads * kUpdates});
  for (const auto& entry : std::filesystem::directory_iterator(dir_)) {
    const std::string name = entry.path().filename();
    EXPECT_TRUE(name == "catalog.json" || name == "catalog.lock") << name;
  }
}

// A full disk: the catalog's reserve file is given up so that the change
// (an unload, a cancel, which free space) is still written.
TEST_F(CatalogTest, AFullDiskGivesUpTheReserveAndTheChangeIsWritten) {
  int writes = 0;
  const std::string reserve = (dir_ / Catalog::kReserveFileName).string();
  Catalog catalog(dir_, [&](const std::string& path, const std::string& text) -> absl::Status {
    ++writes;
    // The disk is full as long as the reserve holds its blocks.
    if (std::filesystem::exists(reserve)) return absl::ResourceExhaustedError("No space left");
    std::ofstream(path) << text;
    return absl::OkStatus();
  });
  ASSERT_TRUE(catalog.EnsureReserve().ok());
  struct stat st;
  ASSERT_EQ(::stat(reserve.c_str(), &st), 0);
  EXPECT_GE(uint64_t(st.st_blocks) * 512, Catalog::kReserveBytes);  // real blocks, not sparse
  // A change that takes space fails: the reserve is not for it.
  auto added = catalog.Update([](CatalogState& s) {
    s.PutMesh(Kitten());
    return absl::OkStatus();
  });
  EXPECT_EQ(added.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(writes, 1);
  EXPECT_TRUE(std::filesystem::exists(reserve));
  // One that frees space (an unload) is written once the reserve is gone.
  auto written = catalog.Update(
      [](CatalogState& s) {
        s.RemoveMesh("kitten");
        return absl::OkStatus();
      },
      Catalog::Reserve::kFreesSpace);
  ASSERT_TRUE(written.ok()) << written.status();
  EXPECT_EQ(writes, 3);
  auto read = catalog.Read();
  ASSERT_TRUE(read.ok()) << read.status();
  EXPECT_EQ(read->generation, 1u);
}

TEST_F(CatalogTest, WithoutAReserveAFullDiskIsReported) {
  Catalog catalog(dir_, [](const std::string&, const std::string&) {
    return absl::ResourceExhaustedError("No space left on device");
  });
  auto written = catalog.Update(
      [](CatalogState& s) {
        s.RemoveMesh("kitten");
        return absl::OkStatus();
      },
      Catalog::Reserve::kFreesSpace);
  EXPECT_EQ(written.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_EQ(catalog.Read()->generation, 0u);
}

// The daemon's own writer on a disk that really is full, if the test may
// mount a small tmpfs (root): unloading frees the reserve and succeeds.
TEST_F(CatalogTest, OnARealFullDiskTheReserveLetsAChangeThrough) {
  const std::filesystem::path mnt = dir_ / "small";
  std::filesystem::create_directories(mnt);
  if (::geteuid() != 0 ||
      ::system(("mount -t tmpfs -o size=8m tmpfs " + mnt.string() + " 2>/dev/null").c_str()) != 0) {
    GTEST_SKIP() << "needs root to mount a tmpfs";
  }
  {
    // The daemon's writer, watched: the first attempt must meet the full
    // disk.
    std::vector<absl::StatusCode> attempts;
    Catalog catalog(mnt.string(), [&](const std::string& path, const std::string& text) {
      absl::Status s = [&]() -> absl::Status {
        auto out = AtomicFileWriter::Create(path);
        if (!out.ok()) return out.status();
        if (absl::Status a = out->Append(text.data(), text.size()); !a.ok()) return a;
        return std::move(*out).Commit();
      }();
      attempts.push_back(s.code());
      return s;
    });
    ASSERT_TRUE(catalog.EnsureReserve().ok());
    ASSERT_TRUE(catalog
                    .Update([](CatalogState& s) {
                      s.PutMesh(Kitten());
                      return absl::OkStatus();
                    })
                    .ok());
    // Fill the rest of the disk, to the last block.
    const int fd = ::open((mnt / "fill").c_str(), O_WRONLY | O_CREAT, 0644);
    ASSERT_GE(fd, 0);
    const std::string block(4096, 'f');
    while (::write(fd, block.data(), block.size()) > 0) {
    }
    ::close(fd);
    attempts.clear();
    auto unloaded = catalog.Update(
        [](CatalogState& s) {
          s.RemoveMesh("kitten");
          return absl::OkStatus();
        },
        Catalog::Reserve::kFreesSpace);
    EXPECT_TRUE(unloaded.ok()) << unloaded.status();
    EXPECT_THAT(attempts, ::testing::ElementsAre(absl::StatusCode::kResourceExhausted,
                                                 absl::StatusCode::kOk));
    EXPECT_EQ(catalog.Read()->FindMesh("kitten"), nullptr);
  }
  ASSERT_EQ(::system(("umount " + mnt.string()).c_str()), 0);
}
}  // namespace
}  // namespace geodesic::server
