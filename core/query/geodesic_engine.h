// Geodesic queries on a DGG: distance fields, point-to-point distances and
// geodesic paths between arbitrary surface points.
//
// A GeodesicEngine is the resident "solver object": it holds a mesh and its
// graph, both immutable and shared, and answers queries from any number of
// threads at once. Each query in flight leases scratch memory from the
// engine's pool (core/query/query_scratch.h), which later queries reuse and which
// goes with the engine.
#ifndef GEODESIC_CORE_QUERY_GEODESIC_ENGINE_H_
#define GEODESIC_CORE_QUERY_GEODESIC_ENGINE_H_

#include <atomic>
#include <cstdint>
#include <functional>
#include <limits>
#include <memory>
#include <optional>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/types/span.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"
#include "core/query/exact_landmarks.h"
#include "core/query/graph_search.h"
#include "core/query/landmarks.h"
#include "core/query/query_scratch.h"
#include "core/query/search_work.h"

namespace geodesic {

inline constexpr double kInfinity = std::numeric_limits<double>::infinity();

// A value made once, on request, while queries read it: written once under
// the mutex, then read lock-free. It may be shared with other owners.
template <typename T>
class MadeOnce {
 public:
  const T* get() const { return ready_.load(std::memory_order_acquire); }
  // The value for another owner to share (null before it is made). Does not
  // wait for a Make under way, which holds the mutex while it computes.
  std::shared_ptr<const T> shared() const {
    if (!get()) return nullptr;
    absl::MutexLock lock(&mu_);
    return storage_;
  }
  // Runs `make` unless a value exists; its error leaves none.
  absl::Status Make(const std::function<absl::StatusOr<std::shared_ptr<const T>>()>& make) {
    absl::MutexLock lock(&mu_);
    if (storage_) return absl::OkStatus();
    absl::StatusOr<std::shared_ptr<const T>> made = make();
    if (!made.ok()) return made.status();
    storage_ = *std::move(made);
    ready_.store(storage_.get(), std::memory_order_release);
    return absl::OkStatus();
  }

