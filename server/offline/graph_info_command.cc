// geodesicd info GRAPH.dgg: describe and validate a graph file.
#include <cstdio>

#include "absl/strings/str_format.h"
#include "core/dgg/graph_file.h"
#include "server/offline/certificate_file.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunGraphInfo(const std::string& path, bool json) {
  auto info = GraphFile::Inspect(path);
  if (!info.ok()) return Fail("info", info.status());
  const double average_degree =
      info->num_nodes ? double(info->num_directed_edges) / info->num_nodes : 0;
  // A sidecar that is not this graph's certificate is reported, not shown.
  auto certificate = ReadCertificate(path, *info);
  if (!certificate.ok()) {
    std::fprintf(stderr, "geodesicd info: certificate ignored: %s\n",
                 std::string(certificate.status().message()).c_str());
    certificate = std::nullopt;
  }
  if (json) {
    Json report = {
        {"path", path},
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
        {"checksums_ok", true}};
    if (*certificate) report["certificate"] = CertificateJson(**certificate);
    PrintJson(report);
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
    if (const auto& c = *certificate) {
      std::printf(
          "  certified max error %g: measured max %.6g, mean %.6g from %u random vertex sources "
          "(seed %llu), %s, after %u build%s\n",
          c->max_error_bound, c->measured_max_error, c->measured_mean_error, c->sources,
          static_cast<unsigned long long>(c->seed), c->sound ? "sound" : "UNSOUND", c->builds,
          c->builds == 1 ? "" : "s");
    }
  }
  return 0;
}

}  // namespace geodesic::offline
