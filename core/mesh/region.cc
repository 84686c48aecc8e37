#include "core/mesh/region.h"

#include <algorithm>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"

namespace geodesic {
namespace {

// The mask as a flag per parent vertex (or face).
absl::StatusOr<std::vector<bool>> MaskOf(const Mesh& parent, RegionMask kind,
                                         absl::Span<const uint32_t> ids, std::string_view source) {
  const bool by_vertex = kind == RegionMask::kVertices;
  const size_t limit = by_vertex ? parent.num_vertices() : parent.num_faces();
  std::vector<bool> in_mask(limit, false);
  for (uint32_t id : ids) {
    if (id >= limit) {
      return absl::OutOfRangeError(absl::StrFormat(
          "%s: %s id %u is out of range: the mesh has %u %s", source, by_vertex ? "vertex" : "face",
          id, limit, by_vertex ? "vertices" : "faces"));
    }
    in_mask[id] = true;
  }
  return in_mask;
}

// The parent faces the mask keeps, as a flag per parent face.
absl::StatusOr<std::vector<bool>> KeptFaces(const Mesh& parent, RegionMask kind,
                                            absl::Span<const uint32_t> ids,
                                            std::string_view source) {
  ASSIGN_OR_RETURN(std::vector<bool> in_mask, MaskOf(parent, kind, ids, source));
  if (kind == RegionMask::kFaces) return in_mask;
  std::vector<bool> kept(parent.num_faces(), false);
  for (FaceId f = 0; f < parent.num_faces(); ++f) {
    kept[f] = in_mask[parent.face_vertex(f, 0)] && in_mask[parent.face_vertex(f, 1)] &&
              in_mask[parent.face_vertex(f, 2)];
  }
  return kept;
}

// Mesh::Build would refuse such a vertex too, but in the region's ids; a
// mask is written in the parent's, so the message names the parent's vertex.
absl::Status CheckSingleFans(const Mesh& parent, const std::vector<bool>& kept,
                             std::string_view source) {
  for (VertexId v = 0; v < parent.num_vertices(); ++v) {
    const HalfedgeId start = parent.vertex_halfedge(v);
    if (start == kNone) continue;
    // Runs of kept faces in the rotation; a closed fan that starts inside a
    // run counts that run twice.
    int runs = 0;
    bool previous = false, first = kept[Mesh::face(start)];
    HalfedgeId h = start;
    do {
      const bool k = kept[Mesh::face(h)];
      runs += k && !previous;
      previous = k;
      h = parent.rotate(h);
    } while (h != kNone && h != start);
    if (h == start && first && previous && runs > 1) --runs;
    if (runs > 1) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: the region would be non-manifold at parent vertex %u: its faces there form %d "
          "fans that touch only at that vertex (keep or drop the faces between them)",
          source, v, runs));
    }
  }
  return absl::OkStatus();
}

}  // namespace

uint32_t ParentToRegion::operator[](uint32_t parent_id) const {
  auto it = std::lower_bound(ids_.begin(), ids_.end(), parent_id);
  if (it == ids_.end() || *it != parent_id) return kNone;
  return static_cast<uint32_t>(it - ids_.begin());
}

uint64_t Region::map_bytes() const {
  return (parent_vertex.capacity() + parent_face.capacity()) * sizeof(uint32_t) +
         region_vertex.memory_bytes() + region_face.memory_bytes();
}

absl::StatusOr<std::vector<uint32_t>> DistinctRegionIds(const Mesh& parent, RegionMask kind,
                                                        absl::Span<const uint32_t> ids,
                                                        std::string_view source) {
  ASSIGN_OR_RETURN(std::vector<bool> in_mask, MaskOf(parent, kind, ids, source));
  std::vector<uint32_t> distinct;
  distinct.reserve(std::min(ids.size(), in_mask.size()));
  for (uint32_t id = 0; id < in_mask.size(); ++id) {
    if (in_mask[id]) distinct.push_back(id);
  }
  distinct.shrink_to_fit();
  return distinct;
}

