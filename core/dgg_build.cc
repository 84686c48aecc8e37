#include "core/dgg_build.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <limits>
#include <mutex>
#include <numbers>
#include <queue>
#include <span>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/dgg_graph_internal.h"
#include "core/exact_geodesic.h"
#include "core/fan.h"
#include "core/geodesic_shooting.h"
#include "core/status.h"

namespace geodesic {
namespace {

constexpr double kTwoPi = 2 * std::numbers::pi;
// Fans used when choosing replacement paths, relative to the solver's.
constexpr double kPruningFanScale = 0.9;
// The error budget. Early termination of the candidates (Theorem 2 and the
// corners) may lengthen a shortest path by 1 + e_c, and pruning (when asked
// for) each replaced edge by 1 + e_p, with (1 + e_c)(1 + e_p) = 1 + b eps.
// Pruning gets a tenth of eps: its loss compounds the most. It then removes
// well under 1% of the candidates for a quarter of the build, so by default
// it is skipped and the candidates get the whole budget.
//
// The budget b eps is a point on a trade-off, not a bound: routes through
// corners that are themselves served routes compound, so a field's largest
// error exceeds what one route may use, and its mean is a quarter of it.
// b = 1.1 instead of 1 (the paper's rule) gives 4-5% fewer edges, for means
// up to 0.28 eps and maxima up to 1.41 eps on the shared meshes at 1e-2 and
// 1e-3 (from 0.25 and 1.36; the contract is 0.3 and 1.5). At the same degree
// this is more accurate than FastDGG's rule, which tests corners by their
// exact distance rather than by their routes (bench/notes.md, "Candidate
// budget"). Smaller eps chains more corners and compounds more: at 1e-4,
// b = 1 already reaches 1.45 eps and b = 1.1 reached 1.58 eps, so the extra
// tenth fades out between 1e-3 and 1e-4.
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

// Adjacency lists in compressed form.
struct Adjacency {
  std::vector<uint64_t> offsets;
  std::vector<DggHalfEdge> edges;
  std::span<const DggHalfEdge> of(uint32_t u) const {
    return {edges.data() + offsets[u], edges.data() + offsets[u + 1]};
  }
  std::span<DggHalfEdge> of(uint32_t u) {
    return {edges.data() + offsets[u], edges.data() + offsets[u + 1]};
  }
};

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

// Phase 1 (section 4.2.1): the direct geodesics from every vertex, each window
// stopped at Theorem 2's d_max. Returns, per vertex, candidates sorted by id.
// Sources [begin, end) only; element i of the result belongs to begin + i.
std::vector<std::vector<DggHalfEdge>> ComputeCandidates(const Mesh& mesh, double candidate_epsilon,
                                                        bool stop_at_corners, uint32_t begin,
                                                        uint32_t end, Progress& progress,
                                                        double progress_end,
                                                        uint64_t* windows_created) {
  std::vector<std::vector<DggHalfEdge>> candidates(end - begin);
  const FaceFrames frames(mesh);
  tbb::enumerable_thread_specific<std::unique_ptr<ExactGeodesic>> engines(
      [&] { return std::make_unique<ExactGeodesic>(mesh, &frames); });
  std::atomic<uint64_t> windows{0};
  const std::vector<uint32_t> order = SpatialOrder(mesh, begin, end);
  ParallelFor(end - begin, progress, "candidates", 0.0, progress_end, [&](uint32_t k) {
    const uint32_t i = order[k];
    const uint32_t s = begin + i;
    if (mesh.is_isolated(s)) return;
    ExactGeodesic& engine = *engines.local();
    DirectOptions options;
    options.epsilon = candidate_epsilon;
    options.stop_at_corners = stop_at_corners;
    auto hits = engine.DirectGeodesics(SurfacePoint::Vertex(s), options);
    if (!hits.ok()) return;  // a validated vertex source cannot fail
    windows.fetch_add(engine.stats().windows_created, std::memory_order_relaxed);
    auto& out = candidates[i];
    out.reserve(hits->size());
    const double period_s = mesh.total_angle(s);
    for (const DirectHit& h : *hits) {
      out.push_back({h.vertex, RoundUp(h.distance), Normalized(h.angle_at_source, period_s),
                     Normalized(h.angle_at_vertex, mesh.total_angle(h.vertex))});
    }
  });
  *windows_created = windows.load();
  return candidates;
}

// An edge found from either end is an edge; its length is the shorter of the
// two direct paths found, with that path's directions.
Adjacency Symmetrize(std::vector<std::vector<DggHalfEdge>> out) {
  const uint32_t n = out.size();
  std::vector<uint64_t> in_offsets(n + 1, 0);
  for (uint32_t s = 0; s < n; ++s)
    for (const auto& e : out[s]) ++in_offsets[e.to + 1];
  for (uint32_t v = 0; v < n; ++v) in_offsets[v + 1] += in_offsets[v];
  std::vector<DggHalfEdge> in(in_offsets[n]);
  {
    std::vector<uint64_t> fill(in_offsets.begin(), in_offsets.end() - 1);
    for (uint32_t s = 0; s < n; ++s) {
      for (const auto& e : out[s]) in[fill[e.to]++] = {s, e.weight, e.angle_there, e.angle_here};
    }
  }
  Adjacency adj;
  adj.offsets.assign(n + 1, 0);
  std::vector<std::vector<DggHalfEdge>> merged(n);
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t s) {
    const auto& a = out[s];
    std::span<const DggHalfEdge> b(in.data() + in_offsets[s], in.data() + in_offsets[s + 1]);
    auto& m = merged[s];
    m.reserve(a.size() + b.size());
    size_t i = 0, j = 0;
    while (i < a.size() || j < b.size()) {
      if (j == b.size() || (i < a.size() && a[i].to < b[j].to)) {
        m.push_back(a[i++]);
      } else if (i == a.size() || b[j].to < a[i].to) {
        m.push_back(b[j++]);
      } else {
        m.push_back(b[j].weight < a[i].weight ? b[j] : a[i]);
        ++i, ++j;
      }
    }
  });
  out = {};
  for (uint32_t s = 0; s < n; ++s) adj.offsets[s + 1] = adj.offsets[s] + merged[s].size();
  adj.edges.resize(adj.offsets[n]);
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t s) {
    std::copy(merged[s].begin(), merged[s].end(), adj.edges.begin() + adj.offsets[s]);
    merged[s] = {};
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
std::vector<uint8_t> FindRedundant(const Mesh& mesh, const Adjacency& adj, double epsilon,
                                   Progress& progress) {
  const uint32_t n = adj.offsets.size() - 1;
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
      sc.bottleneck[i] = EdgeKey::Of(nbrs[i].weight, s, nbrs[i].to);
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
      const double period = is_vertex ? mesh.total_angle(u) : kTwoPi;
      const bool boundary = is_vertex && mesh.is_boundary(u);
      for (const DggHalfEdge& e : adj.of(u)) {
        if (e.to == s || sc.stamp[e.to] != sc.current) continue;
        if (!InFan(sc.arrival[i], e.angle_here, period, boundary, epsilon, kPruningFanScale)) {
          continue;
        }
        const uint32_t j = sc.local[e.to];
        const double through = sc.dist[i] + e.weight;
        const EdgeKey own = EdgeKey::Of(nbrs[j].weight, s, e.to);
        EdgeKey b = std::max(sc.bottleneck[i], EdgeKey::Of(e.weight, u, e.to));
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

// Keeps an edge unless either end found it redundant.
Adjacency DropRedundant(const Adjacency& adj, const std::vector<uint8_t>& redundant) {
  const uint32_t n = adj.offsets.size() - 1;
  auto reverse_index = [&](uint32_t s, uint32_t u) -> uint64_t {
    auto list = adj.of(u);
    auto it = std::lower_bound(list.begin(), list.end(), s,
                               [](const DggHalfEdge& e, uint32_t id) { return e.to < id; });
    return adj.offsets[u] + (it - list.begin());
  };
  std::vector<uint8_t> keep(adj.edges.size(), 0);
  tbb::parallel_for(uint32_t{0}, n, [&](uint32_t s) {
    for (uint64_t i = adj.offsets[s]; i < adj.offsets[s + 1]; ++i) {
      keep[i] = !redundant[i] && !redundant[reverse_index(s, adj.edges[i].to)];
    }
  });
  Adjacency out;
  out.offsets.assign(n + 1, 0);
  for (uint32_t s = 0; s < n; ++s) {
    uint64_t count = 0;
    for (uint64_t i = adj.offsets[s]; i < adj.offsets[s + 1]; ++i) count += keep[i];
    out.offsets[s + 1] = out.offsets[s] + count;
  }
  out.edges.reserve(out.offsets[n]);
  for (uint64_t i = 0; i < adj.edges.size(); ++i)
    if (keep[i]) out.edges.push_back(adj.edges[i]);
  return out;
}

// Phase 3 (section 4.3, ADDPSEUDOVERTICESANDEDGES): where the candidate
// directions at a vertex leave a gap wider than sqrt(2 eps), shoot geodesics
// into it every sqrt(eps) and, unless the graph already serves the end
// point, connect it to the vertices it sees directly. Gaps are measured on
// the candidate edges: a pruned edge's direction is still served by the path
// that replaced it.
struct PseudoVertex {
  SurfacePoint point;
  std::vector<DggHalfEdge> edges;  // to mesh vertices
};

std::vector<PseudoVertex> AddPseudoVertices(const Mesh& mesh, const Adjacency& candidates,
                                            double epsilon, double candidate_epsilon,
                                            Progress& progress) {
  const uint32_t n = mesh.num_vertices();
  const double step = std::sqrt(epsilon);
  const double threshold = std::sqrt(2 * epsilon);
  std::vector<std::vector<PseudoVertex>> per_vertex(n);
  tbb::enumerable_thread_specific<std::unique_ptr<ExactGeodesic>> engines(
      [&] { return std::make_unique<ExactGeodesic>(mesh); });
  ParallelFor(n, progress, "pseudo", 0.7, 0.8, [&](uint32_t s) {
    auto cand = candidates.of(s);
    if (cand.empty()) return;
    const double period = mesh.total_angle(s);
    const double to_raw = period / kTwoPi;
    std::vector<std::pair<float, float>> dirs;  // (normalised angle, length)
    for (const auto& e : cand) dirs.push_back({e.angle_here, e.weight});
    std::sort(dirs.begin(), dirs.end());
    const bool boundary = mesh.is_boundary(s);
    // Gaps between consecutive directions; around a boundary vertex the
    // directions span [0, period] without wrapping.
    std::vector<std::tuple<double, double, double>> gaps;  // from, to (raw), length
    for (size_t i = 0; i + 1 < dirs.size(); ++i) {
      gaps.push_back({dirs[i].first * to_raw, dirs[i + 1].first * to_raw,
                      0.5 * (dirs[i].second + dirs[i + 1].second)});
    }
    if (boundary) {
      gaps.push_back({0.0, dirs.front().first * to_raw, dirs.front().second});
      gaps.push_back({dirs.back().first * to_raw, period, dirs.back().second});
    } else {
      gaps.push_back({dirs.back().first * to_raw, dirs.front().first * to_raw + period,
                      0.5 * (dirs.back().second + dirs.front().second)});
    }
    ExactGeodesic& engine = *engines.local();
    for (auto [from, to, length] : gaps) {
      const double gap = to - from;
      if (gap < threshold) continue;
      const int count = static_cast<int>(gap / step);
      for (int j = 1; j <= count; ++j) {
        double angle = from + gap * j / (count + 1);
        if (angle >= period) angle -= period;
        auto end = ShootGeodesic(mesh, s, angle, length);
        if (!end.ok() || end->hit_vertex || end->point.kind == SurfacePoint::Kind::kVertex ||
            end->length <= 0) {
          continue;
        }
        // COMPUTECANDIDATEEDGES from the pseudo vertex with Theorem 2's early
        // termination but not the corners': the test below needs every
        // vertex p sees directly, and the pseudo vertices kept are few.
        DirectOptions options;
        options.epsilon = candidate_epsilon;
        options.stop_at_corners = false;
        options.max_distance = end->length * (1 + 1e-9) + 1e-300;
        auto hits = engine.DirectGeodesics(end->point, options);
        if (!hits.ok() || hits->empty()) continue;
        // A direction the graph already serves needs no pseudo vertex: an
        // edge s-v and the direct path v-p within 1 + eps of the pseudo
        // edge. Our candidates' corners leave wide gaps wherever routes
        // through near vertices serve, and the gap rule alone filled them
        // all (7 pseudo vertices per vertex on the blade at 1e-2, 0.14 now).
        const double served = (1 + candidate_epsilon) * end->length;
        const bool redundant = std::any_of(hits->begin(), hits->end(), [&](const DirectHit& h) {
          if (h.vertex == s || h.distance >= served) return false;
          auto it = std::lower_bound(cand.begin(), cand.end(), h.vertex,
                                     [](const DggHalfEdge& e, uint32_t v) { return e.to < v; });
          return it != cand.end() && it->to == h.vertex && it->weight + h.distance <= served;
        });
        if (redundant) continue;
        PseudoVertex p{end->point, {}};
        for (const DirectHit& h : *hits) {
          p.edges.push_back({h.vertex, RoundUp(h.distance), Normalized(h.angle_at_source, kTwoPi),
                             Normalized(h.angle_at_vertex, mesh.total_angle(h.vertex))});
        }
        per_vertex[s].push_back(std::move(p));
      }
    }
  });
  std::vector<PseudoVertex> all;
  for (auto& list : per_vertex)
    for (auto& p : list) all.push_back(std::move(p));
  return all;
}

// Joins pseudo vertices (nodes n, n+1, ...) and their edges, seen from both
// ends, to the candidate graph, keeping every list sorted by node id.
Adjacency WithPseudoVertices(const Adjacency& cand, const std::vector<PseudoVertex>& pseudo) {
  if (pseudo.empty()) return cand;
  const uint32_t n = cand.offsets.size() - 1;
  const uint32_t nodes = n + pseudo.size();
  std::vector<std::vector<DggHalfEdge>> extra(n);
  for (uint32_t i = 0; i < pseudo.size(); ++i) {
    for (const auto& e : pseudo[i].edges) {
      extra[e.to].push_back({n + i, e.weight, e.angle_there, e.angle_here});
    }
  }
  Adjacency out;
  out.offsets.assign(nodes + 1, 0);
  for (uint32_t u = 0; u < nodes; ++u) {
    const size_t size = u < n ? cand.of(u).size() + extra[u].size() : pseudo[u - n].edges.size();
    out.offsets[u + 1] = out.offsets[u] + size;
  }
  out.edges.resize(out.offsets[nodes]);
  tbb::parallel_for(uint32_t{0}, nodes, [&](uint32_t u) {
    auto dst = out.edges.begin() + out.offsets[u];
    if (u < n) {
      auto own = cand.of(u);
      // Pseudo ids are above every vertex id: appending keeps the order.
      dst = std::copy(own.begin(), own.end(), dst);
      std::copy(extra[u].begin(), extra[u].end(), dst);
    } else {
      const auto& edges = pseudo[u - n].edges;
      std::copy(edges.begin(), edges.end(), dst);
    }
  });
  return out;
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
  explicit FanBuilder(const DggGraphArrays& a)
      : a_(a), nodes_(a.offsets.size() - 1), fans_(a.edges.size()) {}

  // Fans from paths of at most two edges.
  void TwoEdgePass() {
    tbb::parallel_for(tbb::blocked_range<uint32_t>(0, nodes_, 64),
                      [&](const tbb::blocked_range<uint32_t>& r) {
                        Scratch& sc = Local();
                        for (uint32_t u = r.begin(); u != r.end(); ++u) {
                          CollectTurns(sc, u);
                          KeepTurns(sc, u, sc.best);
                          Clear(sc);
                        }
                      });
  }

  // Fans from exact distances inside each node's two-edge neighbourhood,
  // searched along the fans in `a` (sound ones: the first pass's).
  void ExactPass(Progress& progress) {
    ParallelFor(nodes_, progress, "fans", 0.95, 1.0, [&](uint32_t u) {
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
      KeepTurns(sc, u, sc.exact);
      for (uint32_t y : sc.ring_nodes()) sc.exact[y] = kUnknown;
      Clear(sc);
    });
  }

  // The fans found, indexed like the edges.
  const std::vector<FanRange>& fans() const { return fans_; }

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
  // about ten of u's turns (armadillo, 1e-3), so rather than walking again
  // to test each turn against the final shortest path, the walk lists the
  // turns that were close to the shortest found so far: a turn that fails
  // then fails at the end too (the shortest only shrinks). About a fifth of
  // the turns are listed. The walk does not branch on what it finds (a
  // branch here is mispredicted often enough to double its cost): every
  // turn and node is written, and kept by moving the end past it.
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

  // The fans of u's edges: each keeps the turns that no path in `shortest`
  // (per node of the ring) beats.
  void KeepTurns(Scratch& sc, uint32_t u, const std::vector<double>& shortest) {
    const auto edges = of(u);
    const Turn* t = sc.turns.data();
    const Turn* const end = t + sc.turns_size;
    for (uint32_t i = 0; i < edges.size(); ++i) {
      sc.kept.clear();
      for (; t != end && t->edge == i; ++t) {
        if (shortest[t->y] >= t->length * kStrictlyShorter) sc.kept.push_back(t->k);
      }
      fans_[a_.offsets[u] + i] =
          CircularHull(sc.kept, static_cast<uint32_t>(of(edges[i].target).size()));
    }
  }

  void Clear(Scratch& sc) {
    for (uint32_t y : sc.ring_nodes()) sc.best[y] = kUnknown;
    sc.ring_size = sc.turns_size = 0;
  }

  const DggGraphArrays& a_;
  const uint32_t nodes_;
  std::vector<FanRange> fans_;
  tbb::enumerable_thread_specific<Scratch> scratch_;
};

void ShortcutFreeFans(DggGraphArrays& a, bool exact, Progress& progress) {
  FanBuilder builder(a);
  auto store = [&] {
    for (uint64_t i = 0; i < a.edges.size(); ++i) a.edges[i].fan = builder.fans()[i];
  };
  builder.TwoEdgePass();
  store();
  if (!exact) return;
  builder.ExactPass(progress);
  if (!progress.cancelled()) store();
}

// Phase 4 (section 5.1.2): number the nodes in spatial order (DggGraph), sort
// each node's edges by polar angle and give every directed edge u -> v the
// range of v's edges that a shortest path arriving along it can continue on.
DggGraphArrays Finalize(const Mesh& mesh, const Adjacency& kept,
                        const std::vector<PseudoVertex>& pseudo, bool exact_fans,
                        Progress& progress) {
  const uint32_t n = mesh.num_vertices();
  const uint32_t nodes = kept.offsets.size() - 1;
  DggGraphArrays a;
  a.vertex_of_node = SpatialOrder(mesh, 0, n);
  a.node_of_vertex.resize(n);
  for (uint32_t u = 0; u < n; ++u) a.node_of_vertex[a.vertex_of_node[u]] = u;
  // Pseudo vertices keep their places after the vertices.
  auto node_of = [&](uint32_t id) { return id < n ? a.node_of_vertex[id] : id; };
  auto id_of = [&](uint32_t node) { return node < n ? a.vertex_of_node[node] : node; };
  std::vector<std::vector<DggHalfEdge>> lists(nodes);
  tbb::parallel_for(uint32_t{0}, nodes, [&](uint32_t u) {
    auto e = kept.of(id_of(u));
    lists[u].assign(e.begin(), e.end());
    for (DggHalfEdge& h : lists[u]) h.to = node_of(h.to);
    std::sort(lists[u].begin(), lists[u].end(), [](const DggHalfEdge& a, const DggHalfEdge& b) {
      return a.angle_here < b.angle_here || (a.angle_here == b.angle_here && a.to < b.to);
    });
  });
  a.offsets.assign(nodes + 1, 0);
  for (uint32_t u = 0; u < nodes; ++u) a.offsets[u + 1] = a.offsets[u] + lists[u].size();
  const uint64_t m = a.offsets[nodes];
  a.edges.resize(m);
  a.angles.resize(m);
  tbb::parallel_for(uint32_t{0}, nodes, [&](uint32_t u) {
    uint64_t i = a.offsets[u];
    for (const auto& e : lists[u]) {
      a.edges[i] = {e.to, e.weight, {}};
      a.angles[i] = e.angle_here;
      ++i;
    }
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

// Phases 2-4 on the candidates of every vertex: pseudo vertices, pruning,
// fans. Runs inside the caller's arena.
std::shared_ptr<const DggGraph> FinishBuild(const Mesh& mesh,
                                            std::vector<std::vector<DggHalfEdge>> candidates,
                                            const DggParams& params, Progress& progress,
                                            DggBuildStats& st) {
  const double epsilon = params.epsilon;
  const bool prune = params.prune_redundant, exact_fans = params.exact_fans;
  auto t = std::chrono::steady_clock::now();
  for (const auto& c : candidates) st.found_edges += c.size();
  Adjacency cand = Symmetrize(std::move(candidates));
  st.candidate_edges = cand.edges.size() / 2;
  st.candidate_seconds += Seconds(t);

  t = std::chrono::steady_clock::now();
  std::vector<PseudoVertex> pseudo;
  if (params.pseudo_vertices) {
    pseudo = AddPseudoVertices(mesh, cand, epsilon, CandidateBudget(epsilon, prune), progress);
    if (progress.cancelled()) return nullptr;
    cand = WithPseudoVertices(cand, pseudo);
  }
  st.pseudo_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  Adjacency kept;
  if (prune) {
    auto redundant = FindRedundant(mesh, cand, epsilon, progress);
    if (progress.cancelled()) return nullptr;
    kept = DropRedundant(cand, redundant);
    cand = {};
  } else {
    kept = std::move(cand);
  }
  st.pruning_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  DggGraphArrays arrays = Finalize(mesh, kept, pseudo, exact_fans, progress);
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

[[maybe_unused]] int ThreadCount(const DggBuildOptions& options) {
  return options.threads > 0 ? options.threads : tbb::info::default_concurrency();
}

// The arena a build runs in. Debian's libtbb is not built with TSan, which
// then cannot see how TBB hands split ranges between its threads and reports
// that bookkeeping as races; TSan builds (GEODESIC_TSAN) therefore keep TBB
// to the calling thread, and what TSan checks is the concurrency written here
// (queries and landmarks on shared graphs).
class BuildArena {
 public:
  explicit BuildArena(const DggBuildOptions& options)
#ifdef GEODESIC_TSAN
      : one_thread_(tbb::global_control::max_allowed_parallelism, 1),
        arena_(1)
#else
      : arena_(ThreadCount(options))
#endif
  {
  }
  template <typename F>
  void execute(F&& f) {
    arena_.execute(std::forward<F>(f));
  }

 private:
#ifdef GEODESIC_TSAN
  tbb::global_control one_thread_;
#endif
  tbb::task_arena arena_;
};

}  // namespace

uint64_t EstimateDggBytesLowerBound(uint64_t vertices, double epsilon) {
  constexpr double kDegreeTimesSqrtEpsilon = 1.5;
  // target, weight, angle, fan begin and fan count of each directed edge.
  constexpr double kBytesPerDirectedEdge = 20;
  if (!(epsilon > 0)) return UINT64_MAX;
  return static_cast<uint64_t>(double(vertices) * kDegreeTimesSqrtEpsilon / std::sqrt(epsilon) *
                               kBytesPerDirectedEdge);
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
  BuildArena arena(options);
  std::shared_ptr<const DggGraph> graph;
  arena.execute([&] {
    auto candidates = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, 0, mesh.num_vertices(), progress, 0.7, &st.windows_created);
    st.candidate_seconds = Seconds(start);
    if (progress.cancelled()) return;
    graph = FinishBuild(mesh, std::move(candidates), options.params, progress, st);
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
  BuildArena arena(options);
  std::vector<std::vector<DggHalfEdge>> candidates;
  arena.execute([&] {
    candidates = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, part.begin, part.end, progress, 1.0, &part.windows_created);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  part.offsets.assign(1, 0);
  for (const auto& c : candidates) part.offsets.push_back(part.offsets.back() + c.size());
  part.edges.reserve(part.offsets.back());
  for (const auto& c : candidates) part.edges.insert(part.edges.end(), c.begin(), c.end());
  return part;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggCandidatePart> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats) {
  if (parts.empty()) return absl::InvalidArgumentError("no parts to merge");
  const uint32_t n = mesh.num_vertices();
  const uint64_t fingerprint = MeshFingerprint(mesh);
  const DggParams params = parts[0].params;
  RETURN_IF_ERROR(CheckBuildParams(params));
  for (size_t i = 0; i < parts.size(); ++i) {
    const DggCandidatePart& p = parts[i];
    if (p.mesh_fingerprint != fingerprint || p.num_vertices != n) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "part %u (vertices %u..%u) was built for another mesh", i, p.begin, p.end));
    }
    RETURN_IF_ERROR(CheckSameParams(
        params, p.params,
        absl::StrFormat("part %u (vertices %u..%u), unlike part 0,", i, p.begin, p.end)));
    if (p.begin > p.end || p.end > n || p.offsets.size() != p.end - p.begin + 1 ||
        p.offsets.front() != 0 || p.offsets.back() != p.edges.size() ||
        !std::is_sorted(p.offsets.begin(), p.offsets.end())) {
      return absl::FailedPreconditionError(
          absl::StrFormat("part %u (vertices %u..%u) is inconsistent", i, p.begin, p.end));
    }
    for (const DggHalfEdge& e : p.edges) {
      if (e.to >= n || !(e.weight >= 0) || !std::isfinite(e.weight)) {
        return absl::FailedPreconditionError(
            absl::StrFormat("part %u holds an edge to vertex %u of length %g", i, e.to, e.weight));
      }
    }
  }
  std::sort(parts.begin(), parts.end(),
            [](const auto& a, const auto& b) { return a.begin < b.begin; });
  uint32_t covered = 0;
  for (const DggCandidatePart& p : parts) {
    if (p.begin != covered) {
      return absl::FailedPreconditionError(
          p.begin > covered ? absl::StrFormat("no part covers vertices %u..%u", covered, p.begin)
                            : absl::StrFormat("two parts cover vertex %u", p.begin));
    }
    covered = p.end;
  }
  if (covered != n) {
    return absl::FailedPreconditionError(
        absl::StrFormat("no part covers vertices %u..%u", covered, n));
  }

  DggBuildStats local;
  DggBuildStats& st = stats ? *stats : local;
  st = {};
  const auto start = std::chrono::steady_clock::now();
  std::vector<std::vector<DggHalfEdge>> candidates(n);
  for (DggCandidatePart& p : parts) {
    st.windows_created += p.windows_created;
    for (uint32_t s = p.begin; s < p.end; ++s) {
      const size_t i = s - p.begin;
      candidates[s].assign(p.edges.begin() + p.offsets[i], p.edges.begin() + p.offsets[i + 1]);
    }
    p = {};
  }
  Progress progress(options);
  BuildArena arena(options);
  std::shared_ptr<const DggGraph> graph;
  arena.execute([&] { graph = FinishBuild(mesh, std::move(candidates), params, progress, st); });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  st.total_seconds = Seconds(start);
  return graph;
}

}  // namespace geodesic
