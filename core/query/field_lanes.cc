#include "core/query/field_lanes.h"

#include <tbb/enumerable_thread_specific.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cstring>
#include <numeric>

#include "absl/status/statusor.h"
#include "core/base/for_each_in_parallel.h"
#include "core/base/status.h"
#include "core/dgg/fan.h"
#include "core/query/geodesic_engine.h"

// The x86 kernels are chosen at run time (__builtin_cpu_supports), not by
// an ifunc, whose resolver runs before ThreadSanitizer's runtime is up and
// crashes there; a TSan build keeps to the portable kernel all the same, as
// its checks do not depend on the kernel.
#if defined(__x86_64__) && !defined(__SANITIZE_THREAD__)
#define GEODESIC_LANES_X86 1
#include <immintrin.h>
#else
#define GEODESIC_LANES_X86 0
#endif

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

FanRange FanOf(const LaneFans& fans, int lane) { return fans.fan[lane]; }
FanRange FanOf(const PackedLaneFans& fans, int lane) { return UnpackFan(fans.fan[lane]); }
void SetFan(LaneFans& fans, int lane, FanRange f) { fans.fan[lane] = f; }
void SetFan(PackedLaneFans& fans, int lane, FanRange f) { fans.fan[lane] = PackFan(f); }
// The fan an edge hands its target.
FanRange FanOf(const DggEdge& e) { return e.fan; }
FanRange FanOf(const CompactLaneEdges::Edge& e) { return e.Fan(); }

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

// What the sweep does across lanes, in three kernels: GCC's vector
// extensions for any machine; AVX-512 intrinsics, where a comparison's lanes
// stay a mask register that selects, stores and reduces without being spread
// back over a vector and gathered again (bench/notes.md, "Matrix lanes");
// and AVX2 intrinsics, for x86 machines without AVX-512.
struct PortableLanes {
  template <typename Fans>
  static FanRange Cover(const Fans& fans, uint32_t mask, uint32_t degree) {
    return CoverFans(fans, mask, degree);
  }
  // Lane k's bit of a lane mask, for spreading one over the lanes.
  static constexpr LaneBits kLaneBit = {1, 2, 4, 8, 16, 32, 64, 128};

  // The lanes whose bits are set, one bit each. Narrowed to a byte a lane,
  // the top bits gather by one multiplication.
  static uint32_t MaskOf(const LaneBits& bits) {
    typedef int8_t LaneBytes __attribute__((vector_size(kFieldLanes)));
    const LaneBytes bytes = __builtin_convertvector(bits, LaneBytes);
    uint64_t b;
    std::memcpy(&b, &bytes, sizeof(b));
    return static_cast<uint32_t>(((b & 0x8080808080808080ull) * 0x0002040810204081ull) >> 56);
  }

  // Lowers each label of `dv` that `nd` improves; returns those lanes.
  static uint32_t Relax(Lanes& dv, const Lanes& nd) {
    const LaneBits better = nd < dv;
    dv = better ? nd : dv;
    return MaskOf(better);
  }
  // The lanes of `mask` whose labels are within `limit`; the others of `du`
  // become +inf.
  static uint32_t KeepWithin(Lanes& du, const Lanes& limit, uint32_t mask) {
    const LaneBits keep = (du <= limit) & (((LaneBits{} + mask) & kLaneBit) != 0);
    du = keep ? du : Lanes{} + kInfinity;
    return MaskOf(keep);
  }
  // Sets the fans of the lanes of `mask` to `f`, all in one write.
  static void SetFans(LaneFans& fans, uint32_t mask, FanRange f) {
    LaneBits bits;
    std::memcpy(&bits, static_cast<void*>(fans.fan), sizeof(bits));
    bits = ((LaneBits{} + mask) & kLaneBit) != 0 ? LaneBits{} + std::bit_cast<int64_t>(f) : bits;
    std::memcpy(static_cast<void*>(fans.fan), &bits, sizeof(bits));
  }
  static void SetFans(PackedLaneFans& fans, uint32_t mask, FanRange f) {
    typedef int32_t PackedBits __attribute__((vector_size(sizeof(PackedLaneFans))));
    PackedBits bits;
    std::memcpy(&bits, fans.fan, sizeof(bits));
    const LaneBits which = ((LaneBits{} + mask) & kLaneBit) != 0;
    bits = __builtin_convertvector(which, PackedBits) ? PackedBits{} + int32_t(PackFan(f)) : bits;
    std::memcpy(fans.fan, &bits, sizeof(bits));
  }
  // The smallest label among the lanes of `mask`: a queued node's key.
  static double LowestOf(const LaneLabels& l, uint32_t mask) {
    double low = kInfinity;
    for (; mask; mask &= mask - 1) low = std::min(low, l.dist[std::countr_zero(mask)]);
    return low;
  }
};

