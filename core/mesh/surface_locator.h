// Snapping positions to the nearest point on the surface, with a k-d tree
// (nanoflann) over face centroids.
#ifndef GEODESIC_CORE_MESH_SURFACE_LOCATOR_H_
#define GEODESIC_CORE_MESH_SURFACE_LOCATOR_H_

#include <memory>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

class SurfaceLocator {
 public:
  // INVALID_ARGUMENT for a mesh without faces.
  static absl::StatusOr<SurfaceLocator> Build(const Mesh& mesh);
  SurfaceLocator(SurfaceLocator&&) noexcept;
  SurfaceLocator& operator=(SurfaceLocator&&) noexcept;
  ~SurfaceLocator();

  // The closest surface point (canonical form) to `position`. Exact: every
  // face that could hold a closer point is examined. Thread-safe.
  absl::StatusOr<SurfacePoint> Snap(const Vec3& position) const;

 private:
  struct Index;
  explicit SurfaceLocator(std::unique_ptr<Index> index);
  std::unique_ptr<Index> index_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_SURFACE_LOCATOR_H_
