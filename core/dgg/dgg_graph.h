// The discrete geodesic graph (DGG, Wang et al., CAGD 2017) as an immutable,
// memory-mappable structure.
//
// Nodes 0..n-1 are the mesh vertices and nodes n.. are pseudo vertices (section
// 4.3), each a point inside a face. Vertex nodes are numbered along a Z-order
// curve through their positions, not in the mesh file's order: a search's next
// nodes then lie near each other in memory, and a search waits on memory more
// than on arithmetic (bench/notes.md, "Memory order"). node_of_vertex and
// vertex_of_node translate; callers speak mesh vertex ids. Edges are stored
// directed in compressed adjacency (CSR): every undirected DGG edge appears
// once from each end. Per node, outgoing edges are sorted by their polar angle
// at the node (the node's intrinsic tangent frame, core/mesh/mesh.h), and each
// directed edge u->v carries its fan: the range of v's outgoing edges that a
// shortest path arriving along u->v can continue on (section 5.1.2), which the
// DGG-tailored solver scans instead of all of v's edges.
//
// Weights are float32 lengths of real surface paths, rounded up, so graph
// distances never undercut exact geodesic distances (float32's 6e-8 relative
// step is far below any useful epsilon; BENCHMARKS.md's fields table shows it
// in its "most below exact" column).
#ifndef GEODESIC_CORE_DGG_DGG_GRAPH_H_
#define GEODESIC_CORE_DGG_DGG_GRAPH_H_

#include <compare>
#include <cstdint>
#include <memory>
#include <span>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

// A run of a node's angle-sorted outgoing edges.
struct FanRange {
  uint32_t begin = 0;  // local index into the node's angle-sorted edges
  uint32_t count = 0;  // edges, wrapping around the end of the list
};

// A directed edge u -> v, with everything a search reads of it in one
// record: a search that reaches v along it relaxes `fan` next.
struct DggEdge {
  uint32_t target;  // v
  float weight;
  FanRange fan;  // of v's edges
};
static_assert(sizeof(DggEdge) == 16);

// A candidate edge as a build finds it, seen from one end: a direct geodesic
// from the source to `to`, its length rounded up to float, and its polar
// angles at both ends.
struct DggHalfEdge {
  uint32_t to;
  float weight;
  float angle_here;   // polar angle at this end, normalised to [0, 2*pi)
  float angle_there;  // polar angle at the other end, normalised
};

// Edges a node reached along an edge relaxes, on average over `edges`: the
// build's average fan (DggBuildStats::average_fan).
inline double AverageFan(std::span<const DggEdge> edges) {
  uint64_t fans = 0;
  for (const DggEdge& e : edges) fans += e.fan.count;
  return edges.empty() ? 0 : double(fans) / edges.size();
}

// The version of the rules that decide which candidate edges a build keeps
// (core/dgg/build_phases.h, CornerBudgetFactor) and which fans it gives
// them. Bump it whenever a change to the rules changes the graphs built for
// the same parameters, so that files made under the old rules are told
// apart and rebuilt rather than served as if they were today's. 2: a lit
// vertex needs an edge unless a corner route is within 1 + 1.1 eps, the
// extra tenth fading out between 1e-3 and 1e-4. 3: fans narrowed further
// by a short sweep around each node (core/query/build_dgg.cc), the same
// distances from far fewer relaxations.
inline constexpr uint32_t kCandidateRuleVersion = 3;

// Everything a graph was built with that changes the graph: its identity.
// Graph and part files record all of it, the daemon keys its graphs by it,
// and file names are made from it (GraphFileName).
struct DggParams {
  double epsilon = 1e-3;
  // Section 4.3's pseudo vertices. Off by default: they add nodes and build
  // time that grow quickly as epsilon shrinks, and only anisotropic meshes
  // gain accuracy from them (BENCHMARKS.md, "Build variants: pruning and
  // pseudo vertices"); turn them on for such meshes.
  bool pseudo_vertices = false;
  // Phase 2 of Algorithm 1 (PRUNEREDUNDANTEDGES), with a tenth of epsilon
  // taken from the candidates' budget. Off by default: with a tenth less
  // the candidates keep more edges than pruning then removes, and pruning
  // takes a large share of the build (BENCHMARKS.md, "Build variants:
  // pruning and pseudo vertices").
  bool prune_redundant = false;
  // Fans from each node's exact local distances (core/dgg/fans.cc) instead
  // of the default's short sweeps: about as narrow since the default narrows
  // too, for a longer build (bench/notes.md, "Exact fans", "Fans narrowed in
  // the build"). Distances are the same either way.
  bool exact_fans = false;
  uint32_t candidate_rule = kCandidateRuleVersion;
  friend auto operator<=>(const DggParams&, const DggParams&) = default;
};

