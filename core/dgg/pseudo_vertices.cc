// Phase 3 of the build (section 4.3): pseudo vertices on anisotropic meshes.
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
#include "core/exact/exact_geodesic.h"
#include "core/exact/geodesic_shooting.h"

namespace geodesic::dgg_build_internal {
namespace {

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

}  // namespace

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

}  // namespace geodesic::dgg_build_internal
