#include "core/dgg_build.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstring>
#include <functional>
#include <limits>
#include <mutex>
#include <numbers>
#include <optional>
#include <queue>
#include <span>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/candidate_runs.h"
#include "core/dgg_graph_internal.h"
#include "core/exact_geodesic.h"
#include "core/fan.h"
#include "core/geodesic_shooting.h"
#include "core/large_array.h"
#include "core/status.h"
#include "core/thread_arena.h"

namespace geodesic {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;
// Fans used when choosing replacement paths, relative to the solver's.
constexpr double kPruningFanScale = 0.9;
// The error budget. Early termination of the candidates (Theorem 2 and the
// corners) may lengthen a shortest path by 1 + e_c, and pruning (when asked
// for) each replaced edge by 1 + e_p, with (1 + e_c)(1 + e_p) = 1 + b eps.
// Pruning gets a tenth of eps: its loss compounds the most. It then removes
// few candidates for a large share of the build (BENCHMARKS.md, "Build
// variants: pruning and pseudo vertices"), so by default it is skipped and
// the candidates get the whole budget.
//
// The budget b eps is a point on a trade-off, not a bound: routes through
// corners that are themselves served routes compound, so a field's largest
// error exceeds what one route may use. b = 1.1 instead of 1 (the paper's
// rule) keeps fewer edges while every shared mesh at 1e-2 and 1e-3 stays
// within the contract (mean 0.3 eps, max 1.5 eps), and at the same degree it
// is more accurate than FastDGG's rule, which tests corners by their exact
// distance rather than by their routes. Smaller eps chains more corners and
// compounds more: at 1e-4 the extra tenth took maxima past the contract, so
// it fades out between 1e-3 and 1e-4 (bench/notes.md, "Candidate budget";
// today's errors: BENCHMARKS.md, "Distance fields, side by side with CGAL").
double CornerBudgetFactor(double epsilon) {
  return 1 + 0.1 * std::clamp(std::log10(epsilon / 1e-4), 0.0, 1.0);
}
double PruningBudget(double epsilon) { return 0.1 * epsilon; }
double CandidateBudget(double epsilon, bool prune) {
  const double budget = CornerBudgetFactor(epsilon) * epsilon;
  if (!prune) return budget;
  return (1 + budget) / (1 + PruningBudget(epsilon)) - 1;
}

// Lengths are rounded up to float so that graph distances never undercut the
// surface paths they stand for.
float RoundUp(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) < d) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

float Normalized(double raw, double period) {
  float f = static_cast<float>(WrapAngle(raw * (kTwoPi / period), kTwoPi));
  return f >= static_cast<float>(kTwoPi) ? 0.0f : f;
}

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

// The build numbers its nodes as the graph does (DggGraph): vertices in
// spatial order, then pseudo vertices. Doing so from the candidates on lets
// every later phase work on the graph's own arrays, in place.
struct NodeOrder {
  std::vector<uint32_t> vertex_of_node, node_of_vertex;
  explicit NodeOrder(const Mesh& mesh);
  uint32_t vertices() const { return vertex_of_node.size(); }
  // A vertex or pseudo vertex id (pseudo vertices are numbered after the
  // vertices) to its node, and back.
  uint32_t node(uint32_t id) const { return id < vertices() ? node_of_vertex[id] : id; }
  uint32_t id(uint32_t node) const { return node < vertices() ? vertex_of_node[node] : node; }
};

// Adjacency lists in compressed form, by node, each sorted by target node.
struct Adjacency {
  std::vector<uint64_t> offsets;
  LargeArray<DggHalfEdge> edges;
  uint32_t rows() const { return offsets.size() - 1; }
  std::span<const DggHalfEdge> of(uint32_t u) const {
    return {edges.data() + offsets[u], edges.data() + offsets[u + 1]};
  }
  std::span<DggHalfEdge> of(uint32_t u) {
    return {edges.data() + offsets[u], edges.data() + offsets[u + 1]};
  }
  // Moves every row to its place under `grown` (as many rows or more, none
  // shorter), in place; what follows a row's old end there is unset.
  void Grow(std::vector<uint64_t> grown) {
    edges.resize(grown.back());
    for (uint32_t u = rows(); u-- > 0;) {
      const uint64_t count = offsets[u + 1] - offsets[u];
      if (count == 0) continue;  // and an empty array has no data() to move
      std::memmove(static_cast<void*>(edges.data() + grown[u]), edges.data() + offsets[u],
                   count * sizeof(DggHalfEdge));
    }
    offsets = std::move(grown);
  }
};

// The edge to `to` in a row sorted by target, or null.
template <typename Edge>
Edge* Find(std::span<Edge> row, uint32_t to) {
  auto it = std::lower_bound(row.begin(), row.end(), to,
                             [](const DggHalfEdge& e, uint32_t id) { return e.to < id; });
  return it != row.end() && it->to == to ? &*it : nullptr;
}

// The edge `e` of node `from`, seen from its other end.
DggHalfEdge Reversed(const DggHalfEdge& e, uint32_t from) {
  return {from, e.weight, e.angle_there, e.angle_here};
}

template <typename Less>
void SortRows(Adjacency& adj, Less less) {
  tbb::parallel_for(uint32_t{0}, adj.rows(), [&](uint32_t u) {
    auto row = adj.of(u);
    std::sort(row.begin(), row.end(), less);
  });
}

bool ByTarget(const DggHalfEdge& a, const DggHalfEdge& b) { return a.to < b.to; }

// Feeds every source's candidate list to a visitor (CandidateRuns::Drain, or
// the parts of a distributed build).
using CandidateFeed = std::function<absl::Status(const CandidateRuns::Visitor&)>;

