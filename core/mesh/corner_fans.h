// The fans of faces around each vertex (one per vertex where the mesh is
// manifold), found from a soup's edge uses, and the repair that splits every
// vertex with more than one.
#ifndef GEODESIC_CORE_MESH_CORNER_FANS_H_
#define GEODESIC_CORE_MESH_CORNER_FANS_H_

#include <cstdint>
#include <numeric>
#include <vector>

#include "core/mesh/mesh.h"

namespace geodesic {

// Union-find over indices.
struct DisjointSets {
  std::vector<uint32_t> parent;
  explicit DisjointSets(size_t n) : parent(n) { std::iota(parent.begin(), parent.end(), 0); }
  uint32_t Find(uint32_t x) {
    while (parent[x] != x) x = parent[x] = parent[parent[x]];
    return x;
  }
  void Union(uint32_t a, uint32_t b) { parent[Find(a)] = Find(b); }
};

// The corner of face f at vertex v, as 3 * f + its position in the face.
uint32_t CornerOf(const TriangleSoup& soup, uint32_t f, VertexId v);

// Every use of an edge by a face, as (UndirectedEdgeKey, corner 3 * face +
// k for the edge from corner k to k + 1), sorted so that the uses of one
// edge are adjacent. Degenerate edges (a face repeating a vertex) are left
// out. One linear pass over them then yields whatever is counted per edge.
EdgeUses SortedEdgeUses(const TriangleSoup& soup);

// Corners joined across every edge with exactly two faces, at both of its
// ends: the classes are the fans of faces around each vertex.
DisjointSets CornerFans(const TriangleSoup& soup, const EdgeUses& uses);

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

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_CORNER_FANS_H_
