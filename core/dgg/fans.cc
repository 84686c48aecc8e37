// Phase 4 of the build (section 5.1.2): each edge's fan.
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

// Fans that no shortest path leaves. The turn u -> v -> w is left out of the
// fan of u -> v only when some path from u to w is strictly shorter than
// |uv| + |vw|: a shortest path never takes such a turn, since its part from
// u to w would not be shortest. So a search that relaxes, from each node,
// only the fan of the edge it was reached by still finds every shortest
// distance (core/query/graph_search.h). A fan is the shortest circular range of
// v's angle-sorted edges holding every turn kept.
//
// The first pass tries the paths of at most two edges: a scan of each
// node's two-edge neighbourhood. The optional second (exact_fans) searches
// from each node, along the first pass's fans (already sound), to its exact
// distances inside that neighbourhood, up to its longest listed turn, and
// keeps only the turns nothing there beats.

class FanBuilder {
 public:
  explicit FanBuilder(DggGraphArrays& a) : a_(a), nodes_(a.offsets.size() - 1) {}

  // Fans from paths of at most two edges, into the edges. The pass reads
  // only the edges' targets and weights.
  // Reports progress from 0.95 to `progress_end`: on large graphs this pass
  // takes long enough that a still bar looks like a hang.
  void TwoEdgePass(Progress& progress, double progress_end) {
    ParallelFor(nodes_, progress, "fans", 0.95, progress_end, [&](uint32_t u) {
      Scratch& sc = Local();
      CollectTurns(sc, u);
      KeepTurns(sc, u, sc.best, [&](uint64_t i, FanRange fan) { a_.edges[i].fan = fan; });
      Clear(sc);
    });
  }

  // Fans from exact distances inside each node's two-edge neighbourhood,
  // searched along the fans in the edges (sound ones: the first pass's),
  // then stored there.
  void ExactPass(Progress& progress) {
    std::vector<FanRange> fans(a_.edges.size());
    ParallelFor(nodes_, progress, "fans", 0.97, 1.0, [&](uint32_t u) {
      Scratch& sc = Local();
      if (sc.exact.size() < nodes_) {
        sc.exact.assign(nodes_, kUnknown);
        sc.fan.resize(nodes_);
        sc.queued_in.assign(nodes_, kNotQueued);
        sc.buckets.resize(kSearchBuckets + 1);
      }
      CollectTurns(sc, u);
      // Only a path shorter than a listed turn can drop it, and such a
      // path's nodes are all nearer than the longest: nothing further is
      // queued.
      const double bound = LongestListedTurn(sc, u);
      auto inside = [&](uint32_t y) { return sc.best[y] != kUnknown; };
      // Label-correcting, in buckets over [0, bound] (a binary heap's
      // sifting was most of the pass): a node taken out before its label is
      // final is queued again when it improves, and relaxes then along the
      // fan of its new label.
      const double per_bucket = bound > 0 ? kSearchBuckets / bound : 0;
      auto reach = [&](uint32_t y, double d, FanRange fan, uint32_t current) {
        sc.exact[y] = d;
        sc.fan[y] = fan;
        const uint32_t b =
            std::max(current, uint32_t(std::min<double>(kSearchBuckets, d * per_bucket)));
        if (sc.queued_in[y] <= b) return;  // taken out no later
        sc.queued_in[y] = b;
        sc.buckets[b].push_back(y);
      };
      reach(u, 0, {0, static_cast<uint32_t>(of(u).size())}, 0);
      for (uint32_t b = 0; b <= kSearchBuckets; ++b) {
        std::vector<uint32_t>& bucket = sc.buckets[b];
        for (size_t q = 0; q < bucket.size(); ++q) {
          const uint32_t x = bucket[q];
          if (sc.queued_in[x] != b) continue;  // moved to a lower bucket
          sc.queued_in[x] = kNotQueued;
          const double d = sc.exact[x];
          const auto list = of(x);
          const FanRange fan = sc.fan[x];
          for (uint32_t k = 0, j = fan.begin; k < fan.count; ++k) {
            const DggEdge& e = list[j];
            const double nd = d + e.weight;
            if (inside(e.target) && nd < sc.exact[e.target] && nd <= bound) {
              reach(e.target, nd, e.fan, b);
            }
            if (++j == list.size()) j = 0;
          }
        }
        bucket.clear();
      }
      // A node the fan-restricted search missed, or did not reach by the
      // bound, keeps its two-edge bound.
      for (uint32_t y : sc.ring_nodes()) sc.exact[y] = std::min(sc.exact[y], sc.best[y]);
      KeepTurns(sc, u, sc.exact, [&](uint64_t i, FanRange fan) { fans[i] = fan; });
      for (uint32_t y : sc.ring_nodes()) sc.exact[y] = kUnknown;
      Clear(sc);
    });
    if (progress.cancelled()) return;
    for (uint64_t i = 0; i < fans.size(); ++i) a_.edges[i].fan = fans[i];
  }

