// The build of a discrete geodesic graph (section 4): its phases in order,
// its estimates, and the candidate part of a distributed build.
#include "core/dgg/dgg_build.h"

#include <algorithm>
#include <chrono>
#include <cmath>
#include <memory>
#include <new>
#include <span>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/base/thread_arena.h"
#include "core/dgg/build_phases.h"
#include "core/dgg/candidate_runs.h"

namespace geodesic::dgg_build_internal {
namespace {

absl::Status CheckEpsilon(double epsilon) {
  if (!(epsilon > 0 && epsilon < 1)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("epsilon must be in (0, 1), got %g", epsilon));
  }
  if (epsilon < 1e-6) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "epsilon %g is below 1e-6: the graph would approach the complete direct-geodesic graph "
        "(quadratic size); use the exact engine instead",
        epsilon));
  }
  return absl::OkStatus();
}

}  // namespace

absl::Status CheckBuildParams(const DggParams& params) {
  RETURN_IF_ERROR(CheckEpsilon(params.epsilon));
  if (params.candidate_rule != kCandidateRuleVersion) {
    return absl::InvalidArgumentError(
        absl::StrFormat("candidate rule %u was asked for; this build makes graphs of rule %u",
                        params.candidate_rule, kCandidateRuleVersion));
  }
  return absl::OkStatus();
}

namespace {

absl::StatusOr<std::shared_ptr<const DggGraph>> FinishPhases(
    const Mesh& mesh, std::span<const uint32_t> counts, const CandidateFeed& feed,
    const DggParams& params, double pseudo_vertex_limit, const DggEdgeFile& edge_file,
    Progress& progress, DggBuildStats& st) {
  const double epsilon = params.epsilon;
  const bool prune = params.prune_redundant, exact_fans = params.exact_fans;
  auto t = std::chrono::steady_clock::now();
  NodeOrder order(mesh);
  for (uint32_t c : counts) st.found_edges += c;
  // Pseudo vertices add nodes, and so move where the file's edges start.
  ASSIGN_OR_RETURN(Adjacency cand, Symmetrize(order, counts, feed,
                                              params.pseudo_vertices ? DggEdgeFile{} : edge_file));
  st.candidate_edges = cand.edges.size() / 2;
  st.candidate_seconds += Seconds(t);

  t = std::chrono::steady_clock::now();
  std::vector<PseudoVertex> pseudo;
  if (params.pseudo_vertices) {
    ASSIGN_OR_RETURN(pseudo,
                     AddPseudoVertices(mesh, order, cand, epsilon, CandidateBudget(epsilon, prune),
                                       pseudo_vertex_limit, progress, st));
    if (progress.cancelled()) return nullptr;
    AddPseudoRows(cand, pseudo);
  }
  st.pseudo_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  if (prune) {
    auto redundant = FindRedundant(mesh, order, cand, epsilon, progress);
    if (progress.cancelled()) return nullptr;
    DropRedundant(cand, redundant);
  }
  st.pruning_seconds = Seconds(t);

  t = std::chrono::steady_clock::now();
  DggGraphArrays arrays = Finalize(std::move(cand), std::move(order), pseudo, exact_fans, progress);
  if (progress.cancelled()) return nullptr;
  const uint32_t nodes = mesh.num_vertices() + pseudo.size();
  st.pseudo_vertices = pseudo.size();
  st.edges = arrays.edges.size() / 2;
  for (uint32_t u = 0; u < nodes; ++u) {
    st.max_degree = std::max<uint32_t>(st.max_degree, arrays.offsets[u + 1] - arrays.offsets[u]);
  }
  st.average_degree = nodes ? double(arrays.edges.size()) / nodes : 0;
  st.fan_seconds = Seconds(t);
  st.average_fan = AverageFan({arrays.edges.data(), arrays.edges.size()});
  return DggGraphBuilder::FromArrays(std::move(arrays), nodes, mesh.num_vertices(), params,
                                     MeshFingerprint(mesh));
}

}  // namespace

// Phases 2-4 on the candidates of every vertex (`counts` long lists, by
// vertex, fed by `feed`): pseudo vertices, pruning, fans. Runs inside the
// caller's arena; null when cancelled.
absl::StatusOr<std::shared_ptr<const DggGraph>> FinishBuild(
    const Mesh& mesh, std::span<const uint32_t> counts, const CandidateFeed& feed,
    const DggParams& params, double pseudo_vertex_limit, const DggEdgeFile& edge_file,
    Progress& progress, DggBuildStats& st) {
  // The edge array grows as std::vector does and throws when it cannot have
  // its pages: no memory or, kept in the graph's file, no disk blocks.
  try {
    return FinishPhases(mesh, counts, feed, params, pseudo_vertex_limit, edge_file, progress, st);
  } catch (const std::bad_alloc&) {
    return absl::ResourceExhaustedError(
        edge_file.fd >= 0
            ? "no room for the graph's edges: the disk of its file has no blocks for them, or "
              "there is no memory"
            : "no memory for the graph's edges");
  }
}

}  // namespace geodesic::dgg_build_internal

