// A graph's accuracy on its own mesh, measured against the exact engine.
//
// The DGG's promise is relative: a graph distance is at least the exact
// geodesic distance (edges are real surface paths, rounded up) and at most
// about (1 + eps) of it. This module measures both sides from chosen
// sources at every vertex, together with a property of the exact field
// itself (never shorter than the straight line), so that a user can see what
// a graph delivers on a mesh nobody has checked before, and so that a miss
// by either engine shows up as a count, not as a silently wrong number.
#ifndef GEODESIC_CORE_QUERY_ACCURACY_CHECK_H_
#define GEODESIC_CORE_QUERY_ACCURACY_CHECK_H_

#include <cstdint>
#include <functional>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

// Relative slack for the inequalities that must hold exactly: only rounding
// may cross them. Both engines compute in double precision, but a needle
// triangle unfolds with errors well above double rounding (though below this
// slack), and a real miss is orders of magnitude larger (graph edges are
// rounded up to float).
inline constexpr double kCheckRoundingSlack = 1e-10;

// One source's field from the graph against the exact one, vertex by vertex.
struct FieldComparison {
  uint64_t compared = 0;  // vertices with a finite, positive exact distance
  // (graph - exact) / exact over the compared vertices.
  double max_error = 0;
  double min_error = 0;  // never below -kCheckRoundingSlack in a sound field
  double mean_error = 0;
  VertexId worst_vertex = kNone;  // where max_error is attained
  // Vertices whose graph distance is below the exact one (beyond rounding):
  // either the exact engine missed a geodesic or a graph edge is too short.
  uint64_t below_exact = 0;
  VertexId first_below_exact = kNone;
  // Vertices only one side reaches: the graph leaves out part of a component
  // the surface connects (graph_unreached), or the exact engine does
  // (exact_unreached).
  uint64_t graph_unreached = 0;
  uint64_t exact_unreached = 0;
  // Vertices whose exact distance is below the straight line to the source.
  uint64_t below_straight = 0;
  // A vertex source's own distance, which must be 0 on both sides.
  bool source_nonzero = false;

  // True when no inequality that must hold is broken.
  bool sound() const {
    return below_exact == 0 && graph_unreached == 0 && exact_unreached == 0 &&
           below_straight == 0 && !source_nonzero;
  }
};

// Compares `graph` against `exact` (both per mesh vertex, +inf unreached)
// for a field from `source`.
FieldComparison CompareFields(const Mesh& mesh, const SurfacePoint& source,
                              absl::Span<const double> exact, absl::Span<const double> graph);

struct AccuracyCheckOptions {
  // Sources are checked in parallel on this many threads (0: all cores).
  int threads = 0;
  // Polled between and during sources; returning true aborts with CANCELLED.
  std::function<bool()> cancelled;
  // Called once for each source whose check is complete, from the thread
  // that checked it (for progress reports).
  std::function<void()> source_done;
};

struct SourceCheck {
  SurfacePoint source;
  FieldComparison comparison;
  double exact_seconds = 0;
  double graph_seconds = 0;
};

// The graph's field from each source against the exact engine's. Sources
// are validated (OUT_OF_RANGE / INVALID_ARGUMENT naming the source).
absl::StatusOr<std::vector<SourceCheck>> CheckAgainstExact(
    std::shared_ptr<const Mesh> mesh, std::shared_ptr<const DggGraph> graph,
    absl::Span<const SurfacePoint> sources, const AccuracyCheckOptions& options = {});

// `count` distinct vertices that lie on some face, drawn with `seed`: the
// same seed gives the same sources on the same mesh. Fewer when the mesh has
// fewer such vertices.
std::vector<VertexId> RandomSurfaceVertices(const Mesh& mesh, int count, uint64_t seed);

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_ACCURACY_CHECK_H_
