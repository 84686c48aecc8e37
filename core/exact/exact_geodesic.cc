#include "core/exact/exact_geodesic.h"

#include <algorithm>
#include <cmath>
#include <numbers>
#include <optional>

#include "absl/base/attributes.h"
#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"

namespace geodesic {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();
constexpr double kTwoPi = 2 * std::numbers::pi;
// Windows narrower than this fraction of their edge carry no direction worth
// following; their end vertices are lit by the neighbouring windows.
constexpr double kMinWidth = 1e-12;
// A source image this close to the edge line (relative to L) means the face
// behind it has no area: nothing crosses it.
constexpr double kMinHeight = 1e-14;
// The vertex filter only trims what is dominated by more than this relative
// margin, so rounding never trims the true geodesic.
constexpr double kFilterSlack = 1e-12;
// Root-finding steps when cutting off rays served by a corner: the cut is
// conservative, so fewer steps only keep a little more of a window. Two were
// faster than five with about the same windows and edges, where one left
// more of both (bench/notes.md, "Corner cuts").
constexpr int kRelaySteps = 2;
// Root finding for those cuts also stops once the cut is known to within this
// fraction of the window. A deeper cut is not better: it leaves the descendants
// a corner whose route is closer to its limit, so stopping early costs no
// windows or edges and saves time (bench/notes.md, "Corner cuts").
constexpr double kRelayCloseEnough = 0.3;
// Root-finding steps when trimming by the vertex behind a window: also
// conservative, the cut stays on the dominated side of the root.
constexpr int kFilterSteps = 6;
// A cut moves the window's corner to the cut point, whose route is only just
// within 1 + eps there: a worse corner for every descendant than the vertex it
// replaces. Cuts smaller than this fraction of the window are not worth that:
// skipping them leaves fewer windows per source than cutting every served
// sliver (bench/notes.md, "Corner cuts").
constexpr double kMinRelayCut = 0.2;
// Scratch larger than this after a call is released (bytes).
constexpr size_t kScratchKeepBytes = size_t{64} << 20;
// Windows are queued in buckets this many mean edges wide
// (core/base/wavefront_queue.h): wider buckets take more windows out of
// order, which then trim less (bench/notes.md, "Exact engine").
constexpr double kBucketEdges = 0.2;

double Hypot(double x, double y) { return std::sqrt(x * x + y * y); }

// Hypot(x, y) > k, without the square root: most of the propagation's tests
// compare a distance with a bound, and square roots are much of its time.
bool HypotExceeds(double x, double y, double k) { return k < 0 || x * x + y * y > k * k; }

// Vertices geodesics may pass through: saddles and boundary vertices (where
// they may bend), and flat vertices (total angle 2 pi), which a straight
// geodesic can cross. Windows reach a flat vertex's far side only in the
// limit, from both sides of the ray through it: where edges run along that
// ray (collinear vertices, as CAD meshes and flat strips of thin triangles
// have), those windows degenerate and a whole line of vertices went unlit
// (on the anisotropic blade: unreached, or too long, beyond such a line).
// Radiating from flat vertices makes the continuation a window of its own.
bool RadiatesFrom(const Mesh& mesh, VertexId v) {
  return mesh.is_saddle_or_boundary(v) || mesh.total_angle(v) >= kTwoPi * (1 - 1e-10);
}

// Position of a point in the frame of an edge of length L (tail at the
// origin, head at (L, 0)) from its distances d0 to the tail and d1 to the
// head; `above` picks the side.
//
// The height comes from the triangle's area by Kahan's formula ("Miscalculating
// area and angles of a needle-like triangle"), not from sqrt(d0^2 - x^2):
// for a needle (aspect 100 and more, common in CAD meshes) that difference
// cancels most of its digits, and unfolded sources then carried errors far
// above double rounding into distances.
Vec2 PlaceFromDistances(double L, double d0, double d1, bool above) {
  const double x = (L * L + d0 * d0 - d1 * d1) / (2 * L);
  double a = L, b = d0, c = d1;  // sorted below: a >= b >= c
  if (a < b) std::swap(a, b);
  if (b < c) std::swap(b, c);
  if (a < b) std::swap(a, b);
  const double product = (a + (b + c)) * (c - (a - b)) * (c + (a - b)) * (a + (b - c));
  const double y = product > 0 ? 0.5 * std::sqrt(product) / L : 0.0;
  return {x, above ? y : -y};
}

// Parameter t in [0, 1] where the line from `from` in direction `dir` meets
// segment p -> q; `fallback` when the two are parallel.
double HitParameter(const Vec2& from, const Vec2& dir, const Vec2& p, const Vec2& q,
                    double fallback) {
  double den = Cross(q - p, dir);
  if (std::abs(den) < 1e-300) return fallback;
  double t = Cross(from - p, dir) / den;
  if (!(t >= 0)) return 0;  // also catches NaN
  return std::min(t, 1.0);
}

// Signed angle from a to b (counter-clockwise positive).
double SignedAngle(const Vec2& a, const Vec2& b) { return std::atan2(Cross(a, b), Dot(a, b)); }

// Where, along the edge (0..L), the line from source image (sx, sy) to point
// (px, py) above the edge crosses it.
double CrossingX(double sx, double sy, double px, double py) {
  double den = py - sy;
  if (den <= 0) return px;
  return sx + (px - sx) * (-sy) / den;
}

// Smallest x with sigma + |I - (x, 0)| <= bound + x, given that the left side
// decreases in x towards sigma - sx (see the vertex filter above).
double FilterRoot(double sx, double sy, double c) {
  // sqrt((x - sx)^2 + sy^2) = c + x  with c = bound - sigma.
  return (sx * sx + sy * sy - c * c) / (2 * (sx + c));
}

// Narrows [a, b], where f(a) and f(b) have opposite signs (f(a) <= 0 < f(b) or
// the reverse), around the one root of a smooth f, and returns the bracket's
// end on a's side: every point between a and that end is on a's side of the
// root, so cutting there is conservative. Regula falsi with the Illinois
// modification brackets a smooth root far faster than bisection. Stops after
// `steps`, or once the bracket is no wider than `close_enough`.
template <typename F>
double BracketEndOnSideOf(const F& f, double a, double fa, double b, double fb, int steps,
                          double close_enough = 0) {
  int side = 0;
  for (int i = 0; i < steps && std::abs(b - a) > close_enough; ++i) {
    const double x = b - fb * (b - a) / (fb - fa);
    if (!(x != a && x != b)) break;  // converged to rounding (or NaN)
    const double fx = f(x);
    if ((fx > 0) == (fa > 0)) {
      a = x, fa = fx;
      if (side == -1) fb *= 0.5;
      side = -1;
    } else {
      b = x, fb = fx;
      if (side == 1) fa *= 0.5;
      side = 1;
    }
  }
  return a;
}

// Where |x - I| - |x - R| = c on the edge line (y = 0) within [lo, hi], or
// NaN. Squaring twice leaves a quadratic; of its roots, the one where
// c^2 + (|I|^2 - |R|^2) + 2 (R.x - I.x) x has c's sign is on the right branch
// (the other solves |x - I| - |x - R| = -c).
double HyperbolaCrossing(const Vec2& I, const Vec2& R, double c, double lo, double hi) {
  const double k1 = 2 * (R.x - I.x), k0 = Dot(I, I) - Dot(R, R) + c * c;
  const double a = k1 * k1 - 4 * c * c;
  const double b = 2 * k1 * k0 + 8 * c * c * I.x;
  const double q = k0 * k0 - 4 * c * c * Dot(I, I);
  const double disc = b * b - 4 * a * q;
  if (!(disc >= 0) || c == 0) return std::nan("");
  const double s = -0.5 * (b + std::copysign(std::sqrt(disc), b));
  for (const double x : {s / a, q / s}) {
    if (x >= lo && x <= hi && (k0 + k1 * x) * c > 0) return x;
  }
  return std::nan("");
}

// The end on a's side of the cut where f, |x - I| - |x - R| - c, changes sign
// between a and b once (see BracketEndOnSideOf): the crossing in closed form,
// moved a hair towards a and checked, or else root finding.
template <typename F>
double DominatedEnd(const F& f, const Vec2& I, const Vec2& R, double c, double a, double fa,
                    double b, double fb, double L) {
  const double root = HyperbolaCrossing(I, R, c, std::min(a, b), std::max(a, b));
  if (!std::isnan(root)) {
    // Rounding in the closed form is far below this; the cut gives it up.
    const double hair = 1e-9 * L;
    const double x = a < b ? root - hair : root + hair;
    if ((x - a) * (b - x) > 0) {
      const double fx = f(x);
      if ((fx > 0) == (fa > 0)) return x;
      b = x, fb = fx;
    }
  }
  return BracketEndOnSideOf(f, a, fa, b, fb, kFilterSteps);
}

}  // namespace

