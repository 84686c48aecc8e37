#include "core/query/field_solver.h"

#include <algorithm>
#include <array>
#include <atomic>
#include <bit>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <numeric>
#include <optional>
#include <span>
#include <vector>

#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/for_each_in_parallel.h"
#include "core/base/status.h"
#include "core/exact/exact_geodesic.h"
#include "core/query/field_lanes.h"

namespace geodesic::query_internal {
namespace {

absl::Status CheckTargets(const Mesh& mesh, absl::Span<const VertexId> targets) {
  for (VertexId t : targets) {
    if (t >= mesh.num_vertices()) {
      return absl::OutOfRangeError(absl::StrFormat(
          "target vertex %u is out of range (the mesh has %u vertices)", t, mesh.num_vertices()));
    }
  }
  return absl::OkStatus();
}

// Vertex sources at 0; other points through their temporary edges. A seed
// relaxes all its edges. Returns the seeded nodes, sorted, each once.
template <typename FanSlot>
std::vector<uint32_t> SeedField(const DggGraph& g, QueryScratch& sc, FanSlot* fan,
                                absl::Span<const Endpoint> sources, bool labels) {
  std::vector<uint32_t> seeds;
  auto seed = [&](uint32_t u, double d, uint32_t source) {
    if (!(d < sc.dist[u])) return;
    sc.dist[u] = d;
    SetFan(fan[u], AllEdges(g, u));
    if (labels) sc.label[u] = source;
    seeds.push_back(u);
  };
  for (uint32_t i = 0; i < sources.size(); ++i) {
    if (sources[i].is_node) seed(sources[i].node, 0, i);
    for (const TemporaryEdge& e : sources[i].edges) seed(e.node, e.weight, i);
  }
  std::sort(seeds.begin(), seeds.end());
  seeds.erase(std::unique(seeds.begin(), seeds.end()), seeds.end());
  return seeds;
}

// Back from node order to the mesh's vertex order.
void CopyFieldToVertexOrder(const Mesh& mesh, const DggGraph& g, const QueryScratch& sc,
                            const FieldOptions& options, FieldResult& result) {
  const uint32_t n = mesh.num_vertices();
  auto node_of_vertex = g.node_of_vertex();
  result.distance.resize(n);
  for (VertexId v = 0; v < n; ++v) {
    const double d = sc.dist[node_of_vertex[v]];
    result.distance[v] = d > options.max_distance ? kInfinity : d;
  }
  if (options.nearest_source) {
    result.nearest_source.resize(n);
    for (VertexId v = 0; v < n; ++v) {
      result.nearest_source[v] =
          result.distance[v] == kInfinity ? kNone : sc.label[node_of_vertex[v]];
    }
  }
}

// Calls `f` with the scratch's per-node fans as `layout` keeps them, so
// that each layout's code is its own, with no test for it inside.
template <typename F>
auto WithFans(QueryScratch& sc, LaneFanLayout layout, F f) {
  return layout == LaneFanLayout::kPacked ? f(sc.fan_packed.data()) : f(sc.fan.data());
}

}  // namespace

// The field from sources already joined to the graph.
absl::StatusOr<FieldResult> SolveField(const Mesh& mesh, const DggGraph& g,
                                       const BucketShape& bucket_shape, LaneFanLayout fan_layout,
                                       QueryScratch& sc, absl::Span<const Endpoint> sources,
                                       const FieldOptions& options) {
  RETURN_IF_ERROR(CheckTargets(mesh, options.targets));
  const uint32_t nodes = g.num_nodes();
  sc.PrepareField(nodes, options.nearest_source, fan_layout);
  std::vector<double>& dist = sc.dist;
  std::vector<uint32_t>& label = sc.label;
  std::fill(dist.begin(), dist.begin() + nodes, kInfinity);
  if (options.nearest_source) std::fill(label.begin(), label.begin() + nodes, kNone);
  const bool use_fans = options.method == FieldMethod::kLabelCorrecting;

  // The fans in as few bytes as the graph allows: the search's per-node
  // state is what a search from a cold cache waits on.
  const std::vector<uint32_t> seeds = WithFans(sc, fan_layout, [&](auto* fan) {
    return SeedField(g, sc, fan, sources, options.nearest_source);
  });

  FieldResult result;
  size_t targets_left = options.targets.size();
  std::vector<uint8_t> is_target;
  if (targets_left) {
    is_target.assign(nodes, 0);
    for (VertexId t : options.targets) is_target[g.node_of_vertex(t)] = 1;
    targets_left = std::count(is_target.begin(), is_target.end(), 1);
  }
  bool cancelled = false;
  auto visit = [&](uint32_t u) {
    if (dist[u] > options.max_distance) return Visit::kSkip;
    if (options.cancelled && (result.queue_pops & 4095) == 0 && options.cancelled()) {
      cancelled = true;
      return Visit::kStop;
    }
    ++result.queue_pops;
    if (targets_left && is_target[u] && --targets_left == 0) return Visit::kStop;
    return Visit::kRelax;
  };
  // Each combination of fans, their layout and labels is its own search, so
  // the inner loop tests none of them (labels cost a read and a write per
  // improvement).
  auto search = [&]<bool kUseFans>(auto& queue) {
    return WithFans(sc, fan_layout, [&](auto* fan) {
      if (options.nearest_source) {
        auto improved = [&](uint32_t u, uint32_t v) { label[v] = label[u]; };
        return SearchGraph<kUseFans>(g, queue, dist.data(), fan, visit, improved);
      }
      return SearchGraph<kUseFans>(g, queue, dist.data(), fan, visit, [](uint32_t, uint32_t) {});
    });
  };
  auto run = [&](auto& queue) {
    for (uint32_t s : seeds) queue.Push(s, dist[s]);
    result.work = use_fans ? search.template operator()<true>(queue)
                           : search.template operator()<false>(queue);
    result.work.pushes += seeds.size();
    result.work.improved += seeds.size();
    result.relaxed = result.work.relaxed;
  };
  if (targets_left) {
    // Stopping at targets needs nodes settled in order of distance.
    HeapQueue heap{sc.heap};
    heap.heap.Reset(nodes);
    run(heap);
  } else {
    double max_seed = 0;
    for (uint32_t s : seeds) max_seed = std::max(max_seed, dist[s]);
    sc.buckets.Reset(nodes, bucket_shape.width, std::max(bucket_shape.max_step, max_seed));
    run(sc.buckets);
  }
  if (cancelled) return absl::CancelledError("field cancelled");
  CopyFieldToVertexOrder(mesh, g, sc, options, result);
  return result;
}

}  // namespace geodesic::query_internal

