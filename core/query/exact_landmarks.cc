#include "core/query/exact_landmarks.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <thread>

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/for_each_in_parallel.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"

namespace geodesic {
namespace {

constexpr double kInf = std::numeric_limits<double>::infinity();

// Four float steps (2^-24 each) of the largest distance cover the rounding
// of a landmark's distance to each end of a bound, and one more the float
// subtraction that takes the bound; the engine's own error, ~1e-14 of a
// distance, is far below.
constexpr double kSlackPerDistance = 1e-6;

// Stands for "unreached" in a bound's float arithmetic, where +inf would
// make inf - inf: a field's +inf is clamped to it, and a landmark that does
// not reach the goal gets it as both ends of the goal's range. Then a
// difference near kFar means v and the goal lie in different components,
// and one of 0 that neither is reached.
constexpr float kFar = 1e30f;

// The largest of low[k] - d[k] and d[k] - high[k] over k < n, with d's +inf
// read as kFar. Branch-free, since a floor is asked for every vertex a run
// meets and reads all of its landmarks.
float LargestGap(const float* d, const float* low, const float* high, int n) {
  float best = 0;
  int k = 0;
#if defined(__SSE2__)
  const __m128 far = _mm_set1_ps(kFar);
  __m128 best4 = _mm_setzero_ps();
  for (; k + 4 <= n; k += 4) {
    const __m128 dk = _mm_min_ps(_mm_loadu_ps(d + k), far);
    const __m128 below = _mm_sub_ps(_mm_loadu_ps(low + k), dk);
    const __m128 above = _mm_sub_ps(dk, _mm_loadu_ps(high + k));
    best4 = _mm_max_ps(best4, _mm_max_ps(below, above));
  }
  alignas(16) float lanes[4];
  _mm_store_ps(lanes, best4);
  best = std::max(std::max(lanes[0], lanes[1]), std::max(lanes[2], lanes[3]));
#endif
  for (; k < n; ++k) {
    const float dk = std::min(d[k], kFar);
    best = std::max(best, std::max(low[k] - dk, dk - high[k]));
  }
  return best;
}

// `x` as a float no larger (RoundDown) or no smaller (RoundUp) than it.
float RoundDown(double x) {
  const float f = static_cast<float>(x);
  return f > x ? std::nextafter(f, -std::numeric_limits<float>::infinity()) : f;
}
float RoundUp(double x) {
  const float f = static_cast<float>(x);
  return f < x ? std::nextafter(f, std::numeric_limits<float>::infinity()) : f;
}

// The vertices whose fields place `p`: itself, its edge's ends or its face's
// corners (each joined to p by a straight segment on the surface).
std::vector<VertexId> CornersOf(const Mesh& mesh, const SurfacePoint& p) {
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      return {p.id};
    case SurfacePoint::Kind::kEdge: {
      const HalfedgeId h = mesh.edge_halfedge(p.id);
      return {mesh.tail(h), mesh.head(h)};
    }
    case SurfacePoint::Kind::kFace:
      return {mesh.face_vertex(p.id, 0), mesh.face_vertex(p.id, 1), mesh.face_vertex(p.id, 2)};
  }
  return {};
}

}  // namespace