 private:
  mutable absl::Mutex mu_;
  std::shared_ptr<const T> storage_ ABSL_GUARDED_BY(mu_);
  std::atomic<const T*> ready_{nullptr};
};

// Both give the graph's shortest distances; they differ in the work done.
enum class FieldMethod {
  // The DGG-tailored solver (section 5.1.2): each node relaxes only the fan
  // of the edge it was reached by. The graph's fans hold every turn a
  // shortest path can take, so this is exact on the graph.
  kLabelCorrecting,
  kDijkstra,  // plain Dijkstra over whole adjacency lists, for checking
};

struct FieldOptions {
  FieldMethod method = FieldMethod::kLabelCorrecting;
  // Only vertices within this distance are settled; the rest are +inf.
  double max_distance = kInfinity;
  // If non-empty, stop once these vertices are settled (others may be +inf or
  // upper bounds).
  std::vector<VertexId> targets;
  bool nearest_source = false;  // fill FieldResult::nearest_source
  // Polled during the solve; returning true aborts with CANCELLED.
  std::function<bool()> cancelled;
};

struct FieldResult {
  std::vector<double> distance;          // per mesh vertex; +inf if unreached
  std::vector<uint32_t> nearest_source;  // index into sources; kNone if unreached
  uint64_t queue_pops = 0;               // work measure: pops per vertex ~ 1-2
  uint64_t relaxed = 0;                  // edges relaxed: what the fans save
  SearchWork work;                       // the same search's work, in full
};

struct PathPoint {
  SurfacePoint point;
  Vec3 xyz;
};

struct GeodesicPath {
  double length = 0;
  std::vector<PathPoint> points;  // from the first point to the second
};

struct PairOptions {
  bool want_path = false;
  // Bidirectional A* with the straight-line potential, tightened by the
  // landmark bounds once GeodesicEngine::PrepareLandmarks has run; false:
  // plain bidirectional Dijkstra.
  bool use_astar = true;
  // The exact polyhedral distance (and, with want_path, the exact geodesic)
  // instead of the graph's: a window propagation from the first point that
  // only sweeps what can still reach the second within the graph's answer,
  // judged by the straight line and, once GeodesicEngine::
  // PrepareExactLandmarks has run, by the exact landmarks' bounds.
  bool exact = false;
  // The most bytes of windows an exact pair's propagation may hold (0: no
  // limit): past it the pair fails with RESOURCE_EXHAUSTED.
  uint64_t exact_max_bytes = 0;
  std::function<bool()> cancelled;
};

struct PairResult {
  double distance = kInfinity;  // +inf when the points are in different components
  uint64_t settled = 0;         // nodes settled by the bidirectional search
  uint64_t queued = 0;          // queue insertions and key decreases
  uint64_t relaxed = 0;         // edges relaxed
  bool exact = false;           // the distance and path are exact (PairOptions::exact)
  uint64_t windows = 0;         // exact only: windows the propagation created
  // The bidirectional search's work, both sides (the exact propagation's,
  // if any, is `windows`).
  SearchWork work;
  std::optional<GeodesicPath> path;
};

struct MatrixOptions {
  std::function<bool()> cancelled;
  // Exact polyhedral distances instead of the graph's (PairOptions::exact).
  bool exact = false;
  uint64_t exact_max_bytes = 0;  // per row, as PairOptions::exact_max_bytes
  // Entries farther than this are +inf, and the search stops there: a
  // neighbourhood matrix costs what its neighbourhoods hold.
  double max_distance = kInfinity;
  // A matrix of many rows, from at least half the graph's nodes and
  // without a distance limit, narrows its edges' fans as its rows come in,
  // so that its sweeps relax fewer edges (CompactLaneEdges::NarrowFans):
  // the same numbers, for a copy of the edges (12 bytes each) held while
  // the matrix is made.
  bool narrow_fans = false;
};

// Where GeodesicEngine::StreamMatrix delivers a matrix's rows, so that a
// matrix larger than memory can go to a file row by row.
struct MatrixRowSink {
  // Row i (one entry per target), called from the thread that computed it,
  // rows of a batch in no particular order. The span lives for the call only.
  std::function<absl::Status(size_t i, absl::Span<const double> row)> row;
  // Or, for a sink that keeps float32 only, the same rows rounded to
  // float32 (to nearest): when set, it is called instead of `row`, and rows
  // from vertex sources go straight from the sweep to float32, never held
  // as float64 (half the bytes a row moves).
  std::function<absl::Status(size_t i, absl::Span<const float> row)> float32_row;
  // Or, for a neighbourhood matrix, only the entries within
  // MatrixOptions::max_distance (the finite ones, without a limit): their
  // columns, ascending, and distances. When set, it is called instead of
  // `row` and `float32_row`. Where the sources and targets are vertices, a
  // row is then read from the nodes its sweep reached, not from every
  // target, and costs what its neighbourhood holds.
  std::function<absl::Status(size_t i, absl::Span<const uint32_t> columns,
                             absl::Span<const double> values)>
      sparse_row;
  // Sources are solved in batches of this many rows (0: one batch of all),
  // and batch_done(end) runs on the calling thread once every row before
  // `end` has been delivered: a sink that must append rows in order then
  // holds one batch, never the matrix.
  size_t batch_rows = 0;
  std::function<absl::Status(size_t end)> batch_done;
};

struct SampleOptions {
  // The first point is a vertex drawn with this seed; the rest follow from
  // it, so one seed gives one sampling.
  uint64_t seed = 0;
  std::function<bool()> cancelled;
  // Called on the calling thread between two points' fields, when the
  // sampling holds nothing shared (a server gives its CPU slot back there);
  // an error stops the sampling with it.
  std::function<absl::Status()> between_points;
};

struct SampleResult {
  std::vector<VertexId> vertices;  // in the order chosen
  // Graph distance from the farthest surface vertex to its nearest sample:
  // every vertex lies within it (+inf while a component has no sample).
  double covering_radius = kInfinity;
};

class GeodesicEngine {
 public:
  GeodesicEngine(std::shared_ptr<const Mesh> mesh, std::shared_ptr<const DggGraph> graph);
  ~GeodesicEngine();

  const Mesh& mesh() const { return *mesh_; }
  const DggGraph& graph() const { return *graph_; }

  // Single- or multi-source distance field. Sources are validated
  // (OUT_OF_RANGE / INVALID_ARGUMENT naming the source's index).
  absl::StatusOr<FieldResult> Field(absl::Span<const SurfacePoint> sources,
                                    const FieldOptions& options) const;

  // Distance (and optionally path) between two arbitrary surface points
  // (Algorithm 3: locally augmented graph, bidirectional search).
  absl::StatusOr<PairResult> Distance(const SurfacePoint& a, const SurfacePoint& b,
                                      const PairOptions& options) const;

  // Distance(from[i], to[i], options) for every i, the pairs spread over
  // the cores (TBB): each answer is the one Distance gives alone, bit for
  // bit. The first failing pair's error (by index) is returned.
  absl::StatusOr<std::vector<PairResult>> Distances(absl::Span<const SurfacePoint> from,
                                                    absl::Span<const SurfacePoint> to,
                                                    const PairOptions& options) const;
  // Computes the landmark distances that tighten point-to-point A* bounds
  // (core/query/landmarks.h): `count` + 1 graph searches. Until it has run, queries
  // use straight-line bounds alone, which is correct, only slower on long
  // queries. Safe while queries run; once it has succeeded, later calls
  // return at once. CANCELLED (and no landmarks) if `cancelled` says so.
  absl::Status PrepareLandmarks(int count, const std::function<bool()>& cancelled = {}) const;
  absl::Status PrepareLandmarks() const { return PrepareLandmarks(DefaultLandmarkCount()); }
  // As many landmarks as a quarter of the graph's bytes pays for (each holds
  // 4 bytes per node), from 16 to 64: a denser graph (smaller epsilon)
  // relaxes more edges per settled node, so tighter bounds save more there,
  // and more landmarks settle fewer nodes (bench/notes.md, "Landmarks").
  int DefaultLandmarkCount() const;
  // Bytes held by the landmark distances (0 before PrepareLandmarks).
  uint64_t landmark_bytes() const;