namespace geodesic {
namespace {

// Replaces a matrix row of graph distances by exact ones: one propagation
// from the source, bounded by the row's largest finite entry (each entry is
// the length of a real surface path, so it bounds the exact distance). With
// one target the propagation sweeps only what can still reach it, judged by
// the exact landmarks too when they are ready.
absl::Status MakeRowExact(ExactGeodesic& exact, const ExactLandmarks* landmarks,
                          const SurfacePoint& source,
                          absl::Span<const query_internal::Endpoint> targets,
                          const MatrixOptions& matrix, absl::Span<double> row) {
  double bound = -1;
  for (double d : row) {
    if (d < kInfinity) bound = std::max(bound, d);
  }
  if (bound < 0) return absl::OkStatus();  // nothing reachable
  ExactOptions options =
      query_internal::ExactWithinGraphAnswer(bound, matrix.cancelled, matrix.exact_max_bytes);
  if (targets.size() == 1) options.goal = targets[0].xyz;
  ExactLandmarkRun with_landmarks(landmarks, exact.mesh(),
                                  targets.size() == 1 ? &targets[0].point : nullptr, options);
  absl::Cleanup release = [&exact] { exact.ReleaseLargeWindows(); };
  std::vector<SurfacePoint> reachable;
  for (size_t j = 0; j < targets.size(); ++j) {
    if (row[j] < kInfinity) reachable.push_back(targets[j].point);
  }
  ASSIGN_OR_RETURN(const std::vector<double> d, query_internal::ExactDistancesWithinGraphAnswer(
                                                    exact, source, reachable, options));
  for (size_t j = 0, k = 0; j < targets.size(); ++j) {
    if (row[j] == kInfinity) continue;
    if (d[k] < kInfinity) row[j] = d[k];
    ++k;
  }
  return absl::OkStatus();
}

// Sources in groups of kFieldLanes close together on the surface, for the
// lanes of one sweep: the closer a group, the more its wavefronts move as
// one, so that a node is taken out once for all its lanes and relaxes one
// narrow run of edges (bench/notes.md, "Matrix lanes"). `order` is in node
// order, which follows the surface, but a run of it can straddle a jump of
// the curve: each group is its first source not yet grouped and the nearest
// others, in space, among the next kCandidates.
std::vector<size_t> GroupNearby(const Mesh& mesh, absl::Span<const SurfacePoint> sources,
                                absl::Span<const size_t> order) {
  constexpr size_t kCandidates = 64;
  std::vector<Vec3> at(order.size());
  for (size_t i = 0; i < order.size(); ++i) at[i] = PositionOf(mesh, sources[order[i]]);
  std::vector<uint8_t> grouped(order.size(), 0);
  std::vector<size_t> out, near;
  out.reserve(order.size());
  for (size_t first = 0; first < order.size(); ++first) {
    if (grouped[first]) continue;
    near.clear();
    for (size_t i = first + 1; i < order.size() && near.size() < kCandidates; ++i) {
      if (!grouped[i]) near.push_back(i);
    }
    const size_t take = std::min(near.size(), size_t(kFieldLanes - 1));
    std::partial_sort(near.begin(), near.begin() + take, near.end(), [&](size_t a, size_t b) {
      return Distance(at[a], at[first]) < Distance(at[b], at[first]);
    });
    near.resize(take);
    near.insert(near.begin(), first);
    for (size_t i : near) {
      grouped[i] = 1;
      out.push_back(order[i]);
    }
  }
  return out;
}

// A sweep's labels of every lane at `target`: a vertex's read in place
// (copying the line out, its wide store read back lane by lane, was most of
// the rows' extraction; bench/notes.md), another point's joined through its
// temporary edges into `joined`.
const double* LaneLabelsAt(const DggGraph& g, const QueryScratch& sc,
                           const query_internal::Endpoint& target, double max_distance,
                           LaneLabels& joined) {
  if (target.is_node) return sc.lane_dist[target.node].dist;
  joined = query_internal::LaneDistancesTo(g, sc, target, max_distance);
  return joined.dist;
}

// Lowers each entry of rows[k] (a lane's row, holding its source's direct
// geodesics, else +inf) to lane k's distance to that target after a sweep;
// +inf past `max_distance` (past it, labels are bounds only). Target by
// target: a target's lanes share a cache line.
void LowerRowsToLanes(const DggGraph& g, const QueryScratch& sc,
                      absl::Span<const query_internal::Endpoint> targets, double max_distance,
                      std::vector<std::vector<double>>& rows) {
  for (size_t j = 0; j < targets.size(); ++j) {
    LaneLabels joined;
    const double* labels = LaneLabelsAt(g, sc, targets[j], max_distance, joined);
    for (size_t k = 0; k < rows.size(); ++k) {
      const double d = std::min(rows[k][j], labels[k]);
      rows[k][j] = d > max_distance ? kInfinity : d;
    }
  }
}

// Rows of float32 entries straight from a sweep's lanes, for sources that
// are all graph nodes (so their rows hold nothing before the sweep): row k,
// at rows[k * targets.size()], is lane k's distance to each target rounded
// to float32, as rounding LowerRowsToLanes's row would give; +inf past
// `max_distance`.
void Float32RowsFromLanes(const DggGraph& g, const QueryScratch& sc,
                          absl::Span<const query_internal::Endpoint> targets, double max_distance,
                          size_t lanes, absl::Span<float> rows) {
  const size_t n = targets.size();
  // Each target's label line is a miss (the sweep's edges have gone
  // through the cache since); a few targets ahead, its line is asked for.
  constexpr size_t kAhead = 16;
  for (size_t j = 0; j < n; ++j) {
    if (j + kAhead < n && targets[j + kAhead].is_node) {
      __builtin_prefetch(&sc.lane_dist[targets[j + kAhead].node]);
    }
    LaneLabels joined;
    const double* labels = LaneLabelsAt(g, sc, targets[j], max_distance, joined);
    // All eight lanes at once, in SIMD; only the sources' rows are kept.
    typedef double Doubles __attribute__((vector_size(sizeof(LaneLabels))));
    typedef float Floats __attribute__((vector_size(kFieldLanes * sizeof(float))));
    Doubles d;
    std::memcpy(&d, labels, sizeof(d));
    d = d > max_distance ? Doubles{} + kInfinity : d;
    const Floats rounded = __builtin_convertvector(d, Floats);
    for (size_t k = 0; k < lanes; ++k) rows[k * n + j] = rounded[k];
  }
}

// For each graph node, the indices of the targets at it: a neighbourhood
// row's entries are then read from the nodes its sweep reached. Empty
// unless every target is a node.
class TargetsAtNodes {
 public:
  TargetsAtNodes() = default;
  TargetsAtNodes(uint32_t nodes, absl::Span<const query_internal::Endpoint> targets) {
    for (const query_internal::Endpoint& t : targets) {
      if (!t.is_node) return;
    }
    first_.assign(nodes + 1, 0);
    for (const query_internal::Endpoint& t : targets) ++first_[t.node + 1];
    std::partial_sum(first_.begin(), first_.end(), first_.begin());
    targets_.resize(targets.size());
    std::vector<uint32_t> next(first_.begin(), first_.end() - 1);
    for (size_t j = 0; j < targets.size(); ++j) targets_[next[targets[j].node]++] = j;
  }
  bool empty() const { return first_.empty(); }
  absl::Span<const uint32_t> At(uint32_t node) const {
    return absl::MakeConstSpan(targets_).subspan(first_[node], first_[node + 1] - first_[node]);
  }