#if GEODESIC_LANES_X86
#define GEODESIC_AVX512 gnu::target("arch=x86-64-v4")
#define GEODESIC_AVX2 gnu::target("avx2,bmi,bmi2,fma")
// A lane's fan as begin and count, one int32 lane each.
typedef int32_t LaneInts __attribute__((vector_size(kFieldLanes * sizeof(int32_t))));

// Helpers of both x86 kernels, in GCC's vector extensions, compiled for
// the kernel whose (flattened) sweep inlines them. Vectors go by reference:
// a vector argument's ABI depends on the target.

// The least of eight lanes, in three halvings (GCC 12's masked reductions
// draw a false warning of an uninitialised value).
template <typename V>
[[gnu::always_inline]] inline auto Least(const V& lanes) {
  V v = lanes;
  V w = __builtin_shufflevector(v, v, 4, 5, 6, 7, 0, 1, 2, 3);
  v = w < v ? w : v;
  w = __builtin_shufflevector(v, v, 2, 3, 0, 1, 6, 7, 4, 5);
  v = w < v ? w : v;
  w = __builtin_shufflevector(v, v, 1, 0, 3, 2, 5, 4, 7, 6);
  v = w < v ? w : v;
  return v[0];
}
[[gnu::always_inline]] inline void BeginsAndCounts(const PackedLaneFans& fans, LaneInts& begin,
                                                   LaneInts& count) {
  LaneInts packed;
  std::memcpy(&packed, fans.fan, sizeof(packed));
  begin = packed & 0xffff;
  count = (packed >> 16) & 0xffff;
}
[[gnu::always_inline]] inline void BeginsAndCounts(const LaneFans& fans, LaneInts& begin,
                                                   LaneInts& count) {
  typedef int32_t Pairs __attribute__((vector_size(2 * sizeof(LaneInts))));
  Pairs pairs;
  std::memcpy(&pairs, static_cast<const void*>(fans.fan), sizeof(pairs));
  begin = __builtin_shufflevector(pairs, pairs, 0, 2, 4, 6, 8, 10, 12, 14);
  count = __builtin_shufflevector(pairs, pairs, 1, 3, 5, 7, 9, 11, 13, 15);
}
// As CoverFans, without a branch: each fan placed, by its middle, within
// half a turn of the first lane's, and the run from the earliest start to
// the latest end. Simd::LeastWithin(mask, v, n) is the least lane of `v`
// in `mask` (at most n).
template <typename Simd, typename Fans>
[[gnu::always_inline]] inline FanRange CoverByMiddles(const Fans& fans, uint32_t mask,
                                                      uint32_t degree) {
  LaneInts begin, count;
  BeginsAndCounts(fans, begin, count);
  const LaneInts half = count >> 1, middle = begin + half;
  const int32_t n = static_cast<int32_t>(degree), from = middle[std::countr_zero(mask)];
  LaneInts at = middle - from;
  at = at < 0 ? at + n : at;
  at = at > n / 2 ? at - n : at;
  at -= half;
  const int32_t first = Simd::LeastWithin(mask, at, n);
  const int32_t last = -Simd::LeastWithin(mask, -at - count, n);
  const int32_t run = last - first;
  if (run >= n) return {0, degree};
  // first <= the first lane's own start, so start <= its begin < n.
  const int32_t start = from + first;
  return {static_cast<uint32_t>(start < 0 ? start + n : start), static_cast<uint32_t>(run)};
}

struct Avx512Lanes {
  template <typename Fans>
  [[GEODESIC_AVX512]] static FanRange Cover(const Fans& fans, uint32_t mask, uint32_t degree) {
    return CoverByMiddles<Avx512Lanes>(fans, mask, degree);
  }
  [[GEODESIC_AVX512]] static int32_t LeastWithin(uint32_t mask, const LaneInts& v, int32_t n) {
    return Least(LaneInts(_mm256_mask_mov_epi32(_mm256_set1_epi32(n), mask, __m256i(v))));
  }

