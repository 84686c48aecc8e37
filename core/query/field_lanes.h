// Fields of up to kFieldLanes sources in one sweep of the graph: what a
// matrix's rows are made of. A node's labels for all lanes share a cache
// line and are relaxed together, so each edge is read once for the batch
// and its weight added to every lane at once (SIMD), where one field per
// source reads the whole graph per row.
//
// The search is SolveField's label-correcting one with a lane per source.
// A node is queued while any lane improved since it was taken out, keyed by
// about the smallest such label (the least label of the node that improved
// it, plus the edge: at most that, and found without a look at the lanes),
// and then relaxes, for the lanes that
// improved, one run of its edges covering each lane's fan. Relaxing more than a lane's fan only
// tries more real paths, so every label still ends as the graph distance: the same number as
// SolveField's, since both are the least sum of the same float weights added in double (exact for
// any mesh whose shortest edge is above 2^-29 of its longest path). Sources close together on the
// surface keep their wavefronts together, so a node is taken out about once for the whole batch:
// callers group sources by node order (nearby nodes, core/dgg/dgg_graph.h).
#ifndef GEODESIC_CORE_QUERY_FIELD_LANES_H_
#define GEODESIC_CORE_QUERY_FIELD_LANES_H_

#include <atomic>
#include <functional>
#include <memory>
#include <optional>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/dgg/dgg_graph.h"
#include "core/query/augmented_graph.h"
#include "core/query/graph_search.h"
#include "core/query/query_scratch.h"
#include "core/query/search_work.h"

namespace geodesic::query_internal {

struct LaneStats {
  uint64_t queue_pops = 0;
  uint64_t relaxed = 0;  // edges relaxed, each for every lane at once
  SearchWork work;       // the same sweep's work, in full
};

// A graph's edges as a sweep can read them instead of the graph's own
// records: 12 bytes each, the fan packed as in PackedLaneFans, where a
// DggEdge takes 16. A copy, made for a matrix of many rows and freed after
// it, so its fans can be narrowed, before the rows and as they come in
// (NarrowFansNear, NarrowFans).
class CompactLaneEdges {
 public:
  struct Edge {
    uint32_t target;
    float weight;
    // PackFan. Atomic (read and written relaxed) because NarrowFans may
    // rewrite it while other threads sweep: a sweep reads each fan whole,
    // the old one or the new, and both are sound.
    std::atomic<uint32_t> fan;
    FanRange Fan() const { return UnpackFan(fan.load(std::memory_order_relaxed)); }
  };
  static_assert(sizeof(Edge) == 12);

  // Nothing for a graph with a node of 2^16 edges or more, whose fans do
  // not pack (LaneFanLayoutFor).
  static std::optional<CompactLaneEdges> Of(const DggGraph& g);

  const Edge* data() const { return edges_.get(); }
  uint64_t bytes() const { return count_ * sizeof(Edge); }

  // Narrows the fans of node p's edges towards the turns a shortest path
  // takes, from lane `lane` of a sweep's `labels` whose source in that lane
  // was p: each label the length of a real path from p. The turn p -> u ->
  // w stays unless that path to w is shorter than |pu| + |uw| (by
  // kStrictlyShorter, as the build's fans). A complete row (no distance
  // limit) drops every turn no shortest path takes, which the build cannot
  // know: its exact pass searches only near p, and its default pass tries
  // only paths of two edges. Every sweep after it, from any source, that
  // arrives at u along p -> u relaxes the turns left alone.
  // Returns how many fewer edges the fans now hold.
  uint64_t NarrowFans(const DggGraph& g, uint32_t p, absl::Span<const LaneLabels> labels, int lane);

  // Narrows the fans of the edges of `nodes` (at most kFieldLanes) as
  // NarrowFans does, from one sweep around them that stops short of their
  // longest turns, in `sc`. Any label it leaves is the length of a real
  // path, so a turn longer than one to its end goes as soundly as with a
  // complete row, and most that a row would drop do. Before a matrix's first
  // row, so that every sweep gains, not only those after a source's row.
  // Returns how many fewer edges the fans hold.
  absl::StatusOr<uint64_t> NarrowFansNear(const DggGraph& g, const BucketShape& bucket_shape,
                                          QueryScratch& sc, absl::Span<const uint32_t> nodes,
                                          const std::function<bool()>& cancelled);

 private:
  // The longest turn p -> u -> w the fans of p's edges hold: |pu| + |uw|.
  double LongestTurn(const DggGraph& g, uint32_t p) const;
  // Turn k of `fan`, a run (that may wrap) of the `degree` edges from
  // `list` on.
  const Edge& TurnOf(uint64_t list, uint64_t degree, FanRange fan, uint32_t k) const {
    const uint64_t turn = uint64_t{fan.begin} + k;
    return edges_[list + (turn < degree ? turn : turn - degree)];
  }

  std::unique_ptr<Edge[]> edges_;
  uint64_t count_ = 0;
};

// The code that runs a sweep: the best this machine has, or a named one
// (tests compare them): AVX-512, AVX2 (for x86 machines without AVX-512),
// or the portable kernel, which runs on any.
enum class LaneKernel { kBest, kAvx512, kAvx2, kPortable };
// Whether this machine (and this build) runs `kernel`.
bool LaneKernelRuns(LaneKernel kernel);

// Lane k of sc.lane_dist[node] becomes the graph distance from sources[k]
// (already joined to the graph); lanes past sources.size() stay +inf.
// Labels above `max_distance` are not relaxed further, so they are upper
// bounds only: LaneDistanceTo reads them as +inf. CANCELLED when
// `cancelled` says so. The lanes' fans are kept in `layout`
// (LaneFanLayoutFor(g), or kWhole). The edges are read from `compact`
// (g's, with `layout` kPacked) or, when it is null, from g.
absl::StatusOr<LaneStats> SolveFieldLanes(const DggGraph& g, const BucketShape& bucket_shape,
                                          LaneFanLayout layout, const CompactLaneEdges* compact,
                                          QueryScratch& sc, absl::Span<const Endpoint> sources,
                                          double max_distance,
                                          const std::function<bool()>& cancelled,
                                          LaneKernel kernel = LaneKernel::kBest);

// Every lane's distance to an end point, as FieldDistanceTo reads a field:
// at its node, or the best of its temporary edges; +inf beyond
// `max_distance`.
LaneLabels LaneDistancesTo(const DggGraph& g, const QueryScratch& sc, const Endpoint& end,
                           double max_distance);

}  // namespace geodesic::query_internal

#endif  // GEODESIC_CORE_QUERY_FIELD_LANES_H_
