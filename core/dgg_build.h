// Construction of the discrete geodesic graph: Algorithm 1 of the DGG paper
// (candidate edges with early termination, pruning of redundant edges,
// pseudo vertices on anisotropic meshes), in parallel.
#ifndef GEODESIC_CORE_DGG_BUILD_H_
#define GEODESIC_CORE_DGG_BUILD_H_

#include <functional>
#include <memory>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/dgg_graph.h"
#include "core/mesh.h"

namespace geodesic {

struct DggBuildOptions {
  DggParams params;
  int threads = 0;  // 0: all hardware threads
  // Called now and then from any build thread with the current phase
  // ("candidates", "pruning", "pseudo", "fans") and the fraction of the whole
  // build done, in [0, 1]. Returning false cancels the build (CANCELLED).
  std::function<bool(std::string_view phase, double fraction)> progress;
};

struct DggBuildStats {
  double candidate_seconds = 0;
  double pruning_seconds = 0;
  double pseudo_seconds = 0;
  double fan_seconds = 0;
  double total_seconds = 0;
  uint64_t candidate_edges = 0;  // undirected, before pruning
  uint64_t edges = 0;            // undirected, in the final graph
  uint64_t windows_created = 0;  // by the candidate propagation, all sources
  uint32_t pseudo_vertices = 0;
  uint32_t max_degree = 0;
  double average_degree = 0;
};

// Fails with INVALID_ARGUMENT for epsilon outside (0, 1) or NaN, and with
// CANCELLED when the progress callback asks to stop.
absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDgg(const Mesh& mesh,
                                                         const DggBuildOptions& options,
                                                         DggBuildStats* stats = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_BUILD_H_
