// What the phases of a DGG build share (section 4 of the paper): the node
// order, the adjacency the phases edit in place, the error budget, progress
// reporting, and each phase's entry point. Internal to core/dgg/: the build's
// public face is dgg_build.h.
#ifndef GEODESIC_CORE_DGG_BUILD_PHASES_H_
#define GEODESIC_CORE_DGG_BUILD_PHASES_H_

#include <tbb/blocked_range.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <functional>
#include <limits>
#include <mutex>
#include <numbers>
#include <span>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "core/base/large_array.h"
#include "core/dgg/candidate_runs.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/dgg_graph_internal.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic::dgg_build_internal {

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
inline double CornerBudgetFactor(double epsilon) {
  return 1 + 0.1 * std::clamp(std::log10(epsilon / 1e-4), 0.0, 1.0);
}
inline double PruningBudget(double epsilon) { return 0.1 * epsilon; }
inline double CandidateBudget(double epsilon, bool prune) {
  const double budget = CornerBudgetFactor(epsilon) * epsilon;
  if (!prune) return budget;
  return (1 + budget) / (1 + PruningBudget(epsilon)) - 1;
}

// Lengths are rounded up to float so that graph distances never undercut the
// surface paths they stand for.
inline float RoundUp(double d) {
  float f = static_cast<float>(d);
  if (static_cast<double>(f) < d) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

inline float Normalized(double raw, double period) {
  float f = static_cast<float>(WrapAngle(raw * (kTwoPi / period), kTwoPi));
  return f >= static_cast<float>(kTwoPi) ? 0.0f : f;
}

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
inline DggHalfEdge Reversed(const DggHalfEdge& e, uint32_t from) {
  return {from, e.weight, e.angle_there, e.angle_here};
}

template <typename Less>
void SortRows(Adjacency& adj, Less less) {
  tbb::parallel_for(uint32_t{0}, adj.rows(), [&](uint32_t u) {
    auto row = adj.of(u);
    std::sort(row.begin(), row.end(), less);
  });
}

inline bool ByTarget(const DggHalfEdge& a, const DggHalfEdge& b) { return a.to < b.to; }

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

inline double Seconds(std::chrono::steady_clock::time_point since) {
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

// Phase 1 (candidate_edges.cc): the direct geodesics from sources [begin,
// end), each window stopped at Theorem 2's d_max, into `runs`.
absl::Status ComputeCandidates(const Mesh& mesh, double candidate_epsilon, bool stop_at_corners,
                               uint32_t begin, uint32_t end, Progress& progress,
                               double progress_end, uint64_t* windows_created, CandidateRuns& runs);
// The candidates as an undirected graph (candidate_edges.cc).
// Its edge array lives in `edge_file` when that names one.
absl::StatusOr<Adjacency> Symmetrize(const NodeOrder& order, std::span<const uint32_t> counts,
                                     const CandidateFeed& feed, const DggEdgeFile& edge_file);

// Phase 2 (redundant_edges.cc): marks the edges a path through smaller edges
// replaces within the pruning budget, then drops them.
std::vector<uint8_t> FindRedundant(const Mesh& mesh, const NodeOrder& order, const Adjacency& adj,
                                   double epsilon, Progress& progress);
void DropRedundant(Adjacency& adj, const std::vector<uint8_t>& redundant);

// Phase 3 (pseudo_vertices.cc).
struct PseudoVertex {
  SurfacePoint point;
  std::vector<DggHalfEdge> edges;  // to mesh vertices
};
absl::StatusOr<std::vector<PseudoVertex>> AddPseudoVertices(
    const Mesh& mesh, const NodeOrder& order, const Adjacency& candidates, double epsilon,
    double candidate_epsilon, double limit, Progress& progress, DggBuildStats& stats);
void AddPseudoRows(Adjacency& adj, const std::vector<PseudoVertex>& pseudo);

// Phase 4 (fans.cc): edges sorted by polar angle, each with the fan a
// shortest path arriving along it can continue on.
DggGraphArrays Finalize(Adjacency kept, NodeOrder order, const std::vector<PseudoVertex>& pseudo,
                        bool exact_fans, Progress& progress);

// Phases 2-4 after the candidates, shared by a build and a merge
// (dgg_build.cc); null when cancelled.
absl::Status CheckBuildParams(const DggParams& params);
absl::StatusOr<std::shared_ptr<const DggGraph>> FinishBuild(
    const Mesh& mesh, std::span<const uint32_t> counts, const CandidateFeed& feed,
    const DggParams& params, double pseudo_vertex_limit, const DggEdgeFile& edge_file,
    Progress& progress, DggBuildStats& st);

}  // namespace geodesic::dgg_build_internal

#endif  // GEODESIC_CORE_DGG_BUILD_PHASES_H_
