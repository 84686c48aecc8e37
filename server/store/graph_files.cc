#include "server/store/graph_files.h"

#include <charconv>
#include <string_view>

#include "absl/strings/str_format.h"
#include "core/dgg/graph_file.h"

namespace geodesic::server {

std::string CachedGraphFileName(uint64_t mesh_fingerprint, const DggParams& params,
                                double max_error) {
  if (max_error <= 0) return GraphFileName(mesh_fingerprint, params);
  // As GraphFileName writes epsilon: the shortest text that reads back.
  char bound[32];
  const auto [end, ec] = std::to_chars(bound, bound + sizeof(bound), max_error);
  return absl::StrFormat(
      "%016x-cert%s%s%s%s-r%u.dgg", mesh_fingerprint, std::string_view(bound, end - bound),
      params.pseudo_vertices ? "-pseudo" : "", params.prune_redundant ? "-prune" : "",
      params.exact_fans ? "-xfans" : "", params.candidate_rule);
}

}  // namespace geodesic::server
