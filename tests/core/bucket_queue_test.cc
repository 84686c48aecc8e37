#include "core/base/bucket_queue.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <random>
#include <vector>

#include "core/base/node_heap.h"
#include "gtest/gtest.h"

namespace geodesic {
namespace {

// A wavefront-like workload that runs over many turns of the ring: 50 nodes
// in the queue at any time, each pop pushing one key up to `max_step` beyond
// its own. Nodes come out bucket by
// bucket, never from a bucket below the floor, and all of them come out.
TEST(BucketQueueTest, TakesOutBucketByBucketAcrossManyTurnsOfTheRing) {
  std::mt19937_64 rng(3);
  const double width = 0.25, max_step = 3.0;
  std::uniform_real_distribution<double> step(0.0, max_step);
  BucketQueue queue;
  queue.Reset(20000, width, max_step);
  std::vector<double> key;
  for (int i = 0; i < 50; ++i) {
    key.push_back(step(rng));
    queue.Push(key.size() - 1, key.back());
  }
  size_t popped = 0;
  int64_t last_bucket = -1;
  while (!queue.empty()) {
    const uint32_t node = queue.Pop();
    ++popped;
    const int64_t bucket = static_cast<int64_t>(std::floor(key[node] / width));
    ASSERT_GE(bucket, last_bucket) << "node " << node;
    ASSERT_LE(queue.floor(), key[node]);
    last_bucket = bucket;
    if (key.size() < 20000) {
      key.push_back(key[node] + step(rng));
      queue.Push(key.size() - 1, key.back());
    }
  }
  EXPECT_EQ(popped, key.size());
  // The keys went around the ring (16 buckets here) hundreds of times.
  EXPECT_GT(key.back() / (width * queue.ring_size()), 100);
}

// The use it is for: a label-correcting search that takes a node out again
// whenever its label improves gives Dijkstra's distances.
TEST(BucketQueueTest, LabelCorrectingSearchGivesDijkstrasDistances) {
  std::mt19937_64 rng(11);
  const uint32_t n = 3000;
  std::uniform_int_distribution<uint32_t> pick(0, n - 1);
  std::uniform_real_distribution<double> weight(0.01, 2.0);
  struct Edge {
    uint32_t to;
    double w;
  };
  std::vector<std::vector<Edge>> adj(n);
  double max_weight = 0;
  for (uint32_t u = 0; u < n; ++u) {
    for (int k = 0; k < 4; ++k) {
      const uint32_t v = pick(rng);
      const double w = weight(rng);
      adj[u].push_back({v, w});
      adj[v].push_back({u, w});
      max_weight = std::max(max_weight, w);
    }
  }
  constexpr double kInf = std::numeric_limits<double>::infinity();
  auto solve = [&](auto push, auto pop, auto empty) {
    std::vector<double> dist(n, kInf);
    std::vector<uint8_t> handled(n, 0);
    dist[0] = 0;
    push(0, 0.0);
    while (!empty()) {
      const uint32_t u = pop();
      if (handled[u]) continue;
      handled[u] = 1;
      for (const Edge& e : adj[u]) {
        if (dist[u] + e.w < dist[e.to]) {
          dist[e.to] = dist[u] + e.w;
          handled[e.to] = 0;
          push(e.to, dist[e.to]);
        }
      }
    }
    return dist;
  };
  NodeHeap heap;
  heap.Reset(n);
  const std::vector<double> want = solve([&](uint32_t u, double d) { heap.Push(u, d); },
                                         [&] {
                                           const uint32_t u = heap.top();
                                           heap.Pop();
                                           return u;
                                         },
                                         [&] { return heap.empty(); });
  for (double width : {0.05, 0.5, 3.0}) {
    BucketQueue queue;
    queue.Reset(n, width, max_weight);
    const std::vector<double> got =
        solve([&](uint32_t u, double d) { queue.Push(u, d); }, [&] { return queue.Pop(); },
              [&] { return queue.empty(); });
    for (uint32_t v = 0; v < n; ++v) {
      ASSERT_NEAR(got[v], want[v], 1e-12 * want[v]) << "width " << width << " node " << v;
    }
  }
}

}  // namespace
}  // namespace geodesic
