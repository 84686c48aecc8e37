// Point-to-point queries (Appendix A of the paper): a bidirectional search
// on the locally augmented graph, and the geodesic path it found traced on
// the surface.
#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <span>
#include <vector>

#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/for_each_in_parallel.h"
#include "core/base/node_heap.h"
#include "core/base/status.h"
#include "core/exact/exact_geodesic.h"
#include "core/query/augmented_graph.h"
#include "core/query/geodesic_engine.h"
#include "core/query/graph_search.h"

namespace geodesic {

using query_internal::CheckPoint;
using query_internal::Endpoint;
using query_internal::FieldDistanceTo;
using query_internal::JoinToGraph;
using query_internal::kViaSource;
using query_internal::kViaTemporary;
using query_internal::TemporaryEdge;

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

// The bidirectional search between two end points joined to the graph
// (Appendix A), A* with the average potential p(v) = (bound to b - bound to
// a) / 2 when bounds are given: consistent for both directions because each
// bound is (EndpointBound). Each side relaxes only the fan of the edge a node
// was reached by, as the field solver does.
class BidirectionalSearch {
 public:
  // `best`: a distance already known (the direct geodesic), which the search
  // must beat. `landmarks`: null for straight-line bounds alone.
  BidirectionalSearch(const DggGraph& g, QueryScratch& sc, const Endpoint (&ends)[2],
                      std::span<const Vec3> node_xyz, bool use_astar, const Landmarks* landmarks,
                      double best, PairResult& result)
      : g_(g),
        at_(sc.pairs),
        heap_(sc.pair_heap),
        node_xyz_(node_xyz),
        use_astar_(use_astar),
        landmarks_(landmarks),
        active_(landmarks ? ActiveLandmarks(ends, *landmarks, kActiveLandmarks)
                          : std::vector<uint8_t>{}),
        to_a_(ends[0], landmarks, active_),
        to_b_(ends[1], landmarks, active_),
        mu_(best),
        result_(result) {
    for (uint8_t i : active_) {
      const uint8_t line = i / kFloatsPerLine;
      if (active_lines_.empty() || active_lines_.back() != line) active_lines_.push_back(line);
    }
    at_.Reset(g.num_nodes());
    heap_[0].Clear();
    heap_[1].Clear();
    for (int s = 0; s < 2; ++s) {
      if (ends[s].is_node) {
        Reach(s, ends[s].node, 0, kViaSource, AllEdges(g, ends[s].node));
      } else {
        for (const TemporaryEdge& e : ends[s].edges) {
          Reach(s, e.node, e.weight, kViaTemporary, AllEdges(g, e.node));
        }
      }
    }
  }

  // Runs until neither side can improve on the best meeting found.
  absl::Status Run(const std::function<bool()>& cancelled) {
    uint64_t steps = 0;
    while (!heap_[0].empty() && !heap_[1].empty()) {
      if (heap_[0].top_key() + heap_[1].top_key() >= mu_) break;
      if (cancelled && (++steps & 1023) == 0 && cancelled()) {
        return absl::CancelledError("distance query cancelled");
      }
      Settle(heap_[0].size() <= heap_[1].size() ? 0 : 1);
    }
    return absl::OkStatus();
  }

  double distance() const { return mu_; }
  // The node where the shortest route found meets, kNone when the distance
  // known before the search (or none) won.
  uint32_t meet() const { return meet_; }
  PairTable& table() { return at_; }
  // Settled nodes are the ones that read their edge lists.
  SearchWork work() const {
    SearchWork w;
    w.relaxed = result_.relaxed;
    w.improved = improved_;
    w.pushes = result_.queued;
    w.pops = pops_;
    w.graph_bytes = GraphBytesRead(result_.relaxed, sizeof(DggEdge), result_.settled);
    return w;
  }

