#include "core/query/accuracy_check.h"

#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <memory>
#include <mutex>
#include <random>

#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"
#include "core/exact/exact_geodesic.h"
#include "core/query/geodesic_engine.h"

namespace geodesic {

FieldComparison CompareFields(const Mesh& mesh, const SurfacePoint& source,
                              absl::Span<const double> exact, absl::Span<const double> graph) {
  FieldComparison c;
  const bool vertex_source = source.kind == SurfacePoint::Kind::kVertex;
  const Vec3 at = PositionOf(mesh, source);
  double total = 0;
  for (VertexId v = 0; v < exact.size(); ++v) {
    const double e = exact[v], g = graph[v];
    if (vertex_source && v == source.id) {
      c.source_nonzero = e != 0 || g != 0;
      continue;
    }
    const bool e_reached = e < kInfinity, g_reached = g < kInfinity;
    if (e_reached != g_reached) {
      ++(e_reached ? c.graph_unreached : c.exact_unreached);
      continue;
    }
    if (!e_reached) continue;  // another component, or an isolated vertex
    if (e < Distance(at, mesh.position(v)) * (1 - kCheckRoundingSlack)) ++c.below_straight;
    if (g < e * (1 - kCheckRoundingSlack)) {
      if (c.below_exact++ == 0) c.first_below_exact = v;
    }
    if (!(e > 0)) continue;  // a point on the source: no relative error
    const double error = (g - e) / e;
    ++c.compared;
    total += error;
    if (c.worst_vertex == kNone || error > c.max_error) {
      c.max_error = error;
      c.worst_vertex = v;
    }
    if (c.compared == 1 || error < c.min_error) c.min_error = error;
  }
  c.mean_error = c.compared ? total / c.compared : 0;
  return c;
}

namespace {

double SecondsSince(std::chrono::steady_clock::time_point t) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - t).count();
}

}  // namespace

absl::StatusOr<std::vector<SourceCheck>> CheckAgainstExact(std::shared_ptr<const Mesh> mesh,
                                                           std::shared_ptr<const DggGraph> graph,
                                                           absl::Span<const SurfacePoint> sources,
                                                           const AccuracyCheckOptions& options) {
  for (size_t i = 0; i < sources.size(); ++i) {
    if (absl::Status s = ValidateSurfacePoint(*mesh, sources[i]); !s.ok()) {
      return absl::Status(s.code(), absl::StrFormat("source %d (%s): %s", i,
                                                    FormatSurfacePoint(sources[i]), s.message()));
    }
  }
  const GeodesicEngine engine(mesh, graph);
  std::vector<SourceCheck> checks(sources.size());
  // Each exact engine holds per-vertex scratch: one per thread, not per source.
  // Whole fields from many sources read every face's frame many times: made
  // once, shared.
  const FaceFrames frames(*mesh);
  tbb::enumerable_thread_specific<std::unique_ptr<ExactGeodesic>> engines(
      [&] { return std::make_unique<ExactGeodesic>(*mesh, &frames); });
  std::mutex mu;
  absl::Status first_error;
  std::atomic<bool> failed{false};
  auto fail = [&](absl::Status s) {
    std::lock_guard<std::mutex> lock(mu);
    if (first_error.ok()) first_error = std::move(s);
    failed = true;
  };
  ThreadArena arena(options.threads);
  arena.execute([&] {
    tbb::parallel_for(size_t{0}, sources.size(), size_t{1}, [&](size_t i) {
      if (failed || (options.cancelled && options.cancelled())) return;
      SourceCheck& check = checks[i];
      check.source = sources[i];
      auto t = std::chrono::steady_clock::now();
      ExactOptions exact_options;
      exact_options.cancelled = options.cancelled;
      auto exact = engines.local()->Distances(sources[i], exact_options);
      check.exact_seconds = SecondsSince(t);
      if (!exact.ok()) return fail(exact.status());
      t = std::chrono::steady_clock::now();
      FieldOptions field_options;
      field_options.cancelled = options.cancelled;
      auto field = engine.Field(absl::MakeConstSpan(&sources[i], 1), field_options);
      check.graph_seconds = SecondsSince(t);
      if (!field.ok()) return fail(field.status());
      check.comparison = CompareFields(*mesh, sources[i], *exact, field->distance);
      if (options.source_done) options.source_done();
    });
  });
  if (options.cancelled && options.cancelled()) {
    return absl::CancelledError("accuracy check cancelled");
  }
  RETURN_IF_ERROR(first_error);
  return checks;
}

std::vector<VertexId> RandomSurfaceVertices(const Mesh& mesh, int count, uint64_t seed) {
  std::vector<VertexId> usable;
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) {
    if (!mesh.is_isolated(v)) usable.push_back(v);
  }
  const size_t k = std::min<size_t>(std::max(count, 0), usable.size());
  std::mt19937_64 rng(seed);
  // The first k places of a Fisher-Yates shuffle.
  for (size_t i = 0; i < k; ++i) {
    const size_t j = std::uniform_int_distribution<size_t>(i, usable.size() - 1)(rng);
    std::swap(usable[i], usable[j]);
  }
  usable.resize(k);
  return usable;
}

}  // namespace geodesic