// A queued window: all that a full run reads of it, in one cache line.
struct ExactGeodesic::Window {
  HalfedgeId h;     // crossed into face(h); frame: tail(h) at 0, head(h) at (L, 0)
  uint32_t parent;  // window this one was propagated from (kept windows only)
  uint32_t pseudo;  // vertex the geodesics come from; kNone for the source
  double b0, b1;    // interval along h from its tail
  double sx, sy;    // the (pseudo-)source unfolded into h's frame, sy < 0
  double sigma;     // distance from the source to the pseudo-source
};

// What direct mode also knows of a window's rays.
struct ExactGeodesic::Rays {
  double dmax;    // Theorem 2's travel limit
  double angle0;  // polar angle at the source of the ray through b0
  // With epsilon: points on the window's two boundary rays that the graph
  // reaches by a known route ("corners"), with that route's length. Any
  // point beyond the window is reachable through a corner and a straight
  // segment inside the window's cone (which is convex).
  Vec2 lc, rc;
  double lg, rg;
};

// A window being made or propagated.
struct ExactGeodesic::Draft : Window, Rays {};

struct ExactGeodesic::Candidate {
  double distance = kInf;
  enum class Via { kNone, kWindow, kVertex, kSource } via = Via::kNone;
  uint32_t window = kNone;
  VertexId vertex = kNone;
  Vec2 local;  // the target in the window's frame
};

FaceFrame FaceFrame::Of(const Mesh& mesh, HalfedgeId h) {
  const HalfedgeId hp = Mesh::prev(h), hn = Mesh::next(h);
  FaceFrame f;
  f.length = mesh.length(h);
  f.length_prev = mesh.length(hp);
  f.length_next = mesh.length(hn);
  f.apex = PlaceFromDistances(f.length, f.length_prev, f.length_next, /*above=*/true);
  f.twin_prev = mesh.twin(hp);
  f.twin_next = mesh.twin(hn);
  f.tail = mesh.tail(h);
  f.head = mesh.head(h);
  f.apex_vertex = mesh.opposite(h);
  return f;
}

void FaceFrame::Prefetch(const Mesh& mesh, HalfedgeId h) {
  // A face's three half-edges are consecutive in every per-half-edge array.
  const HalfedgeId first = 3 * Mesh::face(h);
  const Mesh::Arrays& a = mesh.arrays();
  __builtin_prefetch(&a.length[first]);
  __builtin_prefetch(&a.length[first + 2]);
  __builtin_prefetch(&a.twin[first]);
  __builtin_prefetch(&a.corners[first]);
}

FaceFrames::FaceFrames(const Mesh& mesh) : frames_(mesh.num_halfedges()) {
  for (HalfedgeId h = 0; h < frames_.size(); ++h) frames_[h] = FaceFrame::Of(mesh, h);
}

ExactGeodesic::ExactGeodesic(const Mesh& mesh, const FaceFrames* frames)
    : mesh_(mesh), frames_(frames) {
  const size_t n = mesh.num_vertices();
  dist_.assign(n, kInf);
  via_window_.assign(n, kNone);
  via_vertex_.assign(n, kNone);
  angle_src_.assign(n, 0);
  angle_vtx_.assign(n, 0);
  emitted_.assign(n, 0);
  route_.assign(n, kInf);
  excluded_.assign(n, 0);
}

ExactGeodesic::~ExactGeodesic() = default;

void ExactGeodesic::Reset() {
  for (VertexId v : touched_) {
    dist_[v] = kInf;
    via_window_[v] = kNone;
    via_vertex_[v] = kNone;
    emitted_[v] = 0;
    route_[v] = kInf;
    excluded_[v] = 0;
  }
  touched_.clear();
  for (VertexId v : floored_) floor_at_[v] = std::nan("");
  floored_.clear();
  ClearSeen();
  windows_.clear();
  rays_.clear();
  free_windows_.clear();
  queue_.Reset(kBucketEdges * MeanEdge());
  stats_ = {};
}

template <ExactGeodesic::Mode kMode>
uint32_t ExactGeodesic::Allocate(const WindowOf<kMode>& w) {
  ++stats_.windows_created;
  constexpr bool direct = kMode == Mode::kDirect;
  if (!free_windows_.empty()) {
    uint32_t i = free_windows_.back();
    free_windows_.pop_back();
    windows_[i] = w;
    if constexpr (direct) rays_[i] = w;
    return i;
  }
  windows_.push_back(w);
  if constexpr (direct) rays_.push_back(w);
  return static_cast<uint32_t>(windows_.size() - 1);
}

double ExactGeodesic::MeanEdge() {
  if (mean_edge_ == 0 && mesh_.num_halfedges() > 0) {
    double sum = 0;
    for (HalfedgeId h = 0; h < mesh_.num_halfedges(); ++h) sum += mesh_.length(h);
    mean_edge_ = sum / mesh_.num_halfedges();
  }
  return mean_edge_;
}

ABSL_ATTRIBUTE_ALWAYS_INLINE inline void ExactGeodesic::Push(double key, uint32_t window,
                                                             HalfedgeId h) {
  queue_.PushLoose(key, {window, h});
  stats_.peak_queue = std::max<uint64_t>(stats_.peak_queue, queue_.size());
}

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::UpdateVertex(VertexId v, double d, uint32_t window, uint32_t via_vertex,
                                 double angle_src, double angle_vertex) {
  if (!(d < dist_[v])) return;
  if (dist_[v] == kInf) touched_.push_back(v);
  dist_[v] = d;
  excluded_[v] = 0;
  via_window_[v] = window;
  via_vertex_[v] = via_vertex;
  angle_vtx_[v] = angle_vertex;
  if constexpr (kMode == Mode::kDirect) {
    angle_src_[v] = angle_src;
  } else if (!emitted_[v] && RadiatesFrom(mesh_, v) && !PastGoal(v, d)) {
    // A geodesic may bend here, or pass straight through: once this
    // distance is final, v radiates.
    queue_.PushExact(d, {v, kNone});
  }
}

bool ExactGeodesic::PastGoal(VertexId v, double d) {
  // Every window v would radiate starts at v, so none could reach the goal
  // within the bound either: testing the vertex once spares making and
  // trimming a window per face of its fan.
  if (!goal_) return false;
  const double gap = goal_floor_ ? FloorAt(v) : Distance(mesh_.position(v), *goal_);
  return d + gap > max_distance_;
}