class Progress {
 public:
  Progress(const DggBuildOptions& options) : callback_(options.progress) {}
  // Reports `done / total` of a phase spanning [begin, end) of the build.
  // Returns false once the build is cancelled.
  bool Report(std::string_view phase, double begin, double end, uint64_t done, uint64_t total) {
    if (cancelled_.load(std::memory_order_relaxed)) return false;
    if (!callback_) return true;
    std::lock_guard<std::mutex> lock(mu_);
    double f = begin + (end - begin) * (total ? double(done) / double(total) : 1.0);
    if (!callback_(phase, f)) cancelled_ = true;
    return !cancelled_;
  }
  bool cancelled() const { return cancelled_.load(std::memory_order_relaxed); }

 private:
  std::function<bool(std::string_view, double)> callback_;
  std::mutex mu_;
  std::atomic<bool> cancelled_{false};
};

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

// Runs body(i) for i in [0, n) on the arena's threads with dynamic load
// balancing, reporting progress every few items.
template <typename Body>
void ParallelFor(uint32_t n, Progress& progress, std::string_view phase, double begin, double end,
                 Body body) {
  std::atomic<uint64_t> done{0};
  tbb::parallel_for(tbb::blocked_range<uint32_t>(0, n, 8),
                    [&](const tbb::blocked_range<uint32_t>& r) {
                      if (progress.cancelled()) return;
                      for (uint32_t i = r.begin(); i != r.end(); ++i) body(i);
                      uint64_t now = done.fetch_add(r.size()) + r.size();
                      if ((now / 64) != ((now - r.size()) / 64) || now == n)
                        progress.Report(phase, begin, end, now, n);
                    });
}

// Vertices [begin, end) along a Z-order curve through their positions, as
// offsets from begin. Mesh files often list vertices in no spatial order;
// propagating from neighbouring sources one after another keeps the mesh data
// and per-vertex state they share in cache.
std::vector<uint32_t> SpatialOrder(const Mesh& mesh, uint32_t begin, uint32_t end) {
  constexpr double kInf = std::numeric_limits<double>::infinity();
  Vec3 lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
  for (uint32_t v = begin; v < end; ++v) {
    const Vec3& p = mesh.position(v);
    lo = {std::min(lo.x, p.x), std::min(lo.y, p.y), std::min(lo.z, p.z)};
    hi = {std::max(hi.x, p.x), std::max(hi.y, p.y), std::max(hi.z, p.z)};
  }
  const double extent = std::max({hi.x - lo.x, hi.y - lo.y, hi.z - lo.z, 1e-300});
  auto cell = [&](double x, double from) {
    constexpr double kCells = (1 << 21) - 1;
    return static_cast<uint64_t>(std::clamp((x - from) / extent * kCells, 0.0, kCells));
  };
  auto spread = [](uint64_t x) {  // bit i -> bit 3i, for 21 bits
    x &= 0x1fffff;
    x = (x | x << 32) & 0x1f00000000ffff;
    x = (x | x << 16) & 0x1f0000ff0000ff;
    x = (x | x << 8) & 0x100f00f00f00f00f;
    x = (x | x << 4) & 0x10c30c30c30c30c3;
    x = (x | x << 2) & 0x1249249249249249;
    return x;
  };
  std::vector<std::pair<uint64_t, uint32_t>> keyed(end - begin);
  for (uint32_t i = 0; i < end - begin; ++i) {
    const Vec3& p = mesh.position(begin + i);
    keyed[i] = {
        spread(cell(p.x, lo.x)) | spread(cell(p.y, lo.y)) << 1 | spread(cell(p.z, lo.z)) << 2, i};
  }
  std::sort(keyed.begin(), keyed.end());
  std::vector<uint32_t> order(end - begin);
  for (uint32_t i = 0; i < order.size(); ++i) order[i] = keyed[i].second;
  return order;
}

NodeOrder::NodeOrder(const Mesh& mesh)
    : vertex_of_node(SpatialOrder(mesh, 0, mesh.num_vertices())) {
  node_of_vertex.resize(vertex_of_node.size());
  for (uint32_t u = 0; u < vertex_of_node.size(); ++u) node_of_vertex[vertex_of_node[u]] = u;
}

// The first error of many threads.
class FirstError {
 public:
  void Set(absl::Status s) {
    std::lock_guard<std::mutex> lock(mu_);
    if (status_.ok()) status_ = std::move(s);
    failed_ = true;
  }
  bool failed() const { return failed_.load(std::memory_order_relaxed); }
  absl::Status status() {
    std::lock_guard<std::mutex> lock(mu_);
    return status_;
  }

 private:
  std::mutex mu_;
  absl::Status status_;
  std::atomic<bool> failed_{false};
};

