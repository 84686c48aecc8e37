// Graph files as untrusted input, beyond checksums: structurally wrong files
// with valid checksums, other format versions, and failed writes.
#include "core/dgg/graph_file.h"

#include <signal.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <set>

#include "absl/strings/str_cat.h"
#include "core/dgg/dgg_graph_internal.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "gtest/gtest.h"
#include "tests/core/test_util.h"

namespace geodesic {
namespace {

using testing::TempDir;

// Two triangles sharing an edge, and a hand-made graph on it.
Mesh Square() {
  TriangleSoup soup;
  soup.positions = {{0, 0, 0}, {1, 0, 0}, {1, 1, 0}, {0, 1, 0}};
  soup.triangles = {{0, 1, 2}, {0, 2, 3}};
  return *Mesh::Build(std::move(soup), "square");
}

// The arrays of a complete graph on the square's 4 vertices.
DggGraphArrays CompleteArrays(std::vector<uint32_t> node_of_vertex) {
  DggGraphArrays a;
  a.vertex_of_node.assign(4, 0);
  for (uint32_t v = 0; v < 4; ++v) a.vertex_of_node[node_of_vertex[v]] = v;
  a.node_of_vertex = std::move(node_of_vertex);
  a.offsets = {0};
  for (uint32_t u = 0; u < 4; ++u) {
    for (uint32_t v = 0; v < 4; ++v) {
      if (u == v) continue;
      a.edges.push_back({v, 1.5f, {0, 1}});
      a.angles.push_back(0.1f * v);
    }
    a.offsets.push_back(a.edges.size());
  }
  return a;
}

// A complete graph on the square's 4 vertices, with one target replaced.
std::shared_ptr<const DggGraph> CompleteGraph(const Mesh& mesh, uint32_t bad_target,
                                              std::vector<uint32_t> node_of_vertex = {2, 0, 3, 1},
                                              DggParams params = {.epsilon = 0.1}) {
  DggGraphArrays a = CompleteArrays(std::move(node_of_vertex));
  a.edges[5].target = bad_target;
  return DggGraphBuilder::FromArrays(std::move(a), 4, 4, params, MeshFingerprint(mesh));
}

// The square's complete graph and a pseudo vertex in its first face, on no
// edge, whose bytes between its kind and its id are `padding`: what memory
// left there, which a copy need not clear.
std::shared_ptr<const DggGraph> GraphWithPseudoPoint(const Mesh& mesh, unsigned char padding) {
  DggGraphArrays a = CompleteArrays({0, 1, 2, 3});
  a.offsets.push_back(a.edges.size());  // the pseudo vertex's empty row
  a.pseudo_points.resize(1);
  SurfacePoint& p = a.pseudo_points[0];
  std::memset(static_cast<void*>(&p), padding, sizeof(p));
  p.kind = SurfacePoint::Kind::kFace;
  p.id = 0;
  p.t = 0;
  p.bary = {0.25, 0.25, 0.5};
  return DggGraphBuilder::FromArrays(std::move(a), 5, 4, {.epsilon = 0.1, .pseudo_vertices = true},
                                     MeshFingerprint(mesh));
}

std::string FileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// A file holds no byte that memory left undefined: the same graph is the
// same bytes, whatever its pseudo points' padding held.
TEST(GraphFileTest, PseudoPointsAreWrittenWithoutWhatTheirPaddingHeld) {
  Mesh mesh = Square();
  TempDir dir;
  ASSERT_OK(GraphFile::Write(*GraphWithPseudoPoint(mesh, 0xab), dir.File("ab.dgg")));
  ASSERT_OK(GraphFile::Write(*GraphWithPseudoPoint(mesh, 0xcd), dir.File("cd.dgg")));
  const std::string ab = FileBytes(dir.File("ab.dgg")), cd = FileBytes(dir.File("cd.dgg"));
  ASSERT_FALSE(ab.empty());
  EXPECT_EQ(ab.size(), cd.size());
  EXPECT_TRUE(ab == cd) << "the files differ";
  EXPECT_EQ(ab.find("\xab\xab\xab"), std::string::npos);
  auto opened = GraphFile::Open(dir.File("ab.dgg"), mesh, GraphFile::Check::kFull);
  ASSERT_OK(opened);
  ASSERT_EQ((*opened)->num_pseudo_vertices(), 1u);
  EXPECT_EQ((*opened)->pseudo_points()[0].bary[2], 0.5);
}

TEST(GraphFileTest, OutOfRangeIndexWithValidChecksumsIsRejectedByTheFullCheck) {
  const Mesh mesh = Square();
  TempDir dir;
  const std::string path = dir.File("bad-index.dgg");
  // Written by our own writer: every checksum matches, only the structure
  // is wrong, so only validation can catch it.
  ASSERT_TRUE(GraphFile::Write(*CompleteGraph(mesh, 4000000), path).ok());
  auto opened = GraphFile::Open(path, mesh, GraphFile::Check::kFull);
  ASSERT_FALSE(opened.ok());
  EXPECT_EQ(opened.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(opened.status().message().find(path), std::string::npos) << opened.status();
  EXPECT_NE(opened.status().message().find("4000000"), std::string::npos) << opened.status();
  // The same graph with a valid target opens.
  ASSERT_TRUE(GraphFile::Write(*CompleteGraph(mesh, 2), dir.File("good.dgg")).ok());
  EXPECT_TRUE(GraphFile::Open(dir.File("good.dgg"), mesh, GraphFile::Check::kFull).ok());
}

TEST(GraphFileTest, VertexOrderThatIsNoPermutationIsRejectedByTheFullCheck) {
  const Mesh mesh = Square();
  TempDir dir;
  const std::string path = dir.File("bad-order.dgg");
  // Vertices 0 and 2 both claim node 2.
  ASSERT_TRUE(GraphFile::Write(*CompleteGraph(mesh, 2, {2, 0, 2, 1}), path).ok());
  auto opened = GraphFile::Open(path, mesh, GraphFile::Check::kFull);
  ASSERT_FALSE(opened.ok());
  EXPECT_EQ(opened.status().code(), absl::StatusCode::kDataLoss);
  EXPECT_NE(opened.status().message().find("vertex 0 maps to node 2"), std::string::npos)
      << opened.status();
}

TEST(GraphFileTest, OtherFormatVersionIsFailedPreconditionNamingBoth) {
  const Mesh mesh = Square();
  TempDir dir;
  const std::string path = dir.File("v2.dgg");
  ASSERT_TRUE(GraphFile::Write(*CompleteGraph(mesh, 2), path).ok());
  {
    // The version is the 32-bit word after the 8-byte magic.
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    const uint32_t version = kGraphFormatVersion + 1;
    f.seekp(8);
    f.write(reinterpret_cast<const char*>(&version), sizeof(version));
  }
  auto opened = GraphFile::Open(path, mesh, GraphFile::Check::kHeader);
  ASSERT_FALSE(opened.ok());
  EXPECT_EQ(opened.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_NE(opened.status().message().find(absl::StrCat("version ", kGraphFormatVersion + 1)),
            std::string::npos)
      << opened.status();
}

// The whole build record travels with the file: what Inspect and Open read
// back, what Open refuses when the caller expects another graph, and the
// file name a graph directory knows it by.
TEST(GraphFileTest, TheBuildRecordRoundTripsAndIsChecked) {
  const Mesh mesh = Square();
  TempDir dir;
  const DggParams record = {.epsilon = 0.1 + 0.2,
                            .pseudo_vertices = true,
                            .prune_redundant = true,
                            .exact_fans = true,
                            .candidate_rule = kCandidateRuleVersion};
  const std::string path = dir.File("record.dgg");
  ASSERT_OK(GraphFile::Write(*CompleteGraph(mesh, 2, {2, 0, 3, 1}, record), path));
  auto info = GraphFile::Inspect(path);
  ASSERT_OK(info);
  EXPECT_EQ(info->params, record);
  auto opened = GraphFile::Open(path, mesh, GraphFile::Check::kFull, &record);
  ASSERT_OK(opened);
  EXPECT_EQ((*opened)->params(), record);

  struct Change {
    const char* field;
    void (*apply)(DggParams&);
  };
  const Change changes[] = {
      {"epsilon", [](DggParams& p) { p.epsilon = 0.3; }},
      {"pseudo_vertices", [](DggParams& p) { p.pseudo_vertices = false; }},
      {"prune_redundant", [](DggParams& p) { p.prune_redundant = false; }},
      {"exact_fans", [](DggParams& p) { p.exact_fans = false; }},
      {"candidate_rule", [](DggParams& p) { p.candidate_rule = 1; }},
  };
  std::set<std::string> names = {GraphFileName(7, record)};
  for (const Change& c : changes) {
    DggParams other = record;
    c.apply(other);
    auto refused = GraphFile::Open(path, mesh, GraphFile::Check::kHeader, &other);
    ASSERT_FALSE(refused.ok()) << c.field;
    EXPECT_EQ(refused.status().code(), absl::StatusCode::kFailedPrecondition);
    EXPECT_THAT(std::string(refused.status().message()), ::testing::HasSubstr(c.field));
    EXPECT_THAT(std::string(refused.status().message()), ::testing::HasSubstr(path));
    // Every field shows in the name, so two graphs never share a file.
    EXPECT_TRUE(names.insert(GraphFileName(7, other)).second) << GraphFileName(7, other);
  }
  EXPECT_EQ(GraphFileName(0xabc, record),
            "0000000000000abc-eps0.30000000000000004-pseudo-prune-xfans-r3.dgg");
}

// A graph file from before the build record (format version 2) is refused by
// name rather than read with half its identity missing.
TEST(GraphFileTest, FilesWithoutTheBuildRecordAreRefused) {
  const Mesh mesh = Square();
  TempDir dir;
  const std::string path = dir.File("old.dgg");
  ASSERT_OK(GraphFile::Write(*CompleteGraph(mesh, 2), path));
  {
    std::fstream f(path, std::ios::in | std::ios::out | std::ios::binary);
    const uint32_t version = 2;
    f.seekp(8);
    f.write(reinterpret_cast<const char*>(&version), sizeof(version));
  }
  auto opened = GraphFile::Open(path, mesh, GraphFile::Check::kHeader);
  ASSERT_FALSE(opened.ok());
  EXPECT_EQ(opened.status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_THAT(std::string(opened.status().message()),
              ::testing::HasSubstr("format version 2; this build reads version 3"));
}

TEST(GraphFileTest, FailedWritesLeaveNothingAndKeepTheOldFile) {
  const Mesh mesh = Square();
  TempDir dir;
  const std::string path = dir.File("kept.dgg");
  ASSERT_TRUE(GraphFile::Write(*CompleteGraph(mesh, 2), path).ok());
  const auto before = std::filesystem::file_size(path);

  // Into a directory that does not exist: NOT_FOUND naming the path.
  auto missing = GraphFile::Write(*CompleteGraph(mesh, 2), dir.File("no/such/dir/g.dgg"));
  EXPECT_EQ(missing.code(), absl::StatusCode::kNotFound) << missing;

  // Refusals that hold for root too (CI runs as root, where a read-only
  // directory stops nothing). Under a path whose "directory" is a regular
  // file: the temporary file cannot be created.
  auto under_file = GraphFile::Write(*CompleteGraph(mesh, 2), path + "/g.dgg");
  EXPECT_FALSE(under_file.ok());
  EXPECT_NE(under_file.message().find(path), std::string::npos) << under_file;

  // Onto a directory: everything is written, then the rename is refused.
  std::filesystem::create_directory(dir.File("a_directory.dgg"));
  auto onto_dir = GraphFile::Write(*CompleteGraph(mesh, 2), dir.File("a_directory.dgg"));
  EXPECT_FALSE(onto_dir.ok());
  EXPECT_NE(onto_dir.message().find("a_directory.dgg"), std::string::npos) << onto_dir;
  EXPECT_TRUE(std::filesystem::is_directory(dir.File("a_directory.dgg")));

  // Over the existing file, failing half way: a file size limit (which
  // binds root as well) below the graph's size makes a write fail with
  // EFBIG. The old file stays as it was.
  {
    struct rlimit old_limit;
    ASSERT_EQ(getrlimit(RLIMIT_FSIZE, &old_limit), 0);
    struct rlimit small = old_limit;
    small.rlim_cur = before / 2;
    void (*old_handler)(int) = signal(SIGXFSZ, SIG_IGN);
    ASSERT_EQ(setrlimit(RLIMIT_FSIZE, &small), 0);
    auto too_big = GraphFile::Write(*CompleteGraph(mesh, 2), path);
    setrlimit(RLIMIT_FSIZE, &old_limit);
    signal(SIGXFSZ, old_handler);
    EXPECT_FALSE(too_big.ok());
    EXPECT_NE(too_big.message().find("cannot write"), std::string::npos) << too_big;
  }

  EXPECT_EQ(std::filesystem::file_size(path), before);
  EXPECT_TRUE(GraphFile::Open(path, mesh, GraphFile::Check::kFull).ok());
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    EXPECT_EQ(entry.path().string().find(".tmp."), std::string::npos) << entry.path();
  }
}

TEST(GraphFileTest, DirectoryInsteadOfAFileIsAnError) {
  const Mesh mesh = Square();
  TempDir dir;
  auto opened = GraphFile::Open(dir.path(), mesh, GraphFile::Check::kHeader);
  EXPECT_FALSE(opened.ok());
}

}  // namespace

// Every array of two graphs, element by element.
void ExpectSameGraph(const DggGraph& a, const DggGraph& b) {
  ASSERT_GT(a.num_directed_edges(), 0u);
  ASSERT_EQ(a.num_nodes(), b.num_nodes());
  EXPECT_TRUE(std::ranges::equal(a.offsets(), b.offsets()));
  ASSERT_EQ(a.edges().size(), b.edges().size());
  for (size_t i = 0; i < a.edges().size(); ++i) {
    ASSERT_EQ(a.edges()[i].target, b.edges()[i].target) << "edge " << i;
    ASSERT_EQ(a.edges()[i].weight, b.edges()[i].weight) << "edge " << i;
    ASSERT_EQ(a.edges()[i].fan.begin, b.edges()[i].fan.begin) << "edge " << i;
    ASSERT_EQ(a.edges()[i].fan.count, b.edges()[i].fan.count) << "edge " << i;
  }
  EXPECT_TRUE(std::ranges::equal(a.angles(), b.angles()));
  EXPECT_TRUE(std::ranges::equal(a.node_of_vertex(), b.node_of_vertex()));
  EXPECT_TRUE(std::ranges::equal(a.vertex_of_node(), b.vertex_of_node()));
}

// The build keeps its edges in the draft's file, at the edges section, and
// the finished file is the graph the same build writes from memory.
TEST(GraphFileDraftTest, ABuildIntoItsFileIsTheGraphWrittenAfterTheBuild) {
  auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(mesh);
  TempDir dir;
  DggBuildOptions options;
  options.params.epsilon = 1e-2;
  auto in_memory = BuildDgg(*mesh, options);
  ASSERT_OK(in_memory);
  ASSERT_OK(GraphFile::Write(**in_memory, dir.File("memory.dgg")));

  auto draft = GraphFileDraft::Create(dir.File("draft.dgg"), mesh->num_vertices());
  ASSERT_OK(draft);
  options.edge_file = draft->edge_file();
  auto in_file = BuildDgg(*mesh, options);
  ASSERT_OK(in_file);
  // Before Finish the edges are already in the file (a temporary beside it).
  uint64_t largest = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    if (entry.path().filename() != "memory.dgg")
      largest = std::max<uint64_t>(largest, entry.file_size());
  }
  EXPECT_GE(largest, options.edge_file.offset + (*in_file)->edges().size_bytes());
  ASSERT_OK(std::move(*draft).Finish(**in_file));

  auto opened = GraphFile::Open(dir.File("draft.dgg"), *mesh, GraphFile::Check::kFull);
  ASSERT_OK(opened);
  auto written = GraphFile::Open(dir.File("memory.dgg"), *mesh, GraphFile::Check::kFull);
  ASSERT_OK(written);
  ExpectSameGraph(**written, **opened);
  ExpectSameGraph(**in_memory, **in_file);
  // Every writer lays the edges out at the same place: the same bytes.
  EXPECT_EQ(FileBytes(dir.File("memory.dgg")), FileBytes(dir.File("draft.dgg")));
}

// Pseudo vertices change the node count the layout was made for: the build
// keeps its edges in memory and Finish writes them like any section.
TEST(GraphFileDraftTest, APseudoVertexBuildIsWrittenWhole) {
  auto mesh = LoadMesh(testing::SourcePath("data/spot.obj"));
  ASSERT_OK(mesh);
  TempDir dir;
  DggBuildOptions options;
  options.params.epsilon = 5e-2;
  options.params.pseudo_vertices = true;
  auto draft = GraphFileDraft::Create(dir.File("pseudo.dgg"), mesh->num_vertices());
  ASSERT_OK(draft);
  options.edge_file = draft->edge_file();
  auto graph = BuildDgg(*mesh, options);
  ASSERT_OK(graph);
  ASSERT_OK(std::move(*draft).Finish(**graph));
  auto opened = GraphFile::Open(dir.File("pseudo.dgg"), *mesh, GraphFile::Check::kFull);
  ASSERT_OK(opened);
  ExpectSameGraph(**graph, **opened);
}

// A draft dropped without Finish (a failed or cancelled build) leaves
// nothing behind.
TEST(GraphFileDraftTest, ADraftDroppedLeavesNoFile) {
  TempDir dir;
  {
    auto draft = GraphFileDraft::Create(dir.File("dropped.dgg"), 100);
    ASSERT_OK(draft);
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
}

// A draft goes unwritten through its build's candidate phase, and sweeps of
// stale temporary files judge by modification time: a build attached to the
// draft keeps its edges there, and its progress keeps the draft current and
// still reports to the caller's progress.
TEST(GraphFileDraftTest, ProgressKeepsTheDraftFresh) {
  TempDir dir;
  auto draft = GraphFileDraft::Create(dir.File("fresh.dgg"), 100);
  ASSERT_OK(draft);
  const int fd = draft->edge_file().fd;
  const timespec an_hour_ago[2] = {{time(nullptr) - 3600, 0}, {time(nullptr) - 3600, 0}};
  ASSERT_EQ(::futimens(fd, an_hour_ago), 0);
  std::vector<double> reported;
  DggBuildOptions options;
  options.progress = [&](std::string_view, double fraction) {
    reported.push_back(fraction);
    return false;
  };
  draft->AttachTo(options);
  EXPECT_EQ(options.edge_file.fd, fd);
  EXPECT_EQ(options.edge_file.offset, draft->edge_file().offset);
  EXPECT_FALSE(options.progress("candidates", 0.25));  // the caller's answer
  EXPECT_EQ(reported, std::vector<double>{0.25});
  struct stat st;
  ASSERT_EQ(::fstat(fd, &st), 0);
  EXPECT_GE(st.st_mtime, time(nullptr) - 60);
  // With no progress of its own, the build goes on.
  DggBuildOptions quiet;
  draft->AttachTo(quiet);
  EXPECT_TRUE(quiet.progress("fans", 1.0));
}

}  // namespace geodesic
