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

#include <cstddef>
#include <cstdint>
#include <functional>
#include <iterator>
#include <limits>
#include <memory>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

enum class RegionMask { kVertices, kFaces };

// Parent ids -> region ids, kNone outside, as a table indexed by the
// parent's ids reads, but holding only the region's parent ids (increasing,
// so a region id is a position, found by binary search): a region of a few
// faces of a million-vertex mesh would otherwise keep megabytes of kNone.
class ParentToRegion {
 public:
  ParentToRegion() = default;
  // `parent_ids` increasing, each below `parent_count`.
  ParentToRegion(std::vector<uint32_t> parent_ids, uint32_t parent_count)
      : ids_(std::move(parent_ids)), parent_count_(parent_count) {}

  uint32_t operator[](uint32_t parent_id) const;
  // The parent's count, as the table's size was.
  size_t size() const { return parent_count_; }
  uint64_t memory_bytes() const { return ids_.capacity() * sizeof(uint32_t); }

  // Every parent id's region id (kNone outside) in parent order, one step
  // each, as a walk over the table gave them.
  class const_iterator {
   public:
    using iterator_category = std::forward_iterator_tag;
    using value_type = uint32_t;
    using difference_type = std::ptrdiff_t;
    using pointer = void;
    using reference = uint32_t;
    const_iterator() = default;
    uint32_t operator*() const { return Inside() ? next_ : kNone; }
    const_iterator& operator++() {
      next_ += Inside();
      ++parent_id_;
      return *this;
    }
    const_iterator operator++(int) {
      const_iterator before = *this;
      ++*this;
      return before;
    }
    friend bool operator==(const const_iterator& a, const const_iterator& b) {
      return a.parent_id_ == b.parent_id_;
    }

   private:
    friend class ParentToRegion;
    const_iterator(const std::vector<uint32_t>* ids, uint32_t parent_id)
        : ids_(ids), parent_id_(parent_id) {}
    bool Inside() const { return next_ < ids_->size() && (*ids_)[next_] == parent_id_; }
    const std::vector<uint32_t>* ids_ = nullptr;
    uint32_t parent_id_ = 0;
    uint32_t next_ = 0;  // the first region id whose parent id is not below parent_id_
  };
  const_iterator begin() const { return const_iterator(&ids_, 0); }
  const_iterator end() const { return const_iterator(&ids_, parent_count_); }

 private:
  std::vector<uint32_t> ids_;
  uint32_t parent_count_ = 0;
};

struct Region {
  std::shared_ptr<const Mesh> mesh;     // shared, as queries take their mesh
  std::vector<VertexId> parent_vertex;  // region vertex -> parent vertex
  ParentToRegion region_vertex;         // parent vertex -> region vertex, kNone outside
  std::vector<FaceId> parent_face;      // region face -> parent face
  ParentToRegion region_face;           // parent face -> region face, kNone outside

  // The maps' bytes, beside the mesh's (Mesh::memory_bytes): region-sized,
  // whatever the parent's size.
  uint64_t map_bytes() const;
};

// A mask's ids once each, in increasing order, in time linear in the ids
// and the parent's count (a bitmap, no sort): the region they make is the
// mask's, as order and repeats never matter. OUT_OF_RANGE names the first
// id past the parent's vertices (or faces) and their count.
absl::StatusOr<std::vector<uint32_t>> DistinctRegionIds(const Mesh& parent, RegionMask kind,
                                                        absl::Span<const uint32_t> ids,
                                                        std::string_view source);

// Asked with the region's counts once they are known and before its mesh is
// built (which takes several times the mesh's bytes): an error refuses the
// region.
using RegionRoom = std::function<absl::Status(uint64_t vertices, uint64_t faces)>;

// Ids may repeat and come in any order. OUT_OF_RANGE names the first id past
// the parent's vertices (or faces) and their count; INVALID_ARGUMENT for a
// region with no face, or one the half-edge structure refuses (a vertex
// where two parts of the region touch only at that vertex is non-manifold),
// naming the parent's vertex. `source` names the region in messages.
absl::StatusOr<Region> ExtractRegion(const Mesh& parent, RegionMask kind,
                                     absl::Span<const uint32_t> ids, std::string_view source,
                                     const RegionRoom& room = {});

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
