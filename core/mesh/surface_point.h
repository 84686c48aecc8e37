// Points on the surface of a mesh: a vertex, a point on an edge, or a point
// inside a face (after geometry-central's SurfacePoint and CGAL's
// Face_location).
//
// Conventions:
// - Face ids are the order of faces in the mesh file; barycentric
//   coordinates (b0, b1, b2) weight the face's vertices in the order the file
//   lists them for that face (the convention of CGAL and libigl).
// - Edge points are (edge id, t): the point (1 - t) * tail + t * head of the
//   edge's canonical half-edge (see core/mesh/mesh.h for edge numbering).
//
// Text form (the CLI, the offline subcommands, pair files):
//   v:ID            a vertex
//   e:EDGE:T        a point on an edge, T in [0, 1]
//   f:FACE:B0,B1,B2 a point in a face; coordinates >= 0 summing to 1
//   xyz:X,Y,Z       a position, snapped to the nearest surface point
#ifndef GEODESIC_CORE_MESH_SURFACE_POINT_H_
#define GEODESIC_CORE_MESH_SURFACE_POINT_H_

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"

namespace geodesic {

struct SurfacePoint {
  enum class Kind : uint8_t { kVertex, kEdge, kFace };
  Kind kind = Kind::kVertex;
  uint32_t id = 0;               // vertex, edge or face id
  double t = 0;                  // edge parameter
  std::array<double, 3> bary{};  // face barycentrics, file corner order

  static SurfacePoint Vertex(VertexId v) { return {Kind::kVertex, v, 0, {}}; }
  static SurfacePoint Edge(EdgeId e, double t) { return {Kind::kEdge, e, t, {}}; }
  static SurfacePoint Face(FaceId f, double b0, double b1, double b2) {
    return {Kind::kFace, f, 0, {b0, b1, b2}};
  }
};

// A parsed text form: either a surface point or a position still to snap.
struct SurfacePointSpec {
  bool is_position = false;
  SurfacePoint point;
  Vec3 position;
};

// Parses the text form above; INVALID_ARGUMENT names the bad part.
absl::StatusOr<SurfacePointSpec> ParseSurfacePointSpec(std::string_view text);
std::string FormatSurfacePoint(const SurfacePoint& p);

// A pairs file: one pair of point specs per line, separated by white space;
// blank lines are skipped. A line with one spec or more than two is
// INVALID_ARGUMENT naming the file and line, so no pair is dropped or made
// up silently. The specs are not parsed here.
using SpecPair = std::pair<std::string, std::string>;
absl::StatusOr<std::vector<SpecPair>> ReadSpecPairs(const std::string& path);

// Checks ids against the mesh (OUT_OF_RANGE) and coordinates (INVALID_ARGUMENT:
// NaN, negative, not summing to 1 within 1e-6, t outside [0, 1]).
absl::Status ValidateSurfacePoint(const Mesh& mesh, const SurfacePoint& p);

// Rewrites degenerate forms into the simplest one: a face point with a
// single non-zero coordinate becomes a vertex, one with a zero coordinate an
// edge point; an edge point at t = 0 or 1 becomes a vertex. Barycentrics are
// renormalised to sum to exactly 1.
SurfacePoint CanonicalizeSurfacePoint(const Mesh& mesh, const SurfacePoint& p);

Vec3 PositionOf(const Mesh& mesh, const SurfacePoint& p);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_SURFACE_POINT_H_
