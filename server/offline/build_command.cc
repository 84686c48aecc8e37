// geodesicd build: construct the discrete geodesic graph of a mesh.
#include <sys/resource.h>
#include <unistd.h>

#include <cstdio>
#include <filesystem>

#include "CLI/CLI.hpp"
#include "core/dgg_build.h"
#include "core/graph_file.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {
namespace {

uint64_t PeakMemoryBytes() {
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<uint64_t>(usage.ru_maxrss) * 1024;
}

}  // namespace

int RunBuild(int argc, char** argv) {
  CLI::App app{"Build the discrete geodesic graph (DGG) of a mesh", "geodesicd build"};
  std::string mesh_path, out_path;
  double epsilon = 1e-3;
  int threads = 0;
  bool json = false, pseudo = false, quiet = false;
  app.add_option("mesh", mesh_path, "mesh file (obj, off, ply, stl)")->required();
  app.add_option("--eps", epsilon, "accuracy: relative error of graph distances, in (0, 1)");
  app.add_option("--out", out_path, "graph file to write (atomically)")->required();
  app.add_option("--threads", threads, "build threads (0: all cores)");
  app.add_flag("--pseudo-vertices", pseudo,
               "add pseudo vertices where edge directions leave gaps (section 4.3; for "
               "anisotropic meshes)");
  app.add_flag("--json", json, "print a JSON object");
  app.add_flag("--quiet", quiet, "no progress bar");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  auto mesh = LoadMeshOrError(mesh_path);
  if (!mesh.ok()) return Fail("build", mesh.status());
  DggBuildOptions options;
  options.params.epsilon = epsilon;
  options.params.pseudo_vertices = pseudo;
  options.threads = threads;
  const bool bar = !json && !quiet && isatty(STDERR_FILENO);
  if (bar) {
    options.progress = [](std::string_view phase, double fraction) {
      const int width = 40, filled = static_cast<int>(fraction * width);
      std::fprintf(stderr, "\r%-10.*s [%s%s] %5.1f%%", static_cast<int>(phase.size()), phase.data(),
                   std::string(filled, '#').c_str(), std::string(width - filled, ' ').c_str(),
                   100 * fraction);
      return true;
    };
  }
  DggBuildStats stats;
  auto graph = BuildDgg(**mesh, options, &stats);
  if (bar) std::fprintf(stderr, "\n");
  if (!graph.ok()) return Fail("build", graph.status());
  absl::Status written = GraphFile::Write(**graph, out_path);
  if (!written.ok()) return Fail("build", written);
  const uint64_t file_bytes = std::filesystem::file_size(out_path);
  const size_t n = (*mesh)->num_vertices();
  if (json) {
    std::printf(
        "{\"vertices\": %zu, \"nodes\": %u, \"pseudo_vertices\": %u, \"edges\": %llu, "
        "\"candidate_edges\": %llu, \"average_degree\": %.3f, \"max_degree\": %u, "
        "\"epsilon\": %g, \"threads\": %d, \"build_seconds\": %.4f, \"candidate_seconds\": %.4f, "
        "\"pruning_seconds\": %.4f, \"pseudo_seconds\": %.4f, \"fan_seconds\": %.4f, "
        "\"windows_per_source\": %.2f, \"peak_memory_bytes\": %llu, \"file_bytes\": %llu}\n",
        n, (*graph)->num_nodes(), stats.pseudo_vertices,
        static_cast<unsigned long long>(stats.edges),
        static_cast<unsigned long long>(stats.candidate_edges), stats.average_degree,
        stats.max_degree, epsilon, threads, stats.total_seconds, stats.candidate_seconds,
        stats.pruning_seconds, stats.pseudo_seconds, stats.fan_seconds,
        double(stats.windows_created) / std::max<size_t>(n, 1),
        static_cast<unsigned long long>(PeakMemoryBytes()),
        static_cast<unsigned long long>(file_bytes));
  } else {
    std::printf(
        "built %s: %zu vertices, %u pseudo vertices, %llu edges (average degree %.1f, max %u) "
        "at eps %g in %.2f s (candidates %.2f s, pruning %.2f s, pseudo %.2f s, fans %.2f s); "
        "%llu bytes\n",
        out_path.c_str(), n, stats.pseudo_vertices, static_cast<unsigned long long>(stats.edges),
        stats.average_degree, stats.max_degree, epsilon, stats.total_seconds,
        stats.candidate_seconds, stats.pruning_seconds, stats.pseudo_seconds, stats.fan_seconds,
        static_cast<unsigned long long>(file_bytes));
  }
  return 0;
}

}  // namespace geodesic::offline
