// geodesicd info GRAPH.dgg: describe and validate a graph file.
#include <cstdio>

#include "core/graph_file.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunGraphInfo(const std::string& path, bool json) {
  auto info = GraphFile::Inspect(path);
  if (!info.ok()) return Fail("info", info.status());
  const double average_degree =
      info->num_nodes ? double(info->num_directed_edges) / info->num_nodes : 0;
  if (json) {
    std::printf(
        "{\"path\": \"%s\", \"format_version\": %u, \"mesh_fingerprint\": \"%016llx\", "
        "\"epsilon\": %g, \"pseudo_vertices_enabled\": %s, \"vertices\": %u, \"nodes\": %u, "
        "\"pseudo_vertices\": %u, \"edges\": %llu, \"average_degree\": %.3f, \"file_bytes\": %llu, "
        "\"checksums_ok\": true}\n",
        path.c_str(), info->version, static_cast<unsigned long long>(info->mesh_fingerprint),
        info->params.epsilon, info->params.pseudo_vertices ? "true" : "false",
        info->num_mesh_vertices, info->num_nodes, info->num_nodes - info->num_mesh_vertices,
        static_cast<unsigned long long>(info->num_directed_edges / 2), average_degree,
        static_cast<unsigned long long>(info->file_bytes));
  } else {
    std::printf(
        "%s: geodesicd graph, format version %u\n  mesh fingerprint %016llx, %u vertices\n"
        "  epsilon %g, pseudo vertices %s: %u\n  %llu edges, average degree %.2f\n"
        "  %llu bytes, all section checksums valid\n",
        path.c_str(), info->version, static_cast<unsigned long long>(info->mesh_fingerprint),
        info->num_mesh_vertices, info->params.epsilon,
        info->params.pseudo_vertices ? "enabled" : "disabled",
        info->num_nodes - info->num_mesh_vertices,
        static_cast<unsigned long long>(info->num_directed_edges / 2), average_degree,
        static_cast<unsigned long long>(info->file_bytes));
  }
  return 0;
}

}  // namespace geodesic::offline
