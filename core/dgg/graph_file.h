// The graph file: a DGG laid out to be memory-mapped, not parsed.
//
// Layout (little-endian): a 4 KiB header with magic "GEODDGG\0", format
// version, endianness tag, mesh fingerprint, epsilon and build parameters,
// counts, and a table of sections (name, offset, bytes, element size,
// xxHash64 checksum); then the sections, each 64-byte aligned. A header
// checksum covers the header itself.
//
// Files are written to a temporary name, fsynced, renamed into place and the
// directory fsynced: a file is never rewritten in place, so mapped readers
// never see it change.
#ifndef GEODESIC_CORE_DGG_GRAPH_FILE_H_
#define GEODESIC_CORE_DGG_GRAPH_FILE_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/base/atomic_file.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"

namespace geodesic {

// 2: vertex nodes in spatial order (the node_of_vertex and vertex_of_node
// sections); each edge one record with its fan, and fans that hold every
// turn a shortest path takes. 3: the whole build record (DggParams: pruning,
// exact fans and the candidate rule besides epsilon and pseudo vertices),
// which version 2 left out although they change the graph. Files of another
// version are rejected by name.
inline constexpr uint32_t kGraphFormatVersion = 3;

// The name a graph has in a graph directory (geodesicd serve --graph-dir),
// made from its whole build record:
// "<mesh fingerprint, 16 hex digits>-eps<epsilon>[-pseudo][-prune][-xfans]-r<rule>.dgg".
// Offline builds and merges that write into a daemon's directory use the
// same name.
std::string GraphFileName(uint64_t mesh_fingerprint, const DggParams& params);

class GraphFileDraft;

class GraphFile {
 public:
  // Writes atomically (temp + fsync + rename + fsync of the directory).
  static absl::Status Write(const DggGraph& graph, const std::string& path);

  enum class Check {
    kHeader,  // magic, version, sizes, fingerprint: O(1) work, then map
    kFull,    // also every checksum and DggGraph::Validate
  };
  // Maps `path` read-only. FAILED_PRECONDITION when the file was built for
  // another mesh (fingerprint), another format version, or (if `expected`
  // is given) with other parameters, naming the field; DATA_LOSS when it is
  // truncated or corrupt. Messages name the path and the problem.
  static absl::StatusOr<std::shared_ptr<const DggGraph>> Open(const std::string& path,
                                                              const Mesh& mesh, Check check,
                                                              const DggParams* expected = nullptr);

  // Header facts without a mesh: for `geodesicd info GRAPH.dgg`.
  struct Info {
    uint32_t version = 0;
    uint64_t mesh_fingerprint = 0;
    DggParams params;
    uint32_t num_nodes = 0;
    uint32_t num_mesh_vertices = 0;
    uint64_t num_directed_edges = 0;
    uint64_t file_bytes = 0;
  };
  // Reads the header and verifies every section checksum.
  static absl::StatusOr<Info> Inspect(const std::string& path);
};

// A graph file written around its build: the build keeps the graph's edge
// array, its largest part by far, in this file at the place of the edges
// section (DggBuildOptions::edge_file), so the edges take page cache, which
// the kernel writes back and reclaims, instead of memory the build holds;
// Finish adds the other sections around them and commits as Write does. For
// builds whose node count is known before they run: without pseudo vertices,
// one node per mesh vertex. A build that did not use the file is written
// whole by Finish. Dropped without Finish, nothing is left.
class GraphFileDraft {
 public:
  static absl::StatusOr<GraphFileDraft> Create(const std::string& path, uint32_t num_nodes);
  DggEdgeFile edge_file() const { return {file_.fd(), edges_offset_, {}}; }
  absl::Status Finish(const DggGraph& graph) &&;

  // Makes the build of `options` keep its edges in this draft, and its
  // progress reports (options.progress, may be empty) keep the draft's
  // modification time current, at most every kTouchSeconds: sweeps of stale
  // temporary files (a daemon's, at start) judge by it, and a draft goes
  // unwritten for as long as its build's candidate phase. The draft must
  // outlive the build.
  static constexpr int64_t kTouchSeconds = 30;
  void AttachTo(DggBuildOptions& options) const;

 private:
  GraphFileDraft(AtomicFileWriter file, uint32_t num_nodes, uint64_t edges_offset)
      : file_(std::move(file)), num_nodes_(num_nodes), edges_offset_(edges_offset) {}

  AtomicFileWriter file_;
  uint32_t num_nodes_;
  uint64_t edges_offset_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_GRAPH_FILE_H_
