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
#include <span>

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
// it, so its fans can be narrowed as the rows come in (NarrowFans).
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
  // know: its passes search only near p (NarrowAllFans, and the exact
  // fans'). Every sweep after it, from any source, that
  // arrives at u along p -> u relaxes the turns left alone.
  // Returns how many fewer edges the fans now hold.
  uint64_t NarrowFans(const DggGraph& g, uint32_t p, absl::Span<const LaneLabels> labels, int lane);

 private:
  std::unique_ptr<Edge[]> edges_;
  uint64_t count_ = 0;
};

// Every fan of `g` narrowed as CompactLaneEdges::NarrowFans narrows a
// node's, each from a sweep around its run of kFieldLanes nodes in node
// order (close together) out to `reach` of their longest turn: any label
// such a sweep leaves is the length of a real path, so a turn longer than
// it goes as soundly as with a complete row, and most that a row would
// drop do. Written into `edges`, which must be g's
// own edge array (a graph being built, that no one else reads yet): the
// graph build's last pass (core/query/build_dgg.cc). The sweeps read only the
// fans as they were, never ones already narrowed, so which thread ran which
// run, and when, changes nothing: a build gives the same bytes whatever its
// threads. Runs on the calling arena's threads. `progress(done, total)`
// hears of the runs done now and then and returns false to stop
// (CANCELLED). INVALID_ARGUMENT for other edges or a graph whose fans do
// not pack (LaneFanLayoutFor).
absl::Status NarrowAllFans(const DggGraph& g, std::span<DggEdge> edges, double reach,
                           const std::function<bool(uint64_t, uint64_t)>& progress);

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