absl::StatusOr<Region> ExtractRegion(const Mesh& parent, RegionMask kind,
                                     absl::Span<const uint32_t> ids, std::string_view source,
                                     const RegionRoom& room) {
  ASSIGN_OR_RETURN(std::vector<bool> kept, KeptFaces(parent, kind, ids, source));
  Region r;
  // Parent-sized only while the region is cut: the maps kept are
  // region-sized.
  std::vector<bool> used(parent.num_vertices(), false);
  for (FaceId f = 0; f < parent.num_faces(); ++f) {
    if (!kept[f]) continue;
    r.parent_face.push_back(f);
    for (int k = 0; k < 3; ++k) used[parent.face_vertex(f, k)] = true;
  }
  if (r.parent_face.empty()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the region is empty: %s", source,
                        kind == RegionMask::kVertices ? "no face has all three vertices in the mask"
                                                      : "the mask lists no face"));
  }
  RETURN_IF_ERROR(CheckSingleFans(parent, kept, source));
  std::vector<bool>().swap(kept);
  std::vector<VertexId> renumbered(parent.num_vertices(), kNone);
  TriangleSoup soup;
  for (VertexId v = 0; v < parent.num_vertices(); ++v) {
    if (!used[v]) continue;
    renumbered[v] = static_cast<VertexId>(r.parent_vertex.size());
    r.parent_vertex.push_back(v);
  }
  std::vector<bool>().swap(used);
  r.parent_vertex.shrink_to_fit();
  r.parent_face.shrink_to_fit();
  if (room) RETURN_IF_ERROR(room(r.parent_vertex.size(), r.parent_face.size()));
  soup.positions.reserve(r.parent_vertex.size());
  for (VertexId v : r.parent_vertex) soup.positions.push_back(parent.position(v));
  soup.triangles.reserve(r.parent_face.size());
  for (FaceId f : r.parent_face) {
    soup.triangles.push_back({renumbered[parent.face_vertex(f, 0)],
                              renumbered[parent.face_vertex(f, 1)],
                              renumbered[parent.face_vertex(f, 2)]});
  }
  std::vector<VertexId>().swap(renumbered);
  ASSIGN_OR_RETURN(Mesh mesh, Mesh::Build(std::move(soup), source));
  r.mesh = std::make_shared<const Mesh>(std::move(mesh));
  r.region_vertex = ParentToRegion(r.parent_vertex, parent.num_vertices());
  r.region_face = ParentToRegion(r.parent_face, parent.num_faces());
  return r;
}

absl::StatusOr<SurfacePoint> PointInRegion(const Mesh& parent, const Region& region,
                                           const SurfacePoint& p) {
  auto outside = [&] {
    return absl::OutOfRangeError(
        absl::StrFormat("%s is outside the region", FormatSurfacePoint(p)));
  };
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex: {
      const VertexId v = region.region_vertex[p.id];
      if (v == kNone) return outside();
      return SurfacePoint::Vertex(v);
    }
    case SurfacePoint::Kind::kFace: {
      const FaceId f = region.region_face[p.id];
      if (f == kNone) return outside();
      return SurfacePoint::Face(f, p.bary[0], p.bary[1], p.bary[2]);
    }
    case SurfacePoint::Kind::kEdge: {
      // The same point seen from a kept face's half-edge; the region may
      // run the edge's canonical half-edge the other way.
      HalfedgeId h = parent.edge_halfedge(p.id);
      double t = p.t;
      if (region.region_face[Mesh::face(h)] == kNone) {
        h = parent.twin(h);
        t = 1 - t;
        if (h == kNone || region.region_face[Mesh::face(h)] == kNone) return outside();
      }
      const HalfedgeId rh = Mesh::halfedge(region.region_face[Mesh::face(h)], Mesh::corner(h));
      const EdgeId e = region.mesh->edge(rh);
      return SurfacePoint::Edge(e, region.mesh->edge_halfedge(e) == rh ? t : 1 - t);
    }
  }
  return outside();
}

}  // namespace geodesic
