// Shooting a straightest geodesic: start at a vertex in a given direction and
// walk straight across faces (unfolding each next face into the plane of the
// last) for a given length. The DGG uses it to place pseudo vertices
// (section 4.3 of the DGG paper).
#ifndef GEODESIC_CORE_EXACT_GEODESIC_SHOOTING_H_
#define GEODESIC_CORE_EXACT_GEODESIC_SHOOTING_H_

#include <array>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/vec.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

// The faces a shot crossed, unfolded into one plane with the shooting vertex
// at the origin: each edge it crossed, in order, with its end vertices' ids
// and images, and the corners of the face it ended in. A segment inside this
// strip is a path on the surface, so its length bounds a geodesic distance
// from above.
struct ShotStrip {
  struct Portal {
    VertexId a, b;
    Vec2 image_a, image_b;
  };
  std::vector<Portal> portals;
  std::array<VertexId, 3> last_face{};
  std::array<Vec2, 3> last_images{};
  Vec2 end;  // the shot's end point

  // An upper bound on the surface distance from w to the end point: the
  // straight segment from w's image when it stays in the strip, else
  // infinity. w must be a vertex of the strip.
  double StraightDistanceToEnd(VertexId w) const;
  // Every vertex of the strip but the shooting one, each once.
  std::vector<VertexId> Vertices(VertexId shooter) const;
};

struct ShotEnd {
  SurfacePoint point;       // canonical: a face point unless it landed on an edge/vertex
  double length = 0;        // travelled: less than asked if a boundary stopped it
  bool hit_vertex = false;  // passed exactly through a vertex (stopped there)
};

// `polar_angle` is in v's tangent frame (raw radians of its cone, see
// core/mesh/mesh.h). INVALID_ARGUMENT for an isolated vertex or a bad angle.
// With `strip`, also records the faces crossed (cleared first).
absl::StatusOr<ShotEnd> ShootGeodesic(const Mesh& mesh, VertexId v, double polar_angle,
                                      double length, ShotStrip* strip = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_EXACT_GEODESIC_SHOOTING_H_
