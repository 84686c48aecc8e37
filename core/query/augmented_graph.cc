#include "core/query/augmented_graph.h"

#include <algorithm>
#include <cmath>
#include <functional>
#include <limits>
#include <numeric>
#include <span>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/exact/exact_geodesic.h"

namespace geodesic::query_internal {

absl::Status CheckPoint(const Mesh& mesh, const SurfacePoint& p, std::string_view what) {
  absl::Status s = ValidateSurfacePoint(mesh, p);
  if (s.ok()) return s;
  return absl::Status(s.code(), absl::StrFormat("%s: %s", what, s.message()));
}

absl::StatusOr<Endpoint> JoinToGraph(const Mesh& mesh, const DggGraph& graph, QueryScratch& sc,
                                     const SurfacePoint& raw, bool keep_windows) {
  Endpoint end;
  end.point = CanonicalizeSurfacePoint(mesh, raw);
  end.xyz = PositionOf(mesh, end.point);
  if (end.point.kind == SurfacePoint::Kind::kVertex) {
    end.is_node = true;
    end.node = graph.node_of_vertex(end.point.id);
    return end;
  }
  DirectOptions options;
  options.epsilon = graph.params().epsilon;
  options.keep_windows = keep_windows;
  ASSIGN_OR_RETURN(std::vector<DirectHit> hits, sc.Exact(mesh).DirectGeodesics(end.point, options));
  end.edges.reserve(hits.size());
  for (const DirectHit& h : hits) {
    end.edges.push_back({h.vertex, graph.node_of_vertex(h.vertex), h.distance});
  }
  return end;
}

// The distance of an end point from a field given in mesh vertex order: at
// its node, or the best of its temporary edges (the last hop of a path that
// enters it through them).
double FieldDistanceTo(const Endpoint& end, absl::Span<const double> field) {
  if (end.is_node) return field[end.point.id];
  double d = kInfinity;
  for (const TemporaryEdge& e : end.edges) d = std::min(d, field[e.vertex] + e.weight);
  return d;
}

ExactOptions ExactWithinGraphAnswer(double graph_distance, const std::function<bool()>& cancelled,
                                    uint64_t max_window_bytes) {
  ExactOptions options;
  options.max_distance = graph_distance * (1 + 1e-9) + 1e-300;
  options.keep_windows = true;
  options.cancelled = cancelled;
  options.max_window_bytes = max_window_bytes;
  return options;
}

absl::StatusOr<std::vector<double>> ExactDistancesWithinGraphAnswer(
    ExactGeodesic& exact, const SurfacePoint& source, absl::Span<const SurfacePoint> targets,
    ExactOptions options) {
  std::vector<double> d(targets.size(), kInfinity);
  const double bound = options.max_distance;
  for (double limit : {bound, 2 * bound, kInfinity}) {
    options.max_distance = limit;
    RETURN_IF_ERROR(exact.Distances(source, options).status());
    for (size_t j = 0; j < targets.size(); ++j) {
      ASSIGN_OR_RETURN(d[j], exact.DistanceTo(targets[j]));
    }
    const bool all_reached = std::find(d.begin(), d.end(), kInfinity) == d.end();
    if (all_reached || limit == kInfinity) break;
  }
  return d;
}

}  // namespace geodesic::query_internal