// Phase 1 (section 4.2.1): the direct geodesics from every vertex, each window
// stopped at Theorem 2's d_max, into `runs`, each list sorted by vertex id.
// Sources [begin, end) only.
absl::Status ComputeCandidates(const Mesh& mesh, double candidate_epsilon, bool stop_at_corners,
                               uint32_t begin, uint32_t end, Progress& progress,
                               double progress_end, uint64_t* windows_created,
                               CandidateRuns& runs) {
  const FaceFrames frames(mesh);
  struct Local {
    std::unique_ptr<ExactGeodesic> engine;
    std::vector<DggHalfEdge> found;
  };
  tbb::enumerable_thread_specific<Local> locals([&] {
    return Local{std::make_unique<ExactGeodesic>(mesh, &frames), {}};
  });
  std::atomic<uint64_t> windows{0};
  FirstError error;
  const std::vector<uint32_t> order = SpatialOrder(mesh, begin, end);
  ParallelFor(end - begin, progress, "candidates", 0.0, progress_end, [&](uint32_t k) {
    const uint32_t s = begin + order[k];
    if (mesh.is_isolated(s) || error.failed()) return;
    Local& local = locals.local();
    DirectOptions options;
    options.epsilon = candidate_epsilon;
    options.stop_at_corners = stop_at_corners;
    auto hits = local.engine->DirectGeodesics(SurfacePoint::Vertex(s), options);
    if (!hits.ok()) return;  // a validated vertex source cannot fail
    windows.fetch_add(local.engine->stats().windows_created, std::memory_order_relaxed);
    local.found.clear();
    const double period_s = mesh.total_angle(s);
    for (const DirectHit& h : *hits) {
      local.found.push_back({h.vertex, RoundUp(h.distance), Normalized(h.angle_at_source, period_s),
                             Normalized(h.angle_at_vertex, mesh.total_angle(h.vertex))});
    }
    if (absl::Status added = runs.Add(s, local.found); !added.ok()) error.Set(std::move(added));
  });
  *windows_created = windows.load();
  return error.status();
}

// An edge found from either end is an edge; its length is the shorter of the
// two direct paths found (the source's own on a tie), with that path's
// directions. Rows are first filled with what their own source found, then
// edges found from the other end only are appended: each row grows in place.
absl::StatusOr<Adjacency> Symmetrize(const NodeOrder& order, std::span<const uint32_t> counts,
                                     const CandidateFeed& feed) {
  const uint32_t n = counts.size();
  Adjacency adj;
  adj.offsets.assign(n + 1, 0);
  for (uint32_t u = 0; u < n; ++u) {
    adj.offsets[u + 1] = adj.offsets[u] + counts[order.vertex_of_node[u]];
  }
  adj.edges.resize(adj.offsets[n]);
  RETURN_IF_ERROR(feed([&](uint32_t s, std::span<const DggHalfEdge> found) {
    DggHalfEdge* row = adj.of(order.node_of_vertex[s]).data();
    for (const DggHalfEdge& e : found)
      *row++ = {order.node_of_vertex[e.to], e.weight, e.angle_here, e.angle_there};
  }));
  SortRows(adj, ByTarget);

  // Edges found from both ends take the strictly shorter reverse; edges
  // found from one end are counted at the other. Only weights and angles
  // are rewritten, so concurrent searches by target stay sound; an edge's
  // two copies cannot both be the shorter one.
  std::vector<uint32_t> missing(n, 0);
  {
    std::vector<uint8_t> take_reverse(adj.edges.size(), 0);
    tbb::parallel_for(uint32_t{0}, n, [&](uint32_t t) {
      for (const DggHalfEdge& e : adj.of(t)) {
        const DggHalfEdge* back = Find(std::as_const(adj).of(e.to), t);
        if (!back) {
          std::atomic_ref<uint32_t>(missing[e.to]).fetch_add(1, std::memory_order_relaxed);
        } else if (e.weight < back->weight) {
          take_reverse[back - adj.edges.data()] = 1;
        }
      }
    });
    tbb::parallel_for(uint32_t{0}, n, [&](uint32_t s) {
      auto row = adj.of(s);
      for (uint32_t i = 0; i < row.size(); ++i) {
        if (!take_reverse[adj.offsets[s] + i]) continue;
        const DggHalfEdge& shorter = *Find(std::as_const(adj).of(row[i].to), s);
        row[i].weight = shorter.weight;
        row[i].angle_here = shorter.angle_there;
        row[i].angle_there = shorter.angle_here;
      }
    });
  }

  std::vector<uint32_t> own(n);
  std::vector<uint64_t> grown(n + 1, 0);
  for (uint32_t u = 0; u < n; ++u) {
    own[u] = adj.offsets[u + 1] - adj.offsets[u];
    grown[u + 1] = grown[u] + own[u] + missing[u];
  }
  adj.Grow(std::move(grown));
  auto own_of = [&](uint32_t u) {
    return std::span<const DggHalfEdge>(adj.edges.data() + adj.offsets[u], own[u]);
  };
  std::fill(missing.begin(), missing.end(), 0);  // now: how many appended
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t t) {
    for (const DggHalfEdge& e : own_of(t)) {
      if (Find(own_of(e.to), t)) continue;
      const uint32_t k =
          std::atomic_ref<uint32_t>(missing[e.to]).fetch_add(1, std::memory_order_relaxed);
      adj.edges[adj.offsets[e.to] + own[e.to] + k] = Reversed(e, t);
    }
  });
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t u) {
    auto row = adj.of(u);
    std::sort(row.begin() + own[u], row.end(), ByTarget);
    std::inplace_merge(row.begin(), row.begin() + own[u], row.end(), ByTarget);
  });
  return adj;
}

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

// Phase 3 (section 4.3, ADDPSEUDOVERTICESANDEDGES): where the candidate
// directions at a vertex leave a gap wider than sqrt(2 eps), shoot geodesics
// into it every sqrt(eps) and, unless the graph already serves the end
// point, connect it to the vertices it sees directly. Gaps are measured on
// the candidate edges: a pruned edge's direction is still served by the path
// that replaced it.
//
// Most shots are decided without a propagation, by the routes along their
// own strip. On anisotropic meshes at small eps almost every shot stays
// unserved, and a pseudo vertex for each would multiply the graph many times
// over, each costing a propagation (bench/notes.md, "Pruning and pseudo
// vertices"); past a limit on their number the build is refused, with the
// estimate, before any of that is spent.
struct PseudoVertex {
  SurfacePoint point;
  std::vector<DggHalfEdge> edges;  // to mesh vertices
};