  // Computes exact distance fields from `count` landmarks spread by
  // SamplePoints (core/query/exact_landmarks.h): `count` exact single-source
  // solves on `threads` threads (0: every core). Until it has run, exact
  // pairs and one-target exact rows prune by the straight line alone, which
  // is as exact, only slower. Safe while queries run; once it has
  // succeeded, later calls return at once. CANCELLED (and no landmarks) if
  // `cancelled` says so.
  absl::Status PrepareExactLandmarks(int count, const std::function<bool()>& cancelled = {},
                                     int threads = 0) const;
  // Takes landmarks made before (read back from a file, or another engine's
  // on the same mesh: they are the mesh's fields, whatever the graph) as if
  // PrepareExactLandmarks had made them; a no-op once there are some. They
  // must be of a mesh with this engine's mesh's vertices and faces.
  absl::Status AdoptExactLandmarks(std::shared_ptr<const ExactLandmarks> landmarks) const;
  // The exact landmarks, once made (nullptr before).
  const ExactLandmarks* exact_landmarks() const { return exact_landmarks_.get(); }
  // The same, for another engine of the mesh to adopt.
  std::shared_ptr<const ExactLandmarks> shared_exact_landmarks() const {
    return exact_landmarks_.shared();
  }
  // What PrepareExactLandmarks holds while it runs.
  uint64_t ExactLandmarkComputeBytes(int count, int threads = 0) const {
    return ExactLandmarks::ComputeBytes(*mesh_, count, threads);
  }
  // Bytes held by the exact landmark fields (0 before PrepareExactLandmarks).
  uint64_t exact_landmark_bytes() const;
  // Bytes of query scratch held for this engine (core/query/query_scratch.h).
  uint64_t scratch_bytes() const { return scratch_.bytes(); }

  // Geodesic farthest-point sampling: each point after the first is the
  // vertex farthest from those chosen so far, so `count` points cover the
  // surface about as evenly as any `count` points can (within a factor 2 of
  // the best covering radius). Vertices that no face uses are not on the
  // surface and never chosen; a component without a sample is farthest of
  // all. INVALID_ARGUMENT for a count below 1 or above the usable vertices.
  absl::StatusOr<SampleResult> SamplePoints(int count, const SampleOptions& options) const;

  // sources x targets distances, row-major. Entry (i, j) is what
  // Distance(sources[i], targets[j]) answers without a path (points join
  // the graph the same way, and a source that is not a vertex also reaches
  // targets by its direct geodesics), at one field per source; rows are
  // spread over the cores.
  absl::StatusOr<std::vector<double>> Matrix(absl::Span<const SurfacePoint> sources,
                                             absl::Span<const SurfacePoint> targets,
                                             const std::function<bool()>& cancelled = {}) const {
    return Matrix(sources, targets, MatrixOptions{cancelled});
  }
  // With options.exact, every row exact: after the graph's row, one window
  // propagation from the source bounded by the row's largest entry.
  absl::StatusOr<std::vector<double>> Matrix(absl::Span<const SurfacePoint> sources,
                                             absl::Span<const SurfacePoint> targets,
                                             const MatrixOptions& options) const;
  // Matrix's rows, each handed to `sink` as soon as it is computed (the
  // same numbers, bit for bit), instead of the whole matrix returned.
  absl::Status StreamMatrix(absl::Span<const SurfacePoint> sources,
                            absl::Span<const SurfacePoint> targets, const MatrixOptions& options,
                            const MatrixRowSink& sink) const;

 private:
  // A scratch for one query, its exact engine reading the exact landmarks'
  // face frames when there are some.
  ScratchPool::Lease AcquireScratch() const;

  std::shared_ptr<const Mesh> mesh_;
  std::shared_ptr<const DggGraph> graph_;
  // Where each graph node lies, in node order: point-to-point A* reads the
  // position of every node it touches, and the mesh's own array is in
  // vertex order, scattered across the search.
  std::vector<Vec3> node_xyz_;
  BucketShape buckets_;
  LaneFanLayout lane_fans_;  // of matrix sweeps
  mutable ScratchPool scratch_;
  mutable MadeOnce<Landmarks> landmarks_;
  mutable MadeOnce<ExactLandmarks> exact_landmarks_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_GEODESIC_ENGINE_H_