  [[GEODESIC_AVX512]] static uint32_t Relax(Lanes& dv, const Lanes& nd) {
    // Only the improved lanes are written: most relaxations improve none,
    // and leave the line clean.
    const __mmask8 better = _mm512_cmp_pd_mask(__m512d(nd), __m512d(dv), _CMP_LT_OQ);
    _mm512_mask_store_pd(&dv, better, __m512d(nd));
    return better;
  }
  [[GEODESIC_AVX512]] static uint32_t KeepWithin(Lanes& du, const Lanes& limit, uint32_t mask) {
    const __mmask8 keep = _mm512_mask_cmp_pd_mask(mask, __m512d(du), __m512d(limit), _CMP_LE_OQ);
    du = Lanes(_mm512_mask_mov_pd(_mm512_set1_pd(kInfinity), keep, __m512d(du)));
    return keep;
  }
  [[GEODESIC_AVX512]] static void SetFans(LaneFans& fans, uint32_t mask, FanRange f) {
    _mm512_mask_storeu_epi64(fans.fan, mask, _mm512_set1_epi64(std::bit_cast<int64_t>(f)));
  }
  [[GEODESIC_AVX512]] static void SetFans(PackedLaneFans& fans, uint32_t mask, FanRange f) {
    _mm256_mask_storeu_epi32(fans.fan, mask, _mm256_set1_epi32(int32_t(PackFan(f))));
  }
  [[GEODESIC_AVX512]] static double LowestOf(const LaneLabels& l, uint32_t mask) {
    return Least(
        Lanes(_mm512_mask_mov_pd(_mm512_set1_pd(kInfinity), mask, _mm512_load_pd(l.dist))));
  }
};

// The same on AVX2: a node's labels are two registers, and a comparison's
// lanes are gathered into a mask by movemask and spread back for a masked
// store. Relax writes only improved labels, as Avx512Lanes does: a full
// store would dirty every line a sweep reads.
struct Avx2Lanes {
  template <typename Fans>
  [[GEODESIC_AVX2]] static FanRange Cover(const Fans& fans, uint32_t mask, uint32_t degree) {
    return CoverByMiddles<Avx2Lanes>(fans, mask, degree);
  }
  [[GEODESIC_AVX2]] static int32_t LeastWithin(uint32_t mask, const LaneInts& v, int32_t n) {
    return Least(LaneInts(_mm256_blendv_epi8(_mm256_set1_epi32(n), __m256i(v), Spread32(mask))));
  }

  // The lanes of `mask` as all-ones 64-bit lanes: lanes 0-3 for `half` 0,
  // lanes 4-7 for 1.
  [[GEODESIC_AVX2]] static __m256i Spread64(uint32_t mask, int half) {
    const __m256i bit =
        half == 0 ? _mm256_setr_epi64x(1, 2, 4, 8) : _mm256_setr_epi64x(16, 32, 64, 128);
    return _mm256_cmpeq_epi64(_mm256_and_si256(_mm256_set1_epi64x(mask), bit), bit);
  }
  [[GEODESIC_AVX2]] static __m256i Spread32(uint32_t mask) {
    const __m256i bit = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
    return _mm256_cmpeq_epi32(_mm256_and_si256(_mm256_set1_epi32(mask), bit), bit);
  }
  [[GEODESIC_AVX2]] static uint32_t MaskOf(__m256d lo, __m256d hi) {
    return _mm256_movemask_pd(lo) | _mm256_movemask_pd(hi) << 4;
  }
  [[GEODESIC_AVX2]] static double LeastOfTwo(__m256d lo, __m256d hi) {
    __m256d v = _mm256_min_pd(lo, hi);
    v = _mm256_min_pd(v, _mm256_permute2f128_pd(v, v, 1));
    v = _mm256_min_pd(v, _mm256_permute_pd(v, 0b0101));
    return _mm256_cvtsd_f64(v);
  }
  [[GEODESIC_AVX2]] static uint32_t Relax(Lanes& dv, const Lanes& nd) {
    double* d = reinterpret_cast<double*>(&dv);
    const double* n = reinterpret_cast<const double*>(&nd);
    const __m256d n_lo = _mm256_loadu_pd(n), n_hi = _mm256_loadu_pd(n + 4);
    const __m256d better_lo = _mm256_cmp_pd(n_lo, _mm256_load_pd(d), _CMP_LT_OQ);
    const __m256d better_hi = _mm256_cmp_pd(n_hi, _mm256_load_pd(d + 4), _CMP_LT_OQ);
    _mm256_maskstore_pd(d, _mm256_castpd_si256(better_lo), n_lo);
    _mm256_maskstore_pd(d + 4, _mm256_castpd_si256(better_hi), n_hi);
    return MaskOf(better_lo, better_hi);
  }
  [[GEODESIC_AVX2]] static uint32_t KeepWithin(Lanes& du, const Lanes& limit, uint32_t mask) {
    double* d = reinterpret_cast<double*>(&du);
    const double* l = reinterpret_cast<const double*>(&limit);
    const __m256d inf = _mm256_set1_pd(kInfinity);
    const __m256d d_lo = _mm256_loadu_pd(d), d_hi = _mm256_loadu_pd(d + 4);
    const __m256d keep_lo = _mm256_and_pd(_mm256_cmp_pd(d_lo, _mm256_loadu_pd(l), _CMP_LE_OQ),
                                          _mm256_castsi256_pd(Spread64(mask, 0)));
    const __m256d keep_hi = _mm256_and_pd(_mm256_cmp_pd(d_hi, _mm256_loadu_pd(l + 4), _CMP_LE_OQ),
                                          _mm256_castsi256_pd(Spread64(mask, 1)));
    _mm256_storeu_pd(d, _mm256_blendv_pd(inf, d_lo, keep_lo));
    _mm256_storeu_pd(d + 4, _mm256_blendv_pd(inf, d_hi, keep_hi));
    return MaskOf(keep_lo, keep_hi);
  }
  [[GEODESIC_AVX2]] static void SetFans(LaneFans& fans, uint32_t mask, FanRange f) {
    auto* at = reinterpret_cast<long long*>(fans.fan);
    const __m256i fan = _mm256_set1_epi64x(std::bit_cast<int64_t>(f));
    _mm256_maskstore_epi64(at, Spread64(mask, 0), fan);
    _mm256_maskstore_epi64(at + 4, Spread64(mask, 1), fan);
  }
  [[GEODESIC_AVX2]] static void SetFans(PackedLaneFans& fans, uint32_t mask, FanRange f) {
    _mm256_maskstore_epi32(reinterpret_cast<int*>(fans.fan), Spread32(mask),
                           _mm256_set1_epi32(int32_t(PackFan(f))));
  }
  [[GEODESIC_AVX2]] static double LowestOf(const LaneLabels& l, uint32_t mask) {
    const __m256d inf = _mm256_set1_pd(kInfinity);
    return LeastOfTwo(
        _mm256_blendv_pd(inf, _mm256_load_pd(l.dist), _mm256_castsi256_pd(Spread64(mask, 0))),
        _mm256_blendv_pd(inf, _mm256_load_pd(l.dist + 4), _mm256_castsi256_pd(Spread64(mask, 1))));
  }
};
#endif

