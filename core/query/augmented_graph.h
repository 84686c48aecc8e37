// The locally augmented graph (Appendix A of the paper): a query's end point
// that is not a graph node joins the graph by temporary edges, its direct
// geodesics to the mesh vertices it sees. Fields, pairs and matrices join
// their points here, so all of them search one augmented graph. Internal to
// core/query/.
#ifndef GEODESIC_CORE_QUERY_AUGMENTED_GRAPH_H_
#define GEODESIC_CORE_QUERY_AUGMENTED_GRAPH_H_

#include <cstdint>
#include <functional>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/base/vec.h"
#include "core/dgg/dgg_graph.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"
#include "core/query/geodesic_engine.h"
#include "core/query/query_scratch.h"

namespace geodesic::query_internal {

constexpr uint32_t kViaSource = kNone;         // reached from a source node itself
constexpr uint32_t kViaTemporary = kNone - 1;  // reached by a temporary edge

// Direct edges from a point that is not a graph node to mesh vertices
// (Appendix A: the locally augmented graph).
struct TemporaryEdge {
  VertexId vertex;
  uint32_t node;  // the vertex's graph node
  double weight;
};

// OK, or the point's problem prefixed by `what` ("first point", "source 3").
absl::Status CheckPoint(const Mesh& mesh, const SurfacePoint& p, std::string_view what);

// One end of a query (a field's source, a pair's point, a matrix's row or
// column): a graph node, or a point joined to the graph by temporary edges.
struct Endpoint {
  SurfacePoint point;
  Vec3 xyz;
  bool is_node = false;
  uint32_t node = kNone;
  std::vector<TemporaryEdge> edges;
};

// Joins `raw` to the graph: a vertex is its own node; any other point runs
// the exact engine's direct propagation, whose lit vertices become its
// temporary edges. With `keep_windows` the propagation stays in the
// scratch's exact engine, so that its DistanceTo then answers direct
// geodesic distances from the point (the same-face and nearby cases no path
// through vertices gets right).
absl::StatusOr<Endpoint> JoinToGraph(const Mesh& mesh, const DggGraph& graph, QueryScratch& sc,
                                     const SurfacePoint& raw, bool keep_windows);

// The distance of an end point from a field given in mesh vertex order: at
// its node, or the best of its temporary edges (the last hop of a path that
// enters it through them).
double FieldDistanceTo(const Endpoint& end, absl::Span<const double> field);

// The options of an exact propagation bounded by a graph answer
// `graph_distance`: a graph answer is the length of a real surface path, so
// it bounds the exact distance from above; the slack covers rounding in the
// propagation's own sums. Windows are kept for DistanceTo and Trace, up to
// `max_window_bytes` (0: no limit).
ExactOptions ExactWithinGraphAnswer(double graph_distance, const std::function<bool()>& cancelled,
                                    uint64_t max_window_bytes);

// Exact distances from `source` to each of `targets` by a propagation with
// `options` (ExactWithinGraphAnswer's); +inf where even an unbounded one does
// not reach. A target the bounded run leaves unreached has a graph answer
// below its exact distance: rounding past the slack, or a graph file whose
// weights are too short. That answer bounds nothing, so the run is made again
// within twice the bound (a rounding miss costs one more run of about the
// same sweep), then without one; `exact` keeps the last run.
absl::StatusOr<std::vector<double>> ExactDistancesWithinGraphAnswer(
    ExactGeodesic& exact, const SurfacePoint& source, absl::Span<const SurfacePoint> targets,
    ExactOptions options);

}  // namespace geodesic::query_internal

#endif  // GEODESIC_CORE_QUERY_AUGMENTED_GRAPH_H_
