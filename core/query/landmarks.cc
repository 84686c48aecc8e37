#include "core/query/landmarks.h"

#include <algorithm>
#include <limits>
#include <utility>

#include "absl/status/status.h"
#include "core/query/graph_search.h"

namespace geodesic {
namespace {

// Graph distances from `source` to every node; false if cancelled.
bool ShortestDistances(const DggGraph& graph, const BucketShape& shape, uint32_t source,
                       const std::function<bool()>& cancelled, std::vector<double>& dist) {
  if (cancelled && cancelled()) return false;
  dist.assign(graph.num_nodes(), std::numeric_limits<double>::infinity());
  std::vector<FanRange> fan(graph.num_nodes());
  BucketQueue queue;
  queue.Reset(graph.num_nodes(), shape.width, shape.max_step);
  dist[source] = 0;
  fan[source] = AllEdges(graph, source);
  queue.Push(source, 0);
  uint64_t pops = 0;
  bool stopped = false;
  SearchGraph</*kUseFans=*/true>(
      graph, queue, dist.data(), fan.data(),
      [&](uint32_t) {
        stopped = cancelled && (++pops & 4095) == 0 && cancelled();
        return stopped ? Visit::kStop : Visit::kRelax;
      },
      [](uint32_t, uint32_t) {});
  return !stopped;
}

// The reached node with the largest value of `key`, or kNone.
uint32_t Farthest(const std::vector<double>& key) {
  uint32_t best = kNone;
  for (uint32_t v = 0; v < key.size(); ++v) {
    if (key[v] < std::numeric_limits<double>::infinity() && (best == kNone || key[v] > key[best]))
      best = v;
  }
  return best;
}

}  // namespace

uint64_t Landmarks::ComputeBytes(const DggGraph& graph, int count) {
  const uint64_t per_node = uint64_t(std::max(count, 0)) * sizeof(float) +
                            2 * sizeof(double) /* nearest, dist */ + sizeof(FanRange);
  return graph.num_nodes() * per_node;
}

absl::StatusOr<std::unique_ptr<const Landmarks>> Landmarks::Compute(
    const DggGraph& graph, int count, const std::function<bool()>& cancelled) {
  if (count <= 0) return absl::InvalidArgumentError("landmark count must be positive");
  auto result = std::make_unique<Landmarks>();
  const uint32_t n = graph.num_nodes();
  if (n == 0) return std::unique_ptr<const Landmarks>(std::move(result));
  std::vector<double> dist;
  // Farthest-point sampling on the graph metric; `nearest` holds each node's
  // distance to the closest landmark so far.
  std::vector<double> nearest;
  const BucketShape shape = BucketShapeOf(graph);
  if (!ShortestDistances(graph, shape, 0, cancelled, nearest)) {
    return absl::CancelledError("landmark computation cancelled");
  }
  result->count_ = count;
  result->distance_.assign(static_cast<size_t>(n) * count, std::numeric_limits<float>::infinity());
  for (int k = 0; k < count; ++k) {
    uint32_t next = Farthest(nearest);
    if (next == kNone) next = 0;
    if (!ShortestDistances(graph, shape, next, cancelled, dist)) {
      return absl::CancelledError("landmark computation cancelled");
    }
    result->nodes_.push_back(next);
    for (uint32_t v = 0; v < n; ++v) {
      result->distance_[static_cast<size_t>(v) * count + k] = static_cast<float>(dist[v]);
      // The first landmark replaces node 0, which only seeded the sampling.
      nearest[v] = k == 0 ? dist[v] : std::min(nearest[v], dist[v]);
    }
  }
  return std::unique_ptr<const Landmarks>(std::move(result));
}

}  // namespace geodesic