// Asks for the edges of the run node u will relax for the lanes of `mask`
// (a wrapping run as two), as its fans stand now: for a node a few pops
// ahead, since the first loads of a run were where a sweep waited most. Its
// whole cover, not its first lane's fan alone (bench/notes.md).
template <typename Simd, typename Edge, typename Fans>
[[gnu::always_inline]] inline void PrefetchRun(const DggGraph& g, const Edge* edges,
                                               const Fans& fans, uint32_t mask, uint32_t u) {
  const uint64_t list = g.offsets()[u], list_end = g.offsets()[u + 1];
  const FanRange r = Simd::Cover(fans, mask, list_end - list);
  const uint64_t first = list + r.begin, last = first + r.count;
  if (r.count == 0) return;
  PrefetchEdges(edges, first, std::min(last, list_end));
  if (last > list_end) PrefetchEdges(edges, list, list + (last - list_end));
}

// Every node's lanes +inf and clean, for a sweep to start from: only those
// of the nodes the scratch's last sweep listed, when it was a bounded one
// that ran to its end. It listed the nodes it took out, which are all it
// labelled: each label it lowered queued its node, and the queue ran dry.
void ResetLanes(QueryScratch& sc, uint32_t nodes) {
  const Lanes unreached = Lanes{} + kInfinity;
  if (sc.lanes_clear_but_reached) {
    for (uint32_t u : sc.lane_reached) AsLanes(sc.lane_dist[u]) = unreached;
  } else {
    for (uint32_t u = 0; u < nodes; ++u) AsLanes(sc.lane_dist[u]) = unreached;
    std::memset(sc.lane_dirty.data(), 0, nodes);
  }
  sc.lane_reached.clear();
  sc.lanes_clear_but_reached = false;
}

// What a sweep counts as it goes, in the sweep's own locals (never
// addressed outside it, so they stay in registers); its LaneStats at the end.
struct SweepCounts {
  uint64_t pops = 0, relaxed = 0, improved = 0, pushes = 0, expanded = 0;
  LaneStats Stats(uint64_t edge_bytes) const {
    LaneStats stats;
    stats.queue_pops = pops;
    stats.relaxed = relaxed;
    stats.work = {.relaxed = relaxed,
                  .improved = improved,
                  .pushes = pushes,
                  .pops = pops,
                  .graph_bytes = GraphBytesRead(relaxed, edge_bytes, expanded)};
    return stats;
  }
};