 private:
  // The record of node u for this query, initialised on first touch.
  PairTable::Record& Node(uint32_t u) {
    bool inserted;
    PairTable::Record& n = at_.FindOrInsert(u, &inserted);
    if (inserted) {
      n.dist[0] = n.dist[1] = kInfinity;
      n.slot[0] = n.slot[1] = kNotInHeap;
      if (use_astar_) {
        const Vec3& x = node_xyz_[u];
        n.potential = static_cast<float>(0.5 * (to_b_(u, x) - to_a_(u, x)));
      } else {
        n.potential = 0;
      }
    }
    return n;
  }

  // Side s reaches node u at distance d from node `from` (or from an end
  // point), to go on along `fan`.
  void Reach(int s, uint32_t u, double d, uint32_t from, FanRange fan) {
    PairTable::Record& n = Node(u);
    if (!(d < n.dist[s])) return;
    ++improved_;
    n.dist[s] = d;
    n.pred[s] = from;
    n.fan[s] = fan;
    if (d + n.dist[1 - s] < mu_) {
      mu_ = d + n.dist[1 - s];
      meet_ = u;
    }
    // A node whose key already reaches the stopping bound would be popped
    // only after the search stops (the other side's top only grows and mu
    // only shrinks), so it is not queued at all.
    const double key = s == 0 ? d + n.potential : d - n.potential;
    if (!heap_[1 - s].empty() && key + heap_[1 - s].top_key() >= mu_) return;
    heap_[s].Push(u, key);
    ++result_.queued;
  }

  // Pops side s's nearest node and relaxes the fan it was reached by.
  void Settle(int s) {
    const uint32_t u = heap_[s].top();
    heap_[s].Pop();
    ++pops_;
    PairTable::Record& record = *at_.Find(u);
    if (record.done(s)) return;
    record.set_done(s);
    ++result_.settled;
    const double du = record.dist[s];
    const FanRange fan = record.fan[s];
    const auto offsets = g_.offsets();
    const auto edges = g_.edges();
    // Memory-bound: each neighbour is a random node. Ask for the records a
    // few edges ahead so their cache misses overlap.
    constexpr uint64_t kAhead = 6;
    const uint64_t begin = offsets[u], end = offsets[u + 1], degree = end - begin;
    result_.relaxed += fan.count;
    for (uint64_t k = 0, i = begin + fan.begin; k < fan.count; ++k) {
      if (k + kAhead < fan.count) {
        const uint64_t j = i + kAhead < end ? i + kAhead : i + kAhead - degree;
        Prefetch(edges[j].target);
      }
      Reach(s, edges[i].target, du + edges[i].weight, u, edges[i].fan);
      if (++i == end) i = begin;  // fans wrap past u's last edge
    }
  }

  void Prefetch(uint32_t node) const {
    at_.Prefetch(node);
    if (landmarks_) {
      const float* row = landmarks_->of(node).data();
      for (uint8_t line : active_lines_) __builtin_prefetch(row + kFloatsPerLine * line);
    }
    if (use_astar_) __builtin_prefetch(&node_xyz_[node]);
  }