// A shot whose end point no route along its strip serves.
struct UnservedShot {
  uint32_t source;
  SurfacePoint end;
  double length;
};

// The gaps wider than `threshold` between the directions of `s`'s candidate
// edges: (from, to) in raw angles and a shot length (the mean of the two
// edges' lengths).
std::vector<std::tuple<double, double, double>> DirectionGaps(const Mesh& mesh, uint32_t s,
                                                              std::span<const DggHalfEdge> cand,
                                                              double threshold) {
  const double period = mesh.total_angle(s);
  const double to_raw = period / kTwoPi;
  std::vector<std::pair<float, float>> dirs;  // (normalised angle, length)
  for (const auto& e : cand) dirs.push_back({e.angle_here, e.weight});
  std::sort(dirs.begin(), dirs.end());
  std::vector<std::tuple<double, double, double>> gaps;
  auto add = [&](double from, double to, double length) {
    if (to - from >= threshold) gaps.push_back({from, to, length});
  };
  for (size_t i = 0; i + 1 < dirs.size(); ++i) {
    add(dirs[i].first * to_raw, dirs[i + 1].first * to_raw,
        0.5 * (dirs[i].second + dirs[i + 1].second));
  }
  // Around a boundary vertex the directions span [0, period] without
  // wrapping.
  if (mesh.is_boundary(s)) {
    add(0.0, dirs.front().first * to_raw, dirs.front().second);
    add(dirs.back().first * to_raw, period, dirs.back().second);
  } else {
    add(dirs.back().first * to_raw, dirs.front().first * to_raw + period,
        0.5 * (dirs.back().second + dirs.front().second));
  }
  return gaps;
}

// Every shot from s into its gaps that no route along the shot's strip
// serves within 1 + candidate_epsilon: s's edge to a vertex of the strip,
// then the straight segment in the strip to the end point.
std::vector<UnservedShot> UnservedShots(const Mesh& mesh, const NodeOrder& order,
                                        std::span<const DggHalfEdge> cand, uint32_t s,
                                        double epsilon, double candidate_epsilon, uint64_t& shots) {
  std::vector<UnservedShot> out;
  if (cand.empty()) return out;
  const double period = mesh.total_angle(s);
  const double step = std::sqrt(epsilon);
  ShotStrip strip;
  for (auto [from, to, length] : DirectionGaps(mesh, s, cand, std::sqrt(2 * epsilon))) {
    const double gap = to - from;
    const int count = static_cast<int>(gap / step);
    for (int j = 1; j <= count; ++j) {
      double angle = from + gap * j / (count + 1);
      if (angle >= period) angle -= period;
      auto end = ShootGeodesic(mesh, s, angle, length, &strip);
      if (!end.ok() || end->hit_vertex || end->point.kind == SurfacePoint::Kind::kVertex ||
          end->length <= 0) {
        continue;
      }
      ++shots;
      double best = std::numeric_limits<double>::infinity();
      for (VertexId w : strip.Vertices(s)) {
        const DggHalfEdge* edge = Find(cand, order.node(w));
        if (edge) best = std::min(best, edge->weight + strip.StraightDistanceToEnd(w));
      }
      if (best > (1 + candidate_epsilon) * end->length) {
        out.push_back({s, end->point, end->length});
      }
    }
  }
  return out;
}

