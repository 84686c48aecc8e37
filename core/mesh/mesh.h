// A compact, immutable triangle mesh in half-edge form, stored as flat arrays.
//
// Conventions (shared by every algorithm, the graph file and the API):
// - Vertex ids and face ids are the order of the vertices and faces in the
//   mesh file. Corner k of face f is the k-th vertex the file lists for f.
// - Half-edges are implicit: h = 3 * f + k runs from corner k to corner
//   (k + 1) % 3 of face f, so next/prev/face/tail need no storage. Only the
//   twin (kNone on the boundary) and the undirected edge id are stored.
// - Edge ids number the undirected edges in order of first appearance when the
//   faces are scanned in file order, corners in order. The canonical half-edge
//   of an edge is that first appearance; "edge e at t" is the point
//   (1 - t) * tail + t * head of the canonical half-edge.
// - Around each vertex, outgoing half-edges are visited by h -> twin(prev(h)).
//   On a boundary vertex the rotation starts at the outgoing boundary
//   half-edge, so it visits every face of the (single) fan. The polar angle of
//   an outgoing half-edge is the sum of the corner angles before it in this
//   rotation: the vertex's intrinsic tangent frame, in radians of the cone
//   (total_angle(v) may differ from 2*pi).
#ifndef GEODESIC_CORE_MESH_MESH_H_
#define GEODESIC_CORE_MESH_MESH_H_

#include <array>
#include <cstdint>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "core/base/vec.h"

namespace geodesic {

using VertexId = uint32_t;
using FaceId = uint32_t;
using HalfedgeId = uint32_t;
using EdgeId = uint32_t;
inline constexpr uint32_t kNone = 0xffffffffu;

// The same key for both directions of the edge between a and b: the smaller
// id in the high half.
inline uint64_t UndirectedEdgeKey(VertexId a, VertexId b) {
  return (uint64_t{a < b ? a : b} << 32) | (a < b ? b : a);
}

// Sorts (UndirectedEdgeKey, index) pairs, listed in increasing index order,
// into the order std::sort gives pairs, so the uses of one edge are
// adjacent. A radix sort on the keys' significant bits: a comparison sort
// was a large part of loading a million-face mesh.
using EdgeUses = std::vector<std::pair<uint64_t, uint32_t>>;
void SortEdgeUses(EdgeUses& uses, size_t num_vertices);

// Calls body(first, last) for each edge's run [first, last) of sorted uses.
template <typename Body>
void ForEachEdge(const EdgeUses& uses, Body body) {
  for (size_t i = 0, j; i < uses.size(); i = j) {
    for (j = i + 1; j < uses.size() && uses[j].first == uses[i].first; ++j) {
    }
    body(i, j);
  }
}

// The lengths a mesh may have, in its own units: Mesh::Build refuses one
// with a non-zero edge shorter than kMinEdgeLength or a bounding-box
// diagonal longer than kMaxMeshDiagonal. Graph weights are float32, whose
// normal numbers span about 1.2e-38 to 3.4e38: below, weights lose bits or
// vanish (graph distances then far off the exact ones); above, they become
// infinite (connected points unreachable). The exact engine works in double
// but takes up to fourth powers of lengths (Heron's product), which leave
// double's normal range below about 1e-77 and above 1e77. Eight decades of
// margin inside float32's range keep weights normal for pieces much shorter
// than the shortest edge (epsilon fractions, pseudo vertices) and sums much
// longer than the diagonal, and keep every fourth power far inside double's.
inline constexpr double kMinEdgeLength = 1e-30;
inline constexpr double kMaxMeshDiagonal = 1e30;

// Vertices and triangles exactly as a file lists them.
struct TriangleSoup {
  std::vector<Vec3> positions;
  std::vector<std::array<VertexId, 3>> triangles;
};

class Mesh {
 public:
  Mesh() = default;

  // Builds the half-edge structure. Fails with INVALID_ARGUMENT naming the
  // first offending element for out-of-range indices, non-finite coordinates,
  // faces with a repeated vertex, non-manifold edges or vertices, and
  // inconsistently oriented neighbours, and for lengths outside the usable
  // range (kMinEdgeLength, kMaxMeshDiagonal). `source` names the input in
  // messages.
  static absl::StatusOr<Mesh> Build(TriangleSoup soup, std::string_view source);

  size_t num_vertices() const { return a_.positions.size(); }
  size_t num_faces() const { return a_.corners.size() / 3; }
  size_t num_halfedges() const { return a_.corners.size(); }
  size_t num_edges() const { return a_.edge_halfedge.size(); }

  const Vec3& position(VertexId v) const { return a_.positions[v]; }
  const std::vector<Vec3>& positions() const { return a_.positions; }
  VertexId face_vertex(FaceId f, int k) const { return a_.corners[3 * f + k]; }
  const std::vector<VertexId>& corners() const { return a_.corners; }

