// Reading meshes (OBJ, OFF, PLY ascii/binary, STL) into a TriangleSoup with
// the file's own vertex and face order, diagnostics of what was read, and the
// conversion to a Mesh.
#ifndef GEODESIC_CORE_MESH_IO_H_
#define GEODESIC_CORE_MESH_IO_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/mesh.h"

namespace geodesic {

struct MeshDiagnostics {
  std::string path;
  std::string format;  // "obj", "off", "ply", "stl"
  uint64_t vertices = 0;
  uint64_t faces = 0;  // triangles after triangulating polygons
  uint64_t edges = 0;
  uint64_t polygons_triangulated = 0;  // input faces with more than 3 sides
  uint64_t components = 0;             // connected components of faces
  uint64_t boundary_loops = 0;
  int64_t genus = 0;  // meaningful only when manifold
  uint64_t isolated_vertices = 0;
  uint64_t duplicate_vertices = 0;  // exactly equal coordinates
  uint64_t zero_area_faces = 0;
  uint64_t near_degenerate_faces = 0;
  uint64_t non_manifold_edges = 0;
  uint64_t non_manifold_vertices = 0;
  uint64_t faces_refused = 0;  // faces OpenMesh's own kernel would refuse
  double bbox_diagonal = 0;
  double mean_edge_length = 0;
  double min_edge_length = 0;
  double anisotropy_mean = 0;
  double anisotropy_p95 = 0;
  double anisotropy_max = 0;
  uint64_t saddle_vertices = 0;
  uint64_t boundary_vertices = 0;
  bool manifold = false;
  double load_seconds = 0;
  std::string mesh_error;  // why Mesh::Build refused it, empty if usable

  std::string ToJson() const;
  std::string ToText() const;
};

struct LoadOptions {
  // Split non-manifold vertices into one copy per fan (copies get new ids
  // after the file's vertices) instead of rejecting the mesh.
  bool repair_non_manifold = false;
};

// A vertex that SplitNonManifoldVertices added: a copy of `original` for one
// of its fans.
struct VertexCopy {
  VertexId original;
  VertexId copy;
};
// Splits every non-manifold vertex into one copy per fan of its corners;
// copies are appended after the file's vertices so file ids are unchanged.
// Returns the copies made (none for a manifold soup).
std::vector<VertexCopy> SplitNonManifoldVertices(TriangleSoup* soup);

// The format a path names by its extension, lower case ("ply" for a.PLY).
std::string MeshFormatOfPath(const std::string& path);

// Reads the file as it is. NOT_FOUND / PERMISSION_DENIED for a missing or
// unreadable file; INVALID_ARGUMENT for an unknown format, an empty or
// truncated file, NaN/Inf coordinates or out-of-range indices, naming the
// file, the problem and the first offending element.
absl::StatusOr<TriangleSoup> ReadTriangleSoup(const std::string& path,
                                              MeshDiagnostics* diagnostics = nullptr);

// The same from bytes in memory (uploads); `format` is "obj", "off", "ply" or
// "stl", and `name` is used in messages.
absl::StatusOr<TriangleSoup> ReadTriangleSoupFromMemory(std::string_view bytes,
                                                        std::string_view format,
                                                        std::string_view name,
                                                        MeshDiagnostics* diagnostics = nullptr);

// INVALID_ARGUMENT naming `name` when the soup has no triangle: a point
// cloud parses, but no distance on it is defined, and such a file is as
// often a torn copy of a mesh.
absl::Status RequireFaces(const TriangleSoup& soup, std::string_view name);

// Fills the topological and geometric fields of `diagnostics` from a soup.
void ComputeDiagnostics(const TriangleSoup& soup, MeshDiagnostics* diagnostics);

// ReadTriangleSoup + ComputeDiagnostics + RequireFaces + Mesh::Build (with
// optional repair). A refusal after reading leaves the diagnostics filled,
// with mesh_error saying why.
absl::StatusOr<Mesh> LoadMesh(const std::string& path, const LoadOptions& options = {},
                              MeshDiagnostics* diagnostics = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_IO_H_
