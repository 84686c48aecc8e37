// Phase 2 of the build (section 4.2.2): pruning redundant edges.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <memory>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/dgg/build_phases.h"
#include "core/dgg/fan.h"

namespace geodesic::dgg_build_internal {
namespace {

// A total order on undirected edges: by weight, then by end ids. A pruned
// edge is only ever replaced by strictly smaller edges, so replacements are
// well-founded and pruning can run on every vertex in parallel.
struct EdgeKey {
  float w;
  uint32_t lo, hi;
  static EdgeKey Of(float w, uint32_t a, uint32_t b) { return {w, std::min(a, b), std::max(a, b)}; }
  bool operator<(const EdgeKey& o) const {
    if (w != o.w) return w < o.w;
    if (lo != o.lo) return lo < o.lo;
    return hi < o.hi;
  }
};

}  // namespace

// Phase 2 (section 4.2.2, PRUNEREDUNDANTEDGES): edge (s, x) is redundant when
// a path from s through its other neighbours reaches x within (1 + eps) of
// it. The local Dijkstra starts from every neighbour at its direct distance;
// only paths made of edges smaller than (s, x) count (EdgeKey), so the result
// does not depend on the order in which vertices are processed. A replacement
// path must also turn only within the fans (fan.h) at its relays, so that the
// fan-restricted solver can follow it; the fans used here are slightly
// narrower than the solver's so that rounding cannot break that promise.
std::vector<uint8_t> FindRedundant(const Mesh& mesh, const NodeOrder& order, const Adjacency& adj,
                                   double epsilon, Progress& progress) {
  const uint32_t n = adj.rows();
  const double prune_epsilon = PruningBudget(epsilon);
  std::vector<uint8_t> redundant(adj.edges.size(), 0);
  struct Scratch {
    std::vector<uint32_t> stamp, local;
    uint32_t current = 0;
    std::vector<double> dist;
    std::vector<EdgeKey> bottleneck;
    std::vector<float> arrival;
    std::vector<std::pair<double, uint32_t>> heap;
  };
  tbb::enumerable_thread_specific<Scratch> scratch([n] {
    Scratch s;
    s.stamp.assign(n, 0);
    s.local.assign(n, 0);
    return s;
  });
  ParallelFor(n, progress, "pruning", 0.8, 0.95, [&](uint32_t s) {
    Scratch& sc = scratch.local();
    auto nbrs = adj.of(s);
    if (nbrs.size() < 2) return;
    if (++sc.current == 0) {
      std::fill(sc.stamp.begin(), sc.stamp.end(), 0);
      sc.current = 1;
    }
    sc.dist.resize(nbrs.size());
    sc.bottleneck.resize(nbrs.size());
    sc.arrival.resize(nbrs.size());
    sc.heap.clear();
    for (uint32_t i = 0; i < nbrs.size(); ++i) {
      sc.stamp[nbrs[i].to] = sc.current;
      sc.local[nbrs[i].to] = i;
      sc.dist[i] = nbrs[i].weight;
      sc.bottleneck[i] = EdgeKey::Of(nbrs[i].weight, order.id(s), order.id(nbrs[i].to));
      sc.arrival[i] = nbrs[i].angle_there;
      sc.heap.push_back({-sc.dist[i], i});
    }
    std::make_heap(sc.heap.begin(), sc.heap.end());
    const uint64_t base = adj.offsets[s];
    while (!sc.heap.empty()) {
      std::pop_heap(sc.heap.begin(), sc.heap.end());
      auto [neg, i] = sc.heap.back();
      sc.heap.pop_back();
      if (-neg > sc.dist[i]) continue;
      const uint32_t u = nbrs[i].to;
      const bool is_vertex = u < mesh.num_vertices();
      const double period = is_vertex ? mesh.total_angle(order.id(u)) : kTwoPi;
      const bool boundary = is_vertex && mesh.is_boundary(order.id(u));
      for (const DggHalfEdge& e : adj.of(u)) {
        if (e.to == s || sc.stamp[e.to] != sc.current) continue;
        if (!InFan(sc.arrival[i], e.angle_here, period, boundary, epsilon, kPruningFanScale)) {
          continue;
        }
        const uint32_t j = sc.local[e.to];
        const double through = sc.dist[i] + e.weight;
        const EdgeKey own = EdgeKey::Of(nbrs[j].weight, order.id(s), order.id(e.to));
        EdgeKey b = std::max(sc.bottleneck[i], EdgeKey::Of(e.weight, order.id(u), order.id(e.to)));
        if (!(b < own)) continue;
        if (through <= (1 + prune_epsilon) * nbrs[j].weight) redundant[base + j] = 1;
        if (through < sc.dist[j]) {
          sc.dist[j] = through;
          sc.bottleneck[j] = b;
          sc.arrival[j] = e.angle_there;
          sc.heap.push_back({-through, j});
          std::push_heap(sc.heap.begin(), sc.heap.end());
        }
      }
    }
  });
  return redundant;
}

// Keeps an edge unless either end found it redundant, in place.
void DropRedundant(Adjacency& adj, const std::vector<uint8_t>& redundant) {
  const uint32_t n = adj.rows();
  std::vector<uint8_t> keep(adj.edges.size(), 0);
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t s) {
    for (uint64_t i = adj.offsets[s]; i < adj.offsets[s + 1]; ++i) {
      const DggHalfEdge* back = Find(std::as_const(adj).of(adj.edges[i].to), s);
      keep[i] = !redundant[i] && !redundant[back - adj.edges.data()];
    }
  });
  uint64_t kept = 0, from = 0;
  for (uint32_t s = 0; s < n; ++s) {
    for (; from < adj.offsets[s + 1]; ++from) {
      if (keep[from]) adj.edges[kept++] = adj.edges[from];
    }
    adj.offsets[s + 1] = kept;
  }
  adj.edges.resize(kept);
}

}  // namespace geodesic::dgg_build_internal