 private:
  static constexpr double kUnknown = std::numeric_limits<double>::infinity();
  // Buckets of the exact pass's search, the last one for labels at the bound.
  static constexpr uint32_t kSearchBuckets = 64;
  static constexpr uint32_t kNotQueued = ~0u;

  struct Scratch {
    // Per node, valid for the nodes in `ring`: the shortest path of at most
    // two edges from the current node.
    std::vector<double> best;
    // The nodes within two edges, and the listed turns u -> v -> y, each as
    // the index of v -> y in v's edges (its length and y are read again
    // there, from lines the walk just brought in): the first ring_size and
    // listed entries, those of u's i-th edge ending at listed_end[i]. The
    // vectors only grow, since the walk writes past those ends.
    std::vector<uint32_t> ring;
    std::vector<uint32_t> turns;
    std::vector<size_t> listed_end;
    size_t ring_size = 0;
    std::span<const uint32_t> ring_nodes() const { return {ring.data(), ring_size}; }
    std::vector<double> exact;  // the exact pass only
    std::vector<FanRange> fan;  // the exact pass only
    // The exact pass's queue: nodes by bucket, and each node's bucket
    // (kNotQueued outside the queue).
    std::vector<std::vector<uint32_t>> buckets;
    std::vector<uint32_t> queued_in;
  };

  std::span<const DggEdge> of(uint32_t u) const {
    return {a_.edges.data() + a_.offsets[u], a_.edges.data() + a_.offsets[u + 1]};
  }

  Scratch& Local() {
    Scratch& sc = scratch_.local();
    if (sc.best.size() < nodes_) sc.best.assign(nodes_, kUnknown);
    return sc;
  }

  // One walk over u's two-edge neighbourhood. A node there is reached by
  // many of u's turns, so rather than walking again to test each turn
  // against the final shortest path, the walk lists the turns that were
  // close to the shortest found so far: a turn that fails then fails at the
  // end too (the shortest only shrinks), and most turns are never listed.
  // The walk does not branch on what it finds (which way such a branch goes
  // is close to random, so it is mispredicted often): every turn and node is
  // written, and kept by moving the end past it.
  void CollectTurns(Scratch& sc, uint32_t u) {
    const auto edges = of(u);
    size_t turns = 0;
    for (const DggEdge& e : edges) turns += of(e.target).size();
    if (sc.turns.size() < turns) sc.turns.resize(turns);
    if (sc.ring.size() < turns + edges.size() + 1) sc.ring.resize(turns + edges.size() + 1);
    if (sc.listed_end.size() < edges.size()) sc.listed_end.resize(edges.size());
    size_t ring = 0, listed = 0;
    auto touch = [&](uint32_t y, double length) {
      double& best = sc.best[y];
      sc.ring[ring] = y;
      ring += best == kUnknown;
      best = std::min(best, length);
    };
    touch(u, 0);
    for (const DggEdge& e : edges) touch(e.target, e.weight);
    for (uint32_t i = 0; i < edges.size(); ++i) {
      const auto next = of(edges[i].target);
      for (uint32_t k = 0; k < next.size(); ++k) {
        const uint32_t y = next[k].target;
        const double length = double{edges[i].weight} + next[k].weight;
        sc.turns[listed] = k;
        listed += length * kStrictlyShorter <= sc.best[y];
        touch(y, length);
      }
      sc.listed_end[i] = listed;
    }
    sc.ring_size = ring;
  }