absl::StatusOr<std::unique_ptr<const ExactLandmarks>> ExactLandmarks::Compute(
    const Mesh& mesh, std::span<const VertexId> vertices, const std::function<bool()>& cancelled,
    int threads) {
  if (vertices.empty()) {
    return absl::InvalidArgumentError("exact landmarks need at least one landmark vertex");
  }
  for (VertexId v : vertices) {
    if (v >= mesh.num_vertices()) {
      return absl::OutOfRangeError(
          absl::StrFormat("landmark vertex %u: the mesh has %u vertices", v, mesh.num_vertices()));
    }
  }
  auto out = std::make_unique<ExactLandmarks>();
  out->count_ = static_cast<int>(vertices.size());
  out->distance_.assign(mesh.num_vertices() * vertices.size(), static_cast<float>(kInf));
  out->frames_ = std::make_unique<const FaceFrames>(mesh);
  const FaceFrames& frames = *out->frames_;
  std::vector<double> largest(vertices.size(), 0);
  absl::Status computed;
  ThreadArena(threads).execute([&] {
    computed = ForEachInParallel(vertices.size(), [&](size_t k) -> absl::Status {
      if (cancelled && cancelled()) return absl::CancelledError("exact landmarks cancelled");
      ExactGeodesic engine(mesh, &frames);
      ExactOptions options;
      options.cancelled = cancelled;
      ASSIGN_OR_RETURN(const std::vector<double> field,
                       engine.Distances(SurfacePoint::Vertex(vertices[k]), options));
      for (size_t v = 0; v < field.size(); ++v) {
        out->distance_[v * vertices.size() + k] = static_cast<float>(field[v]);
        if (field[v] < kInf) largest[k] = std::max(largest[k], field[v]);
      }
      return absl::OkStatus();
    });
  });
  RETURN_IF_ERROR(computed);
  out->slack_ = kSlackPerDistance * *std::max_element(largest.begin(), largest.end());
  return out;
}

std::unique_ptr<const ExactLandmarks> ExactLandmarks::FromFields(const Mesh& mesh, int count,
                                                                 std::vector<float> fields,
                                                                 double slack) {
  auto out = std::make_unique<ExactLandmarks>();
  out->count_ = count;
  out->distance_ = std::move(fields);
  out->slack_ = slack;
  out->frames_ = std::make_unique<const FaceFrames>(mesh);
  return out;
}

uint64_t ExactLandmarks::ComputeBytes(const Mesh& mesh, int count, int threads) {
  // Each engine holds about 64 bytes per vertex and its wavefront's windows;
  // what is kept is the fields and the frames (one cache line per half-edge).
  const uint64_t cores = threads > 0 ? static_cast<uint64_t>(threads)
                                     : std::max(1u, std::thread::hardware_concurrency());
  const uint64_t engines = std::min<uint64_t>(cores, static_cast<uint64_t>(std::max(count, 1)));
  const uint64_t vertices = mesh.num_vertices();
  return ByteSize(vertices, mesh.num_halfedges(), count) + engines * vertices * 64;
}

ExactLandmarks::Floor ExactLandmarks::FloorFor(const Mesh& mesh, const SurfacePoint& goal) const {
  std::vector<double> low(count_, -kInf), high(count_, kInf);
  const Vec3 at = PositionOf(mesh, goal);
  for (VertexId c : CornersOf(mesh, goal)) {
    const double gap = Distance(mesh.position(c), at);
    const std::span<const float> d = of(c);
    for (int k = 0; k < count_; ++k) {
      low[k] = std::max(low[k], d[k] - gap);
      high[k] = std::min(high[k], d[k] + gap);
    }
  }
  Floor floor;
  floor.landmarks_ = this;
  floor.low_.resize(count_);
  floor.high_.resize(count_);
  for (int k = 0; k < count_; ++k) {
    // The corners share a component, so they are all reached or none is.
    const bool reached = high[k] < kInf;
    floor.low_[k] = reached ? RoundDown(low[k]) : kFar;
    floor.high_[k] = reached ? RoundUp(high[k]) : kFar;
  }
  return floor;
}

ExactLandmarkRun::ExactLandmarkRun(const ExactLandmarks* landmarks, const Mesh& mesh,
                                   const SurfacePoint* goal, ExactOptions& options) {
  if (landmarks && goal) options.goal_floor = &floor_.emplace(landmarks->FloorFor(mesh, *goal));
}

double ExactLandmarks::Floor::At(VertexId v) const {
  const std::span<const float> d = landmarks_->of(v);
  const float gap = LargestGap(d.data(), low_.data(), high_.data(), static_cast<int>(d.size()));
  // A landmark that reaches one of v and the goal but not the other puts
  // them in different components.
  if (gap >= kFar / 2) return kInf;
  return std::max(0.0, gap - landmarks_->slack_);
}

}  // namespace geodesic
