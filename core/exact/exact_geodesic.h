// Exact polyhedral geodesics by window propagation (the MMP / Chen-Han
// family).
//
// A window is an interval of a mesh edge through which geodesics from one
// (pseudo-)source cross into a face along straight lines of the unfolding
// (Surazhsky et al. 2005, section 3). Windows are processed roughly in order
// of their smallest distance (a Dijkstra sweep, as in MMP and ICH's
// priority-queue variant, in buckets a fraction of an edge wide:
// core/base/wavefront_queue.h; a saddle radiates only once every window
// nearer than it has been propagated), and every new window is trimmed by
// the vertex-distance filter of Xin & Wang 2009: a point x of a window on
// edge (P, Q) is useless when d(P) + |Px| (or d(Q) + |Qx|) is already
// shorter, since every geodesic through x could take that route instead.
// Because sigma + |I x| - |Px| is monotone along the edge, the useful part is
// one interval, found in closed form. The third vertex R of the face the
// window came through filters the same way (|Rx| is a segment in that face);
// that test removes a large share of a full solve's windows. In full
// runs a window is also cut where the last window queued on its
// half-edge reaches the same points shorter: the cheap part of MMP's window
// intersection, needing no list per edge, which removes another large share
// (bench/notes.md, "Exact engine"; in direct mode it moved corners and left
// more windows, so it is off there). Windows are trimmed once, when queued.
// Saddle and boundary vertices become pseudo-sources once their distance is
// final. They emit windows only in the directions a shortest path can leave
// them by (a cone, at an interior saddle): a shortest path through a vertex
// turns by at least pi on both sides (VTP and CGAL emit into every face
// around it).
//
// Three uses of one propagation:
//  1. Distances from a source (vertex, edge point or face point) to all
//     vertices, optionally within a radius or until given targets settle.
//  2. Direct-only propagation for the DGG: only windows lit directly by the
//     source, each limited by d_max of Theorem 2 of the DGG paper (section
//     4.2.1); reports each lit vertex with its direct distance and the
//     geodesic's direction at both ends.
//  3. Backtrace: the geodesic from the source to a vertex or surface point as
//     a polyline of edge crossings, whose length equals the distance.
//
// Numerical tolerances (relative to the local edge length L): windows
// narrower than 1e-12 L are dropped, as are windows whose source image lies
// within 1e-14 L of the edge line (a zero-area face: no direction crosses it);
// the vertex filter trims only what is dominated by more than 1e-12 of the
// distance, so rounding never removes the true geodesic. Distances are
// double precision throughout.
//
// An ExactGeodesic object holds per-call scratch that is reused across calls
// (and shrunk when a call left it very large); use one per thread. The mesh
// is only read, so any number of objects may share one mesh.
#ifndef GEODESIC_CORE_EXACT_EXACT_GEODESIC_H_
#define GEODESIC_CORE_EXACT_EXACT_GEODESIC_H_

#include <cstdint>
#include <functional>
#include <limits>
#include <optional>
#include <type_traits>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/base/vec.h"
#include "core/base/wavefront_queue.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

// Lower bounds on each vertex's distance to a run's goal, tighter than the
// straight line on a curved surface (core/query/exact_landmarks.h makes them
// from exact fields of a few landmarks). Any valid bounds keep the goal's
// distance exact; tighter ones leave fewer windows.
class GoalFloor {
 public:
  virtual ~GoalFloor() = default;
  // At most the geodesic distance from v to the goal.
  virtual double At(VertexId v) const = 0;
};

struct ExactOptions {
  // Stop once the wavefront passes this distance; vertices beyond are +inf.
  double max_distance = std::numeric_limits<double>::infinity();
  // If non-empty, stop as soon as all of these are settled.
  std::vector<VertexId> targets;
  // Keep every window so that Trace() can recover paths afterwards.
  bool keep_windows = false;
  // Polled now and then; returning true aborts with CANCELLED.
  std::function<bool()> cancelled;
  // A point whose distance alone is wanted, with max_distance an upper bound
  // on it (a graph answer): a window is dropped when every route through it
  // to the goal, straight on from its segment, passes that bound.
  // Every window holding a point of a shortest path to the goal passes, so
  // the goal's distance (DistanceTo, Trace) stays exact while most of the
  // disc of radius max_distance is never swept; other vertices' distances
  // are then only upper bounds.
  std::optional<Vec3> goal;
  // With goal: bounds that tighten the straight line (a window's segment is
  // no nearer the goal than its edge's ends' bounds less their distance
  // along the edge). Must outlive the run.
  const GoalFloor* goal_floor = nullptr;
  // The most bytes of windows the run may hold (0: no limit); past it the
  // run stops with RESOURCE_EXHAUSTED. A server bounds a query's memory so.
  uint64_t max_window_bytes = 0;
};