 private:
  std::vector<uint32_t> first_;  // CSR offsets by node
  std::vector<uint32_t> targets_;
};

// Rows' entries within a distance (finite): per lane, columns ascending
// and their distances.
struct SparseRows {
  explicit SparseRows(size_t lanes) : columns(lanes), values(lanes) {}
  void Add(size_t lane, uint32_t column, double d) {
    columns[lane].push_back(column);
    values[lane].push_back(d);
  }
  std::vector<std::vector<uint32_t>> columns;
  std::vector<std::vector<double>> values;
};

// The lanes' entries at the targets of the nodes a bounded sweep reached
// (sc.lane_reached: every node it labelled, since each label it lowered
// queued its node), in column order through a bitmap of the targets hit:
// linear in the neighbourhoods, with no sort, however many nodes they hold.
SparseRows RowsFromReached(const QueryScratch& sc,
                           absl::Span<const query_internal::Endpoint> targets,
                           const TargetsAtNodes& targets_at, size_t lanes, double max_distance) {
  std::vector<uint64_t> hit((targets.size() + 63) / 64);
  for (uint32_t u : sc.lane_reached) {
    for (uint32_t j : targets_at.At(u)) hit[j / 64] |= uint64_t{1} << (j % 64);
  }
  SparseRows rows(lanes);
  for (size_t word = 0; word < hit.size(); ++word) {
    for (uint64_t bits = hit[word]; bits != 0; bits &= bits - 1) {
      const uint32_t j = static_cast<uint32_t>(word * 64 + std::countr_zero(bits));
      const double* labels = sc.lane_dist[targets[j].node].dist;
      for (size_t k = 0; k < lanes; ++k) {
        if (labels[k] <= max_distance) rows.Add(k, j, labels[k]);
      }
    }
  }
  return rows;
}

using RowFix = std::function<absl::Status(size_t k, absl::Span<double> row)>;

// Makes a sweep's whole rows, `rows` (empty if no row holds anything before
// the sweep) lowered to its lanes, and hands row k to `done` once
// `make_exact`, if given, has made it exact.
absl::Status ForEachWholeRow(
    const DggGraph& g, const QueryScratch& sc, absl::Span<const query_internal::Endpoint> targets,
    size_t lanes, const MatrixOptions& options, const RowFix& make_exact,
    std::vector<std::vector<double>>& rows,
    const std::function<absl::Status(size_t k, std::vector<double>& row)>& done) {
  if (rows.empty()) rows.assign(lanes, std::vector<double>(targets.size(), kInfinity));
  LowerRowsToLanes(g, sc, targets, options.max_distance, rows);
  for (size_t k = 0; k < lanes; ++k) {
    if (make_exact) RETURN_IF_ERROR(make_exact(k, absl::MakeSpan(rows[k])));
    RETURN_IF_ERROR(done(k, rows[k]));
  }
  return absl::OkStatus();
}

// Hands a sweep's rows to a sparse sink: from the nodes it reached, when
// its sources are nodes and `targets_at` lists every target; else from the
// whole rows, as DeliverRows makes them.
absl::Status DeliverSparseRows(const DggGraph& g, const QueryScratch& sc,
                               absl::Span<const query_internal::Endpoint> targets,
                               const TargetsAtNodes& targets_at, absl::Span<const size_t> group,
                               const MatrixOptions& options, const RowFix& make_exact,
                               std::vector<std::vector<double>>& rows, const MatrixRowSink& sink) {
  std::optional<SparseRows> sparse;
  if (!targets_at.empty() && rows.empty() && !make_exact && options.max_distance < kInfinity) {
    sparse = RowsFromReached(sc, targets, targets_at, group.size(), options.max_distance);
  } else {
    sparse.emplace(group.size());
    auto keep_within = [&](size_t k, std::vector<double>& row) {
      for (size_t j = 0; j < row.size(); ++j) {
        if (row[j] <= options.max_distance && row[j] < kInfinity) sparse->Add(k, j, row[j]);
      }
      return absl::OkStatus();
    };
    RETURN_IF_ERROR(
        ForEachWholeRow(g, sc, targets, group.size(), options, make_exact, rows, keep_within));
  }
  for (size_t k = 0; k < group.size(); ++k) {
    RETURN_IF_ERROR(sink.sparse_row(group[k], sparse->columns[k], sparse->values[k]));
  }
  return absl::OkStatus();
}

// Hands a sweep's rows (group[k] in lane k) to `sink`: rows of float32
// straight from the lanes, for a float32 sink when no row holds anything
// before the sweep; else `rows` (empty if none does), lowered to the lanes,
// made exact by `make_exact` if given, and rounded for a float32 sink.
absl::Status DeliverRows(const DggGraph& g, const QueryScratch& sc,
                         absl::Span<const query_internal::Endpoint> targets,
                         const TargetsAtNodes& targets_at, absl::Span<const size_t> group,
                         const MatrixOptions& options, const RowFix& make_exact,
                         std::vector<std::vector<double>>& rows, const MatrixRowSink& sink) {
  if (sink.sparse_row) {
    return DeliverSparseRows(g, sc, targets, targets_at, group, options, make_exact, rows, sink);
  }
  const size_t n = targets.size();
  std::vector<float> rounded;
  if (sink.float32_row && rows.empty() && !make_exact) {
    rounded.resize(group.size() * n);
    Float32RowsFromLanes(g, sc, targets, options.max_distance, group.size(),
                         absl::MakeSpan(rounded));
    for (size_t k = 0; k < group.size(); ++k) {
      RETURN_IF_ERROR(sink.float32_row(group[k], absl::MakeConstSpan(rounded).subspan(k * n, n)));
    }
    return absl::OkStatus();
  }
  return ForEachWholeRow(g, sc, targets, group.size(), options, make_exact, rows,
                         [&](size_t k, std::vector<double>& row) {
                           if (!sink.float32_row) return sink.row(group[k], row);
                           rounded.assign(row.begin(), row.end());
                           return sink.float32_row(group[k], rounded);
                         });
}

// A graph node at or next to `p`: sources are grouped by it.
uint32_t NodeNear(const Mesh& mesh, const DggGraph& g, const SurfacePoint& p) {
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      return g.node_of_vertex(p.id);
    case SurfacePoint::Kind::kEdge:
      return g.node_of_vertex(mesh.tail(mesh.edge_halfedge(p.id)));
    case SurfacePoint::Kind::kFace:
      break;
  }
  return g.node_of_vertex(mesh.face_vertex(p.id, 0));
}

// The copy of the edges whose fans a matrix of `rows` narrows from its
// complete rows, if it narrows them: the copy (about a sweep's time, 12
// bytes an edge) pays for many rows from a good share of the graph's
// nodes, such as all pairs, not for a few rows of a large mesh; and only
// complete rows narrow (the build's fans hold what short sweeps drop).
std::optional<query_internal::CompactLaneEdges> EdgesToNarrow(const DggGraph& g, size_t rows,
                                                              const MatrixOptions& options) {
  constexpr size_t kNarrowingRows = 16 * kFieldLanes;
  if (!options.narrow_fans || options.max_distance != kInfinity || rows < kNarrowingRows ||
      2 * rows < g.num_nodes()) {
    return std::nullopt;
  }
  return query_internal::CompactLaneEdges::Of(g);
}

}  // namespace

