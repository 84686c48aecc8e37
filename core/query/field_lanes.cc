#include "core/query/field_lanes.h"

#include <algorithm>
#include <bit>
#include <cstring>

#include "absl/status/statusor.h"
#include "core/query/geodesic_engine.h"

namespace geodesic::query_internal {
namespace {

// A node's labels as one value: GCC lowers the arithmetic to the widest
// SIMD the target has.
typedef double Lanes __attribute__((vector_size(sizeof(LaneLabels))));
typedef int64_t LaneBits __attribute__((vector_size(sizeof(LaneLabels))));
static_assert(sizeof(Lanes) == sizeof(LaneLabels) && alignof(LaneLabels) >= alignof(Lanes));

Lanes& AsLanes(LaneLabels& l) { return *reinterpret_cast<Lanes*>(l.dist); }
static_assert(sizeof(LaneFans) == sizeof(LaneBits));
static_assert(kFieldLanes == 8, "MaskOf and kLaneBit spell out eight lanes");

// Sets the fans of the lanes of `which` to `f`, all in one write.
void SetFans(LaneFans& fans, const LaneBits& which, FanRange f) {
  LaneBits bits;
  std::memcpy(&bits, static_cast<void*>(fans.fan), sizeof(bits));
  bits = which ? LaneBits{} + std::bit_cast<int64_t>(f) : bits;
  std::memcpy(static_cast<void*>(fans.fan), &bits, sizeof(bits));
}
void SetFans(PackedLaneFans& fans, const LaneBits& which, FanRange f) {
  typedef int32_t PackedBits __attribute__((vector_size(sizeof(PackedLaneFans))));
  PackedBits bits;
  std::memcpy(&bits, fans.fan, sizeof(bits));
  bits = __builtin_convertvector(which, PackedBits) ? PackedBits{} + int32_t(PackFan(f)) : bits;
  std::memcpy(fans.fan, &bits, sizeof(bits));
}
FanRange FanOf(const LaneFans& fans, int lane) { return fans.fan[lane]; }
FanRange FanOf(const PackedLaneFans& fans, int lane) { return UnpackFan(fans.fan[lane]); }
void SetFan(LaneFans& fans, int lane, FanRange f) { fans.fan[lane] = f; }
void SetFan(PackedLaneFans& fans, int lane, FanRange f) { fans.fan[lane] = PackFan(f); }

// The lanes whose bits are set, one bit each. Narrowed to a byte a lane, the
// top bits gather by one multiplication: with AVX-512 the compiler keeps the
// comparison's mask register and narrows it in two instructions, where a
// loop over the lanes took one extraction each.
uint32_t MaskOf(const LaneBits& bits) {
  typedef int8_t LaneBytes __attribute__((vector_size(kFieldLanes)));
  const LaneBytes bytes = __builtin_convertvector(bits, LaneBytes);
  uint64_t b;
  std::memcpy(&b, &bytes, sizeof(b));
  return static_cast<uint32_t>(((b & 0x8080808080808080ull) * 0x0002040810204081ull) >> 56);
}

// Lane k's bit of a lane mask, for spreading one over the lanes.
constexpr LaneBits kLaneBit = {1, 2, 4, 8, 16, 32, 64, 128};

// The smallest label among the lanes of `mask`: a queued node's key.
double LowestOf(const LaneLabels& l, uint32_t mask) {
  double low = kInfinity;
  for (; mask; mask &= mask - 1) low = std::min(low, l.dist[std::countr_zero(mask)]);
  return low;
}

// A run of a node's `degree` angle-sorted edges that holds the fans of the
// lanes of `mask` (each a run that may wrap past the end). Each fan not
// already inside extends the run at whichever end adds fewer edges: not
// always the shortest such run, but a pop costs a few comparisons, and
// relaxing a little more than the fans is only more real paths tried.
template <typename Fans>
FanRange CoverFans(const Fans& fans, uint32_t mask, uint32_t degree) {
  FanRange cover = FanOf(fans, std::countr_zero(mask));
  for (mask &= mask - 1; mask; mask &= mask - 1) {
    const FanRange f = FanOf(fans, std::countr_zero(mask));
    if (f.count >= degree) return {0, degree};
    // Where f starts, and where cover starts, each seen from the other.
    uint32_t ahead = f.begin - cover.begin, behind = cover.begin - f.begin;
    if (f.begin < cover.begin) ahead += degree;
    if (cover.begin < f.begin) behind += degree;
    if (ahead + f.count <= cover.count) continue;  // inside already
    const uint32_t forward = ahead + f.count, backward = behind + cover.count;
    if (forward <= backward) {
      cover.count = forward;
    } else {
      cover = {f.begin, std::max(backward, f.count)};
    }
    if (cover.count >= degree) return {0, degree};
  }
  return cover;
}

template <typename Fans>
[[gnu::always_inline]] inline absl::StatusOr<LaneStats> Sweep(
    const DggGraph& g, const BucketShape& bucket_shape, QueryScratch& sc, Fans* fan,
    absl::Span<const Endpoint> sources, double max_distance,
    const std::function<bool()>& cancelled) {
  const uint32_t nodes = g.num_nodes();
  LaneLabels* dist = sc.lane_dist.data();
  uint8_t* dirty = sc.lane_dirty.data();
  const Lanes unreached = Lanes{} + kInfinity;
  for (uint32_t u = 0; u < nodes; ++u) AsLanes(dist[u]) = unreached;
  std::memset(dirty, 0, nodes);

  // Vertex sources at 0, other points through their temporary edges; a
  // seed relaxes all its edges, as in SolveField.
  std::vector<uint32_t> seeds;
  double max_seed = 0;
  auto seed = [&](uint32_t u, double d, int lane) {
    if (!(d < dist[u].dist[lane])) return;
    dist[u].dist[lane] = d;
    SetFan(fan[u], lane, AllEdges(g, u));
    if (!dirty[u]) seeds.push_back(u);
    dirty[u] |= 1u << lane;
    max_seed = std::max(max_seed, d);
  };
  for (size_t k = 0; k < sources.size() && k < kFieldLanes; ++k) {
    if (sources[k].is_node) seed(sources[k].node, 0, k);
    for (const TemporaryEdge& e : sources[k].edges) seed(e.node, e.weight, k);
  }
  // Buckets half as wide as a single field's: the lanes' wavefronts are
  // a little apart, and narrower buckets take fewer nodes out twice.
  BucketQueue& queue = sc.buckets;
  queue.Reset(nodes, bucket_shape.width / 2, std::max(bucket_shape.max_step, max_seed));
  for (uint32_t u : seeds) queue.Lower(u, LowestOf(dist[u], dirty[u]));

  const auto offsets = g.offsets();
  const DggEdge* edges = g.edges().data();
  const Lanes limit = Lanes{} + max_distance;
  struct Improvement {
    uint32_t edge;  // among u's
    uint32_t lanes;
  };
  std::vector<Improvement> improvements;
  LaneStats stats;
  while (!queue.empty()) {
    const uint32_t u = queue.Pop();
    const uint32_t mask = dirty[u];
    dirty[u] = 0;
    if (cancelled && (stats.queue_pops & 4095) == 0 && cancelled()) {
      return absl::CancelledError("field cancelled");
    }
    ++stats.queue_pops;
    // Only the lanes that improved relax: the others did so with these
    // labels already. Labels past the limit stop there.
    Lanes du = AsLanes(dist[u]);
    const LaneBits keep = (du <= limit) & (((LaneBits{} + mask) & kLaneBit) != 0);
    du = keep ? du : unreached;
    const uint32_t active = MaskOf(keep);
    if (!active) continue;
    const uint64_t begin = offsets[u], end = offsets[u + 1];
    const FanRange run = CoverFans(fan[u], active, end - begin);
    if (const uint32_t next = queue.Peek(kNone, 4); next != kNone && dirty[next]) {
      const FanRange r = FanOf(fan[next], std::countr_zero(uint32_t(dirty[next])));
      const uint64_t list = offsets[next], list_end = offsets[next + 1];
      const uint64_t first = list + r.begin, last = first + r.count;
      if (r.count > 0 && first < list_end) PrefetchEdges(edges, first, std::min(last, list_end));
      __builtin_prefetch(&dist[next]);
    }
    stats.relaxed += run.count;
    if (improvements.size() < run.count) improvements.resize(run.count);
    // Labels first, without a branch: whether an edge improves a label waits
    // on that label's load, and a branch on it stalled on every load it
    // mispredicted, where the loads of a whole run can be in flight at once.
    // The improved targets are queued after, with their lines in cache, in
    // the order found.
    size_t found = 0;
    for (uint64_t k = 0, i = begin + run.begin; k < run.count; ++k) {
      const DggEdge& e = edges[i];
      const Lanes nd = du + e.weight;
      Lanes& dv = AsLanes(dist[e.target]);
      const LaneBits better = nd < dv;
      dv = better ? nd : dv;
      const uint32_t improved = MaskOf(better);
      improvements[found] = {static_cast<uint32_t>(i - begin), improved};
      found += improved != 0;
      if (++i == end) i = begin;  // runs wrap past u's last edge
    }
    for (size_t k = 0; k < found; ++k) {
      const auto [i, improved] = improvements[k];
      const DggEdge& e = edges[begin + i];
      const uint32_t v = e.target;
      SetFans(fan[v], ((LaneBits{} + improved) & kLaneBit) != 0, e.fan);
      dirty[v] |= improved;
      queue.Lower(v, LowestOf(dist[v], improved));
    }
  }
  return stats;
}

}  // namespace

// Eight lanes are one instruction each with AVX-512, whose mask registers
// also hold the comparisons; without it (AVX2 was no faster) the compiler
// splits them. The loader picks the clone the machine runs, through a
// resolver that runs before ThreadSanitizer's runtime is up (and crashes
// there), so a TSan build has the one portable version.
#if defined(__SANITIZE_THREAD__)
#define GEODESIC_LANE_CLONES
#else
#define GEODESIC_LANE_CLONES __attribute__((target_clones("arch=x86-64-v4", "default")))
#endif
GEODESIC_LANE_CLONES absl::StatusOr<LaneStats> SolveFieldLanes(
    const DggGraph& g, const BucketShape& bucket_shape, LaneFanLayout layout, QueryScratch& sc,
    absl::Span<const Endpoint> sources, double max_distance,
    const std::function<bool()>& cancelled) {
  sc.PrepareLanes(g.num_nodes(), layout);
  return layout == LaneFanLayout::kPacked
             ? Sweep(g, bucket_shape, sc, sc.lane_fan_packed.data(), sources, max_distance,
                     cancelled)
             : Sweep(g, bucket_shape, sc, sc.lane_fan.data(), sources, max_distance, cancelled);
}

LaneLabels LaneDistancesTo(const DggGraph& g, const QueryScratch& sc, const Endpoint& end,
                           double max_distance) {
  auto at = [&](VertexId v) {
    LaneLabels l = sc.lane_dist[g.node_of_vertex(v)];
    for (double& d : l.dist) d = d > max_distance ? kInfinity : d;
    return l;
  };
  if (end.is_node) return at(end.point.id);
  LaneLabels best;
  std::fill(std::begin(best.dist), std::end(best.dist), kInfinity);
  for (const TemporaryEdge& e : end.edges) {
    const LaneLabels l = at(e.vertex);
    for (int k = 0; k < kFieldLanes; ++k)
      best.dist[k] = std::min(best.dist[k], l.dist[k] + e.weight);
  }
  return best;
}

}  // namespace geodesic::query_internal