namespace geodesic {

using dgg_build_internal::CandidateBudget;
using dgg_build_internal::CheckBuildParams;
using dgg_build_internal::ComputeCandidates;
using dgg_build_internal::FinishBuild;
using dgg_build_internal::Progress;
using dgg_build_internal::Seconds;

uint64_t EstimateDggBytesLowerBound(uint64_t vertices, double epsilon) {
  constexpr double kDegreeTimesSqrtEpsilon = 1.5;
  // target, weight, angle, fan begin and fan count of each directed edge.
  constexpr double kBytesPerDirectedEdge = 20;
  if (!(epsilon > 0)) return UINT64_MAX;
  return static_cast<uint64_t>(double(vertices) * kDegreeTimesSqrtEpsilon / std::sqrt(epsilon) *
                               kBytesPerDirectedEdge);
}

DggBuildEstimate EstimateDggBuild(uint64_t num_vertices, double epsilon, bool pseudo) {
  constexpr double kBytesPerVertex = 64.5, kBytesExponent = 0.486;
  constexpr double kSecondsPerVertex = 2.6e-6, kSecondsExponent = 0.646;
  // Pseudo vertices grow quickly as epsilon shrinks, as 1 + c (1e-2 /
  // epsilon)^k, up to the default limit on their number
  // (DggBuildOptions::pseudo_vertex_limit), which about doubles the graph.
  constexpr double kPseudoBytesC = 0.05, kPseudoBytesK = 2.85;
  constexpr double kPseudoSecondsC = 0.5, kPseudoSecondsK = 1.62;
  if (!(epsilon > 0 && epsilon < 1)) return {UINT64_MAX, HUGE_VAL};
  double bytes = double(num_vertices) * kBytesPerVertex * std::pow(epsilon, -kBytesExponent);
  double seconds = double(num_vertices) * kSecondsPerVertex * std::pow(epsilon, -kSecondsExponent);
  if (pseudo) {
    const double finer = 1e-2 / epsilon;
    bytes *= 1 + std::min(1.0, kPseudoBytesC * std::pow(finer, kPseudoBytesK));
    seconds *= 1 + std::min(1.0, kPseudoSecondsC * std::pow(finer, kPseudoSecondsK));
  }
  return {bytes >= 1.8e19 ? UINT64_MAX : static_cast<uint64_t>(bytes), seconds};
}

absl::StatusOr<std::shared_ptr<const DggGraph>> BuildDggWithTwoEdgeFans(
    const Mesh& mesh, const DggBuildOptions& options, DggBuildStats* stats) {
  RETURN_IF_ERROR(CheckBuildParams(options.params));
  DggBuildStats local;
  DggBuildStats& st = stats ? *stats : local;
  st = {};
  const auto start = std::chrono::steady_clock::now();
  Progress progress(options);
  ThreadArena arena(options.threads);
  absl::StatusOr<std::shared_ptr<const DggGraph>> graph;
  arena.execute([&] {
    CandidateRuns runs(mesh.num_vertices(), options.candidate_memory_limit, options.spill_dir,
                       options.admit_spill);
    absl::Status computed = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, 0, mesh.num_vertices(), progress, 0.7, &st.windows_created, runs);
    st.candidate_seconds = Seconds(start);
    st.spilled_bytes = runs.spilled_bytes();  // Drain spills no more
    if (!computed.ok()) {
      graph = computed;
      return;
    }
    if (progress.cancelled()) return;
    graph = FinishBuild(
        mesh, runs.counts(), [&](const auto& visit) { return runs.Drain(visit); }, options.params,
        options.pseudo_vertex_limit, options.edge_file, progress, st);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  st.total_seconds = Seconds(start);
  return graph;
}

absl::StatusOr<DggCandidatePart> BuildDggCandidatePart(const Mesh& mesh,
                                                       const DggBuildOptions& options,
                                                       uint32_t index, uint32_t count) {
  RETURN_IF_ERROR(CheckBuildParams(options.params));
  if (count == 0 || index >= count) {
    return absl::InvalidArgumentError(
        absl::StrFormat("part %u/%u: the index must be in [0, %u)", index, count, count));
  }
  const uint64_t n = mesh.num_vertices();
  DggCandidatePart part;
  part.params = options.params;
  part.mesh_fingerprint = MeshFingerprint(mesh);
  part.num_vertices = n;
  part.begin = n * index / count;
  part.end = n * (index + 1) / count;
  Progress progress(options);
  ThreadArena arena(options.threads);
  CandidateRuns runs(n, options.candidate_memory_limit, options.spill_dir, options.admit_spill);
  absl::Status computed;
  arena.execute([&] {
    computed = ComputeCandidates(
        mesh, CandidateBudget(options.params.epsilon, options.params.prune_redundant),
        options.stop_at_corners, part.begin, part.end, progress, 1.0, &part.windows_created, runs);
  });
  if (progress.cancelled()) return absl::CancelledError("graph build cancelled");
  RETURN_IF_ERROR(computed);
  part.offsets.assign(1, 0);
  for (uint32_t s = part.begin; s < part.end; ++s) {
    part.offsets.push_back(part.offsets.back() + runs.counts()[s]);
  }
  part.edges.resize(part.offsets.back());
  absl::Status drained;
  arena.execute([&] {
    drained = runs.Drain([&](uint32_t s, std::span<const DggHalfEdge> edges) {
      std::copy(edges.begin(), edges.end(), part.edges.begin() + part.offsets[s - part.begin]);
    });
  });
  RETURN_IF_ERROR(drained);
  return part;
}

}  // namespace geodesic
