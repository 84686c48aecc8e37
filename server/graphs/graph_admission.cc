// Whether a graph may be asked for, before any work: its estimate (bytes,
// seconds on this cache's build threads) against --max-graph-bytes, the
// memory limit and the disk limit, and what earlier builds of it taught
// (known_bytes_). Refusing here answers at once what a build would find
// out only after minutes.
#include <algorithm>
#include <filesystem>
#include <string>
#include <system_error>
#include <thread>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {

DggBuildEstimate GraphCache::Estimate(const RegisteredMesh& mesh, const DggParams& params) const {
  DggBuildEstimate estimate =
      EstimateDggBuild(mesh.mesh->num_vertices(), params.epsilon, params.pseudo_vertices);
  const int threads = options_.build_threads > 0
                          ? options_.build_threads
                          : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // Builds scale nearly linearly with threads (BENCHMARKS.md).
  if (threads > 1) estimate.seconds /= 0.95 * threads;
  return estimate;
}

absl::StatusOr<DggBuildEstimate> GraphCache::Admit(const RegisteredMesh& mesh,
                                                   const DggParams& params,
                                                   double max_error) const {
  DggBuildEstimate estimate = Estimate(mesh, params);
  uint64_t least = EstimateDggBytesLowerBound(mesh.mesh->num_vertices(), params.epsilon);
  uint64_t spill = 0;
  {
    absl::MutexLock lock(&mu_);
    if (auto it = known_bytes_.find(KnownBytesOf(mesh, params, max_error));
        it != known_bytes_.end()) {
      if (it->second.file > 0) estimate.bytes = least = it->second.file;
      spill = it->second.spill;
    }
  }
  const std::string what =
      max_error > 0
          ? absl::StrFormat("the graph of '%s' certified to max error %g (epsilon %g)%s", mesh.name,
                            max_error, params.epsilon,
                            params.pseudo_vertices ? " with pseudo vertices" : "")
          : absl::StrFormat("the graph of '%s' at epsilon %g%s", mesh.name, params.epsilon,
                            params.pseudo_vertices ? " with pseudo vertices" : "");
  if (options_.memory_limit > 0 && least > options_.memory_limit) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("%s needs at least %u bytes, over the server's memory limit of %u bytes "
                        "(--memory-limit): use a larger epsilon",
                        what, least, options_.memory_limit));
  }
  const std::string path = GraphPath(mesh.fingerprint, params, max_error);
  std::error_code ec;
  if (!path.empty() && std::filesystem::exists(path, ec)) return estimate;
  if (options_.max_graph_bytes > 0 && estimate.bytes > options_.max_graph_bytes) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s is estimated at %u bytes (a %.0f s build), over the server's limit of %u bytes per "
        "graph (--max-graph-bytes): use a larger epsilon",
        what, estimate.bytes, estimate.seconds, options_.max_graph_bytes));
  }
  if (options_.disk && options_.disk->limit() > 0 && least > options_.disk->limit()) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s needs at least %u bytes on disk, over the server's disk limit of %u bytes "
        "(--disk-limit): use a larger epsilon",
        what, least, options_.disk->limit()));
  }
  if (options_.disk && options_.disk->limit() > 0 && spill > options_.disk->limit()) {
    // Its last build stopped there: building again would end the same way.
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s needs at least %u bytes of spill file on disk for its candidate edges past "
        "--build-memory-limit, over the server's disk limit of %u bytes (--disk-limit): raise "
        "--build-memory-limit or --disk-limit",
        what, spill, options_.disk->limit()));
  }
  return estimate;
}

}  // namespace geodesic::server