// "eps 0.001, pseudo vertices, pruned, exact fans, candidate rule 2": every
// field, for messages and `geodesicd info`.
std::string DescribeParams(const DggParams& params);
// OK if `have` equals `want`; otherwise FAILED_PRECONDITION "<what> was
// built with <field> <value>, not <value>", naming the first field that
// differs.
absl::Status CheckSameParams(const DggParams& want, const DggParams& have, std::string_view what);

// DggParams as file headers store them: fixed size, no padding holes (a
// header's checksum covers every byte).
struct StoredDggParams {
  double epsilon;
  uint32_t pseudo_vertices;
  uint32_t prune_redundant;
  uint32_t exact_fans;
  uint32_t candidate_rule;
  static StoredDggParams Of(const DggParams& p);
  DggParams params() const;
};
static_assert(sizeof(StoredDggParams) == 24);

class DggGraph {
 public:
  // Ownership of the arrays: either vectors built in memory or a mapping of a
  // graph file. The spans below point into one or the other.
  struct Storage;

  uint32_t num_nodes() const { return num_nodes_; }
  uint32_t num_mesh_vertices() const { return num_mesh_vertices_; }
  uint32_t num_pseudo_vertices() const { return num_nodes_ - num_mesh_vertices_; }
  uint64_t num_directed_edges() const { return edges_.size(); }
  const DggParams& params() const { return params_; }
  uint64_t mesh_fingerprint() const { return mesh_fingerprint_; }

  // Outgoing edges of node u: indices [offsets[u], offsets[u+1]).
  std::span<const uint64_t> offsets() const { return offsets_; }
  std::span<const DggEdge> edges() const { return edges_; }
  // Polar angle of each directed edge at its tail, normalised to [0, 2*pi).
  std::span<const float> angles() const { return angles_; }
  // Where pseudo vertex n + i lies.
  std::span<const SurfacePoint> pseudo_points() const { return pseudo_points_; }
  // The node of mesh vertex v, and the mesh vertex of node u < n.
  uint32_t node_of_vertex(VertexId v) const { return node_of_vertex_[v]; }
  VertexId vertex_of_node(uint32_t u) const { return vertex_of_node_[u]; }
  std::span<const uint32_t> node_of_vertex() const { return node_of_vertex_; }
  std::span<const VertexId> vertex_of_node() const { return vertex_of_node_; }
  // Where node u lies on the surface.
  SurfacePoint point_of_node(uint32_t u) const {
    return u < num_mesh_vertices_ ? SurfacePoint::Vertex(vertex_of_node_[u])
                                  : pseudo_points_[u - num_mesh_vertices_];
  }

  // Bytes of the arrays (resident if built, mapped if opened from a file).
  uint64_t byte_size() const;
  bool is_mapped() const;

  // Full validation: every index in range, offsets monotone, fans inside their
  // target's edge list, weights finite and positive, pseudo points valid, the
  // vertex order a permutation.
  absl::Status Validate(const Mesh& mesh) const;

 private:
  friend class DggGraphBuilder;
  friend class GraphFile;
  friend class GraphFileDraft;

  uint32_t num_nodes_ = 0;
  uint32_t num_mesh_vertices_ = 0;
  DggParams params_;
  uint64_t mesh_fingerprint_ = 0;
  std::span<const uint64_t> offsets_;
  std::span<const DggEdge> edges_;
  std::span<const float> angles_;
  std::span<const SurfacePoint> pseudo_points_;
  std::span<const uint32_t> node_of_vertex_;
  std::span<const VertexId> vertex_of_node_;
  std::shared_ptr<const Storage> storage_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_DGG_GRAPH_H_