template <ExactGeodesic::Mode kMode>
bool ExactGeodesic::Trim(WindowOf<kMode>& w, const EdgeEnds& edge) const {
  const double L = edge.length;
  if (!(w.sy < -kMinHeight * L)) return false;
  const double width_floor = kMinWidth * L;
  if (w.b1 - w.b0 <= width_floor) return false;
  const double b0 = w.b0, b1 = w.b1;

  // Vertex filter against the edge's end points.
  const double dP = dist_[edge.tail];
  if (dP < kInf) {
    const double c = dP * (1 + kFilterSlack) + kFilterSlack * L - w.sigma;
    // Dominated at x: |I x| > c + x.
    if (HypotExceeds(w.b1 - w.sx, w.sy, c + w.b1)) return false;
    if (HypotExceeds(w.b0 - w.sx, w.sy, c + w.b0)) {
      w.b0 = std::max(w.b0, FilterRoot(w.sx, w.sy, c));
    }
  }
  const double dQ = dist_[edge.head];
  if (dQ < kInf) {
    const double c = dQ * (1 + kFilterSlack) + kFilterSlack * L - w.sigma;
    // Dominated at x: |I x| > c + (L - x).
    if (HypotExceeds(w.b0 - w.sx, w.sy, c + (L - w.b0))) return false;
    if (HypotExceeds(w.b1 - w.sx, w.sy, c + (L - w.b1))) {
      // Mirror the edge so the same closed form applies.
      w.b1 = std::min(w.b1, L - FilterRoot(L - w.sx, w.sy, c));
    }
  }
  if (w.b1 - w.b0 <= width_floor) return false;
  if constexpr (kMode == Mode::kDirect) {
    if (relays_) {
      // The third vertex of the face behind is then a corner of the window's
      // shadow, whose cut (TrimByRelays) already covers TrimByFaceBehind's:
      // that test would remove nothing.
      KeepCornersOnBoundary(w, b0, b1);
      return true;
    }
  }
  return TrimByFaceBehind(w, edge);
}

void ExactGeodesic::KeepCornersOnBoundary(Draft& w, double b0, double b1) const {
  // A corner serves the points beyond a window along segments that stay
  // between the window's boundary rays and the corner, a region no vertex
  // lies in: the vertices inside the cone split it, and each child takes
  // the splitting vertex as its corner. A cut moves a boundary ray inwards,
  // and vertices beyond the edge between the old ray and the new one split
  // nothing from now on, so the corner moves onto the new ray (at the cut,
  // with the route's length so far) to keep them out of that region.
  if (w.b0 > b0) {
    const Vec2 p{w.b0, 0};
    w.lg += Norm(p - w.lc);
    w.lc = p;
  }
  if (w.b1 < b1) {
    const Vec2 p{w.b1, 0};
    w.rg += Norm(p - w.rc);
    w.rc = p;
  }
}

bool ExactGeodesic::TrimByFaceBehind(Window& w, const EdgeEnds& edge) const {
  // The third vertex R of the face the window came through: a point x of the
  // window is also reached by d(R) + |R x| (a segment inside that face).
  if (edge.behind == kNone) return true;
  const double dR = dist_[edge.behind];
  if (!(dR < kInf)) return true;
  return CutWhereShorter(w, edge.behind_at, dR, w.b0, w.b1, edge.length);
}

bool ExactGeodesic::CutWhereShorter(Window& w, const Vec2& R, double dR, double lo, double hi,
                                    double L) const {
  // Since |I x| - |R x| is not monotone along the edge, where it exceeds
  // d(R) - sigma needs a root: there w is useless.
  lo = std::max(lo, w.b0);
  hi = std::min(hi, w.b1);
  if (!(hi > lo)) return true;
  const Vec2 I{w.sx, w.sy};
  const double c = dR * (1 + kFilterSlack) + kFilterSlack * L - w.sigma;
  // |I x| - |R x| <= |I R|: a route from R no shorter than the window's
  // source to R is nowhere shorter. Most windows pass so, with no root.
  if (c >= 0 && Dot(I - R, I - R) <= c * c) return true;
  auto excess = [&](double x) {
    const Vec2 p{x, 0};
    return Norm(p - I) - Norm(p - R) - c;
  };
  const double e0 = excess(lo), e1 = excess(hi);
  if (e0 <= 0 && e1 <= 0) return true;
  if (e0 > 0 && e1 > 0) {
    // For c >= 0 the dominated points form the convex inside of a hyperbola
    // branch around R, which holds all of [lo, hi] once it holds both ends.
    // For c < 0 the middle may escape it; keep the window (rare).
    if (c < 0) return true;
    if (lo <= w.b0 && hi >= w.b1) return false;
    if (lo <= w.b0) {
      w.b0 = hi;
    } else if (hi >= w.b1) {
      w.b1 = lo;
    }
  } else if (e0 > 0) {
    // One end is dominated, so the hyperbola crosses [lo, hi] once; only a
    // part at an end of w can be cut from it.
    if (lo <= w.b0) w.b0 = DominatedEnd(excess, I, R, c, lo, e0, hi, e1, L);
  } else if (hi >= w.b1) {
    w.b1 = DominatedEnd(excess, I, R, c, hi, e1, lo, e0, L);
  }
  return w.b1 - w.b0 > kMinWidth * L;
}

inline bool ExactGeodesic::TrimBySeenWindows(Window& w, const EdgeEnds& edge) const {
  const uint32_t slot = seen_slot_[w.h];
  if (slot == kNone) return true;
  const SeenSlot& seen = seen_slots_[slot];
  for (int k = 0; k < seen.count; ++k) {
    const SeenWindow& s = seen.windows[k];
    if (!CutWhereShorter(w, {s.sx, s.sy}, s.sigma, s.b0, s.b1, edge.length)) return false;
  }
  return true;
}

inline void ExactGeodesic::RememberSeen(const Window& w) {
  uint32_t& slot = seen_slot_[w.h];
  if (slot == kNone) {
    slot = seen_slots_.size();
    seen_slots_.push_back({.windows = {}, .h = w.h});
  }
  SeenSlot& seen = seen_slots_[slot];
  seen.windows[seen.next] = {w.b0, w.b1, w.sx, w.sy, w.sigma};
  seen.next = (seen.next + 1) % kSeenPerEdge;
  seen.count = std::min<int>(seen.count + 1, kSeenPerEdge);
}

void ExactGeodesic::ClearSeen() {
  for (const SeenSlot& s : seen_slots_) seen_slot_[s.h] = kNone;
  seen_slots_.clear();
}

inline double ExactGeodesic::Nearest(const Window& w) {
  if (w.sx < w.b0) return w.sigma + Hypot(w.b0 - w.sx, w.sy);
  if (w.sx > w.b1) return w.sigma + Hypot(w.b1 - w.sx, w.sy);
  return w.sigma - w.sy;
}

template <ExactGeodesic::Mode kMode>
bool ExactGeodesic::TrimAndPush(WindowOf<kMode>& w, const EdgeEnds& edge) {
  // Rays the corners serve are cut before the window is queued, so windows
  // served whole are never stored (a window's own corners do not change
  // while it waits).
  if constexpr (kMode == Mode::kDirect) {
    if (relays_ && !TrimByRelays(w)) return false;
  }
  if (!Trim<kMode>(w, edge)) return false;
  if (kMode == Mode::kFull && !TrimBySeenWindows(w, edge)) return false;
  const double key = Nearest(w);
  if (key > max_distance_) return false;
  if (goal_ && PastGoal(w, edge, key)) return false;
  if constexpr (kMode == Mode::kFull) RememberSeen(w);
  Push(key, Allocate<kMode>(w), w.h);
  return true;
}

