// The engine's resident state: the mesh, the graph, the nodes' positions,
// the scratch pool and the landmarks (graph and exact). Its queries live beside it:
// field_solver.cc, point_to_point.cc, sampling.cc.
#include "core/query/geodesic_engine.h"

#include <algorithm>
#include <thread>

#include "absl/status/status.h"
#include "core/base/status.h"

namespace geodesic {

GeodesicEngine::GeodesicEngine(std::shared_ptr<const Mesh> mesh,
                               std::shared_ptr<const DggGraph> graph)
    : mesh_(std::move(mesh)),
      graph_(std::move(graph)),
      scratch_(std::max<int>(2, std::thread::hardware_concurrency())) {
  buckets_ = BucketShapeOf(*graph_);
  lane_fans_ = LaneFanLayoutFor(*graph_);
  node_xyz_.resize(graph_->num_nodes());
  for (uint32_t u = 0; u < node_xyz_.size(); ++u) {
    node_xyz_[u] = PositionOf(*mesh_, graph_->point_of_node(u));
  }
}

GeodesicEngine::~GeodesicEngine() = default;

absl::Status GeodesicEngine::PrepareLandmarks(int count,
                                              const std::function<bool()>& cancelled) const {
  return landmarks_.Make([&] { return Landmarks::Compute(*graph_, count, cancelled); });
}

absl::Status GeodesicEngine::PrepareExactLandmarks(int count,
                                                   const std::function<bool()>& cancelled,
                                                   int threads) const {
  return exact_landmarks_.Make([&]() -> absl::StatusOr<std::unique_ptr<const ExactLandmarks>> {
    SampleOptions sample;
    sample.cancelled = cancelled;
    ASSIGN_OR_RETURN(const SampleResult spread, SamplePoints(count, sample));
    return ExactLandmarks::Compute(*mesh_, spread.vertices, cancelled, threads);
  });
}

absl::Status GeodesicEngine::AdoptExactLandmarks(
    std::shared_ptr<const ExactLandmarks> landmarks) const {
  return exact_landmarks_.Make([&]() -> absl::StatusOr<std::shared_ptr<const ExactLandmarks>> {
    return std::move(landmarks);
  });
}

int GeodesicEngine::DefaultLandmarkCount() const {
  constexpr uint64_t kMin = 16, kMax = 64;
  const uint64_t nodes = std::max<uint64_t>(graph_->num_nodes(), 1);
  return static_cast<int>(
      std::clamp(graph_->byte_size() / 4 / (sizeof(float) * nodes), kMin, kMax));
}

ScratchPool::Lease GeodesicEngine::AcquireScratch() const {
  ScratchPool::Lease lease = scratch_.Acquire();
  const ExactLandmarks* landmarks = exact_landmarks_.get();
  lease->frames = landmarks ? landmarks->frames() : nullptr;
  return lease;
}

uint64_t GeodesicEngine::landmark_bytes() const {
  const Landmarks* l = landmarks_.get();
  return l ? l->byte_size() : 0;
}

uint64_t GeodesicEngine::exact_landmark_bytes() const {
  const ExactLandmarks* l = exact_landmarks_.get();
  return l ? l->byte_size() : 0;
}

}  // namespace geodesic
