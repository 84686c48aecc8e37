#include "core/dgg/graph_file.h"

#include <fcntl.h>
#include <sys/mman.h>
#include <sys/stat.h>
#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <charconv>
#include <chrono>
#include <cstring>
#include <filesystem>
#include <future>
#include <random>
#include <span>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/file_header.h"
#include "core/base/status.h"
#include "core/dgg/dgg_graph_internal.h"
#include "xxhash.h"

namespace geodesic {
namespace {

constexpr char kGraphMagic[8] = {'G', 'E', 'O', 'D', 'D', 'G', 'G', '\0'};
constexpr size_t kHeaderBytes = 4096;
constexpr size_t kAlignment = kSectionAlignment;

enum Section : uint32_t {
  kOffsets,
  kEdges,
  kAngles,
  kPseudoPoints,
  kNodeOfVertex,
  kVertexOfNode,
  kSectionCount
};
constexpr const char* kSectionNames[kSectionCount] = {
    "offsets", "edges", "angles", "pseudo_points", "node_of_vertex", "vertex_of_node"};
constexpr uint32_t kElementSize[kSectionCount] = {8, sizeof(DggEdge), 4, sizeof(SurfacePoint), 4,
                                                  4};

struct SectionEntry {
  char name[16];
  uint64_t offset;
  uint64_t bytes;
  uint32_t element_size;
  uint32_t reserved;
  uint64_t checksum;  // XXH3-64 of the section's bytes
};

struct Header {
  char magic[8];
  uint32_t version;
  uint32_t endian;
  uint64_t mesh_fingerprint;
  StoredDggParams params;
  uint32_t num_nodes;
  uint32_t num_mesh_vertices;
  uint32_t section_count;
  uint32_t reserved;  // zero: keeps the next field aligned, every byte defined
  uint64_t num_directed_edges;
  uint64_t file_bytes;
  SectionEntry sections[kSectionCount];
  uint64_t header_checksum;  // XXH3-64 of this struct with this field zero
};
static_assert(sizeof(Header) <= kHeaderBytes);
static_assert(std::is_trivially_copyable_v<SurfacePoint>);

// Validates the header of a mapped file of `size` bytes.
absl::StatusOr<Header> ReadHeader(const void* base, size_t size, const std::string& path) {
  if (size < kHeaderBytes) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes is too short for a graph file header", path, size));
  }
  Header h;
  std::memcpy(&h, base, sizeof(h));
  RETURN_IF_ERROR(CheckHeader(h, kGraphMagic, kGraphFormatVersion, size, "graph file", path));
  if (h.section_count != kSectionCount) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u sections, expected %u", path, h.section_count, kSectionCount));
  }
  const uint64_t expected_elements[kSectionCount] = {
      uint64_t{h.num_nodes} + 1, h.num_directed_edges,
      h.num_directed_edges,      uint64_t{h.num_nodes} - h.num_mesh_vertices,
      h.num_mesh_vertices,       h.num_mesh_vertices};
  if (h.num_nodes < h.num_mesh_vertices) {
    return absl::DataLossError(absl::StrFormat("%s: fewer nodes than mesh vertices", path));
  }
  uint64_t previous_end = kHeaderBytes;
  for (uint32_t i = 0; i < kSectionCount; ++i) {
    const SectionEntry& s = h.sections[i];
    if (s.element_size != kElementSize[i] || s.bytes / kElementSize[i] != expected_elements[i] ||
        s.bytes % kElementSize[i] != 0) {
      return absl::DataLossError(
          absl::StrFormat("%s: section %s has the wrong size", path, kSectionNames[i]));
    }
    if (s.offset % kAlignment != 0 || s.offset < previous_end || s.offset > size ||
        s.bytes > size - s.offset) {
      return absl::DataLossError(absl::StrFormat(
          "%s: section %s lies outside the file or out of order", path, kSectionNames[i]));
    }
    previous_end = s.offset + s.bytes;
  }
  return h;
}

}  // namespace

