// Merging the candidate parts of a distributed build into one graph.
#include <tbb/enumerable_thread_specific.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <atomic>
#include <memory>
#include <optional>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"
#include "core/dgg/build_phases.h"
#include "core/dgg/dgg_part_file.h"

namespace geodesic::dgg_build_internal {
namespace {

// The edges of a part loaded for a merge: in range and of finite length.
absl::Status CheckPartEdges(const DggCandidatePart& p, uint32_t n, const std::string& name) {
  for (const DggHalfEdge& e : p.edges) {
    if (e.to >= n || !(e.weight >= 0) || !std::isfinite(e.weight)) {
      return absl::FailedPreconditionError(
          absl::StrFormat("%s holds an edge to vertex %u of length %g", name, e.to, e.weight));
    }
  }
  return absl::OkStatus();
}

}  // namespace
}  // namespace geodesic::dgg_build_internal

namespace geodesic {

using dgg_build_internal::CandidateFeed;
using dgg_build_internal::CheckBuildParams;
using dgg_build_internal::CheckPartEdges;
using dgg_build_internal::FinishBuild;
using dgg_build_internal::Progress;
using dgg_build_internal::Seconds;

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggPartsWithTwoEdgeFans(
    const Mesh& mesh, std::vector<DggPartSource> parts, const DggBuildOptions& options,
    DggBuildStats* stats) {
  if (parts.empty()) return absl::InvalidArgumentError("no parts to merge");
  const uint32_t n = mesh.num_vertices();
  const uint64_t fingerprint = MeshFingerprint(mesh);
  const DggParams params = parts[0].index.params;
  RETURN_IF_ERROR(CheckBuildParams(params));
  for (size_t i = 0; i < parts.size(); ++i) {
    const DggCandidatePart& p = parts[i].index;
    const std::string part = absl::StrFormat("%s (vertices %u..%u)", parts[i].name, p.begin, p.end);
    if (p.mesh_fingerprint != fingerprint || p.num_vertices != n) {
      return absl::FailedPreconditionError(absl::StrCat(part, " was built for another mesh"));
    }
    RETURN_IF_ERROR(
        CheckSameParams(params, p.params, absl::StrCat(part, ", unlike ", parts[0].name, ",")));
    if (p.begin > p.end || p.end > n || p.offsets.size() != p.end - p.begin + 1 ||
        p.offsets.front() != 0 || !std::is_sorted(p.offsets.begin(), p.offsets.end())) {
      return absl::FailedPreconditionError(absl::StrCat(part, " is inconsistent"));
    }
  }
  std::sort(parts.begin(), parts.end(),
            [](const auto& a, const auto& b) { return a.index.begin < b.index.begin; });
  uint32_t covered = 0;
  for (const DggPartSource& p : parts) {
    if (p.index.begin != covered) {
      return absl::FailedPreconditionError(
          p.index.begin > covered
              ? absl::StrFormat("no part covers vertices %u..%u", covered, p.index.begin)
              : absl::StrFormat("two parts cover vertex %u", p.index.begin));
    }
    covered = p.index.end;
  }
  if (covered != n) {
    return absl::FailedPreconditionError(
        absl::StrFormat("no part covers vertices %u..%u", covered, n));
  }

  DggBuildStats local;
  DggBuildStats& st = stats ? *stats : local;
  st = {};
  const auto start = std::chrono::steady_clock::now();
  std::vector<uint32_t> counts(n);
  for (const DggPartSource& p : parts) {
    for (uint32_t s = p.index.begin; s < p.index.end; ++s) {
      const size_t i = s - p.index.begin;
      counts[s] = p.index.offsets[i + 1] - p.index.offsets[i];
    }
  }
  auto feed = [&](const CandidateRuns::Visitor& visit) -> absl::Status {
    for (DggPartSource& source : parts) {
      ASSIGN_OR_RETURN(DggCandidatePart p, source.load());
      if (p.begin != source.index.begin || p.offsets != source.index.offsets ||
          p.edges.size() != p.offsets.back()) {
        return absl::FailedPreconditionError(
            absl::StrCat(source.name, " changed while it was being merged"));
      }
      RETURN_IF_ERROR(CheckPartEdges(p, n, source.name));
      st.windows_created += p.windows_created;
      for (uint32_t s = p.begin; s < p.end; ++s) {
        const size_t i = s - p.begin;
        visit(s, {p.edges.data() + p.offsets[i], p.edges.data() + p.offsets[i + 1]});
      }
      source = {};
    }
    return absl::OkStatus();
  };
  Progress progress(options);
  ThreadArena arena(options.threads);
  absl::StatusOr<std::shared_ptr<const DggGraph>> graph;
  arena.execute([&] {
    graph = FinishBuild(mesh, counts, feed, params, options.pseudo_vertex_limit, options.edge_file,
                        progress, st);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  st.total_seconds = Seconds(start);
  return graph;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggPartsWithTwoEdgeFans(
    const Mesh& mesh, std::vector<DggCandidatePart> parts, const DggBuildOptions& options,
    DggBuildStats* stats) {
  std::vector<DggPartSource> sources;
  for (size_t i = 0; i < parts.size(); ++i) {
    std::vector<DggHalfEdge> edges = std::move(parts[i].edges);
    DggCandidatePart index = parts[i];
    auto whole = std::make_shared<DggCandidatePart>(std::move(parts[i]));
    whole->edges = std::move(edges);
    sources.push_back(
        {absl::StrFormat("part %u", i), std::move(index),
         [whole]() -> absl::StatusOr<DggCandidatePart> { return std::move(*whole); }});
  }
  return MergeDggPartsWithTwoEdgeFans(mesh, std::move(sources), options, stats);
}

}  // namespace geodesic