// FAILED_PRECONDITION when more than `limit` pseudo vertices per mesh vertex
// could be needed (limit 0: no limit).
absl::StatusOr<std::vector<PseudoVertex>> AddPseudoVertices(
    const Mesh& mesh, const NodeOrder& order, const Adjacency& candidates, double epsilon,
    double candidate_epsilon, double limit, Progress& progress, DggBuildStats& stats) {
  const uint32_t n = mesh.num_vertices();
  std::vector<std::vector<UnservedShot>> per_vertex(n);
  std::atomic<uint64_t> all_shots{0};
  ParallelFor(n, progress, "pseudo", 0.7, 0.75, [&](uint32_t s) {
    uint64_t shots = 0;
    per_vertex[s] = UnservedShots(mesh, order, candidates.of(order.node(s)), s, epsilon,
                                  candidate_epsilon, shots);
    all_shots += shots;
  });
  std::vector<UnservedShot> unserved;
  for (auto& list : per_vertex) {
    unserved.insert(unserved.end(), list.begin(), list.end());
    list = {};
  }
  stats.pseudo_shots = all_shots;

  // COMPUTECANDIDATEEDGES from each unserved end point with Theorem 2's
  // early termination but not the corners': the test below needs every
  // vertex p sees directly. Stops once past the limit: the answer is then
  // a refusal whatever the rest would give.
  const uint64_t most = limit > 0 ? static_cast<uint64_t>(limit * n) : UINT64_MAX;
  std::atomic<uint64_t> kept{0}, propagated{0};
  std::atomic<bool> over{false};
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::optional<PseudoVertex>> chosen(unserved.size());
  tbb::enumerable_thread_specific<std::unique_ptr<ExactGeodesic>> engines(
      [&] { return std::make_unique<ExactGeodesic>(mesh); });
  ParallelFor(unserved.size(), progress, "pseudo", 0.75, 0.8, [&](uint32_t i) {
    if (over.load(std::memory_order_relaxed)) return;
    ++propagated;
    const UnservedShot& shot = unserved[i];
    DirectOptions options;
    options.epsilon = candidate_epsilon;
    options.stop_at_corners = false;
    options.max_distance = shot.length * (1 + 1e-9) + 1e-300;
    auto hits = engines.local()->DirectGeodesics(shot.end, options);
    if (!hits.ok() || hits->empty()) return;
    // A direction the graph already serves needs no pseudo vertex: an edge
    // s-v and the direct path v-p within 1 + eps of the pseudo edge, for
    // any v p sees.
    auto cand = candidates.of(order.node(shot.source));
    const double served = (1 + candidate_epsilon) * shot.length;
    const bool redundant = std::any_of(hits->begin(), hits->end(), [&](const DirectHit& h) {
      if (h.vertex == shot.source || h.distance >= served) return false;
      const DggHalfEdge* edge = Find(cand, order.node(h.vertex));
      return edge && edge->weight + h.distance <= served;
    });
    if (redundant) return;
    if (++kept > most) over = true;
    PseudoVertex p{shot.end, {}};
    for (const DirectHit& h : *hits) {
      p.edges.push_back({order.node(h.vertex), RoundUp(h.distance),
                         Normalized(h.angle_at_source, kTwoPi),
                         Normalized(h.angle_at_vertex, mesh.total_angle(h.vertex))});
    }
    std::sort(p.edges.begin(), p.edges.end(), ByTarget);  // rows are sorted by node
    chosen[i] = std::move(p);
  });
  stats.pseudo_propagations = propagated;
  if (over) {
    // The rest, at the rate of those done.
    const double done = propagated.load(), share = unserved.size() / done;
    uint64_t edges = 0;
    for (const auto& p : chosen)
      if (p) edges += 2 * p->edges.size();
    constexpr double kFileBytesPerHalfEdge = 20;
    return absl::FailedPreconditionError(absl::StrFormat(
        "pseudo vertices at eps %g: the graph would get about %.0f (%.1f per mesh vertex, over "
        "the limit of %g) for about %.0f MB and %.0f s more than its plain graph's %.0f MB; "
        "a plain graph at a quarter of this eps is usually both more accurate and far smaller "
        "(bench/notes.md, \"Pruning and pseudo vertices\"); or raise the limit "
        "(--pseudo-vertex-limit, 0 for none)",
        epsilon, kept * share, kept * share / n, limit, edges * share * kFileBytesPerHalfEdge / 1e6,
        Seconds(start) * share, candidates.edges.size() * kFileBytesPerHalfEdge / 1e6));
  }
  // In the order chosen, which does not depend on threads.
  std::vector<PseudoVertex> all;
  for (auto& p : chosen)
    if (p) all.push_back(*std::move(p));
  return all;
}

// Joins pseudo vertices (nodes n, n+1, ...) and their edges, seen from both
// ends, to the candidate graph in place, keeping every row sorted by node.
void AddPseudoRows(Adjacency& adj, const std::vector<PseudoVertex>& pseudo) {
  if (pseudo.empty()) return;
  const uint32_t n = adj.rows();
  std::vector<uint64_t> cursor(n), grown(n + pseudo.size() + 1, 0);
  for (const PseudoVertex& p : pseudo) {
    for (const DggHalfEdge& e : p.edges) ++grown[e.to + 1];
  }
  for (uint32_t u = 0; u < n; ++u) {
    cursor[u] = grown[u] + (adj.offsets[u + 1] - adj.offsets[u]);
    grown[u + 1] += cursor[u];
  }
  for (uint32_t i = 0; i < pseudo.size(); ++i)
    grown[n + i + 1] = grown[n + i] + pseudo[i].edges.size();
  adj.Grow(std::move(grown));
  // Pseudo ids are above every vertex's node: appending keeps the order.
  for (uint32_t i = 0; i < pseudo.size(); ++i) {
    const auto& edges = pseudo[i].edges;
    for (const DggHalfEdge& e : edges) adj.edges[cursor[e.to]++] = Reversed(e, n + i);
    std::copy(edges.begin(), edges.end(), adj.of(n + i).begin());
  }
}

// Fans that no shortest path leaves. The turn u -> v -> w is left out of the
// fan of u -> v only when some path from u to w is strictly shorter than
// |uv| + |vw|: a shortest path never takes such a turn, since its part from
// u to w would not be shortest. So a search that relaxes, from each node,
// only the fan of the edge it was reached by still finds every shortest
// distance (core/graph_search.h). A fan is the shortest circular range of
// v's angle-sorted edges holding every turn kept.
//
// The first pass tries the paths of at most two edges: a scan of each
// node's two-edge neighbourhood. The optional second (exact_fans) searches
// from each node, along the first pass's fans (already sound), to its exact
// distances inside that neighbourhood, and keeps only the turns nothing
// there beats.

// Only turns at least this much (relative) longer than a shortcut are left
// out, so that the rounding of a search's sums cannot make a left-out turn
// the only shortest way on.
constexpr double kStrictlyShorter = 1 - 1e-9;