namespace exact_internal {

double LeastStraightRoute(const SegmentRoutes& r, Vec2 goal) {
  // The goal hinged about the line onto the side away from the source:
  // |x - s| + |x - g| is least where segment s-g crosses the line, or at
  // the segment's end nearer that crossing (the sum is convex in x).
  const double sy = std::min(r.s.y, 0.0), gy = std::abs(goal.y);
  const double crossing = r.s.x + (goal.x - r.s.x) * (-sy / (gy - sy));
  const double x = std::clamp(std::isfinite(crossing) ? crossing : r.s.x, r.b0, r.b1);
  return r.sigma + Hypot(x - r.s.x, sy) + Hypot(goal.x - x, gy);
}

FloorCrossing FlooredRest(const SegmentRoutes& r, double length, double f_tail, double f_head) {
  const double at = std::clamp((f_tail - f_head + length) / 2, r.b0, r.b1);
  return {at, std::max(f_tail - at, f_head - (length - at))};
}

double LeastFlooredRoute(const SegmentRoutes& r, const FloorCrossing& c) {
  // D(x) - x falls and D(x) + x grows (|D'| < 1), so D plus the larger of
  // f_tail - x and f_head - (L - x) is least where those two cross, or at
  // the segment's end nearer that crossing.
  return r.sigma + Hypot(c.at - r.s.x, r.s.y) + c.rest;
}

}  // namespace exact_internal

bool ExactGeodesic::PastGoal(const Window& w, const EdgeEnds& edge, double key) {
  // Each test bounds the least, over the window's segment, of the distance
  // there plus a lower bound on the rest of the way: the region swept is
  // the ellipse of short routes, not what the two separate minima allow.
  const exact_internal::SegmentRoutes routes{{w.sx, w.sy}, w.sigma, w.b0, w.b1};
  if (goal_floor_) {
    // A point x along the edge is at least floor(tail) - x and floor(head) -
    // (L - x) from the goal (the edge is a path on the surface). The floors
    // hold the straight line at the ends too (FloorAt), which near the goal
    // is what binds: a straight-line test per window besides cost more
    // than the few windows it dropped (bench/notes.md, "Exact engine").
    const double f_tail = FloorAt(edge.tail), f_head = FloorAt(edge.head);
    // An edge's ends share a component: a goal beyond it is beyond both.
    if (f_tail == kInf || f_head == kInf) return true;
    const exact_internal::FloorCrossing crossing =
        exact_internal::FlooredRest(routes, edge.length, f_tail, f_head);
    // The nearest distance first: it needs no square root.
    if (key + crossing.rest > max_distance_) return true;
    return exact_internal::LeastFlooredRoute(routes, crossing) > max_distance_;
  }
  const Vec3& p = mesh_.position(edge.tail);
  const Vec3 along = (mesh_.position(edge.head) - p) * (1 / edge.length);
  const Vec3 from_p = *goal_ - p;
  const double gx = Dot(from_p, along);
  const Vec2 goal{gx, Norm(from_p - along * gx)};
  return exact_internal::LeastStraightRoute(routes, goal) > max_distance_;
}

double ExactGeodesic::FloorAt(VertexId v) {
  if (floor_at_.empty()) floor_at_.assign(mesh_.num_vertices(), std::nan(""));
  double& f = floor_at_[v];
  if (std::isnan(f)) {
    f = std::max(goal_floor_->At(v), Distance(mesh_.position(v), *goal_));
    floored_.push_back(v);
  }
  return f;
}

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::EmitWindowAcross(HalfedgeId inner, const Vec3& point, double sigma,
                                     uint32_t pseudo_source, double angle_tail,
                                     double /*angle_head*/) {
  const HalfedgeId g = mesh_.twin(inner);
  if (g == kNone) return;
  const double L = mesh_.length(g);
  // g runs head(inner) -> tail(inner); the point lies in face(inner), below g.
  double d0 = Distance(point, mesh_.position(mesh_.tail(g)));
  double d1 = Distance(point, mesh_.position(mesh_.head(g)));
  Vec2 s = PlaceFromDistances(L, d0, d1, /*above=*/false);
  Draft w{{g, kNone, pseudo_source, 0, L, s.x, s.y, sigma},
          {kInf, angle_tail, {0, 0}, {L, 0}, sigma + d0, sigma + d1}};
  TrimAndPush<kMode>(w, EndsOf(g));
}

namespace {

// Where shortest paths through a vertex v can leave it. Such a path turns by
// at least pi on each side: were the angle between its arriving and leaving
// segments below pi on one side, a segment across that corner of v's (flat)
// neighbourhood would be shorter. So it leaves at polar angles at least pi
// from `back`, the direction back along the arriving path, both ways round.
// At an interior vertex of total angle T that is a cone as wide as T - 2 pi
// (at a flat vertex, the straight continuation, as wide as the margin); at a
// boundary vertex only the way round through the surface counts, which
// leaves nothing at a convex corner. The other directions are served
// strictly shorter by paths around v; windows v emitted there would travel
// until trimmed, a large share of a full solve's work on scanned meshes
// (bench/notes.md, "Exact engine"). Any one shortest arriving path gives
// sound directions, since every one has to turn so.
struct ExitDirections {
  // Polar angles allowed at v: two intervals, widened by the margin.
  double lo[2], hi[2];

  // The part [b0, b1] of the twin of next(h) (the edge across v's face(h),
  // of length L) that rays leaving v in allowed directions cross; false when
  // none do.
  bool Within(const Mesh& mesh, HalfedgeId h, double L, double& b0, double& b1) const {
    const double first = mesh.polar_angle(h), corner = mesh.corner_angle(h);
    // The face spans polar angles [first, first + corner]. A face's corner
    // is below pi, so it meets at most one interval; the hull is taken
    // all the same.
    double from = kInf, to = -kInf;
    for (int k = 0; k < 2; ++k) {
      const double a = std::max(first, lo[k]), b = std::min(first + corner, hi[k]);
      if (a <= b) {
        from = std::min(from, a - first);
        to = std::max(to, b - first);
      }
    }
    if (!(from <= to)) return false;
    // The face in v's frame: v at the origin, b = head(h) on the x axis, c
    // at the corner's angle. A ray at angle psi meets b -> c at s (0 at b);
    // the twin edge runs c -> b, so it is at (1 - s) L there.
    const HalfedgeId p = Mesh::prev(h);
    const Vec2 b{mesh.length(h), 0};
    const Vec2 c{mesh.length(p) * std::cos(corner), mesh.length(p) * std::sin(corner)};
    auto at = [&](double psi) {
      const Vec2 dir{std::cos(psi), std::sin(psi)};
      const double s = Cross(dir, b) / Cross(dir, b - c);
      return std::clamp((1 - s) * L, 0.0, L);
    };
    b0 = to < corner ? at(to) : 0;
    b1 = from > 0 ? at(from) : L;
    return b1 > b0;
  }
};

// The directions v radiates into, or none (all of them) at the source and
// when the arriving path is unknown (`back` NaN).
std::optional<ExitDirections> ExitDirectionsAt(const Mesh& mesh, VertexId v, double back) {
  if (std::isnan(back)) return std::nullopt;
  // Rounding in the arriving direction is far below this; a wider cone only
  // keeps a sliver of a window more.
  constexpr double kMargin = 1e-8;
  constexpr double kPi = std::numbers::pi;
  // Polar angles run from 0 to T around v; on the boundary they do not wrap.
  const double total = mesh.total_angle(v);
  const bool boundary = mesh.is_boundary(v);
  return ExitDirections{{boundary ? -kInf : back - total + kPi - kMargin, back + kPi - kMargin},
                        {back - kPi + kMargin, boundary ? kInf : back + total - kPi + kMargin}};
}

}  // namespace

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::EmitFromVertex(VertexId v, double sigma, uint32_t pseudo, double back) {
  const HalfedgeId start = mesh_.vertex_halfedge(v);
  if (start == kNone) return;
  // Only full runs radiate from vertices past the source, so a window's
  // direct-mode ray angle need not follow its narrowed start.
  const std::optional<ExitDirections> exits =
      kMode == Mode::kFull ? ExitDirectionsAt(mesh_, v, back) : std::nullopt;
  HalfedgeId h = start;
  do {
    const HalfedgeId p = Mesh::prev(h);
    const VertexId b = mesh_.head(h), c = mesh_.opposite(h);
    const HalfedgeId back_b = mesh_.twin(h);
    const double at_b = back_b != kNone
                            ? mesh_.polar_angle(back_b)
                            : mesh_.polar_angle(Mesh::next(h)) + mesh_.corner_angle(Mesh::next(h));
    UpdateVertex<kMode>(b, sigma + mesh_.length(h), kNone, v, mesh_.polar_angle(h), at_b);
    route_[b] = std::min(route_[b], sigma + mesh_.length(h));
    if (mesh_.twin(p) == kNone) {
      // Last face of a boundary fan: its far edge is reached by no rotation.
      UpdateVertex<kMode>(c, sigma + mesh_.length(p), kNone, v,
                          mesh_.polar_angle(h) + mesh_.corner_angle(h), mesh_.polar_angle(p));
      route_[c] = std::min(route_[c], sigma + mesh_.length(p));
    }
    // Across the edge opposite v. The window's tail is c, where the ray's
    // polar angle is polar(h) + corner(h).
    const HalfedgeId far = Mesh::next(h);
    const HalfedgeId g = mesh_.twin(far);
    if (g != kNone) {
      const double L = mesh_.length(g);
      double b0 = 0, b1 = L;
      if (exits && !exits->Within(mesh_, h, L, b0, b1)) {
        ++stats_.pseudo_windows_skipped;
      } else {
        Vec2 s = PlaceFromDistances(L, mesh_.length(p), mesh_.length(h), /*above=*/false);
        Draft w{{g, kNone, pseudo, b0, b1, s.x, s.y, sigma},
                {kInf,
                 mesh_.polar_angle(h) + mesh_.corner_angle(h),
                 {0, 0},
                 {L, 0},
                 sigma + mesh_.length(p),
                 sigma + mesh_.length(h)}};
        TrimAndPush<kMode>(w, EndsOf(g));
      }
    }
    h = mesh_.rotate(h);
  } while (h != kNone && h != start);
}

