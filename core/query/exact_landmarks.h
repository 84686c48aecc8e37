// Exact distance fields from a few landmark vertices, which bound the
// distance between any two points from below (ALT's triangle inequality,
// Goldberg and Harrelson 2005, on the surface itself): for a landmark L,
// d(v, t) >= |d_L(t) - d_L(v)|. An exact pair's window propagation prunes by
// these bounds (ExactOptions::goal_floor) where the straight line is weak: on
// a curved surface most of the straight line's disc cannot reach the goal
// within the graph's answer, and the landmarks see that.
//
// Unlike the graph's landmarks (landmarks.h), these are exact polyhedral
// distances, so the bounds hold for the exact geodesic, not only for graph
// routes: a graph distance overstates the exact one by up to the graph's
// error, which is measured, not proven. One exact field per landmark, so a
// set is worth computing for a graph that answers many exact pairs.
//
// Fields are stored as float32, rounded to nearest, and a bound is taken in
// float too, four landmarks at a time: it then loses a slack of a few float
// steps of the largest distance, which keeps it valid.
#ifndef GEODESIC_CORE_QUERY_EXACT_LANDMARKS_H_
#define GEODESIC_CORE_QUERY_EXACT_LANDMARKS_H_

#include <cstdint>
#include <functional>
#include <memory>
#include <optional>
#include <span>
#include <vector>

#include "absl/status/statusor.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh.h"
#include "core/mesh/surface_point.h"

namespace geodesic {

class ExactLandmarks {
 public:
  // One exact field from each of `vertices` (OUT_OF_RANGE for an id past the
  // mesh, INVALID_ARGUMENT for none), spread over `threads` threads (0: every
  // core). `cancelled` is polled during the propagations (CANCELLED).
  static absl::StatusOr<std::unique_ptr<const ExactLandmarks>> Compute(
      const Mesh& mesh, std::span<const VertexId> vertices,
      const std::function<bool()>& cancelled = {}, int threads = 0);
  // Landmarks from fields computed before (as `fields()` and `slack()` give
  // them), with the face frames made again from `mesh`: for reading them
  // back from a file (core/query/exact_landmarks_file.h).
  static std::unique_ptr<const ExactLandmarks> FromFields(const Mesh& mesh, int count,
                                                          std::vector<float> fields, double slack);
  // What Compute holds while it runs (the fields it keeps, the face frames
  // its engines share and their per-vertex state), for counting it first.
  static uint64_t ComputeBytes(const Mesh& mesh, int count, int threads = 0);

  // Lower bounds on each vertex's distance to `goal` (a valid surface point
  // of the mesh the fields were computed on), for one exact run.
  class Floor final : public GoalFloor {
   public:
    double At(VertexId v) const override;

   private:
    friend class ExactLandmarks;
    const ExactLandmarks* landmarks_ = nullptr;
    // Per landmark, the goal's distance lies in [low, high]: from the
    // fields at the corners of the goal's edge or face, rounded outwards to
    // float; kFar for a landmark that does not reach the goal.
    std::vector<float> low_, high_;
  };
  Floor FloorFor(const Mesh& mesh, const SurfacePoint& goal) const;

  int count() const { return count_; }
  // Every field, vertex-major: count() values per vertex, +inf unreached.
  std::span<const float> fields() const { return distance_; }
  // What every bound is lowered by (float rounding of the fields).
  double slack() const { return slack_; }
  // The face frames the fields were computed with, kept for the queries'
  // exact engines (their joins to the graph and their exact pairs): reading
  // a frame is cheaper than computing it per window.
  const FaceFrames* frames() const { return frames_.get(); }
  // The fields and the frames.
  uint64_t byte_size() const {
    return ByteSize(distance_.size() / count_, frames_->size(), count_);
  }
  static uint64_t ByteSize(uint64_t vertices, uint64_t halfedges, int count) {
    return vertices * count * sizeof(float) + halfedges * sizeof(FaceFrame);
  }

 private:
  std::span<const float> of(VertexId v) const {
    return {distance_.data() + static_cast<size_t>(v) * count_, static_cast<size_t>(count_)};
  }

  int count_ = 0;
  std::vector<float> distance_;  // vertex-major: count_ values per vertex, +inf unreached
  // Subtracted from every bound: float rounding of both distances, and the
  // engine's own, at the largest finite distance.
  double slack_ = 0;
  std::unique_ptr<const FaceFrames> frames_;
};

// What one exact run takes from the landmarks, when they are ready: their
// bounds towards the run's goal (if it has one), put in its options and
// kept while it runs. (Their face frames reach pooled engines through the
// query scratch.)
class ExactLandmarkRun {
 public:
  ExactLandmarkRun(const ExactLandmarks* landmarks, const Mesh& mesh, const SurfacePoint* goal,
                   ExactOptions& options);
  ExactLandmarkRun(const ExactLandmarkRun&) = delete;
  ExactLandmarkRun& operator=(const ExactLandmarkRun&) = delete;

 private:
  std::optional<ExactLandmarks::Floor> floor_;
};

}  // namespace geodesic

#endif  // GEODESIC_CORE_QUERY_EXACT_LANDMARKS_H_