struct DirectOptions {
  // The DGG accuracy: windows stop travelling at d_max of Theorem 2.
  // Zero or negative disables the early termination.
  double epsilon = 0;
  // Lit vertices farther than this are not reported (and windows beyond it are
  // not propagated).
  double max_distance = std::numeric_limits<double>::infinity();
  bool keep_windows = false;
  // With epsilon: also stop rays that a route through a corner of their
  // window's shadow already serves within 1+epsilon (our FastDGG-style early
  // stop). Off gives plain Algorithm 1 with Theorem 2 only, for comparison.
  bool stop_at_corners = true;
};

// A vertex lit directly by the source.
struct DirectHit {
  VertexId vertex;
  double distance;
  // Polar angles (raw radians of each end's cone, see core/mesh/mesh.h) of the
  // geodesic's direction at the source and at the vertex (pointing back
  // towards the source). For a non-vertex source the frame is the face
  // plane with the face's first edge as reference (edge points: the
  // canonical half-edge's direction), angles in [0, 2*pi).
  double angle_at_source;
  double angle_at_vertex;
};

struct ExactStats {
  uint64_t windows_created = 0;
  uint64_t windows_propagated = 0;
  // Windows computed by propagating one across a face, before any trim:
  // what VTP (Qin et al. 2016) counts as interval propagations.
  uint64_t children_computed = 0;
  uint64_t pseudo_sources = 0;
  // Faces around a vertex that no shortest path leaves it through, so it
  // emits no window across them (see ExitDirections).
  uint64_t pseudo_windows_skipped = 0;
  uint64_t peak_queue = 0;
};

// What propagating a window across half-edge h reads about face(h), in h's
// frame: tail at the origin, head at (length, 0), the face above.
struct alignas(64) FaceFrame {
  Vec2 apex;             // the face's third vertex
  double length;         // |h|
  double length_prev;    // |prev(h)|: tail to apex
  double length_next;    // |next(h)|: apex to head
  HalfedgeId twin_prev;  // across prev(h), running tail -> apex (kNone: boundary)
  HalfedgeId twin_next;  // across next(h), running apex -> head
  VertexId tail, head, apex_vertex;

  static FaceFrame Of(const Mesh& mesh, HalfedgeId h);
  // Asks for the mesh's cache lines Of(mesh, h) reads.
  static void Prefetch(const Mesh& mesh, HalfedgeId h);
};

// The frames of every half-edge, for engines that share one mesh over many
// sources (the DGG build): one cache line per window propagated instead of
// reads from five mesh arrays and a square root. 64 bytes per half-edge,
// built once and shared read-only.
class FaceFrames {
 public:
  explicit FaceFrames(const Mesh& mesh);
  const FaceFrame& operator[](HalfedgeId h) const { return frames_[h]; }
  size_t size() const { return frames_.size(); }

 private:
  std::vector<FaceFrame> frames_;
};

class ExactGeodesic {
 public:
  // `frames`, if given, must be built from `mesh` and outlive the engine.
  explicit ExactGeodesic(const Mesh& mesh, const FaceFrames* frames = nullptr);
  ~ExactGeodesic();
  ExactGeodesic(const ExactGeodesic&) = delete;
  ExactGeodesic& operator=(const ExactGeodesic&) = delete;

  // Use 1: distances to every vertex (+inf where unreachable or beyond the
  // limit). The source is validated (OUT_OF_RANGE / INVALID_ARGUMENT).
  absl::StatusOr<std::vector<double>> Distances(const SurfacePoint& source,
                                                const ExactOptions& options = {});

  // Use 2: vertices lit directly by the source, sorted by vertex id. The
  // source itself (if a vertex) is not reported.
  absl::StatusOr<std::vector<DirectHit>> DirectGeodesics(const SurfacePoint& source,
                                                         const DirectOptions& options);

  // After a call with keep_windows: the distance from the source to an
  // arbitrary surface point (+inf if unreached) ...
  absl::StatusOr<double> DistanceTo(const SurfacePoint& target) const;
  // ... and the geodesic path to it, from the source to the target. Points
  // are the source, each edge crossing (as edge + t) or vertex passed, and the
  // target.
  struct TracePoint {
    SurfacePoint point;
    Vec3 xyz;
  };
  absl::StatusOr<std::vector<TracePoint>> Trace(const SurfacePoint& target) const;

  // Frees the windows a run kept when they are many, as a run without
  // keep_windows does: DistanceTo and Trace then need a new run. For
  // engines that live in a pool after a large run.
  void ReleaseLargeWindows();

  // What the engine holds between runs: its per-vertex state and the
  // window and queue buffers it keeps for the next run.
  uint64_t memory_bytes() const;