// The shortest circular range of `degree` indices holding every index in
// `kept` (sorted): it starts after the widest gap.
FanRange CircularHull(std::span<const uint32_t> kept, uint32_t degree) {
  if (kept.empty()) return {};
  uint32_t widest = kept.front() + degree - kept.back(), start = kept.front();
  for (size_t q = 1; q < kept.size(); ++q) {
    if (kept[q] - kept[q - 1] > widest) {
      widest = kept[q] - kept[q - 1];
      start = kept[q];
    }
  }
  return {start, degree - widest + 1};
}

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
      }
      CollectTurns(sc, u);
      auto inside = [&](uint32_t y) { return sc.best[y] != kUnknown; };
      auto later = std::greater<std::pair<double, uint32_t>>();
      auto reach = [&](uint32_t y, double d, FanRange fan) {
        sc.exact[y] = d;
        sc.fan[y] = fan;
        sc.heap.push_back({d, y});
        std::push_heap(sc.heap.begin(), sc.heap.end(), later);
      };
      reach(u, 0, {0, static_cast<uint32_t>(of(u).size())});
      while (!sc.heap.empty()) {
        std::pop_heap(sc.heap.begin(), sc.heap.end(), later);
        const auto [d, x] = sc.heap.back();
        sc.heap.pop_back();
        if (d > sc.exact[x]) continue;
        const auto list = of(x);
        const FanRange fan = sc.fan[x];
        for (uint32_t k = 0, j = fan.begin; k < fan.count; ++k) {
          const DggEdge& e = list[j];
          const double nd = d + e.weight;
          if (inside(e.target) && nd < sc.exact[e.target]) reach(e.target, nd, e.fan);
          if (++j == list.size()) j = 0;
        }
      }
      // A node the fan-restricted search missed keeps its two-edge bound.
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

  // A turn u -> v -> y: the k-th edge of v after u's edge `edge` (local
  // indices), and its length.
  struct Turn {
    double length;
    uint32_t y;
    uint32_t edge, k;
  };
  struct Scratch {
    // Per node, valid for the nodes in `ring`: the shortest path of at most
    // two edges from the current node.
    std::vector<double> best;
    // The nodes within two edges and the listed turns (in order of edge,
    // then k): the first ring_size and turns_size entries. The vectors only
    // grow, since the walk writes past those ends.
    std::vector<uint32_t> ring;
    std::vector<Turn> turns;
    size_t ring_size = 0, turns_size = 0;
    std::span<const uint32_t> ring_nodes() const { return {ring.data(), ring_size}; }
    std::vector<uint32_t> kept;
    std::vector<double> exact;  // the exact pass only
    std::vector<FanRange> fan;  // the exact pass only
    std::vector<std::pair<double, uint32_t>> heap;
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
        sc.turns[listed] = {length, y, i, k};
        listed += length * kStrictlyShorter <= sc.best[y];
        touch(y, length);
      }
    }
    sc.turns_size = listed;
    sc.ring_size = ring;
  }

  // The fans of u's edges, each passed to store(edge index, fan): each keeps
  // the turns that no path in `shortest` (per node of the ring) beats.
  template <typename Store>
  void KeepTurns(Scratch& sc, uint32_t u, const std::vector<double>& shortest, Store store) {
    const auto edges = of(u);
    const Turn* t = sc.turns.data();
    const Turn* const end = t + sc.turns_size;
    for (uint32_t i = 0; i < edges.size(); ++i) {
      sc.kept.clear();
      for (; t != end && t->edge == i; ++t) {
        if (shortest[t->y] >= t->length * kStrictlyShorter) sc.kept.push_back(t->k);
      }
      store(a_.offsets[u] + i,
            CircularHull(sc.kept, static_cast<uint32_t>(of(edges[i].target).size())));
    }
  }

  void Clear(Scratch& sc) {
    for (uint32_t y : sc.ring_nodes()) sc.best[y] = kUnknown;
    sc.ring_size = sc.turns_size = 0;
  }

  DggGraphArrays& a_;
  const uint32_t nodes_;
  tbb::enumerable_thread_specific<Scratch> scratch_;
};

void ShortcutFreeFans(DggGraphArrays& a, bool exact, Progress& progress) {
  FanBuilder builder(a);
  builder.TwoEdgePass(progress, exact ? 0.97 : 1.0);
  if (exact) builder.ExactPass(progress);
}

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
  if (!progress.cancelled()) progress.Report("fans", 0.95, 1.0, 1, 1);
  return a;
}

}  // namespace

namespace {

absl::Status CheckEpsilon(double epsilon) {
  if (!(epsilon > 0 && epsilon < 1)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("epsilon must be in (0, 1), got %g", epsilon));
  }
  if (epsilon < 1e-6) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "epsilon %g is below 1e-6: the graph would approach the complete direct-geodesic graph "
        "(quadratic size); use the exact engine instead",
        epsilon));
  }
  return absl::OkStatus();
}

absl::Status CheckBuildParams(const DggParams& params) {
  RETURN_IF_ERROR(CheckEpsilon(params.epsilon));
  if (params.candidate_rule != kCandidateRuleVersion) {
    return absl::InvalidArgumentError(
        absl::StrFormat("candidate rule %u was asked for; this build makes graphs of rule %u",
                        params.candidate_rule, kCandidateRuleVersion));
  }
  return absl::OkStatus();
}

