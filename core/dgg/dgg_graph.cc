#include "core/dgg/dgg_graph.h"

#include <sys/mman.h>

#include <cmath>
#include <numbers>

#include "absl/status/status.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/dgg/dgg_graph_internal.h"

namespace geodesic {

std::string DescribeParams(const DggParams& p) {
  return absl::StrFormat(
      "eps %.9g%s%s%s, candidate rule %u", p.epsilon, p.pseudo_vertices ? ", pseudo vertices" : "",
      p.prune_redundant ? ", pruned" : "", p.exact_fans ? ", exact fans" : "", p.candidate_rule);
}

absl::Status CheckSameParams(const DggParams& want, const DggParams& have, std::string_view what) {
  auto text = [](auto v) -> std::string {
    if constexpr (std::is_same_v<decltype(v), bool>) {
      return v ? "true" : "false";
    } else {
      return absl::StrCat(v);
    }
  };
  auto differs = [&](std::string_view field, auto want_value, auto have_value) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s was built with %s %s, not %s", what, field, text(have_value), text(want_value)));
  };
  if (have.epsilon != want.epsilon) {
    return absl::FailedPreconditionError(absl::StrFormat("%s was built with epsilon %.9g, not %.9g",
                                                         what, have.epsilon, want.epsilon));
  }
  if (have.pseudo_vertices != want.pseudo_vertices) {
    return differs("pseudo_vertices", want.pseudo_vertices, have.pseudo_vertices);
  }
  if (have.prune_redundant != want.prune_redundant) {
    return differs("prune_redundant", want.prune_redundant, have.prune_redundant);
  }
  if (have.exact_fans != want.exact_fans) {
    return differs("exact_fans", want.exact_fans, have.exact_fans);
  }
  if (have.candidate_rule != want.candidate_rule) {
    return differs("candidate_rule", want.candidate_rule, have.candidate_rule);
  }
  return absl::OkStatus();
}

StoredDggParams StoredDggParams::Of(const DggParams& p) {
  return {p.epsilon, p.pseudo_vertices ? 1u : 0u, p.prune_redundant ? 1u : 0u,
          p.exact_fans ? 1u : 0u, p.candidate_rule};
}

DggParams StoredDggParams::params() const {
  DggParams p;
  p.epsilon = epsilon;
  p.pseudo_vertices = pseudo_vertices != 0;
  p.prune_redundant = prune_redundant != 0;
  p.exact_fans = exact_fans != 0;
  p.candidate_rule = candidate_rule;
  return p;
}

DggGraph::Storage::~Storage() {
  if (mapping != nullptr) munmap(mapping, mapping_bytes);
}

uint64_t DggGraph::byte_size() const {
  if (storage_ && storage_->mapping) return storage_->mapping_bytes;
  return offsets_.size_bytes() + edges_.size_bytes() + angles_.size_bytes() +
         pseudo_points_.size_bytes() + node_of_vertex_.size_bytes() + vertex_of_node_.size_bytes();
}

bool DggGraph::is_mapped() const { return storage_ && storage_->mapping; }

absl::Status DggGraph::Validate(const Mesh& mesh) const {
  if (num_mesh_vertices_ != mesh.num_vertices()) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "graph has %u mesh vertices but the mesh has %u", num_mesh_vertices_, mesh.num_vertices()));
  }
  if (num_nodes_ < num_mesh_vertices_ || pseudo_points_.size() != num_nodes_ - num_mesh_vertices_) {
    return absl::DataLossError("pseudo vertex count does not match the node count");
  }
  if (offsets_.size() != size_t{num_nodes_} + 1 || offsets_[0] != 0) {
    return absl::DataLossError("offsets table has the wrong size or does not start at 0");
  }
  const uint64_t m = edges_.size();
  if (angles_.size() != m || offsets_[num_nodes_] != m) {
    return absl::DataLossError("edge arrays disagree in length");
  }
  for (uint32_t u = 0; u < num_nodes_; ++u) {
    if (offsets_[u] > offsets_[u + 1]) {
      return absl::DataLossError(absl::StrFormat("offsets are not monotone at node %u", u));
    }
  }
  constexpr float kTwoPi = 2 * std::numbers::pi_v<float>;
  for (uint32_t u = 0; u < num_nodes_; ++u) {
    for (uint64_t i = offsets_[u]; i < offsets_[u + 1]; ++i) {
      const DggEdge& e = edges_[i];
      const uint32_t v = e.target;
      if (v >= num_nodes_ || v == u) {
        return absl::DataLossError(absl::StrFormat("edge %u of node %u points to %u", i, u, v));
      }
      if (!(e.weight > 0) || !std::isfinite(e.weight)) {
        return absl::DataLossError(absl::StrFormat("edge %u has weight %g", i, e.weight));
      }
      if (!(angles_[i] >= 0 && angles_[i] <= kTwoPi)) {
        return absl::DataLossError(absl::StrFormat("edge %u has angle %g", i, angles_[i]));
      }
      const uint64_t degree = offsets_[v + 1] - offsets_[v];
      if (e.fan.count > degree || (degree > 0 && e.fan.begin >= degree)) {
        return absl::DataLossError(absl::StrFormat("fan of edge %u leaves node %u's edges", i, v));
      }
    }
  }
  if (node_of_vertex_.size() != num_mesh_vertices_ ||
      vertex_of_node_.size() != num_mesh_vertices_) {
    return absl::DataLossError("vertex order tables have the wrong size");
  }
  // Each vertex's node is in range and maps back to it: a bijection.
  for (VertexId v = 0; v < num_mesh_vertices_; ++v) {
    const uint32_t u = node_of_vertex_[v];
    if (u >= num_mesh_vertices_ || vertex_of_node_[u] != v) {
      return absl::DataLossError(
          absl::StrFormat("vertex %u maps to node %u, which does not map back", v, u));
    }
  }
  for (uint32_t i = 0; i < pseudo_points_.size(); ++i) {
    absl::Status s = ValidateSurfacePoint(mesh, pseudo_points_[i]);
    if (!s.ok()) {
      return absl::DataLossError(absl::StrFormat("pseudo vertex %u: %s", i, s.message()));
    }
  }
  return absl::OkStatus();
}

std::shared_ptr<const DggGraph> DggGraphBuilder::FromArrays(DggGraphArrays arrays,
                                                            uint32_t num_nodes,
                                                            uint32_t num_mesh_vertices,
                                                            const DggParams& params,
                                                            uint64_t mesh_fingerprint) {
  auto storage = std::make_shared<DggGraph::Storage>();
  storage->arrays = std::move(arrays);
  auto graph = std::make_shared<DggGraph>();
  graph->num_nodes_ = num_nodes;
  graph->num_mesh_vertices_ = num_mesh_vertices;
  graph->params_ = params;
  graph->mesh_fingerprint_ = mesh_fingerprint;
  const DggGraphArrays& a = storage->arrays;
  graph->offsets_ = a.offsets;
  graph->edges_ = a.edges;
  graph->angles_ = a.angles;
  graph->pseudo_points_ = a.pseudo_points;
  graph->node_of_vertex_ = a.node_of_vertex;
  graph->vertex_of_node_ = a.vertex_of_node;
  graph->storage_ = std::move(storage);
  return graph;
}

}  // namespace geodesic
