#include "core/mesh/surface_locator.h"

#include <cmath>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "nanoflann.hpp"

namespace geodesic {
namespace {

// Closest point to p on triangle (a, b, c) as barycentric weights (Ericson,
// Real-Time Collision Detection, 5.1.5: Voronoi regions of the triangle).
std::array<double, 3> ClosestBarycentric(const Vec3& p, const Vec3& a, const Vec3& b,
                                         const Vec3& c) {
  const Vec3 ab = b - a, ac = c - a, ap = p - a;
  const double d1 = Dot(ab, ap), d2 = Dot(ac, ap);
  if (d1 <= 0 && d2 <= 0) return {1, 0, 0};
  const Vec3 bp = p - b;
  const double d3 = Dot(ab, bp), d4 = Dot(ac, bp);
  if (d3 >= 0 && d4 <= d3) return {0, 1, 0};
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) {
    const double v = d1 / (d1 - d3);
    return {1 - v, v, 0};
  }
  const Vec3 cp = p - c;
  const double d5 = Dot(ab, cp), d6 = Dot(ac, cp);
  if (d6 >= 0 && d5 <= d6) return {0, 0, 1};
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) {
    const double w = d2 / (d2 - d6);
    return {1 - w, 0, w};
  }
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    const double w = (d4 - d3) / ((d4 - d3) + (d5 - d6));
    return {0, 1 - w, w};
  }
  const double denom = va + vb + vc;
  if (!(denom > 0)) return {1, 0, 0};  // degenerate face: its first corner
  const double v = vb / denom, w = vc / denom;
  return {1 - v - w, v, w};
}

}  // namespace

struct SurfaceLocator::Index {
  const Mesh* mesh;
  std::vector<Vec3> centroids;
  double max_radius = 0;  // largest centroid-to-corner distance

  size_t kdtree_get_point_count() const { return centroids.size(); }
  double kdtree_get_pt(size_t i, size_t dim) const {
    return dim == 0 ? centroids[i].x : dim == 1 ? centroids[i].y : centroids[i].z;
  }
  template <class BBox>
  bool kdtree_get_bbox(BBox&) const {
    return false;
  }
  using Tree = nanoflann::KDTreeSingleIndexAdaptor<nanoflann::L2_Simple_Adaptor<double, Index>,
                                                   Index, 3, uint32_t>;
  std::unique_ptr<Tree> tree;
};

SurfaceLocator::SurfaceLocator(std::unique_ptr<Index> index) : index_(std::move(index)) {}
SurfaceLocator::SurfaceLocator(SurfaceLocator&&) noexcept = default;
SurfaceLocator& SurfaceLocator::operator=(SurfaceLocator&&) noexcept = default;
SurfaceLocator::~SurfaceLocator() = default;

absl::StatusOr<SurfaceLocator> SurfaceLocator::Build(const Mesh& mesh) {
  if (mesh.num_faces() == 0) return absl::InvalidArgumentError("the mesh has no faces to snap to");
  auto index = std::make_unique<Index>();
  index->mesh = &mesh;
  index->centroids.resize(mesh.num_faces());
  for (FaceId f = 0; f < mesh.num_faces(); ++f) {
    const Vec3 &a = mesh.position(mesh.face_vertex(f, 0)),
               &b = mesh.position(mesh.face_vertex(f, 1)),
               &c = mesh.position(mesh.face_vertex(f, 2));
    const Vec3 m = (a + b + c) * (1.0 / 3);
    index->centroids[f] = m;
    index->max_radius =
        std::max({index->max_radius, Distance(m, a), Distance(m, b), Distance(m, c)});
  }
  index->tree =
      std::make_unique<Index::Tree>(3, *index, nanoflann::KDTreeSingleIndexAdaptorParams(16));
  index->tree->buildIndex();
  return SurfaceLocator(std::move(index));
}

absl::StatusOr<SurfacePoint> SurfaceLocator::Snap(const Vec3& position) const {
  if (!std::isfinite(position.x) || !std::isfinite(position.y) || !std::isfinite(position.z)) {
    return absl::InvalidArgumentError("cannot snap a non-finite position");
  }
  const Mesh& mesh = *index_->mesh;
  const double q[3] = {position.x, position.y, position.z};
  // The nearest centroid's face bounds the answer; any face holding a closer
  // point has its centroid within that bound plus the largest face radius.
  uint32_t nearest = 0;
  double nearest_sq = 0;
  index_->tree->knnSearch(q, 1, &nearest, &nearest_sq);
  auto closest_in = [&](FaceId f, std::array<double, 3>* bary) {
    const Vec3 &a = mesh.position(mesh.face_vertex(f, 0)),
               &b = mesh.position(mesh.face_vertex(f, 1)),
               &c = mesh.position(mesh.face_vertex(f, 2));
    *bary = ClosestBarycentric(position, a, b, c);
    return Distance(position, a * (*bary)[0] + b * (*bary)[1] + c * (*bary)[2]);
  };
  std::array<double, 3> best_bary;
  FaceId best_face = nearest;
  double best = closest_in(nearest, &best_bary);
  const double radius = best + index_->max_radius;
  std::vector<std::pair<uint32_t, double>> matches;
  index_->tree->radiusSearch(q, radius * radius * (1 + 1e-12), matches, nanoflann::SearchParams());
  for (const auto& [f, unused] : matches) {
    std::array<double, 3> bary;
    const double d = closest_in(f, &bary);
    if (d < best || (d == best && f < best_face)) {
      best = d;
      best_face = f;
      best_bary = bary;
    }
  }
  return CanonicalizeSurfacePoint(
      mesh, SurfacePoint::Face(best_face, best_bary[0], best_bary[1], best_bary[2]));
}

}  // namespace geodesic