struct Seeds {
  std::vector<uint32_t> nodes;  // each once
  double max_label = 0;
  uint64_t labels = 0;  // lanes' labels set
};

// Vertex sources at 0, other points through their temporary edges; a seed
// relaxes all its edges, as in SolveField. Returned, not counted into the
// sweep's counts, so that the sweep never hands out their address.
template <typename Fans>
Seeds SeedLanes(const DggGraph& g, QueryScratch& sc, Fans* fan,
                absl::Span<const Endpoint> sources) {
  LaneLabels* dist = sc.lane_dist.data();
  uint8_t* dirty = sc.lane_dirty.data();
  Seeds seeds;
  auto seed = [&](uint32_t u, double d, int lane) {
    if (!(d < dist[u].dist[lane])) return;
    ++seeds.labels;
    dist[u].dist[lane] = d;
    SetFan(fan[u], lane, AllEdges(g, u));
    if (!dirty[u]) seeds.nodes.push_back(u);
    dirty[u] |= 1u << lane;
    seeds.max_label = std::max(seeds.max_label, d);
  };
  for (size_t k = 0; k < sources.size() && k < kFieldLanes; ++k) {
    if (sources[k].is_node) seed(sources[k].node, 0, k);
    for (const TemporaryEdge& e : sources[k].edges) seed(e.node, e.weight, k);
  }
  return seeds;
}

template <typename Simd, typename Edge, typename Fans>
[[gnu::always_inline]] inline absl::StatusOr<LaneStats> Sweep(
    const DggGraph& g, const Edge* edges, const BucketShape& bucket_shape, QueryScratch& sc,
    Fans* fan, absl::Span<const Endpoint> sources, double max_distance,
    const std::function<bool()>& cancelled) {
  const uint32_t nodes = g.num_nodes();
  ResetLanes(sc, nodes);
  LaneLabels* dist = sc.lane_dist.data();
  uint8_t* dirty = sc.lane_dirty.data();
  // Only a bounded sweep lists the nodes it takes out: an unbounded one
  // reaches every node.
  const bool bounded = max_distance < kInfinity;

  const Seeds seeds = SeedLanes(g, sc, fan, sources);
  // Buckets half as wide as a single field's: the lanes' wavefronts are
  // a little apart, and narrower buckets take fewer nodes out twice.
  BucketQueue& queue = sc.buckets;
  queue.Reset(nodes, bucket_shape.width / 2, std::max(bucket_shape.max_step, seeds.max_label));
  for (uint32_t u : seeds.nodes) queue.Lower(u, Simd::LowestOf(dist[u], dirty[u]));
  SweepCounts counts{.improved = seeds.labels, .pushes = seeds.nodes.size()};

  const auto offsets = g.offsets();
  const Lanes limit = Lanes{} + max_distance;
  struct Improvement {
    uint32_t edge;  // among u's
    uint32_t lanes;
  };
  std::vector<Improvement> improvements;
  while (!queue.empty()) {
    const uint32_t u = queue.Pop();
    const uint32_t mask = dirty[u];
    dirty[u] = 0;
    if (cancelled && (counts.pops & 4095) == 0 && cancelled()) {
      return absl::CancelledError("field cancelled");
    }
    ++counts.pops;
    if (bounded) sc.lane_reached.push_back(u);
    // Only the lanes that improved relax: the others did so with these
    // labels already. Labels past the limit stop there.
    Lanes du = AsLanes(dist[u]);
    const uint32_t active = Simd::KeepWithin(du, limit, mask);
    if (!active) continue;
    // An improved node's key: its improved labels are du + an edge's
    // weight, so the least of du plus the weight is a key at most theirs
    // (taken out no later than due, the label-correcting search's only
    // need), without reading the lanes again for each.
    const double du_low = Simd::LowestOf(dist[u], active);
    const uint64_t begin = offsets[u], end = offsets[u + 1];
    const FanRange run = Simd::Cover(fan[u], active, end - begin);
    if (const uint32_t next = queue.Peek(kNone, 4); next != kNone && dirty[next]) {
      PrefetchRun<Simd>(g, edges, fan[next], dirty[next], next);
      __builtin_prefetch(&dist[next]);
    }
    counts.relaxed += run.count;
    ++counts.expanded;
    if (improvements.size() < run.count) improvements.resize(run.count);
    // Labels first, without a branch: whether an edge improves a label waits
    // on that label's load, and a branch on it stalled on every load it
    // mispredicted, where the loads of a whole run can be in flight at once.
    // The improved targets are queued after, with their lines in cache, in
    // the order found.
    size_t found = 0;
    Improvement* const improved_at = improvements.data();
    auto relax = [&](uint64_t from, uint64_t to) {
      for (uint64_t i = from; i < to; ++i) {
        const uint32_t improved = Simd::Relax(AsLanes(dist[edges[i].target]), du + edges[i].weight);
        improved_at[found] = {static_cast<uint32_t>(i - begin), improved};
        found += improved != 0;
      }
    };
    // A run may wrap past u's last edge: then it is two.
    const uint64_t first = begin + run.begin, stop = first + run.count;
    relax(first, std::min(stop, end));
    if (stop > end) relax(begin, begin + (stop - end));
    counts.pushes += found;
    for (size_t k = 0; k < found; ++k) {
      const auto [i, improved] = improvements[k];
      const Edge& e = edges[begin + i];
      const uint32_t v = e.target;
      counts.improved += std::popcount(improved);
      Simd::SetFans(fan[v], improved, FanOf(e));
      dirty[v] |= improved;
      queue.Lower(v, du_low + e.weight);
    }
  }
  // Every node taken out has clean lanes again.
  sc.lanes_clear_but_reached = bounded;
  return counts.Stats(sizeof(Edge));
}

