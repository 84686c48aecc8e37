// Phase 1 of the build (section 4.2.1): candidate edges, the direct geodesics
// from every vertex, and their symmetric graph.
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

namespace geodesic::dgg_build_internal {
namespace {

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

}  // namespace

NodeOrder::NodeOrder(const Mesh& mesh)
    : vertex_of_node(SpatialOrder(mesh, 0, mesh.num_vertices())) {
  node_of_vertex.resize(vertex_of_node.size());
  for (uint32_t u = 0; u < vertex_of_node.size(); ++u) node_of_vertex[vertex_of_node[u]] = u;
}

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
                                     const CandidateFeed& feed, const DggEdgeFile& edge_file) {
  const uint32_t n = counts.size();
  Adjacency adj;
  if (edge_file.fd >= 0) adj.edges.BackWithFile(edge_file.fd, edge_file.offset);
  adj.offsets.assign(n + 1, 0);
  for (uint32_t u = 0; u < n; ++u) {
    adj.offsets[u + 1] = adj.offsets[u] + counts[order.vertex_of_node[u]];
  }
  auto admit = [&](uint64_t count) {
    return edge_file.fd >= 0 && edge_file.admit_growth
               ? edge_file.admit_growth(count * sizeof(DggHalfEdge))
               : absl::OkStatus();
  };
  RETURN_IF_ERROR(admit(adj.offsets[n]));
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
  RETURN_IF_ERROR(admit(grown[n]));
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

}  // namespace geodesic::dgg_build_internal
