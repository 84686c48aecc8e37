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

#include <memory>
#include <string>

#include "absl/status/statusor.h"
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

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_GRAPH_FILE_H_