using query_internal::CheckPoint;
using query_internal::Endpoint;
using query_internal::JoinToGraph;
using query_internal::SolveField;
using query_internal::SolveFieldLanes;

absl::StatusOr<FieldResult> GeodesicEngine::Field(absl::Span<const SurfacePoint> sources,
                                                  const FieldOptions& options) const {
  const Mesh& mesh = *mesh_;
  if (sources.empty()) return absl::InvalidArgumentError("a field needs at least one source");
  for (size_t i = 0; i < sources.size(); ++i) {
    RETURN_IF_ERROR(CheckPoint(mesh, sources[i], absl::StrFormat("source %u", i)));
  }
  ScratchPool::Lease sc = AcquireScratch();
  std::vector<Endpoint> ends;
  ends.reserve(sources.size());
  for (const SurfacePoint& p : sources) {
    ASSIGN_OR_RETURN(ends.emplace_back(), JoinToGraph(mesh, *graph_, *sc, p, false));
  }
  return SolveField(mesh, *graph_, buckets_, lane_fans_, *sc, ends, options);
}

absl::StatusOr<std::vector<double>> GeodesicEngine::Matrix(
    absl::Span<const SurfacePoint> sources, absl::Span<const SurfacePoint> targets,
    const MatrixOptions& matrix_options) const {
  std::vector<double> out(sources.size() * targets.size(), kInfinity);
  MatrixRowSink sink;
  sink.row = [&](size_t i, absl::Span<const double> row) {
    std::copy(row.begin(), row.end(), out.begin() + i * targets.size());
    return absl::OkStatus();
  };
  RETURN_IF_ERROR(StreamMatrix(sources, targets, matrix_options, sink));
  return out;
}