namespace {

// The tangent frame at a non-vertex source: the plane of face f, reference
// direction `ref`; returns the polar angle of direction d in [0, 2*pi).
double FacePlaneAngle(const Mesh& mesh, FaceId f, const Vec3& ref, const Vec3& d) {
  const Vec3& a = mesh.position(mesh.face_vertex(f, 0));
  const Vec3& b = mesh.position(mesh.face_vertex(f, 1));
  const Vec3& c = mesh.position(mesh.face_vertex(f, 2));
  Vec3 n = Cross(b - a, c - a);
  double nn = Norm(n);
  if (nn > 0) n = n * (1 / nn);
  double angle = std::atan2(Dot(n, Cross(ref, d)), Dot(ref, d));
  return WrapAngle(angle, kTwoPi);
}

// Polar angle at the tail of half-edge `corner` of the direction towards
// point p inside that corner's face.
double CornerDirection(const Mesh& mesh, HalfedgeId corner, const Vec3& p) {
  const Vec3& x = mesh.position(mesh.tail(corner));
  Vec3 e = mesh.position(mesh.head(corner)) - x;
  Vec3 d = p - x;
  double angle = std::atan2(Norm(Cross(e, d)), Dot(e, d));
  return mesh.polar_angle(corner) + std::clamp(angle, 0.0, mesh.corner_angle(corner));
}

}  // namespace

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::SeedSource(const SurfacePoint& source) {
  if (source.kind == SurfacePoint::Kind::kVertex) {
    const VertexId v = source.id;
    touched_.push_back(v);
    dist_[v] = 0;
    emitted_[v] = 1;
    EmitFromVertex<kMode>(v, 0, v, std::numeric_limits<double>::quiet_NaN());
    return;
  }
  // A point on an edge or inside a face: the faces that contain it, and for
  // each, the half-edges to emit windows across.
  const Vec3 p = PositionOf(mesh_, source);
  Vec3 ref;
  std::vector<std::pair<FaceId, int>> faces;  // face, index of the skipped edge (-1: none)
  if (source.kind == SurfacePoint::Kind::kFace) {
    faces.push_back({source.id, -1});
    ref = mesh_.position(mesh_.face_vertex(source.id, 1)) -
          mesh_.position(mesh_.face_vertex(source.id, 0));
  } else {
    const HalfedgeId e = mesh_.edge_halfedge(source.id);
    faces.push_back({Mesh::face(e), Mesh::corner(e)});
    if (mesh_.twin(e) != kNone)
      faces.push_back({Mesh::face(mesh_.twin(e)), Mesh::corner(mesh_.twin(e))});
    ref = mesh_.position(mesh_.head(e)) - mesh_.position(mesh_.tail(e));
  }
  for (auto [f, skip] : faces) {
    for (int k = 0; k < 3; ++k) {
      const HalfedgeId h = Mesh::halfedge(f, k);
      const VertexId x = mesh_.tail(h);
      const Vec3 xp = mesh_.position(x);
      const double a_src = FacePlaneAngle(mesh_, f, ref, xp - p);
      UpdateVertex<kMode>(x, Distance(p, xp), kNone, kNone, a_src, CornerDirection(mesh_, h, p));
      route_[x] = std::min(route_[x], Distance(p, xp));
      if (k == skip) continue;
      // Window across h, whose tail (as seen from the twin) is head(h).
      const double a_tail = FacePlaneAngle(mesh_, f, ref, mesh_.position(mesh_.head(h)) - p);
      EmitWindowAcross<kMode>(h, p, 0, kNone, a_tail, 0);
    }
  }
}

bool ExactGeodesic::TrimByRelays(Draft& w) const {
  // Rays through x are served by a corner c once g_c + |c x| <= (1 + eps)
  // |I x|: every point p beyond x then has a graph route within 1 + eps of
  // its direct geodesic, g_c + |c x| + |x p| <= (1 + eps) (|I x| + |x p|).
  // Served rays form an interval at each end of the window; cut both off.
  const Vec2 I{w.sx, w.sy};
  auto slack = [&](const Vec2& c, double g, double x) {
    const Vec2 p{x, 0};
    return g + Norm(p - c) - (1 + epsilon_) * (w.sigma + Norm(p - I));
  };
  // Largest x (conservatively) with slack <= 0 on [from, x], given the
  // slack at `from`, which is not positive.
  auto reach = [&](const Vec2& c, double g, double from, double f_from, double to) {
    const double f_to = slack(c, g, to);
    if (f_to <= 0) return to;
    auto f = [&](double x) { return slack(c, g, x); };
    return BracketEndOnSideOf(f, from, f_from, to, f_to, kRelaySteps,
                              kRelayCloseEnough * (w.b1 - w.b0));
  };
  // Cuts smaller than min_cut are not made, so one probe at that depth
  // settles most windows without root finding. A probe that finds the ray
  // unserved (most do) needs the slack's sign only: one square root.
  auto probe = [&](const Vec2& c, double g, double x) {
    const Vec2 p{x, 0};
    const double k = (1 + epsilon_) * (w.sigma + Norm(p - I)) - g;
    const Vec2 cp = p - c;
    return HypotExceeds(cp.x, cp.y, k) ? 1.0 : Norm(cp) - k;
  };
  const double min_cut = kMinRelayCut * (w.b1 - w.b0);
  double x_left = w.b0;
  const double probe_left = w.b0 + min_cut;
  if (const double f = probe(w.lc, w.lg, probe_left); f <= 0) {
    x_left = reach(w.lc, w.lg, probe_left, f, w.b1);
  }
  if (x_left >= w.b1) return false;
  double x_right = w.b1;
  const double probe_right = std::max(w.b1 - min_cut, x_left);
  if (const double f = probe(w.rc, w.rg, probe_right); f <= 0) {
    x_right = reach(w.rc, w.rg, probe_right, f, x_left);
  }
  if (x_right <= x_left) return false;
  const double b0 = w.b0, b1 = w.b1;
  w.b0 = x_left;
  w.b1 = x_right;
  KeepCornersOnBoundary(w, b0, b1);
  return true;
}