std::string GraphFileName(uint64_t mesh_fingerprint, const DggParams& params) {
  // The shortest text that reads back as the same double: any fixed number
  // of digits either gives two epsilons one name or "0.10000000000000001".
  char eps[32];
  const auto [end, ec] = std::to_chars(eps, eps + sizeof(eps), params.epsilon);
  return absl::StrFormat("%016x-eps%s%s%s%s-r%u.dgg", mesh_fingerprint,
                         std::string_view(eps, end - eps), params.pseudo_vertices ? "-pseudo" : "",
                         params.prune_redundant ? "-prune" : "", params.exact_fans ? "-xfans" : "",
                         params.candidate_rule);
}

namespace {

using SectionData = std::array<std::pair<const void*, uint64_t>, kSectionCount>;

// SurfacePoint has padding after its kind, which holds whatever the memory
// held: pseudo points are written from a copy with it zeroed, so that a
// graph's file is the same bytes whenever the graph is built.
std::vector<SurfacePoint> WithZeroPadding(std::span<const SurfacePoint> points) {
  std::vector<SurfacePoint> out(points.size());
  if (out.empty()) return out;  // no data() to clear
  std::memset(static_cast<void*>(out.data()), 0, out.size() * sizeof(SurfacePoint));
  for (size_t i = 0; i < points.size(); ++i) {
    out[i].kind = points[i].kind;
    out[i].id = points[i].id;
    out[i].t = points[i].t;
    out[i].bary = points[i].bary;
  }
  return out;
}

// The bytes each section is written from. `data` points into
// `pseudo_points`, so a Sections is used where it was made, not copied.
struct Sections {
  std::vector<SurfacePoint> pseudo_points;
  SectionData data;
};

Sections SectionsOf(const DggGraph& graph) {
  Sections s{WithZeroPadding(graph.pseudo_points()), {}};
  s.data = {{
      {graph.offsets().data(), graph.offsets().size_bytes()},
      {graph.edges().data(), graph.edges().size_bytes()},
      {graph.angles().data(), graph.angles().size_bytes()},
      {s.pseudo_points.data(), s.pseudo_points.size() * sizeof(SurfacePoint)},
      {graph.node_of_vertex().data(), graph.node_of_vertex().size_bytes()},
      {graph.vertex_of_node().data(), graph.vertex_of_node().size_bytes()},
  }};
  return s;
}

uint64_t PageSize() { return static_cast<uint64_t>(sysconf(_SC_PAGESIZE)); }

// The edges follow the header and the offsets from a page boundary on, so
// that a build can keep them mapped in the file it is writing
// (GraphFileDraft); every writer lays them out there, so that a graph's file
// is the same whichever wrote it.
uint64_t EdgesOffset(uint32_t num_nodes) {
  const uint64_t page = PageSize();
  return (kHeaderBytes + 8 * (uint64_t{num_nodes} + 1) + page - 1) / page * page;
}

// The header of `graph`'s file: sections in order after the header, each
// 64-byte aligned, the edges at EdgesOffset.
Header LayOut(const DggGraph& graph, const SectionData& data) {
  const uint64_t edges_at = EdgesOffset(graph.num_nodes());
  Header h{};
  std::memcpy(h.magic, kGraphMagic, sizeof(kGraphMagic));
  h.version = kGraphFormatVersion;
  h.endian = kEndianTag;
  h.mesh_fingerprint = graph.mesh_fingerprint();
  h.params = StoredDggParams::Of(graph.params());
  h.num_nodes = graph.num_nodes();
  h.num_mesh_vertices = graph.num_mesh_vertices();
  h.section_count = kSectionCount;
  h.num_directed_edges = graph.num_directed_edges();
  uint64_t offset = kHeaderBytes;
  for (uint32_t i = 0; i < kSectionCount; ++i) {
    SectionEntry& s = h.sections[i];
    std::strncpy(s.name, kSectionNames[i], sizeof(s.name) - 1);
    if (i == kEdges) offset = edges_at;
    s.offset = offset;
    s.bytes = data[i].second;
    s.element_size = kElementSize[i];
    s.checksum = XXH3_64bits(data[i].first, data[i].second);
    offset = AlignToSection(offset + s.bytes);
  }
  h.file_bytes = offset;
  h.header_checksum = HeaderChecksum(h);
  return h;
}

// Writes the header and the sections, each at its offset, and commits. With
// `edges_in_place` the edges section is already there, written through a
// mapping of the file, and is passed over.
absl::Status WriteLaidOut(AtomicFileWriter file, const Header& h, const SectionData& data,
                          bool edges_in_place) {
  std::vector<char> header_block(kHeaderBytes, 0);
  std::memcpy(header_block.data(), &h, sizeof(h));
  absl::Status s = file.Append(header_block.data(), header_block.size());
  static const char kZeros[4096] = {};
  for (uint32_t i = 0; i < kSectionCount && s.ok(); ++i) {
    const SectionEntry& entry = h.sections[i];
    while (s.ok() && file.bytes_written() < entry.offset) {
      s = file.Append(kZeros,
                      std::min<uint64_t>(sizeof(kZeros), entry.offset - file.bytes_written()));
    }
    if (!s.ok()) break;
    s = i == kEdges && edges_in_place ? file.SkipTo(entry.offset + entry.bytes)
                                      : file.Append(data[i].first, data[i].second);
  }
  if (s.ok()) s = file.PadTo(kAlignment);
  if (!s.ok()) return s;
  return std::move(file).Commit();
}

}  // namespace