  static HalfedgeId halfedge(FaceId f, int k) { return 3 * f + k; }
  static FaceId face(HalfedgeId h) { return h / 3; }
  static int corner(HalfedgeId h) { return h % 3; }
  static HalfedgeId next(HalfedgeId h) { return h % 3 == 2 ? h - 2 : h + 1; }
  static HalfedgeId prev(HalfedgeId h) { return h % 3 == 0 ? h + 2 : h - 1; }
  VertexId tail(HalfedgeId h) const { return a_.corners[h]; }
  VertexId head(HalfedgeId h) const { return a_.corners[next(h)]; }
  // The vertex of face(h) not on h.
  VertexId opposite(HalfedgeId h) const { return a_.corners[prev(h)]; }
  HalfedgeId twin(HalfedgeId h) const { return a_.twin[h]; }
  EdgeId edge(HalfedgeId h) const { return a_.edge[h]; }
  HalfedgeId edge_halfedge(EdgeId e) const { return a_.edge_halfedge[e]; }

  double length(HalfedgeId h) const { return a_.length[h]; }
  // Interior angle of face(h) at tail(h).
  double corner_angle(HalfedgeId h) const { return a_.corner_angle[h]; }
  // Polar angle of outgoing half-edge h in tail(h)'s tangent frame.
  double polar_angle(HalfedgeId h) const { return a_.polar_angle[h]; }

  // An outgoing half-edge of v that starts the rotation (kNone if isolated).
  HalfedgeId vertex_halfedge(VertexId v) const { return a_.vertex_halfedge[v]; }
  // Rotation step around tail(h); kNone past the last face of a boundary fan.
  HalfedgeId rotate(HalfedgeId h) const { return a_.twin[prev(h)]; }
  double total_angle(VertexId v) const { return a_.total_angle[v]; }
  bool is_boundary(VertexId v) const { return a_.flags[v] & kBoundary; }
  bool is_isolated(VertexId v) const { return a_.vertex_halfedge[v] == kNone; }
  // Saddle (cone angle above 2*pi) or boundary: a geodesic may bend here, so
  // exact propagation treats it as a pseudo-source.
  bool is_saddle_or_boundary(VertexId v) const { return a_.flags[v] & (kSaddle | kBoundary); }
  bool is_saddle(VertexId v) const { return a_.flags[v] & kSaddle; }

  // Position of the point at parameter t along half-edge h.
  Vec3 point_on_halfedge(HalfedgeId h, double t) const {
    return position(tail(h)) * (1 - t) + position(head(h)) * t;
  }
  // Structural consistency checks (twin of twin, next cycles, angle
  // sums); used by tests and by graph validation.
  absl::Status CheckConsistency() const;
  // Bytes the mesh's arrays hold, for memory budgets.
  uint64_t memory_bytes() const;
  // About memory_bytes() of a mesh of this many vertices and faces, before
  // it is built (a closed mesh's edge count): to refuse one that cannot fit
  // a budget without building it.
  static uint64_t EstimateMemoryBytes(uint64_t vertices, uint64_t faces);

  // Everything a built mesh holds, for saving it and restoring it without
  // rebuilding (core/mesh/mesh_snapshot.h).
  struct Arrays {
    std::vector<Vec3> positions;
    std::vector<VertexId> corners;
    std::vector<HalfedgeId> twin;
    std::vector<EdgeId> edge;
    std::vector<HalfedgeId> edge_halfedge;
    std::vector<double> length;
    std::vector<double> corner_angle;
    std::vector<double> polar_angle;
    std::vector<HalfedgeId> vertex_halfedge;
    std::vector<double> total_angle;
    std::vector<uint8_t> flags;
  };
  const Arrays& arrays() const { return a_; }
  // Restores a mesh from arrays() of a built one. Checks every size, every
  // index range and CheckConsistency(), so damaged arrays give DATA_LOSS
  // naming `source`, never a mesh that reads out of bounds.
  static absl::StatusOr<Mesh> FromArrays(Arrays arrays, std::string_view source);

 private:
  enum Flag : uint8_t { kBoundary = 1, kSaddle = 2 };

  // The steps of Build after the corners and positions are in place, in
  // this order: each reads what the ones before it filled in.
  absl::Status LinkTwins(std::string_view source);       // twin
  void NumberEdges();                                    // edge, edge_halfedge
  void MeasureCorners();                                 // length, corner_angle
  absl::Status WalkVertexFans(std::string_view source);  // the per-vertex rest

  Arrays a_;
};

// Hash of the mesh's positions and faces (xxHash64): a graph is only ever used
// with the mesh it was built for, and a snapshot only restores the mesh it saved.
uint64_t MeshFingerprint(const Mesh& mesh);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_MESH_H_