// The direction from the window's source through x on its edge, as an angle
// around the source.
inline double ExactGeodesic::RayAngle(const Draft& w, double x) {
  return w.angle0 + SignedAngle(Vec2{w.b0 - w.sx, -w.sy}, Vec2{x - w.sx, -w.sy});
}

// The distance past which a direct-mode window's rays stop: its own limit,
// and Theorem 2's d_max, past which every geodesic through the window is
// within 1 + epsilon of a route through a vertex of its face sequence.
template <ExactGeodesic::Mode kMode>
ABSL_ATTRIBUTE_ALWAYS_INLINE inline double ExactGeodesic::DirectLimit(const WindowOf<kMode>& w,
                                                                      double L) const {
  if constexpr (kMode == Mode::kFull) {
    return kInf;
  } else {
    double dmax = w.dmax;
    if (epsilon_ > 0) {
      const double d0 = Hypot(w.sx, w.sy), d1 = Hypot(w.sx - L, w.sy);
      const double dmin = std::min(d0, d1);
      if (dmin > L / 2) {
        dmax = std::min(dmax, L * L / (8 * epsilon_ * (dmin - L / 2)) + L / 2 + std::max(d0, d1));
      }
    }
    return dmax;
  }
}

// The window lights its face's apex C, crossing its edge at xc: C's distance
// (and in direct mode the directions at both ends), and whether a route
// through a corner already serves it.
template <ExactGeodesic::Mode kMode>
ABSL_ATTRIBUTE_ALWAYS_INLINE inline void ExactGeodesic::ReachApex(uint32_t index,
                                                                  const WindowOf<kMode>& w,
                                                                  const FaceFrame& face,
                                                                  double xc) {
  const Vec2 A{0, 0}, C = face.apex, I{w.sx, w.sy};
  const VertexId vc = face.apex_vertex;
  const double d = w.sigma + Hypot(C.x - w.sx, C.y - w.sy);
  double a_src = 0, a_vtx = 0;
  // The directions cost an atan2 each; they are only kept when d improves.
  // Full runs keep the one at the vertex: where the path arrived from is what
  // a saddle radiates away from (EmitFromVertex).
  if (d < dist_[vc]) {
    if constexpr (kMode == Mode::kDirect) a_src = RayAngle(w, std::clamp(xc, w.b0, w.b1));
    const HalfedgeId hp = Mesh::prev(w.h);
    a_vtx =
        mesh_.polar_angle(hp) + std::clamp(SignedAngle(A - C, I - C), 0.0, mesh_.corner_angle(hp));
  }
  UpdateVertex<kMode>(vc, d, keep_windows_ ? index : kNone, w.pseudo, a_src, a_vtx);
  if constexpr (kMode == Mode::kDirect) {
    if (!relays_) return;
    // A vertex the graph already reaches within 1 + epsilon through a
    // corner needs no edge from the source: only the route is recorded.
    // Most are needed, which takes no square root to tell.
    const double limit = (1 + epsilon_) * d;
    const Vec2 l = C - w.lc, r = C - w.rc;
    const bool needed =
        HypotExceeds(l.x, l.y, limit - w.lg) && HypotExceeds(r.x, r.y, limit - w.rg);
    if (dist_[vc] == d) excluded_[vc] = !needed;
    route_[vc] = std::min(route_[vc], needed ? d : std::min(w.lg + Norm(l), w.rg + Norm(r)));
  }
}

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::Propagate(uint32_t index) {
  // A copy: children may reallocate windows_. The window is not trimmed again
  // by distances that improved while it was queued: that removed few windows
  // for a large share of the solve (bench/notes.md, "Exact engine").
  const WindowOf<kMode> w = [&] {
    if constexpr (kMode == Mode::kDirect) {
      return Draft{windows_[index], rays_[index]};
    } else {
      return windows_[index];
    }
  }();
  ++stats_.windows_propagated;
  const FaceFrame& face = FrameOf(w.h);
  // What the apex and the children read first, asked for together rather
  // than one miss after another: the apex's distance, and in full runs the
  // children's seen slots.
  __builtin_prefetch(&dist_[face.apex_vertex]);
  if constexpr (kMode == Mode::kFull) {
    if (face.twin_prev != kNone) __builtin_prefetch(&seen_slot_[face.twin_prev]);
    if (face.twin_next != kNone) __builtin_prefetch(&seen_slot_[face.twin_next]);
  }
  const double L = face.length;
  const double lb = face.length_prev;  // |AC|
  const double la = face.length_next;  // |BC|
  const Vec2 A{0, 0}, B{L, 0};
  const Vec2 C = face.apex;
  const Vec2 I{w.sx, w.sy};
  const VertexId vc = face.apex_vertex;

  const double dmax = DirectLimit<kMode>(w, L);
  const double xc = CrossingX(w.sx, w.sy, C.x, C.y);
  const double tol = kMinWidth * L;
  const bool sees_c = xc >= w.b0 - tol && xc <= w.b1 + tol;
  if (sees_c) ReachApex<kMode>(index, w, face, xc);

  auto make_child = [&](HalfedgeId g, EdgeEnds edge, const Vec2& origin, const Vec2& toward,
                        double t0, double t1, double ray_start, bool c_is_left, bool c_is_right) {
    const double len = edge.length;
    if (g == kNone || len <= 0) return;
    ++stats_.children_computed;
    // The child's face is read when it is propagated, usually soon: asking
    // for it now hides that miss, which the candidate phase would otherwise
    // wait on (bench/notes.md, "Build engine").
    PrefetchFrame(g);
    const Vec2 u = (toward - origin) * (1 / len);
    auto to_child = [&](const Vec2& p) {
      const Vec2 rel = p - origin;
      return Vec2{Dot(rel, u), Cross(u, rel)};
    };
    const Vec2 src = to_child(I);
    edge.behind_at = to_child(edge.behind == face.head ? B : A);
    WindowOf<kMode> c;
    static_cast<Window&>(c) = {
        g, keep_windows_ ? index : kNone, w.pseudo, t0 * len, t1 * len, src.x, src.y, w.sigma};
    if constexpr (kMode == Mode::kDirect) {
      // The child's rays start at ray_start on w's edge.
      const double angle0 = ray_start == w.b0 ? w.angle0 : RayAngle(w, ray_start);
      static_cast<Rays&>(c) = {dmax, angle0, w.lc, w.rc, w.lg, w.rg};
      if (relays_) {
        // The ray through C bounds the children it separates; C is its corner.
        c.lc = c_is_left ? to_child(C) : to_child(w.lc);
        c.rc = c_is_right ? to_child(C) : to_child(w.rc);
        if (c_is_left) c.lg = route_[vc];
        if (c_is_right) c.rg = route_[vc];
      }
      if (dmax < kInf) {
        // The paper's rule: a child travels on only if both of its ends are
        // still within the parent's limit.
        const double reach = dmax - c.sigma;
        if (!(reach > 0) || (c.b0 - c.sx) * (c.b0 - c.sx) + c.sy * c.sy >= reach * reach ||
            (c.b1 - c.sx) * (c.b1 - c.sx) + c.sy * c.sy >= reach * reach) {
          return;
        }
      }
    }
    TrimAndPush<kMode>(c, edge);
  };

  // Child on edge A -> C (the twin of prev(h) runs A -> C).
  if (w.b0 < xc) {
    const double end = std::min(w.b1, xc);
    const double t0 = HitParameter(I, Vec2{w.b0, 0} - I, A, C, 0);
    const double t1 = sees_c || xc <= w.b1 ? 1.0 : HitParameter(I, Vec2{end, 0} - I, A, C, 1);
    make_child(face.twin_prev, {lb, face.tail, vc, face.head, {}}, A, C, t0, t1, w.b0, false,
               sees_c && route_[vc] < kInf);
  }
  // Child on edge C -> B (the twin of next(h) runs C -> B).
  if (w.b1 > xc) {
    const double begin = std::max(w.b0, xc);
    const double t0 = sees_c || xc >= w.b0 ? 0.0 : HitParameter(I, Vec2{begin, 0} - I, C, B, 0);
    const double t1 = HitParameter(I, Vec2{w.b1, 0} - I, C, B, 1);
    make_child(face.twin_next, {la, vc, face.head, face.tail, {}}, C, B, t0, t1, begin,
               sees_c && route_[vc] < kInf, false);
  }
}