  const ExactStats& stats() const { return stats_; }
  const Mesh& mesh() const { return mesh_; }
  // Frames to read instead of computing each face's per window (nullptr:
  // compute them); built from this engine's mesh, alive while in use.
  void set_frames(const FaceFrames* frames) { frames_ = frames; }

 private:
  struct Window;
  struct Rays;
  struct Draft;
  struct Seed;
  enum class Mode { kFull, kDirect };
  // What a run of the mode reads and writes of a window: full runs follow no
  // rays, and copying those showed in their time.
  template <Mode kMode>
  using WindowOf = std::conditional_t<kMode == Mode::kDirect, Draft, Window>;

  absl::Status Run(const SurfacePoint& source, Mode mode, double max_distance,
                   const std::vector<VertexId>* targets, bool keep_windows,
                   const std::function<bool()>* cancelled, double epsilon,
                   bool stop_at_corners = false);
  void Reset();
  // The run itself, with every test of the mode settled when compiled: the
  // propagation's inner loop is most of a solve's time, and its branches on
  // the mode showed in it (bench/notes.md, "Exact engine").
  template <Mode kMode>
  absl::Status Solve(const std::vector<VertexId>* targets, const std::function<bool()>* cancelled);
  template <Mode kMode>
  void SeedSource(const SurfacePoint& source);
  // `back`: the polar angle at v back along the path that reached it (NaN:
  // unknown, or v is the source), which bounds where paths leave v.
  template <Mode kMode>
  void EmitFromVertex(VertexId v, double sigma, uint32_t provenance_vertex, double back);
  template <Mode kMode>
  void EmitWindowAcross(HalfedgeId inner, const Vec3& point, double sigma, uint32_t pseudo_source,
                        double angle_tail, double angle_head);
  template <Mode kMode>
  void Propagate(uint32_t index);
  static double RayAngle(const Draft& w, double x);
  template <Mode kMode>
  double DirectLimit(const WindowOf<kMode>& w, double L) const;
  template <Mode kMode>
  void ReachApex(uint32_t index, const WindowOf<kMode>& w, const FaceFrame& face, double xc);
  template <Mode kMode>
  void UpdateVertex(VertexId v, double d, uint32_t window, uint32_t via_vertex, double angle_src,
                    double angle_vertex);
  // The edge a window lies on, as its creator knows it: a child's edge is a
  // side of its parent's face, so trimming it reads nothing of its own face,
  // and the parent's face is the face behind it, whose third vertex trims it
  // too (kNone for windows from a vertex or source point: the face behind
  // holds their source, which no vertex of it can beat).
  struct EdgeEnds {
    double length;
    VertexId tail, head;
    VertexId behind = kNone;
    Vec2 behind_at;  // in the edge's frame
  };
  EdgeEnds EndsOf(HalfedgeId h) const {
    return {mesh_.length(h), mesh_.tail(h), mesh_.head(h), kNone, {}};
  }
  const FaceFrame& FrameOf(HalfedgeId h) {
    if (frames_) return (*frames_)[h];
    own_frame_ = FaceFrame::Of(mesh_, h);
    return own_frame_;
  }
  // Asks for what FrameOf(h) will read.
  void PrefetchFrame(HalfedgeId h) const {
    if (frames_) {
      __builtin_prefetch(&(*frames_)[h]);
    } else {
      FaceFrame::Prefetch(mesh_, h);
    }
  }
  // Whether no route through v, reached at d, can reach the goal within the
  // run's bound.
  bool PastGoal(VertexId v, double d);
  template <Mode kMode>
  bool Trim(WindowOf<kMode>& w, const EdgeEnds& edge) const;
  bool TrimByRelays(Draft& w) const;
  void KeepCornersOnBoundary(Draft& w, double b0, double b1) const;
  bool TrimByFaceBehind(Window& w, const EdgeEnds& edge) const;
  // Cuts from w's ends what a route from R (at distance dR, in w's frame)
  // reaches shorter on [lo, hi] of the edge; false when nothing is left.
  bool CutWhereShorter(Window& w, const Vec2& R, double dR, double lo, double hi, double L) const;
  bool TrimBySeenWindows(Window& w, const EdgeEnds& edge) const;
  void RememberSeen(const Window& w);
  // Trims w in place (copying the window for each child showed in the DGG
  // candidates' time) and queues what is left.
  template <Mode kMode>
  bool TrimAndPush(WindowOf<kMode>& w, const EdgeEnds& edge);
  // The distance from the source to the window's nearest point: its key.
  static double Nearest(const Window& w);
  // Whether every route from the source through the window (nearest at
  // `key`) to the goal passes the run's bound: by the goal floor when the
  // run has one, else straight on from the window's segment.
  bool PastGoal(const Window& w, const EdgeEnds& edge, double key);
  // The goal floor at v, or v's straight line to the goal where that is
  // larger, asked once per run: every window on an edge of v reads it.
  double FloorAt(VertexId v);
  template <Mode kMode>
  uint32_t Allocate(const WindowOf<kMode>& w);
  // What the run's windows hold: the windows, their rays and the seen slots.
  uint64_t WindowBytes() const;
  void Push(double key, uint32_t window, HalfedgeId h);