template <typename Simd>
[[gnu::always_inline]] inline absl::StatusOr<LaneStats> SweepLayout(
    const DggGraph& g, const BucketShape& bucket_shape, LaneFanLayout layout,
    const CompactLaneEdges* compact, QueryScratch& sc, absl::Span<const Endpoint> sources,
    double max_distance, const std::function<bool()>& cancelled) {
  if (compact) {
    return Sweep<Simd>(g, compact->data(), bucket_shape, sc, sc.lane_fan_packed.data(), sources,
                       max_distance, cancelled);
  }
  const DggEdge* edges = g.edges().data();
  return layout == LaneFanLayout::kPacked
             ? Sweep<Simd>(g, edges, bucket_shape, sc, sc.lane_fan_packed.data(), sources,
                           max_distance, cancelled)
             : Sweep<Simd>(g, edges, bucket_shape, sc, sc.lane_fan.data(), sources, max_distance,
                           cancelled);
}

absl::StatusOr<LaneStats> SweepPortable(const DggGraph& g, const BucketShape& bucket_shape,
                                        LaneFanLayout layout, const CompactLaneEdges* compact,
                                        QueryScratch& sc, absl::Span<const Endpoint> sources,
                                        double max_distance,
                                        const std::function<bool()>& cancelled) {
  return SweepLayout<PortableLanes>(g, bucket_shape, layout, compact, sc, sources, max_distance,
                                    cancelled);
}

#if GEODESIC_LANES_X86
// Each x86 sweep is flattened, so that its kernel's helpers (compiled for
// the kernel's target, which the rest of the sweep's code is not) are
// inlined into it, where they may be.
[[GEODESIC_AVX512, gnu::flatten]] absl::StatusOr<LaneStats> SweepAvx512(
    const DggGraph& g, const BucketShape& bucket_shape, LaneFanLayout layout,
    const CompactLaneEdges* compact, QueryScratch& sc, absl::Span<const Endpoint> sources,
    double max_distance, const std::function<bool()>& cancelled) {
  return SweepLayout<Avx512Lanes>(g, bucket_shape, layout, compact, sc, sources, max_distance,
                                  cancelled);
}

[[GEODESIC_AVX2, gnu::flatten]] absl::StatusOr<LaneStats> SweepAvx2(
    const DggGraph& g, const BucketShape& bucket_shape, LaneFanLayout layout,
    const CompactLaneEdges* compact, QueryScratch& sc, absl::Span<const Endpoint> sources,
    double max_distance, const std::function<bool()>& cancelled) {
  return SweepLayout<Avx2Lanes>(g, bucket_shape, layout, compact, sc, sources, max_distance,
                                cancelled);
}
#endif

}  // namespace

bool LaneKernelRuns(LaneKernel kernel) {
#if GEODESIC_LANES_X86
  // The features each kernel is compiled for, named one by one (clang 14
  // knows no level names).
  static const bool avx2 = __builtin_cpu_supports("avx2") && __builtin_cpu_supports("bmi") &&
                           __builtin_cpu_supports("bmi2") && __builtin_cpu_supports("fma");
  static const bool avx512 =
      avx2 && __builtin_cpu_supports("avx512f") && __builtin_cpu_supports("avx512bw") &&
      __builtin_cpu_supports("avx512cd") && __builtin_cpu_supports("avx512dq") &&
      __builtin_cpu_supports("avx512vl");
#else
  constexpr bool avx2 = false, avx512 = false;
#endif
  switch (kernel) {
    case LaneKernel::kAvx512:
      return avx512;
    case LaneKernel::kAvx2:
      return avx2;
    case LaneKernel::kBest:
    case LaneKernel::kPortable:
      return true;
  }
  return false;
}

