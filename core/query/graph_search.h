// The search every whole-graph query runs (fields, landmarks): labels grow
// outwards from seeded nodes, and a node taken out of the queue relaxes the
// fan of the edge it was reached by.
//
// The graph's fans hold every turn a shortest path can take
// (core/dgg/fans.cc), so the labels end as exactly the graph's shortest
// distances, in any queue order that takes a node out again after it
// improves. The induction, over nodes in order of distance: let v -> w be
// the last edge of a shortest path to w, and v's final label set by u -> v,
// so d(v) = d(u) + |uv|. Were w outside that edge's fan, some path from u to
// w would be shorter than |uv| + |vw|, so d(w) < d(v) + |vw| = d(w).
#ifndef GEODESIC_CORE_QUERY_GRAPH_SEARCH_H_
#define GEODESIC_CORE_QUERY_GRAPH_SEARCH_H_

#include <algorithm>
#include <cstdint>
#include <vector>

#include "core/base/bucket_queue.h"
#include "core/base/node_heap.h"
#include "core/dgg/dgg_graph.h"
#include "core/query/search_work.h"

namespace geodesic {

// NodeHeap in the interface BucketQueue has: for searches that must take
// nodes out in order of distance (stopping at targets).
struct HeapQueue {
  NodeHeap& heap;
  bool empty() const { return heap.empty(); }
  void Push(uint32_t node, double key) { heap.Push(node, key); }
  uint32_t Pop() {
    const uint32_t node = heap.top();
    heap.Pop();
    return node;
  }
  uint32_t Peek(uint32_t none, size_t /*ahead*/) const { return heap.empty() ? none : heap.top(); }
};

// How a bucket queue suits a graph: buckets one mean edge weight wide, and
// keys at most the longest edge ahead. Wider buckets take a few nodes out
// more than once but visit fewer empty buckets; one mean weight was the
// fastest of the widths tried (bench/notes.md, "Bucket width").
struct BucketShape {
  double width = 1;
  double max_step = 1;
};
inline BucketShape BucketShapeOf(const DggGraph& g) {
  double sum = 0, longest = 0;
  for (const DggEdge& e : g.edges()) {
    sum += e.weight;
    longest = std::max<double>(longest, e.weight);
  }
  if (g.edges().empty() || longest == 0) return {};
  return {sum / g.edges().size(), longest};
}

// A fan in 32 bits, its begin and count in 16 each: half a FanRange's
// bytes, for graphs whose nodes all have fewer than 2^16 edges.
inline constexpr uint64_t kMaxPackedDegree = 0xffff;
inline uint32_t PackFan(FanRange f) { return f.begin | f.count << 16; }
inline FanRange UnpackFan(uint32_t packed) { return {packed & 0xffff, packed >> 16}; }

// A search keeps each node's fan whole or packed: these read and write
// either.
inline FanRange FanIn(FanRange slot) { return slot; }
inline FanRange FanIn(uint32_t slot) { return UnpackFan(slot); }
inline void SetFan(FanRange& slot, FanRange fan) { slot = fan; }
inline void SetFan(uint32_t& slot, FanRange fan) { slot = PackFan(fan); }

// The edges a seed relaxes: all of them.
inline FanRange AllEdges(const DggGraph& g, uint32_t u) {
  return {0, static_cast<uint32_t>(g.offsets()[u + 1] - g.offsets()[u])};
}

enum class Visit { kRelax, kSkip, kStop };

// Asks for the cache lines of edges [begin, end), begin < end.
template <typename Edge>
inline void PrefetchEdges(const Edge* edges, uint64_t begin, uint64_t end) {
  constexpr uint64_t kPerLine = 64 / sizeof(Edge);
  // Steps of a line from begin, the last one moved back to end - 1: that
  // covers the last line when begin is not aligned.
  for (uint64_t i = begin; i < end + kPerLine - 1; i += kPerLine) {
    __builtin_prefetch(&edges[std::min(i, end - 1)]);
  }
}

// Runs the search from what `queue` holds (the caller has set each seed's
// dist and fan, a FanRange or a packed one per node: FanIn). `visit(u)` is asked about each node
// taken out; after `dist[v]` improved through u, `improved(u, v)` is called. Without fans every
// node relaxes all its edges (Dijkstra's rule, for checking). Returns the work done from the first
// pop on: the seeds' pushes and labels are the caller's to add. The choice is a template argument
// so that the inner loop carries no test for it.
template <bool kUseFans, typename Queue, typename FanSlot, typename VisitFn, typename ImprovedFn>
SearchWork SearchGraph(const DggGraph& g, Queue& queue, double* dist, FanSlot* fan, VisitFn visit,
                       ImprovedFn improved) {
  const auto offsets = g.offsets();
  const DggEdge* edges = g.edges().data();
  // Locals, not the struct's fields, so that they stay in registers across
  // the calls the loop makes.
  uint64_t relaxed = 0, pops = 0, improved_labels = 0, expanded = 0;
  std::vector<uint32_t> improvements;  // of u's edges, by index in its list
  while (!queue.empty()) {
    const uint32_t u = queue.Pop();
    ++pops;
    const Visit what = visit(u);
    if (what == Visit::kSkip) continue;
    if (what == Visit::kStop) break;
    const uint64_t begin = offsets[u], end = offsets[u + 1];
    const FanRange run = kUseFans ? FanIn(fan[u]) : AllEdges(g, u);
    // The graph is too large for the cache and the search visits it in no
    // order memory likes: start loading a coming node's fan now, every line
    // of it (a fan may wrap past the end of the node's list). With buckets
    // the next few nodes are known, and the very next is too close. Finding
    // that fan reads the node's offsets and fan record, which a cold cache
    // (a new process, its graph just validated) misses as well: those are
    // asked for further ahead still (bench/notes.md, "Memory order").
    constexpr size_t kAhead = 8, kFarAhead = 16;
    if (const uint32_t far = queue.Peek(kNone, kFarAhead); far != kNone) {
      __builtin_prefetch(&offsets[far]);
      if constexpr (kUseFans) __builtin_prefetch(&fan[far]);
    }
    if (const uint32_t next = queue.Peek(kNone, kAhead); next != kNone) {
      const uint64_t list = offsets[next], list_end = offsets[next + 1];
      const FanRange r = kUseFans ? FanIn(fan[next]) : AllEdges(g, next);
      const uint64_t first = list + r.begin, last = first + r.count;
      if (r.count > 0) PrefetchEdges(edges, first, std::min(last, list_end));
      if (last > list_end) PrefetchEdges(edges, list, list + (last - list_end));
    }
    const double du = dist[u];
    relaxed += run.count;
    ++expanded;
    if (improvements.size() < run.count) improvements.resize(run.count);
    // Labels first, without a branch: whether an edge improves a label waits
    // on that label's load, and a branch on it stalled on each load it
    // mispredicted, where the loads of a whole run can be in flight at once.
    // The improved targets are queued after, in the order found.
    size_t found = 0;
    for (uint64_t k = 0, i = begin + run.begin; k < run.count; ++k) {
      const DggEdge& e = edges[i];
      const double nd = du + e.weight, old = dist[e.target];
      const bool better = nd < old;
      dist[e.target] = better ? nd : old;
      improvements[found] = static_cast<uint32_t>(i - begin);
      found += better;
      if (++i == end) i = begin;  // fans wrap past u's last edge
    }
    improved_labels += found;
    for (size_t k = 0; k < found; ++k) {
      const DggEdge& e = edges[begin + improvements[k]];
      if constexpr (kUseFans) SetFan(fan[e.target], e.fan);
      improved(u, e.target);
      queue.Push(e.target, dist[e.target]);
    }
  }
  SearchWork work;
  work.relaxed = relaxed;
  work.improved = improved_labels;
  work.pushes = improved_labels;  // each improvement queues its target once
  work.pops = pops;
  work.graph_bytes = GraphBytesRead(relaxed, sizeof(DggEdge), expanded);
  return work;
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_GRAPH_SEARCH_H_