absl::Status GeodesicEngine::StreamMatrix(absl::Span<const SurfacePoint> sources,
                                          absl::Span<const SurfacePoint> targets,
                                          const MatrixOptions& matrix_options,
                                          const MatrixRowSink& sink) const {
  const Mesh& mesh = *mesh_;
  for (size_t i = 0; i < sources.size(); ++i) {
    RETURN_IF_ERROR(CheckPoint(mesh, sources[i], absl::StrFormat("source %u", i)));
  }
  for (size_t j = 0; j < targets.size(); ++j) {
    RETURN_IF_ERROR(CheckPoint(mesh, targets[j], absl::StrFormat("target %u", j)));
  }
  // Entry (i, j) is what Distance(sources[i], targets[j]) answers without a
  // path: the graph distance on the augmented graph, or the direct geodesic
  // from a source that is not a vertex, whichever is shorter. One field per
  // source serves its whole row.
  std::vector<Endpoint> target_ends;
  target_ends.reserve(targets.size());
  {
    ScratchPool::Lease sc = AcquireScratch();
    for (const SurfacePoint& t : targets) {
      ASSIGN_OR_RETURN(target_ends.emplace_back(), JoinToGraph(mesh, *graph_, *sc, t, false));
    }
  }
  // Only a bounded sweep lists the nodes it reached.
  const TargetsAtNodes targets_at = sink.sparse_row && matrix_options.max_distance < kInfinity
                                        ? TargetsAtNodes(graph_->num_nodes(), target_ends)
                                        : TargetsAtNodes();
  std::optional<query_internal::CompactLaneEdges> compact =
      EdgesToNarrow(*graph_, sources.size(), matrix_options);
  // Sources go in lanes of one sweep (core/query/field_lanes.h), grouped
  // by graph node: node order follows the surface, so a group's wavefronts
  // move together.
  auto solve_group = [&](absl::Span<const size_t> group) -> absl::Status {
    ScratchPool::Lease sc = AcquireScratch();
    const size_t n = target_ends.size();
    std::vector<Endpoint> ends;
    // Float64 rows, made once a source needs one: each holds its source's
    // direct geodesics (a source that is not a vertex), else +inf.
    std::vector<std::vector<double>> rows;
    for (size_t k = 0; k < group.size(); ++k) {
      ASSIGN_OR_RETURN(ends.emplace_back(),
                       JoinToGraph(mesh, *graph_, *sc, sources[group[k]], true));
      // The direct geodesics, while the scratch's exact engine still holds
      // the source's propagation.
      if (ends.back().is_node) continue;
      if (rows.empty()) rows.assign(group.size(), std::vector<double>(n, kInfinity));
      for (size_t j = 0; j < n; ++j) {
        auto d = sc->Exact(mesh).DistanceTo(target_ends[j].point);
        if (d.ok()) rows[k][j] = *d;
      }
    }
    RETURN_IF_ERROR(SolveFieldLanes(*graph_, buckets_, lane_fans_, compact ? &*compact : nullptr,
                                    *sc, ends, matrix_options.max_distance,
                                    matrix_options.cancelled)
                        .status());
    // A vertex source's complete row tells which turns its edges' shortest
    // paths take: every later sweep relaxes only those.
    if (compact) {
      for (size_t k = 0; k < ends.size(); ++k) {
        if (ends[k].is_node) compact->NarrowFans(*graph_, ends[k].node, sc->lane_dist, k);
      }
    }
    auto make_exact = [&](size_t k, absl::Span<double> row) {
      return MakeRowExact(sc->Exact(mesh), exact_landmarks_.get(), ends[k].point, target_ends,
                          matrix_options, row);
    };
    return DeliverRows(*graph_, *sc, target_ends, targets_at, group, matrix_options,
                       matrix_options.exact ? make_exact : RowFix(), rows, sink);
  };
  const size_t batch = sink.batch_rows > 0 ? sink.batch_rows : std::max<size_t>(sources.size(), 1);
  std::vector<size_t> order;
  for (size_t begin = 0; begin < sources.size(); begin += batch) {
    const size_t end = std::min(sources.size(), begin + batch);
    order.resize(end - begin);
    std::iota(order.begin(), order.end(), begin);
    std::stable_sort(order.begin(), order.end(), [&](size_t a, size_t b) {
      return NodeNear(mesh, *graph_, sources[a]) < NodeNear(mesh, *graph_, sources[b]);
    });
    order = GroupNearby(mesh, sources, order);
    const size_t groups = (order.size() + kFieldLanes - 1) / kFieldLanes;
    RETURN_IF_ERROR(ForEachInParallel(groups, [&](size_t i) {
      const size_t first = i * kFieldLanes;
      return solve_group(absl::MakeConstSpan(order).subspan(first, kFieldLanes));
    }));
    if (sink.batch_done) RETURN_IF_ERROR(sink.batch_done(end));
  }
  return absl::OkStatus();
}

}  // namespace geodesic
