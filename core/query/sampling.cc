// Farthest-point sampling of surface vertices by geodesic distance.
#include <algorithm>
#include <random>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/query/geodesic_engine.h"

namespace geodesic {

absl::StatusOr<SampleResult> GeodesicEngine::SamplePoints(int count,
                                                          const SampleOptions& options) const {
  const Mesh& mesh = *mesh_;
  std::vector<VertexId> usable;
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
    if (!mesh.is_isolated(v)) usable.push_back(v);
  }
  if (count < 1 || static_cast<size_t>(count) > usable.size()) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "cannot sample %d points: the mesh has %u vertices on its surface", count, usable.size()));
  }
  std::mt19937_64 rng(options.seed);
  SampleResult result;
  result.vertices.push_back(
      usable[std::uniform_int_distribution<size_t>(0, usable.size() - 1)(rng)]);
  // Distance of each vertex from its nearest sample so far.
  std::vector<double> nearest(mesh.num_vertices(), kInfinity);
  std::vector<bool> chosen(mesh.num_vertices(), false);
  FieldOptions field_options;
  field_options.cancelled = options.cancelled;
  while (true) {
    // Only vertices nearer to the new sample than to every earlier one
    // change, and none of those is farther than the covering radius: the
    // search stops there.
    field_options.max_distance = result.covering_radius;
    const SurfacePoint sample = SurfacePoint::Vertex(result.vertices.back());
    ASSIGN_OR_RETURN(FieldResult field, Field(absl::MakeConstSpan(&sample, 1), field_options));
    chosen[result.vertices.back()] = true;
    // Chosen vertices are at 0, so the farthest unchosen one (there is one
    // while fewer than `usable` are chosen, even where points coincide)
    // gives the covering radius.
    VertexId farthest = kNone;
    for (VertexId v : usable) {
      nearest[v] = std::min(nearest[v], field.distance[v]);
      if (!chosen[v] && (farthest == kNone || nearest[v] > nearest[farthest])) farthest = v;
    }
    result.covering_radius = farthest == kNone ? 0 : nearest[farthest];
    if (result.vertices.size() == static_cast<size_t>(count)) break;
    result.vertices.push_back(farthest);
    if (options.between_points) RETURN_IF_ERROR(options.between_points());
  }
  return result;
}

}  // namespace geodesic
