#include "core/query/build_dgg.h"

#include <chrono>
#include <span>
#include <utility>

#include "absl/status/status.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"
#include "core/dgg/dgg_graph_internal.h"
#include "core/query/field_lanes.h"

namespace geodesic {
namespace {

// Out to half the longest turn: the fans shrink fast up to there and little
// beyond, while a sweep's cost grows as the square of its reach
// (bench/notes.md, "Fans narrowed in the build").
constexpr double kNarrowingReach = 0.5;

// Narrows the fans of a graph the phases just built, in the build's arena,
// and brings its stats up to date. Exact fans are narrower already, and a
// graph whose fans do not pack (a node of 2^16 edges or more) keeps its own.
absl::StatusOr<std::shared_ptr<const DggGraph>> NarrowFans(
    absl::StatusOr<std::shared_ptr<const DggGraph>> built, const DggBuildOptions& options,
    DggBuildStats* stats) {
  if (!built.ok() || *built == nullptr) return built;
  std::shared_ptr<const DggGraph> graph = *std::move(built);
  const auto start = std::chrono::steady_clock::now();
  if (!graph->params().exact_fans && LaneFanLayoutFor(*graph) == LaneFanLayout::kPacked) {
    DggEdge* edges = DggGraphBuilder::EditableEdges(graph);
    if (edges == nullptr) return absl::InternalError("a graph just built is shared already");
    absl::Status narrowed;
    ThreadArena arena(options.threads);
    arena.execute([&] {
      narrowed = query_internal::NarrowAllFans(
          *graph, {edges, graph->num_directed_edges()}, kNarrowingReach,
          [&](uint64_t done, uint64_t total) {
            return !options.progress ||
                   options.progress("fans", 0.97 + 0.03 * double(done) / double(total));
          });
    });
    if (absl::IsCancelled(narrowed)) return absl::CancelledError("graph build cancelled");
    RETURN_IF_ERROR(narrowed);
  }
  if (options.progress && !options.progress("fans", 1.0)) {
    return absl::CancelledError("graph build cancelled");
  }
  if (stats) {
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    stats->fan_seconds += seconds;
    stats->total_seconds += seconds;
    stats->average_fan = AverageFan(graph->edges());
  }
  return graph;
}

}  // namespace

absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDgg(const Mesh& mesh,
                                                         const DggBuildOptions& options,
                                                         DggBuildStats* stats) {
  return NarrowFans(BuildDggWithTwoEdgeFans(mesh, options, stats), options, stats);
}

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggPartSource> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats) {
  return NarrowFans(MergeDggPartsWithTwoEdgeFans(mesh, std::move(parts), options, stats), options,
                    stats);
}

absl::StatusOr<std::shared_ptr<const DggGraph>> MergeDggParts(const Mesh& mesh,
                                                              std::vector<DggCandidatePart> parts,
                                                              const DggBuildOptions& options,
                                                              DggBuildStats* stats) {
  return NarrowFans(MergeDggPartsWithTwoEdgeFans(mesh, std::move(parts), options, stats), options,
                    stats);
}

}  // namespace geodesic
