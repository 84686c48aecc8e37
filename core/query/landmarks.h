// Landmark lower bounds for point-to-point A* on a DGG (ALT: A*, landmarks
// and the triangle inequality; Goldberg and Harrelson, SODA 2005).
//
// For a landmark node L and graph distances d_L, the triangle inequality
// gives d(v, t) >= |d_L(t) - d_L(v)| on the (undirected) graph. With a
// handful of landmarks spread over the surface by farthest-point sampling,
// the largest of these bounds is far tighter than the straight-line distance
// on a curved surface (a limb, a fold), so far fewer nodes are settled.
//
// The distances are graph distances, which is what a search on the graph
// needs; they are stored as float32 (the graph's own weight precision): the
// rounding, ~6e-8 relative, can loosen a bound by as much, which moves an
// answer by no more than that.
#ifndef GEODESIC_CORE_QUERY_LANDMARKS_H_
#define GEODESIC_CORE_QUERY_LANDMARKS_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <span>
#include <vector>

#include "absl/status/statusor.h"
#include "core/dgg/dgg_graph.h"

namespace geodesic {

class Landmarks {
 public:
  // Picks `count` landmarks, each the node farthest (on the graph) from those
  // picked before, starting from the node farthest from node 0: count + 1
  // single-source searches. Nodes in components no landmark reaches get no
  // bound (+inf distances). `cancelled` is polled during the searches.
  static absl::StatusOr<std::unique_ptr<const Landmarks>> Compute(
      const DggGraph& graph, int count, const std::function<bool()>& cancelled = {});

  int count() const { return count_; }
  std::span<const uint32_t> nodes() const { return nodes_; }
  // Graph distance from each landmark to `node` (+inf if unreachable).
  std::span<const float> of(uint32_t node) const {
    return {distance_.data() + static_cast<size_t>(node) * count_, static_cast<size_t>(count_)};
  }
  uint64_t byte_size() const { return distance_.size() * sizeof(float); }
  // What Compute holds while it runs: the distances it keeps and the
  // per-node arrays of its searches, for counting them before they exist.
  static uint64_t ComputeBytes(const DggGraph& graph, int count);

 private:
  int count_ = 0;
  std::vector<uint32_t> nodes_;
  std::vector<float> distance_;  // node-major: count_ values per node
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_LANDMARKS_H_