  struct Candidate;
  Candidate BestCandidate(const SurfacePoint& target) const;

  const Mesh& mesh_;
  const FaceFrames* frames_;
  FaceFrame own_frame_;  // FrameOf's answer without frames_
  ExactStats stats_;
  Mode mode_ = Mode::kFull;
  bool keep_windows_ = false;
  double epsilon_ = 0;
  bool relays_ = false;  // direct mode with epsilon: stop rays served by corners
  double max_distance_ = 0;
  std::optional<Vec3> goal_;  // ExactOptions::goal of the run
  const GoalFloor* goal_floor_ = nullptr;
  std::vector<double> floor_at_;   // FloorAt's answers, NaN: not asked yet
  std::vector<VertexId> floored_;  // the vertices FloorAt answered this run
  uint64_t max_window_bytes_ = 0;  // ExactOptions::max_window_bytes of the run
  SurfacePoint source_;
  bool have_source_ = false;

  // Per-vertex state, valid for vertices in touched_.
  std::vector<double> dist_;
  std::vector<uint32_t> via_window_;  // window that lit the vertex, or kNone
  std::vector<uint32_t> via_vertex_;  // pseudo-source it was reached from
  std::vector<double> angle_src_;     // direct mode: direction at the source
  std::vector<double> angle_vtx_;     // direction at the vertex back along its path
  std::vector<uint8_t> emitted_;      // pseudo-source already emitted
  std::vector<double> route_;         // relay mode: length of a known graph route
  std::vector<uint8_t> excluded_;     // relay mode: best lighting is served by a relay
  std::vector<VertexId> touched_;
  // Full mode: the last windows queued on each half-edge, which trim those
  // queued after them where they reach the same points shorter (a cheap part
  // of MMP's window intersection, as VTP's second rule is). Slots exist only
  // for half-edges a window reached: a run bounded by a goal touches few.
  // Since saddles radiate only into their cone, a second window per edge
  // removes about 1% of the windows for more than it saves (bench/notes.md,
  // "Exact engine").
  struct SeenWindow {
    double b0, b1, sx, sy, sigma;
  };
  static constexpr int kSeenPerEdge = 1;
  struct SeenSlot {
    SeenWindow windows[kSeenPerEdge];
    HalfedgeId h;  // whose slot, for clearing seen_slot_
    uint8_t count = 0, next = 0;
  };
  std::vector<uint32_t> seen_slot_;  // per half-edge, kNone: no slot yet
  std::vector<SeenSlot> seen_slots_;
  void ClearSeen();

  std::vector<Window> windows_;
  std::vector<Rays> rays_;  // direct mode: each window's rays, beside it
  std::vector<uint32_t> free_windows_;
  // Queued windows, and saddle or boundary vertices waiting to radiate.
  struct QueueItem {
    uint32_t item;
    // A window's half-edge, so that its frame is fetched alongside it; kNone:
    // item is a vertex.
    HalfedgeId h;
  };
  WavefrontQueue<QueueItem> queue_;
  double MeanEdge();
  double mean_edge_ = 0;  // MeanEdge's answer, once asked
  template <Mode kMode>
  void Prefetch(const QueueItem& item) const;
};

namespace exact_internal {

// Routes that reach a point (x, 0) of a segment [b0, b1] of the x axis at
// sigma + |(x, 0) - s|, with s below the axis: a window on its edge's line.
struct SegmentRoutes {
  Vec2 s;
  double sigma;
  double b0, b1;
};
// The least, over the segment, of a route's length there plus the straight
// line on to `goal` (taken on the axis' far side from s, as when hinged).
double LeastStraightRoute(const SegmentRoutes& r, Vec2 goal);
// Where, on the segment, the larger of f_tail - x and f_head - (length - x)
// (the goal floors at the edge's ends less the way along it) is least, and
// that value: where the two cross, or the segment's end nearer that.
struct FloorCrossing {
  double at;
  double rest;
};
FloorCrossing FlooredRest(const SegmentRoutes& r, double length, double f_tail, double f_head);
// The least, over the segment, of a route's length plus that larger of the
// two, given where they cross.
double LeastFlooredRoute(const SegmentRoutes& r, const FloorCrossing& c);

}  // namespace exact_internal

}  // namespace geodesic

#endif  // GEODESIC_CORE_EXACT_EXACT_GEODESIC_H_
