// The discrete geodesic graph (DGG, Wang et al., CAGD 2017) as an immutable,
// memory-mappable structure.
//
// Nodes 0..n-1 are the mesh vertices and nodes n.. are pseudo vertices (section
// 4.3), each a point inside a face. Vertex nodes are numbered along a Z-order
// curve through their positions, not in the mesh file's order: a search's next
// nodes then lie near each other in memory (armadillo at 1e-3: a Dijkstra field
// 25 -> 20 ms, point-to-point 4.6 -> 3.8 ms). node_of_vertex and vertex_of_node
// translate; callers speak mesh vertex ids. Edges are stored directed in
// compressed adjacency (CSR): every undirected DGG edge appears once from each
// end. Per node, outgoing edges are sorted by their polar angle at the node
// (the node's intrinsic tangent frame, core/mesh.h), and each directed edge
// u->v carries its fan: the range of v's outgoing edges that a shortest path
// arriving along u->v can continue on (section 5.1.2), which the DGG-tailored
// solver scans instead of all of v's edges.
//
// Weights are float32 lengths of real surface paths, rounded up, so graph
// distances never undercut exact geodesic distances (float32's 6e-8 relative
// step is far below any useful epsilon; see BENCHMARKS.md).
#ifndef GEODESIC_CORE_DGG_GRAPH_H_
#define GEODESIC_CORE_DGG_GRAPH_H_

#include <compare>
#include <cstdint>
#include <memory>
#include <span>
#include <string>

#include "absl/status/statusor.h"
#include "core/mesh.h"
#include "core/surface_point.h"

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

// Parameters a graph was built with; part of its identity.
struct DggParams {
  double epsilon = 1e-3;
  // Section 4.3's pseudo vertices. Off by default: on the isotropic meshes
  // measured (BENCHMARKS.md) they double the node count for no accuracy gain;
  // turn them on for anisotropic meshes.
  bool pseudo_vertices = false;
  friend auto operator<=>(const DggParams&, const DggParams&) = default;
};

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

// Hash of the mesh's positions and faces (xxHash64): a graph is only ever used
// with the mesh it was built for.
uint64_t MeshFingerprint(const Mesh& mesh);

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_GRAPH_H_