  double LongestListedTurn(const Scratch& sc, uint32_t u) const {
    const auto edges = of(u);
    double longest = 0;
    size_t t = 0;
    for (uint32_t i = 0; i < edges.size(); ++i) {
      const auto next = of(edges[i].target);
      for (; t < sc.listed_end[i]; ++t) {
        longest = std::max(longest, double{edges[i].weight} + next[sc.turns[t]].weight);
      }
    }
    return longest;
  }

  // The fans of u's edges, each passed to store(edge index, fan): each keeps
  // the turns that no path in `shortest` (per node of the ring) beats.
  template <typename Store>
  void KeepTurns(Scratch& sc, uint32_t u, const std::vector<double>& shortest, Store store) {
    const auto edges = of(u);
    // The turns kept move to the front of the edge's listed ones, without
    // a branch (whether a turn is kept is close to random).
    size_t t = 0;
    for (uint32_t i = 0; i < edges.size(); ++i) {
      const auto next = of(edges[i].target);
      uint32_t* const kept = sc.turns.data() + t;
      uint32_t count = 0;
      for (; t < sc.listed_end[i]; ++t) {
        const uint32_t k = sc.turns[t];
        const double length = double{edges[i].weight} + next[k].weight;
        kept[count] = k;
        count += shortest[next[k].target] >= length * kStrictlyShorter;
      }
      store(a_.offsets[u] + i, CircularHull({kept, count}, static_cast<uint32_t>(next.size())));
    }
  }

  void Clear(Scratch& sc) {
    for (uint32_t y : sc.ring_nodes()) sc.best[y] = kUnknown;
    sc.ring_size = 0;
  }

  DggGraphArrays& a_;
  const uint32_t nodes_;
  tbb::enumerable_thread_specific<Scratch> scratch_;
};

void ShortcutFreeFans(DggGraphArrays& a, bool exact, Progress& progress) {
  FanBuilder builder(a);
  builder.TwoEdgePass(progress, 0.97);
  if (exact) builder.ExactPass(progress);
}

}  // namespace

// Phase 4 (section 5.1.2): sort each node's edges by polar angle and give
// every directed edge u -> v the range of v's edges that a shortest path
// arriving along it can continue on. The edges become the graph's in place.
DggGraphArrays Finalize(Adjacency kept, NodeOrder order, const std::vector<PseudoVertex>& pseudo,
                        bool exact_fans, Progress& progress) {
  SortRows(kept, [](const DggHalfEdge& a, const DggHalfEdge& b) {
    return a.angle_here < b.angle_here || (a.angle_here == b.angle_here && a.to < b.to);
  });
  DggGraphArrays a;
  a.vertex_of_node = std::move(order.vertex_of_node);
  a.node_of_vertex = std::move(order.node_of_vertex);
  a.angles.resize(kept.edges.size());
  tbb::parallel_for(uint64_t{0}, uint64_t{kept.edges.size()},
                    [&](uint64_t i) { a.angles[i] = kept.edges[i].angle_here; });
  a.offsets = std::move(kept.offsets);
  a.edges = std::move(kept.edges).TransformInPlace<DggEdge>([](const DggHalfEdge& h) {
    return DggEdge{h.to, h.weight, {}};
  });
  ShortcutFreeFans(a, exact_fans, progress);
  a.pseudo_points.reserve(pseudo.size());
  for (const auto& p : pseudo) a.pseudo_points.push_back(p.point);
  return a;
}

}  // namespace geodesic::dgg_build_internal
