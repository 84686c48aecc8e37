// geodesicd info GRAPH.dgg: describe and validate a graph file.
#include <cstdio>

#include "absl/strings/str_format.h"
#include "core/dgg/graph_file.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunGraphInfo(const std::string& path, bool json) {
  auto info = GraphFile::Inspect(path);
  if (!info.ok()) return Fail("info", info.status());
  const double average_degree =
      info->num_nodes ? double(info->num_directed_edges) / info->num_nodes : 0;
  if (json) {
    PrintJson({{"path", path},
               {"format_version", info->version},
               {"mesh_fingerprint",
                absl::StrFormat("%016x", static_cast<unsigned long long>(info->mesh_fingerprint))},
               {"epsilon", info->params.epsilon},
               {"pseudo_vertices_enabled", info->params.pseudo_vertices},
               {"prune_redundant", info->params.prune_redundant},
               {"exact_fans", info->params.exact_fans},
               {"candidate_rule", info->params.candidate_rule},
               {"build", DescribeParams(info->params)},
               {"vertices", info->num_mesh_vertices},
               {"nodes", info->num_nodes},
               {"pseudo_vertices", info->num_nodes - info->num_mesh_vertices},
               {"edges", info->num_directed_edges / 2},
               {"average_degree", average_degree},
               {"file_bytes", info->file_bytes},
               {"checksums_ok", true}});
  } else {
    std::printf(
        "%s: geodesicd graph, format version %u\n  mesh fingerprint %016llx, %u vertices\n"
        "  built with %s\n  pseudo vertices: %u\n  %llu edges, average degree %.2f\n"
        "  %llu bytes, all section checksums valid\n",
        path.c_str(), info->version, static_cast<unsigned long long>(info->mesh_fingerprint),
        info->num_mesh_vertices, DescribeParams(info->params).c_str(),
        info->num_nodes - info->num_mesh_vertices,
        static_cast<unsigned long long>(info->num_directed_edges / 2), average_degree,
        static_cast<unsigned long long>(info->file_bytes));
  }
  return 0;
}

}  // namespace geodesic::offline