absl::Status ExactGeodesic::Run(const SurfacePoint& raw_source, Mode mode, double max_distance,
                                const std::vector<VertexId>* targets, bool keep_windows,
                                const std::function<bool()>* cancelled, double epsilon,
                                bool stop_at_corners) {
  RETURN_IF_ERROR(ValidateSurfacePoint(mesh_, raw_source));
  if (targets) {
    for (VertexId t : *targets) {
      if (t >= mesh_.num_vertices()) {
        return absl::OutOfRangeError(
            absl::StrFormat("target vertex %u is out of range (the mesh has %u vertices)", t,
                            mesh_.num_vertices()));
      }
    }
  }
  Reset();
  if (mode == Mode::kFull && seen_slot_.empty()) seen_slot_.assign(mesh_.num_halfedges(), kNone);
  mode_ = mode;
  keep_windows_ = keep_windows;
  epsilon_ = epsilon;
  relays_ = mode == Mode::kDirect && epsilon > 0 && stop_at_corners;
  max_distance_ = max_distance;
  source_ = CanonicalizeSurfacePoint(mesh_, raw_source);
  have_source_ = true;
  const absl::Status status = mode == Mode::kDirect ? Solve<Mode::kDirect>(targets, cancelled)
                                                    : Solve<Mode::kFull>(targets, cancelled);
  // Windows past the limit stay unprocessed: vertices they would light are
  // beyond max_distance and reported as +inf by the callers.
  queue_.Clear();
  return status;
}

template <ExactGeodesic::Mode kMode>
absl::Status ExactGeodesic::Solve(const std::vector<VertexId>* targets,
                                  const std::function<bool()>* cancelled) {
  SeedSource<kMode>(source_);
  uint64_t steps = 0;
  size_t settled_scan = 0;  // targets known to be settled, in order
  while (!queue_.empty()) {
    const auto [key, top] = queue_.Pop();
    if (key > max_distance_) break;
    if (targets && !targets->empty()) {
      while (settled_scan < targets->size() && dist_[(*targets)[settled_scan]] <= key) {
        ++settled_scan;
      }
      if (settled_scan == targets->size()) break;
    }
    if (cancelled && *cancelled && (++steps & 4095) == 0 && (*cancelled)()) {
      return absl::CancelledError("exact propagation cancelled");
    }
    if (max_window_bytes_ && WindowBytes() > max_window_bytes_) {
      return absl::ResourceExhaustedError(absl::StrFormat(
          "the exact propagation passed %u windows (%u MB), over its limit of %u MB",
          windows_.size(), WindowBytes() >> 20, max_window_bytes_ >> 20));
    }
    if (top.h == kNone) {
      const VertexId v = top.item;
      if (emitted_[v]) continue;  // an older, longer entry
      emitted_[v] = 1;
      ++stats_.pseudo_sources;
      EmitFromVertex<kMode>(v, dist_[v], v, angle_vtx_[v]);
      continue;
    }
    // A window taken from the heap or from a bucket not yet reached was
    // queued long before it is propagated, so it and its frame are likely
    // out of cache (a child taken straight after its parent is not): the
    // next window's are asked for now, to arrive while this one is
    // propagated.
    Prefetch<kMode>(top);
    if (const QueueItem* next = queue_.PeekNext()) Prefetch<kMode>(*next);
    Propagate<kMode>(top.item);
    if (!keep_windows_) free_windows_.push_back(top.item);
  }
  return absl::OkStatus();
}

template <ExactGeodesic::Mode kMode>
void ExactGeodesic::Prefetch(const QueueItem& item) const {
  if (item.h == kNone) return;
  __builtin_prefetch(&windows_[item.item]);
  if constexpr (kMode == Mode::kDirect) __builtin_prefetch(&rays_[item.item]);
  PrefetchFrame(item.h);
}

uint64_t ExactGeodesic::WindowBytes() const {
  return windows_.size() * sizeof(Window) + rays_.size() * sizeof(Rays) +
         seen_slots_.size() * sizeof(SeenSlot);
}

void ExactGeodesic::ReleaseLargeWindows() {
  if (windows_.capacity() * sizeof(Window) + rays_.capacity() * sizeof(Rays) +
          seen_slots_.capacity() * sizeof(SeenSlot) <=
      kScratchKeepBytes) {
    return;
  }
  windows_ = {};
  rays_ = {};
  free_windows_ = {};
  ClearSeen();
  seen_slots_.shrink_to_fit();
  have_source_ = false;  // nothing left to trace
}

uint64_t ExactGeodesic::memory_bytes() const {
  auto bytes = [](const auto& v) { return uint64_t{v.capacity()} * sizeof(v[0]); };
  return sizeof(*this) + bytes(dist_) + bytes(via_window_) + bytes(via_vertex_) +
         bytes(angle_src_) + bytes(angle_vtx_) + bytes(emitted_) + bytes(route_) +
         bytes(excluded_) + bytes(touched_) + bytes(floor_at_) + bytes(floored_) +
         bytes(seen_slot_) + bytes(seen_slots_) + bytes(windows_) + bytes(rays_) +
         bytes(free_windows_) + queue_.memory_bytes();
}

absl::StatusOr<std::vector<double>> ExactGeodesic::Distances(const SurfacePoint& source,
                                                             const ExactOptions& options) {
  goal_ = options.goal;
  goal_floor_ = options.goal ? options.goal_floor : nullptr;
  max_window_bytes_ = options.max_window_bytes;
  absl::Status run = Run(source, Mode::kFull, options.max_distance, &options.targets,
                         options.keep_windows, &options.cancelled, 0);
  goal_.reset();
  goal_floor_ = nullptr;
  max_window_bytes_ = 0;
  RETURN_IF_ERROR(run);
  std::vector<double> out(mesh_.num_vertices(), kInf);
  for (VertexId v : touched_) {
    if (dist_[v] <= options.max_distance) out[v] = dist_[v];
  }
  if (!keep_windows_) ReleaseLargeWindows();
  return out;
}

absl::StatusOr<std::vector<DirectHit>> ExactGeodesic::DirectGeodesics(
    const SurfacePoint& source, const DirectOptions& options) {
  RETURN_IF_ERROR(Run(source, Mode::kDirect, options.max_distance, nullptr, options.keep_windows,
                      nullptr, options.epsilon, options.stop_at_corners));
  std::vector<DirectHit> hits;
  hits.reserve(touched_.size());
  const bool vertex_source = source_.kind == SurfacePoint::Kind::kVertex;
  const double source_period = vertex_source ? mesh_.total_angle(source_.id) : kTwoPi;
  for (VertexId v : touched_) {
    if (vertex_source && v == source_.id) continue;
    if (!(dist_[v] <= options.max_distance) || excluded_[v]) continue;
    hits.push_back({v, dist_[v], WrapAngle(angle_src_[v], source_period),
                    WrapAngle(angle_vtx_[v], mesh_.total_angle(v))});
  }
  std::sort(hits.begin(), hits.end(),
            [](const DirectHit& a, const DirectHit& b) { return a.vertex < b.vertex; });
  if (!keep_windows_) ReleaseLargeWindows();
  return hits;
}

