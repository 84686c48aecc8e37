#include "core/queries.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <numeric>
#include <random>
#include <span>
#include <thread>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/exact_geodesic.h"
#include "core/graph_search.h"
#include "core/node_heap.h"
#include "core/status.h"
#include "tbb/blocked_range.h"
#include "tbb/parallel_for.h"

namespace geodesic {
namespace {

// Runs body(0), ..., body(n - 1) on TBB's workers, one index per task (a
// pair or a row is milliseconds of work, so finer grains only add
// overhead). Returns the error of the lowest failing index, so that a
// request's error does not depend on scheduling.
absl::Status ForEachInParallel(size_t n, const std::function<absl::Status(size_t)>& body) {
  std::vector<absl::Status> errors(n);
  std::atomic<bool> failed{false};
  auto run = [&](size_t i) {
    errors[i] = body(i);
    if (!errors[i].ok()) failed = true;
  };
#ifdef GEODESIC_TSAN
  // TSan cannot see TBB's synchronisation (core/thread_arena.h): in order.
  for (size_t i = 0; i < n; ++i) run(i);
#else
  tbb::parallel_for(tbb::blocked_range<size_t>(0, n, 1), [&](const tbb::blocked_range<size_t>& r) {
    for (size_t i = r.begin(); i != r.end(); ++i) run(i);
  });
#endif
  if (failed) {
    for (absl::Status& e : errors) {
      if (!e.ok()) return e;
    }
  }
  return absl::OkStatus();
}

constexpr uint32_t kViaSource = kNone;         // reached from a source node itself
constexpr uint32_t kViaTemporary = kNone - 1;  // reached by a temporary edge

// Direct edges from a point that is not a graph node to mesh vertices
// (Appendix A: the locally augmented graph).
struct TemporaryEdge {
  VertexId vertex;
  uint32_t node;  // the vertex's graph node
  double weight;
};

absl::Status CheckPoint(const Mesh& mesh, const SurfacePoint& p, std::string_view what) {
  absl::Status s = ValidateSurfacePoint(mesh, p);
  if (s.ok()) return s;
  return absl::Status(s.code(), absl::StrFormat("%s: %s", what, s.message()));
}

}  // namespace

GeodesicEngine::GeodesicEngine(std::shared_ptr<const Mesh> mesh,
                               std::shared_ptr<const DggGraph> graph)
    : mesh_(std::move(mesh)),
      graph_(std::move(graph)),
      scratch_(std::max<int>(2, std::thread::hardware_concurrency())) {
  buckets_ = BucketShapeOf(*graph_);
  node_xyz_.resize(graph_->num_nodes());
  for (uint32_t u = 0; u < node_xyz_.size(); ++u) {
    node_xyz_[u] = PositionOf(*mesh_, graph_->point_of_node(u));
  }
}

GeodesicEngine::~GeodesicEngine() = default;

absl::Status GeodesicEngine::PrepareLandmarks(int count,
                                              const std::function<bool()>& cancelled) const {
  absl::MutexLock lock(&landmarks_mu_);
  if (landmarks_storage_) return absl::OkStatus();
  ASSIGN_OR_RETURN(landmarks_storage_, Landmarks::Compute(*graph_, count, cancelled));
  landmarks_.store(landmarks_storage_.get(), std::memory_order_release);
  return absl::OkStatus();
}

int GeodesicEngine::DefaultLandmarkCount() const {
  constexpr uint64_t kMin = 16, kMax = 64;
  const uint64_t nodes = std::max<uint64_t>(graph_->num_nodes(), 1);
  return static_cast<int>(
      std::clamp(graph_->byte_size() / 4 / (sizeof(float) * nodes), kMin, kMax));
}

uint64_t GeodesicEngine::landmark_bytes() const {
  const Landmarks* l = landmarks_.load(std::memory_order_acquire);
  return l ? l->byte_size() : 0;
}

namespace {

// One end of a query (a field's source, a pair's point, a matrix's row or
// column): a graph node, or a point joined to the graph by temporary edges.
struct Endpoint {
  SurfacePoint point;
  Vec3 xyz;
  bool is_node = false;
  uint32_t node = kNone;
  std::vector<TemporaryEdge> edges;
};

// Joins `raw` to the graph: a vertex is its own node; any other point runs
// the exact engine's direct propagation, whose lit vertices become its
// temporary edges. With `keep_windows` the propagation stays in the
// scratch's exact engine, so that its DistanceTo then answers direct
// geodesic distances from the
// point (the same-face and nearby cases no path through vertices gets
// right). Every query joins its points here, so fields, pairs and matrices
// see one augmented graph.
absl::StatusOr<Endpoint> JoinToGraph(const Mesh& mesh, const DggGraph& graph, QueryScratch& sc,
                                     const SurfacePoint& raw, bool keep_windows) {
  Endpoint end;
  end.point = CanonicalizeSurfacePoint(mesh, raw);
  end.xyz = PositionOf(mesh, end.point);
  if (end.point.kind == SurfacePoint::Kind::kVertex) {
    end.is_node = true;
    end.node = graph.node_of_vertex(end.point.id);
    return end;
  }
  DirectOptions options;
  options.epsilon = graph.params().epsilon;
  options.keep_windows = keep_windows;
  ASSIGN_OR_RETURN(std::vector<DirectHit> hits, sc.Exact(mesh).DirectGeodesics(end.point, options));
  end.edges.reserve(hits.size());
  for (const DirectHit& h : hits) {
    end.edges.push_back({h.vertex, graph.node_of_vertex(h.vertex), h.distance});
  }
  return end;
}

// The distance of an end point from a field given in mesh vertex order: at
// its node, or the best of its temporary edges (the last hop of a path that
// enters it through them).
double FieldDistanceTo(const Endpoint& end, absl::Span<const double> field) {
  if (end.is_node) return field[end.point.id];
  double d = kInfinity;
  for (const TemporaryEdge& e : end.edges) d = std::min(d, field[e.vertex] + e.weight);
  return d;
}

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
std::vector<uint32_t> SeedField(const DggGraph& g, QueryScratch& sc,
                                absl::Span<const Endpoint> sources) {
  std::vector<uint32_t> seeds;
  auto seed = [&](uint32_t u, double d, uint32_t source) {
    if (!(d < sc.dist[u])) return;
    sc.dist[u] = d;
    sc.fan[u] = AllEdges(g, u);
    sc.label[u] = source;
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

// The field from sources already joined to the graph.
absl::StatusOr<FieldResult> SolveField(const Mesh& mesh, const DggGraph& g,
                                       const BucketShape& bucket_shape, QueryScratch& sc,
                                       absl::Span<const Endpoint> sources,
                                       const FieldOptions& options) {
  RETURN_IF_ERROR(CheckTargets(mesh, options.targets));
  const uint32_t nodes = g.num_nodes();
  sc.PrepareField(nodes);
  std::vector<double>& dist = sc.dist;
  std::vector<FanRange>& fan = sc.fan;
  std::vector<uint32_t>& label = sc.label;
  std::fill(dist.begin(), dist.begin() + nodes, kInfinity);
  if (options.nearest_source) std::fill(label.begin(), label.begin() + nodes, kNone);
  const bool use_fans = options.method == FieldMethod::kLabelCorrecting;

  const std::vector<uint32_t> seeds = SeedField(g, sc, sources);

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
  // Each combination of fans and labels is its own search, so the inner
  // loop tests neither (labels cost a read and a write per improvement).
  auto search = [&]<bool kUseFans>(auto& queue) {
    if (options.nearest_source) {
      auto improved = [&](uint32_t u, uint32_t v) { label[v] = label[u]; };
      return SearchGraph<kUseFans>(g, queue, dist.data(), fan.data(), visit, improved);
    }
    return SearchGraph<kUseFans>(g, queue, dist.data(), fan.data(), visit,
                                 [](uint32_t, uint32_t) {});
  };
  auto run = [&](auto& queue) {
    for (uint32_t s : seeds) queue.Push(s, dist[s]);
    result.relaxed = use_fans ? search.template operator()<true>(queue)
                              : search.template operator()<false>(queue);
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

}  // namespace

absl::StatusOr<FieldResult> GeodesicEngine::Field(absl::Span<const SurfacePoint> sources,
                                                  const FieldOptions& options) const {
  const Mesh& mesh = *mesh_;
  if (sources.empty()) return absl::InvalidArgumentError("a field needs at least one source");
  for (size_t i = 0; i < sources.size(); ++i) {
    RETURN_IF_ERROR(CheckPoint(mesh, sources[i], absl::StrFormat("source %u", i)));
  }
  ScratchPool::Lease sc = scratch_.Acquire();
  std::vector<Endpoint> ends;
  ends.reserve(sources.size());
  for (const SurfacePoint& p : sources) {
    ASSIGN_OR_RETURN(ends.emplace_back(), JoinToGraph(mesh, *graph_, *sc, p, false));
  }
  return SolveField(mesh, *graph_, buckets_, *sc, ends, options);
}

namespace {

// Length of the straight segments of a traced path.
double PolylineLength(const std::vector<PathPoint>& points) {
  double length = 0;
  for (size_t i = 1; i < points.size(); ++i)
    length += geodesic::Distance(points[i - 1].xyz, points[i].xyz);
  return length;
}

// Lower bound on the graph distance between any node and one endpoint of a
// query: the straight line (every edge is at least as long as its chord),
// and per landmark L the triangle inequality. For an endpoint joined by
// temporary edges (w, t), with lo(L) = min_w d_L(w) + t (the endpoint's graph
// distance from L) and hi(L) = max_w d_L(w) - t, any node v is at least
// lo(L) - d_L(v) and d_L(v) - hi(L) from it. Both are 1-Lipschitz along
// edges, so the bound stays consistent.
class EndpointBound {
 public:
  // `active`: the landmarks to use, indices into the landmark set.
  EndpointBound(const Endpoint& end, const Landmarks* landmarks, std::span<const uint8_t> active)
      : xyz_(end.xyz) {
    if (!landmarks) return;
    landmarks_ = landmarks;
    active_.assign(active.begin(), active.end());
    lo_.assign(active.size(), kInfinity);
    hi_.assign(active.size(), -kInfinity);
    auto add = [&](uint32_t node, double t) {
      auto d = landmarks->of(node);
      for (size_t i = 0; i < active_.size(); ++i) {
        const double di = d[active_[i]];
        if (di == kInfinity) continue;
        lo_[i] = std::min(lo_[i], di + t);
        hi_[i] = std::max(hi_[i], di - t);
      }
    };
    if (end.is_node) {
      add(end.node, 0);
    } else {
      for (const TemporaryEdge& e : end.edges) add(e.node, e.weight);
    }
  }

  // The endpoint's graph distance from its i-th active landmark.
  double landmark_distance(size_t i) const { return lo_[i]; }

  double operator()(uint32_t node, const Vec3& x) const {
    double bound = geodesic::Distance(x, xyz_);
    if (!landmarks_) return bound;
    auto d = landmarks_->of(node);
    for (size_t i = 0; i < active_.size(); ++i) {
      const double di = d[active_[i]];
      // An unreached landmark (another component) has lo = +inf, hi = -inf.
      if (di == kInfinity || lo_[i] == kInfinity) continue;
      bound = std::max(bound, std::max(lo_[i] - di, di - hi_[i]));
    }
    return bound;
  }

 private:
  Vec3 xyz_;
  const Landmarks* landmarks_ = nullptr;
  std::vector<uint8_t> active_;
  std::vector<double> lo_, hi_;
};

// Few active landmarks bound a pair almost as tightly as all of them for a
// cheaper potential per node; too few settle more nodes. The value is in
// the flat middle of that trade-off (bench/notes.md, "Landmarks").
constexpr size_t kActiveLandmarks = 12;
constexpr int kFloatsPerLine = 64 / sizeof(float);

// The landmarks that bound the distance between the two endpoints best
// (Goldberg and Harrelson's active landmarks): a node's potential costs a
// lookup per landmark, and a few well-placed ones give nearly the bound of
// all of them.
std::vector<uint8_t> ActiveLandmarks(const Endpoint ends[2], const Landmarks& landmarks,
                                     size_t count) {
  const std::vector<uint8_t> all = [&] {
    std::vector<uint8_t> v(landmarks.count());
    std::iota(v.begin(), v.end(), 0);
    return v;
  }();
  if (all.size() <= count) return all;
  const EndpointBound a(ends[0], &landmarks, all), b(ends[1], &landmarks, all);
  std::vector<std::pair<double, uint8_t>> ranked;
  for (uint8_t i : all) {
    const double da = a.landmark_distance(i), db = b.landmark_distance(i);
    ranked.push_back({da < kInfinity && db < kInfinity ? std::abs(da - db) : -1.0, i});
  }
  std::partial_sort(ranked.begin(), ranked.begin() + count, ranked.end(), std::greater<>());
  std::vector<uint8_t> active;
  for (size_t i = 0; i < count; ++i) active.push_back(ranked[i].second);
  std::sort(active.begin(), active.end());
  return active;
}

}  // namespace

namespace {

// The weight of the edge u -> v (u's list is short: a scan).
float EdgeWeight(const DggGraph& g, uint32_t u, uint32_t v) {
  auto offsets = g.offsets();
  auto edges = g.edges();
  for (uint64_t i = offsets[u]; i < offsets[u + 1]; ++i) {
    if (edges[i].target == v) return edges[i].weight;
  }
  return std::numeric_limits<float>::infinity();  // not reached: the search used it
}

// The graph nodes of the bidirectional search's path through `meet`, from
// the first end point's side to the second's.
std::vector<uint32_t> RouteThrough(PairTable& at, uint32_t meet) {
  std::vector<uint32_t> route;
  for (uint32_t u = meet; u != kViaSource && u != kViaTemporary; u = at.Find(u)->pred[0]) {
    route.push_back(u);
  }
  std::reverse(route.begin(), route.end());
  for (uint32_t u = at.Find(meet)->pred[1]; u != kViaSource && u != kViaTemporary;
       u = at.Find(u)->pred[1]) {
    route.push_back(u);
  }
  return route;
}

// The length of `route`, summed from the first end point to the second, hop
// by hop, as a field from the first point sums it. The search's own total
// adds the second half in the other order, which may round differently: this
// way a matrix entry (one field per row) equals the pair's distance to the
// last bit when both find one path.
double SumAlongRoute(const DggGraph& g, const Endpoint ends[2], PairTable& at,
                     const std::vector<uint32_t>& route) {
  auto join_weight = [](const Endpoint& end, uint32_t node) {
    for (const TemporaryEdge& e : end.edges) {
      if (e.node == node) return e.weight;
    }
    return kInfinity;  // not reached: the node was joined by one of them
  };
  double d =
      at.Find(route.front())->pred[0] == kViaTemporary ? join_weight(ends[0], route.front()) : 0.0;
  for (size_t k = 0; k + 1 < route.size(); ++k) d += EdgeWeight(g, route[k], route[k + 1]);
  if (at.Find(route.back())->pred[1] == kViaTemporary) d += join_weight(ends[1], route.back());
  return d;
}

}  // namespace

absl::StatusOr<PairResult> GeodesicEngine::Distance(const SurfacePoint& raw_a,
                                                    const SurfacePoint& raw_b,
                                                    const PairOptions& options) const {
  const Mesh& mesh = *mesh_;
  const DggGraph& g = *graph_;
  RETURN_IF_ERROR(CheckPoint(mesh, raw_a, "first point"));
  RETURN_IF_ERROR(CheckPoint(mesh, raw_b, "second point"));
  ScratchPool::Lease lease = scratch_.Acquire();
  QueryScratch& sc = *lease;
  PairResult result;
  // A point that is not a node joins the graph by its direct geodesics. The
  // first one also gives the direct geodesic to the second point, if it sees
  // it: exact, and the answer whenever it is shortest. When either point is
  // a vertex the other's temporary edges (or the graph's own) already hold
  // that geodesic up to the candidate budget, so a vertex costs no
  // propagation at all. Matrix makes the same choices, entry by entry.
  Endpoint ends[2];
  ASSIGN_OR_RETURN(ends[0], JoinToGraph(mesh, g, sc, raw_a, /*keep_windows=*/true));
  double best = kInfinity;
  if (!ends[0].is_node) {
    auto direct = sc.Exact(mesh).DistanceTo(CanonicalizeSurfacePoint(mesh, raw_b));
    if (direct.ok()) best = *direct;
  }
  ASSIGN_OR_RETURN(ends[1], JoinToGraph(mesh, g, sc, raw_b, /*keep_windows=*/false));

  PairTable& at = sc.pairs;
  at.Reset(g.num_nodes());
  auto offsets = g.offsets();
  auto edges = g.edges();
  // Average potential p(v) = (bound to b - bound to a) / 2: consistent for
  // both directions because each bound is (EndpointBound).
  // Plain Dijkstra (no A*) needs no bounds, so no landmark work either.
  const Landmarks* landmarks =
      options.use_astar ? landmarks_.load(std::memory_order_acquire) : nullptr;
  const std::vector<uint8_t> active =
      landmarks ? ActiveLandmarks(ends, *landmarks, kActiveLandmarks) : std::vector<uint8_t>{};
  const EndpointBound to_a(ends[0], landmarks, active), to_b(ends[1], landmarks, active);
  // The cache lines of a node's landmark row that hold active landmarks.
  std::vector<uint8_t> active_lines;
  for (uint8_t i : active) {
    const uint8_t line = i / kFloatsPerLine;
    if (active_lines.empty() || active_lines.back() != line) active_lines.push_back(line);
  }
  // The record of node u for this query, initialised on first touch.
  auto node = [&](uint32_t u) -> PairTable::Record& {
    bool inserted;
    PairTable::Record& n = at.FindOrInsert(u, &inserted);
    if (inserted) {
      n.dist[0] = n.dist[1] = kInfinity;
      n.slot[0] = n.slot[1] = kNotInHeap;
      if (options.use_astar) {
        const Vec3& x = node_xyz_[u];
        n.potential = static_cast<float>(0.5 * (to_b(u, x) - to_a(u, x)));
      } else {
        n.potential = 0;
      }
    }
    return n;
  };
  auto& heap = sc.pair_heap;
  heap[0].Clear();
  heap[1].Clear();
  uint32_t meet = kNone;
  double mu = best;
  // Side s reaches node u at distance d from node `from` (or from an end
  // point), to go on along `fan`.
  auto set = [&](int s, uint32_t u, double d, uint32_t from, FanRange fan) {
    PairTable::Record& n = node(u);
    if (!(d < n.dist[s])) return;
    n.dist[s] = d;
    n.pred[s] = from;
    n.fan[s] = fan;
    if (d + n.dist[1 - s] < mu) {
      mu = d + n.dist[1 - s];
      meet = u;
    }
    // A node whose key already reaches the stopping bound would be popped
    // only after the search stops (the other side's top only grows and mu
    // only shrinks), so it is not queued at all.
    const double key = s == 0 ? d + n.potential : d - n.potential;
    if (!heap[1 - s].empty() && key + heap[1 - s].top_key() >= mu) return;
    heap[s].Push(u, key);
    ++result.queued;
  };
  for (int s = 0; s < 2; ++s) {
    if (ends[s].is_node) {
      set(s, ends[s].node, 0, kViaSource, AllEdges(g, ends[s].node));
    } else {
      for (const TemporaryEdge& e : ends[s].edges) {
        set(s, e.node, e.weight, kViaTemporary, AllEdges(g, e.node));
      }
    }
  }
  uint64_t steps = 0;
  while (!heap[0].empty() && !heap[1].empty()) {
    if (heap[0].top_key() + heap[1].top_key() >= mu) break;
    if (options.cancelled && (++steps & 1023) == 0 && options.cancelled()) {
      return absl::CancelledError("distance query cancelled");
    }
    const int s = heap[0].size() <= heap[1].size() ? 0 : 1;
    const uint32_t u = heap[s].top();
    heap[s].Pop();
    PairTable::Record& record = *at.Find(u);
    if (record.done(s)) continue;
    record.set_done(s);
    ++result.settled;
    const double du = record.dist[s];
    const FanRange fan = record.fan[s];
    // Memory-bound: each neighbour is a random node. Ask for the records a
    // few edges ahead so their cache misses overlap.
    constexpr uint64_t kAhead = 6;
    const uint64_t begin = offsets[u], end = offsets[u + 1], degree = end - begin;
    result.relaxed += fan.count;
    for (uint64_t k = 0, i = begin + fan.begin; k < fan.count; ++k) {
      if (k + kAhead < fan.count) {
        const uint64_t j = i + kAhead < end ? i + kAhead : i + kAhead - degree;
        const uint32_t ahead = edges[j].target;
        at.Prefetch(ahead);
        if (landmarks) {
          const float* row = landmarks->of(ahead).data();
          for (uint8_t line : active_lines) __builtin_prefetch(row + kFloatsPerLine * line);
        }
        if (options.use_astar) __builtin_prefetch(&node_xyz_[ahead]);
      }
      set(s, edges[i].target, du + edges[i].weight, u, edges[i].fan);
      if (++i == end) i = begin;  // fans wrap past u's last edge
    }
  }
  result.distance = mu;
  // A direct geodesic that won has no route through the graph.
  std::vector<uint32_t> route;
  if (meet != kNone && mu < best) route = RouteThrough(at, meet);
  // The same number whether or not a path is asked for, and the number a
  // field from the first point gives (see SumAlongRoute).
  if (!route.empty()) result.distance = std::min(best, SumAlongRoute(g, ends, at, route));
  if (!options.want_path || mu == kInfinity) return result;

  // Graph path: first point, the route's nodes, second point, with the
  // distance along the graph at each stop (up to the meeting node the first
  // side's, after it what the second side leaves of mu).
  std::vector<SurfacePoint> stops{ends[0].point};
  std::vector<double> along{0.0};
  const size_t meet_at = std::find(route.begin(), route.end(), meet) - route.begin();
  for (size_t k = 0; k < route.size(); ++k) {
    const uint32_t u = route[k];
    const bool first_side = k <= meet_at;
    const Endpoint& end = first_side ? ends[0] : ends[1];
    if (end.is_node && u == end.node) continue;  // the end point's own stop
    stops.push_back(g.point_of_node(u));
    along.push_back(first_side ? at.Find(u)->dist[0] : mu - at.Find(u)->dist[1]);
  }
  stops.push_back(ends[1].point);
  along.push_back(mu);
  // Each hop is a direct geodesic: trace it with the exact engine, bounding
  // the propagation by the hop's graph length.
  ExactGeodesic& exact = sc.Exact(mesh);
  GeodesicPath path;
  for (size_t k = 0; k + 1 < stops.size(); ++k) {
    const SurfacePoint& from = stops[k];
    const SurfacePoint& to = stops[k + 1];
    DirectOptions options_hop;
    options_hop.keep_windows = true;
    options_hop.max_distance = (along[k + 1] - along[k]) * (1 + 1e-6) + 1e-12;
    auto hits = exact.DirectGeodesics(from, options_hop);
    if (!hits.ok()) return hits.status();
    auto traced = exact.Trace(to);
    if (!traced.ok()) {
      return absl::InternalError(absl::StrFormat("could not trace graph edge %s -> %s: %s",
                                                 FormatSurfacePoint(from), FormatSurfacePoint(to),
                                                 traced.status().message()));
    }
    for (const auto& tp : *traced) {
      if (!path.points.empty() && geodesic::Distance(path.points.back().xyz, tp.xyz) == 0) continue;
      path.points.push_back({tp.point, tp.xyz});
    }
  }
  // The traced polyline is a real surface path, never longer than the
  // graph's rounded-up weights; its own length goes with it, while the
  // pair's distance stays the graph's, as without a path.
  path.length = PolylineLength(path.points);
  result.path = std::move(path);
  return result;
}

absl::StatusOr<SampleResult> GeodesicEngine::SamplePoints(int count,
                                                          const SampleOptions& options) const {
  const Mesh& mesh = *mesh_;
  std::vector<VertexId> usable;
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
    if (!mesh.is_isolated(v)) usable.push_back(v);
  }
  if (count < 1 || static_cast<size_t>(count) > usable.size()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "cannot sample %d points: the mesh has %u vertices on its surface", count, usable.size()));
  }
  std::mt19937_64 rng(options.seed);
  SampleResult result;
  result.vertices.push_back(
      usable[std::uniform_int_distribution<size_t>(0, usable.size() - 1)(rng)]);
  // Distance of each vertex from its nearest sample so far.
  std::vector<double> nearest(mesh.num_vertices(), kInfinity);
  std::vector<bool> chosen(mesh.num_vertices(), false);
  FieldOptions field_options;
  field_options.cancelled = options.cancelled;
  while (true) {
    // Only vertices nearer to the new sample than to every earlier one
    // change, and none of those is farther than the covering radius: the
    // search stops there.
    field_options.max_distance = result.covering_radius;
    const SurfacePoint sample = SurfacePoint::Vertex(result.vertices.back());
    ASSIGN_OR_RETURN(FieldResult field, Field(absl::MakeConstSpan(&sample, 1), field_options));
    chosen[result.vertices.back()] = true;
    // Chosen vertices are at 0, so the farthest unchosen one (there is one
    // while fewer than `usable` are chosen, even where points coincide)
    // gives the covering radius.
    VertexId farthest = kNone;
    for (VertexId v : usable) {
      nearest[v] = std::min(nearest[v], field.distance[v]);
      if (!chosen[v] && (farthest == kNone || nearest[v] > nearest[farthest])) farthest = v;
    }
    result.covering_radius = farthest == kNone ? 0 : nearest[farthest];
    if (result.vertices.size() == static_cast<size_t>(count)) break;
    result.vertices.push_back(farthest);
  }
  return result;
}

absl::StatusOr<std::vector<double>> GeodesicEngine::Matrix(
    absl::Span<const SurfacePoint> sources, absl::Span<const SurfacePoint> targets,
    const std::function<bool()>& cancelled) const {
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
    ScratchPool::Lease sc = scratch_.Acquire();
    for (const SurfacePoint& t : targets) {
      ASSIGN_OR_RETURN(target_ends.emplace_back(), JoinToGraph(mesh, *graph_, *sc, t, false));
    }
  }
  std::vector<double> out(sources.size() * targets.size(), kInfinity);
  FieldOptions options;
  options.cancelled = cancelled;
  auto solve_row = [&](size_t i) -> absl::Status {
    ScratchPool::Lease row_sc = scratch_.Acquire();
    ASSIGN_OR_RETURN(Endpoint source, JoinToGraph(mesh, *graph_, *row_sc, sources[i], true));
    double* row = out.data() + i * target_ends.size();
    for (size_t j = 0; j < target_ends.size(); ++j) {
      if (!source.is_node) {
        auto d = row_sc->Exact(mesh).DistanceTo(target_ends[j].point);
        if (d.ok()) row[j] = *d;
      }
    }
    ASSIGN_OR_RETURN(FieldResult field, SolveField(mesh, *graph_, buckets_, *row_sc,
                                                   absl::MakeConstSpan(&source, 1), options));
    for (size_t j = 0; j < target_ends.size(); ++j) {
      row[j] = std::min(row[j], FieldDistanceTo(target_ends[j], field.distance));
    }
    return absl::OkStatus();
  };
  RETURN_IF_ERROR(ForEachInParallel(sources.size(), solve_row));
  return out;
}

absl::StatusOr<std::vector<PairResult>> GeodesicEngine::Distances(
    absl::Span<const SurfacePoint> from, absl::Span<const SurfacePoint> to,
    const PairOptions& options) const {
  if (from.size() != to.size()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%u first points but %u second points: pairs need one of each", from.size(), to.size()));
  }
  std::vector<PairResult> out(from.size());
  RETURN_IF_ERROR(ForEachInParallel(from.size(), [&](size_t i) -> absl::Status {
    ASSIGN_OR_RETURN(out[i], Distance(from[i], to[i], options));
    return absl::OkStatus();
  }));
  return out;
}

}  // namespace geodesic
