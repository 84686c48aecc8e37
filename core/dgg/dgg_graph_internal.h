// Internal to core: how a DggGraph owns its arrays and how the builder and
// the graph file make one. Not part of the public interface.
#ifndef GEODESIC_CORE_DGG_DGG_GRAPH_INTERNAL_H_
#define GEODESIC_CORE_DGG_DGG_GRAPH_INTERNAL_H_

#include <cstddef>
#include <memory>
#include <vector>

#include "core/base/large_array.h"
#include "core/dgg/dgg_graph.h"

namespace geodesic {

struct DggGraphArrays {
  std::vector<uint64_t> offsets;
  LargeArray<DggEdge> edges;  // the build's edge array, in place
  std::vector<float> angles;
  std::vector<SurfacePoint> pseudo_points;
  std::vector<uint32_t> node_of_vertex;
  std::vector<VertexId> vertex_of_node;
};

struct DggGraph::Storage {
  DggGraphArrays arrays;    // a graph built in memory
  void* mapping = nullptr;  // or a read-only mapping of a graph file
  size_t mapping_bytes = 0;
  ~Storage();
};

class DggGraphBuilder {
 public:
  // The edges of a graph its caller has just built and holds the only
  // reference to, for a pass that rewrites their fans before the graph is
  // shared (core/query/build_dgg.cc). Null for a graph that is not its
  // builder's alone or not built in memory.
  static DggEdge* EditableEdges(const std::shared_ptr<const DggGraph>& graph) {
    if (graph.use_count() != 1 || graph->is_mapped()) return nullptr;
    return const_cast<DggEdge*>(graph->edges_.data());
  }
  static std::shared_ptr<const DggGraph> FromArrays(DggGraphArrays arrays, uint32_t num_nodes,
                                                    uint32_t num_mesh_vertices,
                                                    const DggParams& params,
                                                    uint64_t mesh_fingerprint);
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_DGG_GRAPH_INTERNAL_H_