std::optional<CompactLaneEdges> CompactLaneEdges::Of(const DggGraph& g) {
  if (LaneFanLayoutFor(g) != LaneFanLayout::kPacked) return std::nullopt;
  const auto edges = g.edges();
  CompactLaneEdges compact;
  compact.count_ = edges.size();
  compact.edges_ = std::make_unique_for_overwrite<Edge[]>(edges.size());
  for (uint64_t i = 0; i < edges.size(); ++i) {
    Edge& e = compact.edges_[i];
    e.target = edges[i].target;
    e.weight = edges[i].weight;
    e.fan.store(PackFan(edges[i].fan), std::memory_order_relaxed);
  }
  return compact;
}

namespace {

// Turn k of `fan`, a run (that may wrap) of the `degree` edges from `list`
// on.
template <typename Edge>
const Edge& TurnOf(const Edge* edges, uint64_t list, uint64_t degree, FanRange fan, uint32_t k) {
  const uint64_t turn = uint64_t{fan.begin} + k;
  return edges[list + (turn < degree ? turn : turn - degree)];
}

// The longest turn p -> u -> w the fans of p's edges hold: |pu| + |uw|.
template <typename Edge>
double LongestTurnOf(const DggGraph& g, const Edge* edges, uint32_t p) {
  const auto offsets = g.offsets();
  double longest = 0;
  for (uint64_t i = offsets[p]; i < offsets[p + 1]; ++i) {
    const Edge& e = edges[i];
    const uint64_t list = offsets[e.target], degree = offsets[e.target + 1] - list;
    const FanRange fan = FanOf(e);
    float next = 0;
    for (uint32_t k = 0; k < fan.count; ++k)
      next = std::max(next, TurnOf(edges, list, degree, fan, k).weight);
    longest = std::max(longest, double{e.weight} + next);
  }
  return longest;
}

// The fan of edge e = p -> u narrowed to the turns u -> w that the path to
// w of length `to[w]` (lane `lane` of a sweep from p) does not beat by the
// build's rule (kStrictlyShorter). `kept` is scratch.
template <typename Edge>
FanRange NarrowedFan(const DggGraph& g, const Edge* edges, const Edge& e,
                     absl::Span<const LaneLabels> to, int lane, std::vector<uint32_t>& kept) {
  const auto offsets = g.offsets();
  const uint64_t list = offsets[e.target], degree = offsets[e.target + 1] - list;
  // Only the fan's own turns are tried: it already holds every turn a
  // shortest path takes, in a small part of the node's edges.
  const FanRange before = FanOf(e);
  kept.resize(before.count);
  // Kept turns, counted from the fan's start so that they stay sorted when
  // it wraps, move to the front without a branch (whether one is kept is
  // close to random).
  uint32_t count = 0;
  for (uint32_t k = 0; k < before.count; ++k) {
    const Edge& next = TurnOf(edges, list, degree, before, k);
    const double length = double{e.weight} + next.weight;
    kept[count] = k;
    count += to[next.target].dist[lane] >= length * kStrictlyShorter;
  }
  FanRange narrowed = CircularHull({kept.data(), count}, static_cast<uint32_t>(degree));
  if (narrowed.count >= before.count) return before;
  narrowed.begin = (narrowed.begin + before.begin) % degree;
  return narrowed;
}

// The sweep around `nodes` (at most kFieldLanes) that NarrowAllFans
// narrows their fans from: out to `reach` of the longest of their turns, in
// `sc`.
absl::Status SweepAround(const DggGraph& g, const BucketShape& bucket_shape, QueryScratch& sc,
                         absl::Span<const uint32_t> nodes, double reach,
                         const std::function<bool()>& cancelled) {
  std::vector<Endpoint> ends(std::min<size_t>(nodes.size(), kFieldLanes));
  double longest = 0;
  for (size_t k = 0; k < ends.size(); ++k) {
    ends[k].is_node = true;
    ends[k].node = nodes[k];
    longest = std::max(longest, LongestTurnOf(g, g.edges().data(), nodes[k]));
  }
  return SolveFieldLanes(g, bucket_shape, LaneFanLayout::kPacked, nullptr, sc, ends,
                         reach * longest, cancelled)
      .status();
}

}  // namespace