  const DggGraph& g_;
  PairTable& at_;
  BasicNodeHeap<QueryScratch::PairSlot> (&heap_)[2];
  std::span<const Vec3> node_xyz_;
  const bool use_astar_;
  const Landmarks* const landmarks_;
  const std::vector<uint8_t> active_;
  // The cache lines of a node's landmark row that hold active landmarks.
  std::vector<uint8_t> active_lines_;
  const EndpointBound to_a_, to_b_;
  double mu_;
  uint32_t meet_ = kNone;
  PairResult& result_;
  uint64_t pops_ = 0, improved_ = 0;
};

// The surface path of a graph route: the first point, the route's nodes,
// the second point, each hop a direct geodesic traced by the exact engine
// with its propagation bounded by the hop's graph length.
absl::StatusOr<GeodesicPath> TraceRoute(const Mesh& mesh, const DggGraph& g, QueryScratch& sc,
                                        const Endpoint (&ends)[2],
                                        const std::vector<uint32_t>& route, uint32_t meet,
                                        double mu) {
  // The distance along the graph at each stop: up to the meeting node the
  // first side's, after it what the second side leaves of mu.
  PairTable& at = sc.pairs;
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
  ExactGeodesic& exact = sc.Exact(mesh);
  GeodesicPath path;
  for (size_t k = 0; k + 1 < stops.size(); ++k) {
    const SurfacePoint& from = stops[k];
    const SurfacePoint& to = stops[k + 1];
    DirectOptions options_hop;
    options_hop.keep_windows = true;
    options_hop.max_distance = (along[k + 1] - along[k]) * (1 + 1e-6) + 1e-12;
    RETURN_IF_ERROR(exact.DirectGeodesics(from, options_hop).status());
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
  return path;
}

// Replaces the graph's answer in `result` by the exact distance from `a` to
// `b` (and the exact geodesic with `want_path`), by a propagation bounded by
// that answer and aimed at `b`.
absl::Status MakeExact(const Mesh& mesh, QueryScratch& sc, const ExactLandmarks* landmarks,
                       const SurfacePoint& a, const SurfacePoint& b, const PairOptions& pair,
                       PairResult& result) {
  result.exact = true;
  if (result.distance == kInfinity) return absl::OkStatus();
  ExactGeodesic& exact = sc.Exact(mesh);
  ExactOptions options =
      query_internal::ExactWithinGraphAnswer(result.distance, pair.cancelled, pair.exact_max_bytes);
  options.goal = PositionOf(mesh, b);
  ExactLandmarkRun with_landmarks(landmarks, mesh, &b, options);
  // The windows go once the answer is read: the engine stays in the pool.
  absl::Cleanup release = [&exact] { exact.ReleaseLargeWindows(); };
  ASSIGN_OR_RETURN(const std::vector<double> reached,
                   query_internal::ExactDistancesWithinGraphAnswer(exact, a, {&b, 1}, options));
  result.windows = exact.stats().windows_created;
  const double d = reached[0];
  // Not reached even without the bound only on a surface the exact engine
  // cannot cross where the graph's edges do; the graph answer stays.
  if (d == kInfinity) return absl::OkStatus();
  result.distance = d;
  if (!pair.want_path) return absl::OkStatus();
  ASSIGN_OR_RETURN(std::vector<ExactGeodesic::TracePoint> traced, exact.Trace(b));
  GeodesicPath path;
  for (const auto& tp : traced) path.points.push_back({tp.point, tp.xyz});
  path.length = PolylineLength(path.points);
  result.path = std::move(path);
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<PairResult> GeodesicEngine::Distance(const SurfacePoint& raw_a,
                                                    const SurfacePoint& raw_b,
                                                    const PairOptions& options) const {
  const Mesh& mesh = *mesh_;
  const DggGraph& g = *graph_;
  RETURN_IF_ERROR(CheckPoint(mesh, raw_a, "first point"));
  RETURN_IF_ERROR(CheckPoint(mesh, raw_b, "second point"));
  ScratchPool::Lease lease = AcquireScratch();
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

  // Plain Dijkstra (no A*) needs no bounds, so no landmark work either.
  const Landmarks* landmarks = options.use_astar ? landmarks_.get() : nullptr;
  BidirectionalSearch search(g, sc, ends, node_xyz_, options.use_astar, landmarks, best, result);
  RETURN_IF_ERROR(search.Run(options.cancelled));
  result.work = search.work();
  const double mu = search.distance();
  result.distance = mu;
  // A direct geodesic that won has no route through the graph.
  std::vector<uint32_t> route;
  if (search.meet() != kNone && mu < best) route = RouteThrough(search.table(), search.meet());
  // The same number whether or not a path is asked for, and the number a
  // field from the first point gives (see SumAlongRoute).
  if (!route.empty()) result.distance = std::min(best, SumAlongRoute(g, ends, sc.pairs, route));
  if (options.exact) {
    RETURN_IF_ERROR(
        MakeExact(mesh, sc, exact_landmarks_.get(), ends[0].point, ends[1].point, options, result));
    return result;
  }
  if (!options.want_path || mu == kInfinity) return result;
  ASSIGN_OR_RETURN(result.path, TraceRoute(mesh, g, sc, ends, route, search.meet(), mu));
  return result;
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
