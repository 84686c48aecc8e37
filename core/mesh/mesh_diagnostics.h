// What a mesh file holds, measured: counts, topology (components, boundary
// loops, genus, non-manifold elements), face shapes and what OpenMesh's own
// kernel would refuse; as text for people and JSON for scripts.
#ifndef GEODESIC_CORE_MESH_MESH_DIAGNOSTICS_H_
#define GEODESIC_CORE_MESH_MESH_DIAGNOSTICS_H_

#include <cstdint>
#include <string>

#include "core/mesh/mesh.h"

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

  // One JSON object: the fields above in their order, plus "usable" (no
  // mesh_error) before mesh_error; the keys of `geodesicd info --json`.
  // Counts are integers and measures floats (0.0, never 0); a non-finite
  // measure is null, strings that are not UTF-8 get U+FFFD.
  std::string ToJson() const;
  std::string ToText() const;
};

// Fills the topological and geometric fields of `diagnostics` from a soup.
void ComputeDiagnostics(const TriangleSoup& soup, MeshDiagnostics* diagnostics);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_MESH_DIAGNOSTICS_H_