uint64_t CompactLaneEdges::NarrowFans(const DggGraph& g, uint32_t p,
                                      absl::Span<const LaneLabels> labels, int lane) {
  const auto offsets = g.offsets();
  std::vector<uint32_t> kept;
  uint64_t dropped = 0;
  for (uint64_t i = offsets[p]; i < offsets[p + 1]; ++i) {
    Edge& e = edges_[i];
    const FanRange before = e.Fan();
    const FanRange narrowed = NarrowedFan(g, edges_.get(), e, labels, lane, kept);
    if (narrowed.count >= before.count) continue;
    dropped += before.count - narrowed.count;
    e.fan.store(PackFan(narrowed), std::memory_order_relaxed);
  }
  return dropped;
}

absl::Status NarrowAllFans(const DggGraph& g, std::span<DggEdge> edges, double reach,
                           const std::function<bool(uint64_t, uint64_t)>& progress) {
  if (LaneFanLayoutFor(g) != LaneFanLayout::kPacked || edges.data() != g.edges().data() ||
      edges.size() != g.num_directed_edges()) {
    return absl::InvalidArgumentError(
        "fans narrow in place, on the graph's own edges, where they pack");
  }
  const BucketShape shape = BucketShapeOf(g);
  const uint32_t nodes = g.num_nodes();
  const uint64_t runs = (uint64_t{nodes} + kFieldLanes - 1) / kFieldLanes;
  const auto offsets = g.offsets();
  // The new fans wait here until every sweep is done (4 bytes an edge).
  std::vector<uint32_t> narrowed(edges.size());
  tbb::enumerable_thread_specific<QueryScratch> scratch;
  std::atomic<uint64_t> done{0};
  std::atomic<bool> stop{false};
  auto cancelled = [&] { return stop.load(std::memory_order_relaxed); };
  RETURN_IF_ERROR(ForEachInParallel(runs, [&](size_t r) -> absl::Status {
    if (cancelled()) return absl::CancelledError("fan narrowing cancelled");
    std::array<uint32_t, kFieldLanes> run;
    const uint32_t first = static_cast<uint32_t>(r * kFieldLanes);
    const uint32_t count = std::min<uint32_t>(kFieldLanes, nodes - first);
    std::iota(run.begin(), run.begin() + count, first);
    QueryScratch& sc = scratch.local();
    RETURN_IF_ERROR(SweepAround(g, shape, sc, {run.data(), count}, reach, cancelled));
    std::vector<uint32_t> kept;
    for (uint32_t k = 0; k < count; ++k) {
      for (uint64_t i = offsets[run[k]]; i < offsets[run[k] + 1]; ++i) {
        narrowed[i] = PackFan(NarrowedFan(g, edges.data(), edges[i], sc.lane_dist, k, kept));
      }
    }
    const uint64_t now = done.fetch_add(1, std::memory_order_relaxed) + 1;
    if ((now % 256 == 0 || now == runs) && !progress(now, runs)) stop = true;
    return absl::OkStatus();
  }));
  if (cancelled()) return absl::CancelledError("fan narrowing cancelled");
  for (uint64_t i = 0; i < edges.size(); ++i) edges[i].fan = UnpackFan(narrowed[i]);
  return absl::OkStatus();
}

absl::StatusOr<LaneStats> SolveFieldLanes(const DggGraph& g, const BucketShape& bucket_shape,
                                          LaneFanLayout layout, const CompactLaneEdges* compact,
                                          QueryScratch& sc, absl::Span<const Endpoint> sources,
                                          double max_distance,
                                          const std::function<bool()>& cancelled,
                                          LaneKernel kernel) {
  if (!LaneKernelRuns(kernel)) {
    return absl::FailedPreconditionError("this machine cannot run the lane kernel asked for");
  }
  if (compact && layout != LaneFanLayout::kPacked) {
    return absl::InvalidArgumentError("compact edges go with packed lane fans");
  }
  sc.PrepareLanes(g.num_nodes(), layout);
#if GEODESIC_LANES_X86
  if (kernel == LaneKernel::kBest) {
    kernel = LaneKernelRuns(LaneKernel::kAvx512) ? LaneKernel::kAvx512
             : LaneKernelRuns(LaneKernel::kAvx2) ? LaneKernel::kAvx2
                                                 : LaneKernel::kPortable;
  }
  if (kernel == LaneKernel::kAvx512) {
    return SweepAvx512(g, bucket_shape, layout, compact, sc, sources, max_distance, cancelled);
  }
  if (kernel == LaneKernel::kAvx2) {
    return SweepAvx2(g, bucket_shape, layout, compact, sc, sources, max_distance, cancelled);
  }
#endif
  return SweepPortable(g, bucket_shape, layout, compact, sc, sources, max_distance, cancelled);
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