absl::Status GraphFile::Write(const DggGraph& graph, const std::string& path) {
  const Sections sections = SectionsOf(graph);
  const Header h = LayOut(graph, sections.data);
  auto file = AtomicFileWriter::Create(path);
  if (!file.ok()) return file.status();
  return WriteLaidOut(std::move(*file), h, sections.data, /*edges_in_place=*/false);
}

absl::StatusOr<GraphFileDraft> GraphFileDraft::Create(const std::string& path, uint32_t num_nodes) {
  auto file = AtomicFileWriter::Create(path);
  if (!file.ok()) return file.status();
  return GraphFileDraft(std::move(*file), num_nodes, EdgesOffset(num_nodes));
}

void GraphFileDraft::AttachTo(DggBuildOptions& options) const {
  options.edge_file = edge_file();
  auto touched = std::make_shared<std::atomic<int64_t>>(0);  // seconds, steady clock
  options.progress = [fd = file_.fd(), touched, progress = std::move(options.progress)](
                         std::string_view phase, double fraction) {
    const int64_t now = std::chrono::duration_cast<std::chrono::seconds>(
                            std::chrono::steady_clock::now().time_since_epoch())
                            .count();
    int64_t last = touched->load();
    if ((last == 0 || now - last >= kTouchSeconds) && touched->compare_exchange_strong(last, now)) {
      ::futimens(fd, nullptr);
    }
    return progress ? progress(phase, fraction) : true;
  };
}

absl::Status GraphFileDraft::Finish(const DggGraph& graph) && {
  const bool in_place = graph.storage_->arrays.edges.backing_fd() == file_.fd();
  if (in_place && graph.num_nodes() != num_nodes_) {
    return absl::InternalError(
        absl::StrFormat("a graph of %u nodes was built into a file laid out for %u",
                        graph.num_nodes(), num_nodes_));
  }
  const Sections sections = SectionsOf(graph);
  // Where the build did not keep its edges here (it added pseudo vertices),
  // they are written like any other section.
  const Header h = LayOut(graph, sections.data);
  // Pages written through the mapping are the file's; fsync at commit
  // writes them with the rest.
  return WriteLaidOut(std::move(file_), h, sections.data, in_place);
}

namespace {

struct Mapping {
  void* base = nullptr;
  size_t size = 0;
};

absl::StatusOr<Mapping> MapReadOnly(const std::string& path) {
  int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) return ErrnoStatus("cannot open", path);
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    absl::Status s = ErrnoStatus("cannot stat", path);
    ::close(fd);
    return s;
  }
  Mapping m;
  m.size = st.st_size;
  if (m.size == 0) {
    ::close(fd);
    return absl::DataLossError(absl::StrFormat("%s is empty", path));
  }
  m.base = ::mmap(nullptr, m.size, PROT_READ, MAP_PRIVATE, fd, 0);
  ::close(fd);
  if (m.base == MAP_FAILED) return ErrnoStatus("cannot map", path);
  return m;
}

