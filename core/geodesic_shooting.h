// Shooting a straightest geodesic: start at a vertex in a given direction and
// walk straight across faces (unfolding each next face into the plane of the
// last) for a given length. The DGG uses it to place pseudo vertices
// (section 4.3 of the DGG paper).
#ifndef GEODESIC_CORE_GEODESIC_SHOOTING_H_
#define GEODESIC_CORE_GEODESIC_SHOOTING_H_

#include "absl/status/statusor.h"
#include "core/mesh.h"
#include "core/surface_point.h"

namespace geodesic {

struct ShotEnd {
  SurfacePoint point;       // canonical: a face point unless it landed on an edge/vertex
  double length = 0;        // travelled: less than asked if a boundary stopped it
  bool hit_vertex = false;  // passed exactly through a vertex (stopped there)
};

// `polar_angle` is in v's tangent frame (raw radians of its cone, see
// core/mesh.h). INVALID_ARGUMENT for an isolated vertex or a bad angle.
absl::StatusOr<ShotEnd> ShootGeodesic(const Mesh& mesh, VertexId v, double polar_angle,
                                      double length);

}  // namespace geodesic

#endif  // GEODESIC_CORE_GEODESIC_SHOOTING_H_