// Phases 2-4 on the candidates of every vertex (`counts` long lists, by
// vertex, fed by `feed`): pseudo vertices, pruning, fans. Runs inside the
// caller's arena; null when cancelled.
absl::StatusOr<std::shared_ptr<const DggGraph>> FinishBuild(
    const Mesh& mesh, std::span<const uint32_t> counts, const CandidateFeed& feed,
    const DggParams& params, double pseudo_vertex_limit, Progress& progress, DggBuildStats& st) {
  const double epsilon = params.epsilon;
  const bool prune = params.prune_redundant, exact_fans = params.exact_fans;
  auto t = std::chrono::steady_clock::now();
  NodeOrder order(mesh);
  for (uint32_t c : counts) st.found_edges += c;
  ASSIGN_OR_RETURN(Adjacency cand, Symmetrize(order, counts, feed));
  st.candidate_edges = cand.edges.size() / 2;
  st.candidate_seconds += Seconds(t);

  t = std::chrono::steady_clock::now();
  std::vector<PseudoVertex> pseudo;
  if (params.pseudo_vertices) {
    ASSIGN_OR_RETURN(pseudo,
                     AddPseudoVertices(mesh, order, cand, epsilon, CandidateBudget(epsilon, prune),
                                       pseudo_vertex_limit, progress, st));
    if (progress.cancelled()) return nullptr;
    AddPseudoRows(cand, pseudo);
  }
  st.pseudo_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  if (prune) {
    auto redundant = FindRedundant(mesh, order, cand, epsilon, progress);
    if (progress.cancelled()) return nullptr;
    DropRedundant(cand, redundant);
  }
  st.pruning_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  DggGraphArrays arrays = Finalize(std::move(cand), std::move(order), pseudo, exact_fans, progress);
  if (progress.cancelled()) return nullptr;
  st.fan_seconds = Seconds(t);
  const uint32_t nodes = mesh.num_vertices() + pseudo.size();
  st.pseudo_vertices = pseudo.size();
  st.edges = arrays.edges.size() / 2;
  for (uint32_t u = 0; u < nodes; ++u) {
    st.max_degree = std::max<uint32_t>(st.max_degree, arrays.offsets[u + 1] - arrays.offsets[u]);
  }
  st.average_degree = nodes ? double(arrays.edges.size()) / nodes : 0;
  uint64_t fans = 0;
  for (const DggEdge& e : arrays.edges) fans += e.fan.count;
  st.average_fan = arrays.edges.empty() ? 0 : double(fans) / arrays.edges.size();
  return DggGraphBuilder::FromArrays(std::move(arrays), nodes, mesh.num_vertices(), params,
                                     MeshFingerprint(mesh));
}

}  // namespace

uint64_t EstimateDggBytesLowerBound(uint64_t vertices, double epsilon) {
  constexpr double kDegreeTimesSqrtEpsilon = 1.5;
  // target, weight, angle, fan begin and fan count of each directed edge.
  constexpr double kBytesPerDirectedEdge = 20;
  if (!(epsilon > 0)) return UINT64_MAX;
  return static_cast<uint64_t>(double(vertices) * kDegreeTimesSqrtEpsilon / std::sqrt(epsilon) *
                               kBytesPerDirectedEdge);
}

DggBuildEstimate EstimateDggBuild(uint64_t num_vertices, double epsilon, bool pseudo) {
  constexpr double kBytesPerVertex = 64.5, kBytesExponent = 0.486;
  constexpr double kSecondsPerVertex = 2.1e-6, kSecondsExponent = 0.646;
  // Pseudo vertices grow quickly as epsilon shrinks, as 1 + c (1e-2 /
  // epsilon)^k, up to the default limit on their number
  // (DggBuildOptions::pseudo_vertex_limit), which about doubles the graph.
  constexpr double kPseudoBytesC = 0.05, kPseudoBytesK = 2.85;
  constexpr double kPseudoSecondsC = 0.5, kPseudoSecondsK = 1.62;
  if (!(epsilon > 0 && epsilon < 1)) return {UINT64_MAX, HUGE_VAL};
  double bytes = double(num_vertices) * kBytesPerVertex * std::pow(epsilon, -kBytesExponent);
  double seconds = double(num_vertices) * kSecondsPerVertex * std::pow(epsilon, -kSecondsExponent);
  if (pseudo) {
    const double finer = 1e-2 / epsilon;
    bytes *= 1 + std::min(1.0, kPseudoBytesC * std::pow(finer, kPseudoBytesK));
    seconds *= 1 + std::min(1.0, kPseudoSecondsC * std::pow(finer, kPseudoSecondsK));
  }
  return {bytes >= 1.8e19 ? UINT64_MAX : static_cast<uint64_t>(bytes), seconds};
}

absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDgg(const Mesh& mesh,
                                                         const DggBuildOptions& options,
                                                         DggBuildStats* stats) {
  RETURN_IF_ERROR(CheckBuildParams(options.params));
  DggBuildStats local;
  DggBuildStats& st = stats ? *stats : local;
  st = {};
  const auto start = std::chrono::steady_clock::now();
  Progress progress(options);
  ThreadArena arena(options.threads);
  absl::StatusOr<std::shared_ptr<const DggGraph>> graph;
  arena.execute([&] {
    CandidateRuns runs(mesh.num_vertices(), options.candidate_memory_limit, options.spill_dir);
    absl::Status computed = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, 0, mesh.num_vertices(), progress, 0.7, &st.windows_created, runs);
    st.candidate_seconds = Seconds(start);
    st.spilled_bytes = runs.spilled_bytes();  // Drain spills no more
    if (!computed.ok()) {
      graph = computed;
      return;
    }
    if (progress.cancelled()) return;
    graph = FinishBuild(
        mesh, runs.counts(), [&](const auto& visit) { return runs.Drain(visit); }, options.params,
        options.pseudo_vertex_limit, progress, st);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  st.total_seconds = Seconds(start);
  return graph;
}

absl::StatusOr<DggCandidatePart> BuildDggCandidatePart(const Mesh& mesh,
                                                       const DggBuildOptions& options,
                                                       uint32_t index, uint32_t count) {
  RETURN_IF_ERROR(CheckBuildParams(options.params));
  if (count == 0 || index >= count) {
    return absl::InvalidArgumentError(
        absl::StrFormat("part %u/%u: the index must be in [0, %u)", index, count, count));
  }
  const uint64_t n = mesh.num_vertices();
  DggCandidatePart part;
  part.params = options.params;
  part.mesh_fingerprint = MeshFingerprint(mesh);
  part.num_vertices = n;
  part.begin = n * index / count;
  part.end = n * (index + 1) / count;
  Progress progress(options);
  ThreadArena arena(options.threads);
  CandidateRuns runs(n, options.candidate_memory_limit, options.spill_dir);
  absl::Status computed;
  arena.execute([&] {
    computed = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, part.begin, part.end, progress, 1.0, &part.windows_created, runs);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  RETURN_IF_ERROR(computed);
  part.offsets.assign(1, 0);
  for (uint32_t s = part.begin; s < part.end; ++s) {
    part.offsets.push_back(part.offsets.back() + runs.counts()[s]);
  }
  part.edges.resize(part.offsets.back());
  absl::Status drained;
  arena.execute([&] {
    drained = runs.Drain([&](uint32_t s, std::span<const DggHalfEdge> edges) {
      std::copy(edges.begin(), edges.end(), part.edges.begin() + part.offsets[s - part.begin]);
    });
  });
  RETURN_IF_ERROR(drained);
  return part;
}

namespace {

// The edges of a part loaded for a merge: in range and of finite length.
absl::Status CheckPartEdges(const DggCandidatePart& p, uint32_t n, const std::string& name) {
  for (const DggHalfEdge& e : p.edges) {
    if (e.to >= n || !(e.weight >= 0) || !std::isfinite(e.weight)) {
      return absl::FailedPreconditionError(
          absl::StrFormat("%s holds an edge to vertex %u of length %g", name, e.to, e.weight));
    }
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggPartSource> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats) {
  if (parts.empty()) return absl::InvalidArgumentError("no parts to merge");
  const uint32_t n = mesh.num_vertices();
  const uint64_t fingerprint = MeshFingerprint(mesh);
  const DggParams params = parts[0].index.params;
  RETURN_IF_ERROR(CheckBuildParams(params));
  for (size_t i = 0; i < parts.size(); ++i) {
    const DggCandidatePart& p = parts[i].index;
    const std::string part = absl::StrFormat("%s (vertices %u..%u)", parts[i].name, p.begin, p.end);
    if (p.mesh_fingerprint != fingerprint || p.num_vertices != n) {
      return absl::FailedPreconditionError(absl::StrCat(part, " was built for another mesh"));
    }
    RETURN_IF_ERROR(
        CheckSameParams(params, p.params, absl::StrCat(part, ", unlike ", parts[0].name, ",")));
    if (p.begin > p.end || p.end > n || p.offsets.size() != p.end - p.begin + 1 ||
        p.offsets.front() != 0 || !std::is_sorted(p.offsets.begin(), p.offsets.end())) {
      return absl::FailedPreconditionError(absl::StrCat(part, " is inconsistent"));
    }
  }
  std::sort(parts.begin(), parts.end(),
            [](const auto& a, const auto& b) { return a.index.begin < b.index.begin; });
  uint32_t covered = 0;
  for (const DggPartSource& p : parts) {
    if (p.index.begin != covered) {
      return absl::FailedPreconditionError(
          p.index.begin > covered
              ? absl::StrFormat("no part covers vertices %u..%u", covered, p.index.begin)
              : absl::StrFormat("two parts cover vertex %u", p.index.begin));
    }
    covered = p.index.end;
  }
  if (covered != n) {
    return absl::FailedPreconditionError(
        absl::StrFormat("no part covers vertices %u..%u", covered, n));
  }

  DggBuildStats local;
  DggBuildStats& st = stats ? *stats : local;
  st = {};
  const auto start = std::chrono::steady_clock::now();
  std::vector<uint32_t> counts(n);
  for (const DggPartSource& p : parts) {
    for (uint32_t s = p.index.begin; s < p.index.end; ++s) {
      const size_t i = s - p.index.begin;
      counts[s] = p.index.offsets[i + 1] - p.index.offsets[i];
    }
  }
  auto feed = [&](const CandidateRuns::Visitor& visit) -> absl::Status {
    for (DggPartSource& source : parts) {
      ASSIGN_OR_RETURN(DggCandidatePart p, source.load());
      if (p.begin != source.index.begin || p.offsets != source.index.offsets ||
          p.edges.size() != p.offsets.back()) {
        return absl::FailedPreconditionError(
            absl::StrCat(source.name, " changed while it was being merged"));
      }
      RETURN_IF_ERROR(CheckPartEdges(p, n, source.name));
      st.windows_created += p.windows_created;
      for (uint32_t s = p.begin; s < p.end; ++s) {
        const size_t i = s - p.begin;
        visit(s, {p.edges.data() + p.offsets[i], p.edges.data() + p.offsets[i + 1]});
      }
      source = {};
    }
    return absl::OkStatus();
  };
  Progress progress(options);
  ThreadArena arena(options.threads);
  absl::StatusOr<std::shared_ptr<const DggGraph>> graph;
  arena.execute([&] {
    graph = FinishBuild(mesh, counts, feed, params, options.pseudo_vertex_limit, progress, st);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  st.total_seconds = Seconds(start);
  return graph;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggCandidatePart> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats) {
  std::vector<DggPartSource> sources;
  for (size_t i = 0; i < parts.size(); ++i) {
    std::vector<DggHalfEdge> edges = std::move(parts[i].edges);
    DggCandidatePart index = parts[i];
    auto whole = std::make_shared<DggCandidatePart>(std::move(parts[i]));
    whole->edges = std::move(edges);
    sources.push_back(
        {absl::StrFormat("part %u", i), std::move(index),
         [whole]() -> absl::StatusOr<DggCandidatePart> { return std::move(*whole); }});
  }
  return MergeDggParts(mesh, std::move(sources), options, stats);
}

}  // namespace geodesic