absl::Status VerifyChecksums(const Header& h, const char* base, const std::string& path) {
  for (uint32_t i = 0; i < kSectionCount; ++i) {
    const SectionEntry& s = h.sections[i];
    if (XXH3_64bits(base + s.offset, s.bytes) != s.checksum) {
      return absl::DataLossError(
          absl::StrFormat("%s: section %s is corrupt (checksum mismatch)", path, kSectionNames[i]));
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphFile::Open(const std::string& path,
                                                                const Mesh& mesh, Check check,
                                                                const DggParams* expected) {
  ASSIGN_OR_RETURN(Mapping m, MapReadOnly(path));
  auto storage = std::make_shared<DggGraph::Storage>();
  storage->mapping = m.base;
  storage->mapping_bytes = m.size;
  ASSIGN_OR_RETURN(Header h, ReadHeader(m.base, m.size, path));
  if (h.num_mesh_vertices != mesh.num_vertices() || h.mesh_fingerprint != MeshFingerprint(mesh)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s was built for another mesh (fingerprint %016x, this mesh has %016x)",
                        path, h.mesh_fingerprint, MeshFingerprint(mesh)));
  }
  if (expected) RETURN_IF_ERROR(CheckSameParams(*expected, h.params.params(), path));
  const char* base = static_cast<const char*>(m.base);
  auto graph = std::make_shared<DggGraph>();
  graph->num_nodes_ = h.num_nodes;
  graph->num_mesh_vertices_ = h.num_mesh_vertices;
  graph->params_ = h.params.params();
  graph->mesh_fingerprint_ = h.mesh_fingerprint;
  auto section = [&]<typename T>(Section i, std::span<const T>& out) {
    out = std::span<const T>(reinterpret_cast<const T*>(base + h.sections[i].offset),
                             h.sections[i].bytes / sizeof(T));
  };
  section(kOffsets, graph->offsets_);
  section(kEdges, graph->edges_);
  section(kAngles, graph->angles_);
  section(kPseudoPoints, graph->pseudo_points_);
  section(kNodeOfVertex, graph->node_of_vertex_);
  section(kVertexOfNode, graph->vertex_of_node_);
  graph->storage_ = std::move(storage);
  if (check == Check::kFull) {
    // Validate reads only within the sizes the header check confirmed, so it
    // may run beside the checksums; a checksum mismatch is the better
    // report and wins. A thread of its own rather than a TBB task: TSan
    // sees its synchronisation (Debian's TBB is not instrumented).
    auto sums = std::async(std::launch::async, [&] { return VerifyChecksums(h, base, path); });
    const absl::Status valid = graph->Validate(mesh);
    RETURN_IF_ERROR(sums.get());
    if (!valid.ok()) return absl::DataLossError(absl::StrFormat("%s: %s", path, valid.message()));
  }
  return graph;
}

absl::StatusOr<GraphFile::Info> GraphFile::Inspect(const std::string& path) {
  ASSIGN_OR_RETURN(Mapping m, MapReadOnly(path));
  DggGraph::Storage owner;  // unmaps on return
  owner.mapping = m.base;
  owner.mapping_bytes = m.size;
  ASSIGN_OR_RETURN(Header h, ReadHeader(m.base, m.size, path));
  RETURN_IF_ERROR(VerifyChecksums(h, static_cast<const char*>(m.base), path));
  Info info;
  info.version = h.version;
  info.mesh_fingerprint = h.mesh_fingerprint;
  info.params = h.params.params();
  info.num_nodes = h.num_nodes;
  info.num_mesh_vertices = h.num_mesh_vertices;
  info.num_directed_edges = h.num_directed_edges;
  info.file_bytes = h.file_bytes;
  return info;
}

}  // namespace geodesic
