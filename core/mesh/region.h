// A region of a mesh (everything but the medial wall, one lobe, ...) as a
// mesh of its own that remembers where it came from, so that distances on it
// never leave the region and its results can be written back in the parent's
// vertex ids.
//
// The region's faces are the given faces, or, from a vertex mask, the faces
// whose three vertices are all in the mask; its vertices are the ones those
// faces use, numbered in increasing parent order, and its faces keep the
// parent's order and corner order (so a face point's barycentrics mean the
// same on both). A vertex mask can thus lose vertices that no kept face uses.
#ifndef GEODESIC_CORE_MESH_REGION_H_
#define GEODESIC_CORE_MESH_REGION_H_

#include <cstdint>
#include <limits>
#include <memory>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

enum class RegionMask { kVertices, kFaces };

struct Region {
  std::shared_ptr<const Mesh> mesh;     // shared, as queries take their mesh
  std::vector<VertexId> parent_vertex;  // region vertex -> parent vertex
  std::vector<VertexId> region_vertex;  // parent vertex -> region vertex, kNone outside
  std::vector<FaceId> parent_face;      // region face -> parent face
  std::vector<FaceId> region_face;      // parent face -> region face, kNone outside
};

// Ids may repeat and come in any order. OUT_OF_RANGE names the first id past
// the parent's vertices (or faces) and their count; INVALID_ARGUMENT for a
// region with no face, or one the half-edge structure refuses (a vertex
// where two parts of the region touch only at that vertex is non-manifold),
// naming the parent's vertex. `source` names the region in messages.
absl::StatusOr<Region> ExtractRegion(const Mesh& parent, RegionMask kind,
                                     absl::Span<const uint32_t> ids, std::string_view source);

// One value per region vertex (a field, a matrix row, labels), as one per
// parent vertex: `fill` outside the region, +inf for distances (outside is
// unreachable from inside), NaN where a consumer must tell the two apart.
template <typename T>
std::vector<T> ScatterToParent(const Region& region, absl::Span<const T> values, T fill) {
  std::vector<T> out(region.region_vertex.size(), fill);
  for (size_t i = 0; i < values.size() && i < region.parent_vertex.size(); ++i) {
    out[region.parent_vertex[i]] = values[i];
  }
  return out;
}
inline std::vector<double> ScatterToParent(const Region& region, absl::Span<const double> values) {
  return ScatterToParent(region, values, std::numeric_limits<double>::infinity());
}

// A valid point of the parent as the same point of the region; OUT_OF_RANGE
// naming the point when it is not on the region (an edge point counts when
// either face beside the edge is kept).
absl::StatusOr<SurfacePoint> PointInRegion(const Mesh& parent, const Region& region,
                                           const SurfacePoint& p);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_REGION_H_