ExactGeodesic::Candidate ExactGeodesic::BestCandidate(const SurfacePoint& raw_target) const {
  Candidate best;
  const SurfacePoint target = CanonicalizeSurfacePoint(mesh_, raw_target);
  if (target.kind == SurfacePoint::Kind::kVertex) {
    const VertexId v = target.id;
    if (dist_[v] == kInf) return best;
    best.distance = dist_[v];
    if (have_source_ && source_.kind == SurfacePoint::Kind::kVertex && source_.id == v) {
      best.via = Candidate::Via::kSource;
    } else if (via_window_[v] != kNone) {
      best.via = Candidate::Via::kWindow;
      best.window = via_window_[v];
      const Window& w = windows_[best.window];
      best.local = PlaceFromDistances(mesh_.length(w.h), mesh_.length(Mesh::prev(w.h)),
                                      mesh_.length(Mesh::next(w.h)), true);
    } else if (via_vertex_[v] != kNone) {
      best.via = Candidate::Via::kVertex;
      best.vertex = via_vertex_[v];
    } else {
      best.via = Candidate::Via::kSource;  // seeded straight from a non-vertex source
    }
    return best;
  }

  const Vec3 p = PositionOf(mesh_, target);
  std::vector<FaceId> faces;
  if (target.kind == SurfacePoint::Kind::kFace) {
    faces.push_back(target.id);
  } else {
    const HalfedgeId e = mesh_.edge_halfedge(target.id);
    faces.push_back(Mesh::face(e));
    if (mesh_.twin(e) != kNone) faces.push_back(Mesh::face(mesh_.twin(e)));
  }
  const Vec3 source_xyz = have_source_ ? PositionOf(mesh_, source_) : Vec3{};
  for (FaceId f : faces) {
    for (int k = 0; k < 3; ++k) {
      const VertexId x = mesh_.face_vertex(f, k);
      const bool is_source = source_.kind == SurfacePoint::Kind::kVertex && source_.id == x;
      const bool radiates = is_source || (mode_ == Mode::kFull && emitted_[x]);
      if (radiates && dist_[x] < kInf) {
        double d = dist_[x] + Distance(mesh_.position(x), p);
        if (d < best.distance) {
          best = {};
          best.distance = d;
          best.via = is_source ? Candidate::Via::kSource : Candidate::Via::kVertex;
          best.vertex = x;
        }
      }
    }
    // A non-vertex source in the same face sees the target directly.
    if (source_.kind != SurfacePoint::Kind::kVertex) {
      bool shares = source_.kind == SurfacePoint::Kind::kFace && source_.id == f;
      if (source_.kind == SurfacePoint::Kind::kEdge) {
        const HalfedgeId e = mesh_.edge_halfedge(source_.id);
        shares = Mesh::face(e) == f || (mesh_.twin(e) != kNone && Mesh::face(mesh_.twin(e)) == f);
      }
      if (shares) {
        double d = Distance(source_xyz, p);
        if (d < best.distance) {
          best = {};
          best.distance = d;
          best.via = Candidate::Via::kSource;
        }
      }
    }
  }
  // Windows entering one of the faces.
  for (uint32_t i = 0; i < windows_.size(); ++i) {
    const Window& w = windows_[i];
    const FaceId f = Mesh::face(w.h);
    if (std::find(faces.begin(), faces.end(), f) == faces.end()) continue;
    const double L = mesh_.length(w.h);
    const Vec2 q = PlaceFromDistances(L, Distance(p, mesh_.position(mesh_.tail(w.h))),
                                      Distance(p, mesh_.position(mesh_.head(w.h))), true);
    const double x = CrossingX(w.sx, w.sy, q.x, q.y);
    const double tol = 1e-9 * L;
    if (x < w.b0 - tol || x > w.b1 + tol) continue;
    const double d = w.sigma + Hypot(q.x - w.sx, q.y - w.sy);
    if (d < best.distance) {
      best = {};
      best.distance = d;
      best.via = Candidate::Via::kWindow;
      best.window = i;
      best.local = q;
    }
  }
  return best;
}

absl::StatusOr<double> ExactGeodesic::DistanceTo(const SurfacePoint& target) const {
  if (!have_source_) return absl::FailedPreconditionError("no propagation has run yet");
  RETURN_IF_ERROR(ValidateSurfacePoint(mesh_, target));
  if (target.kind != SurfacePoint::Kind::kVertex && !keep_windows_) {
    return absl::FailedPreconditionError("distances to surface points need keep_windows");
  }
  return BestCandidate(target).distance;
}

absl::StatusOr<std::vector<ExactGeodesic::TracePoint>> ExactGeodesic::Trace(
    const SurfacePoint& raw_target) const {
  if (!have_source_) return absl::FailedPreconditionError("no propagation has run yet");
  if (!keep_windows_) return absl::FailedPreconditionError("Trace needs keep_windows");
  RETURN_IF_ERROR(ValidateSurfacePoint(mesh_, raw_target));
  const SurfacePoint target = CanonicalizeSurfacePoint(mesh_, raw_target);
  std::vector<SurfacePoint> points{target};
  Candidate c = BestCandidate(target);
  if (c.distance == kInf) {
    return absl::NotFoundError("the target is not reachable from the source");
  }
  for (size_t guard = 0; guard <= mesh_.num_vertices() + 1; ++guard) {
    if (c.via == Candidate::Via::kSource) break;
    VertexId next_vertex = c.vertex;
    if (c.via == Candidate::Via::kWindow) {
      uint32_t cur = c.window;
      Vec2 q = c.local;
      while (true) {
        const Window& w = windows_[cur];
        const double L = mesh_.length(w.h);
        double x = std::clamp(CrossingX(w.sx, w.sy, q.x, q.y), 0.0, L);
        if (q.y > kMinWidth * L) {
          const EdgeId e = mesh_.edge(w.h);
          const bool canonical = mesh_.edge_halfedge(e) == w.h;
          points.push_back(SurfacePoint::Edge(e, canonical ? x / L : 1 - x / L));
        }
        if (w.parent == kNone) break;
        // Express the crossing in the parent's frame, where w's edge is one
        // of the two far edges of the parent's face.
        const Window& pw = windows_[w.parent];
        const double Lp = mesh_.length(pw.h);
        const double lb = mesh_.length(Mesh::prev(pw.h)), la = mesh_.length(Mesh::next(pw.h));
        const Vec2 C = PlaceFromDistances(Lp, lb, la, true);
        if (w.h == mesh_.twin(Mesh::prev(pw.h))) {
          q = C * (x / lb);
        } else {
          q = C + (Vec2{Lp, 0} - C) * (x / la);
        }
        cur = w.parent;
      }
      next_vertex = windows_[cur].pseudo;
      if (next_vertex == kNone) break;  // reached the (non-vertex) source
    }
    points.push_back(SurfacePoint::Vertex(next_vertex));
    if (source_.kind == SurfacePoint::Kind::kVertex && next_vertex == source_.id) break;
    c = BestCandidate(SurfacePoint::Vertex(next_vertex));
  }
  if (!(source_.kind == SurfacePoint::Kind::kVertex && points.back().kind == source_.kind &&
        points.back().id == source_.id)) {
    points.push_back(source_);
  }
  std::reverse(points.begin(), points.end());
  std::vector<TracePoint> out;
  out.reserve(points.size());
  for (const SurfacePoint& sp : points) {
    SurfacePoint canon = CanonicalizeSurfacePoint(mesh_, sp);
    Vec3 xyz = PositionOf(mesh_, canon);
    if (!out.empty() && Distance(out.back().xyz, xyz) == 0) continue;
    out.push_back({canon, xyz});
  }
  return out;
}

}  // namespace geodesic
