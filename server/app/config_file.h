// geodesicd serve --config FILE: the meshes and graphs a deployment
// declares, so that every replica starts with them without a client
// registering anything.
//
//   meshes:
//     - name: kitten
//       path: scans/kitten.off      # under --mesh-root, or an absolute path
//       repair_non_manifold: false  # optional
//   graphs:
//     - mesh: kitten
//       eps: 1e-3
//       pseudo_vertices: false      # optional
//     - mesh: kitten
//       max_error: 0.01             # instead of eps: a certified graph
//   flags:                          # any `geodesicd serve` flag but --config
//     memory-limit: 6G
//     max-pairs: 20000
//     exact-fans: true
//
// `flags` are the command line's own flags, by their names without the
// dashes, read by the same parser with the same checks and --help text
// (serve_options.cc): one set of limits for the command line, the file and
// the docs. A flag given on the command line wins over the file's.
//
// A graph with `max_error` (in [1e-5, 0.5], RequestGraph's range) is the
// certified graph of that bound, as RequestGraph's max_error asks for: its
// build chooses the epsilon, so an entry giving both `eps` and `max_error`
// is refused rather than have its `eps` silently ignored.
//
// Unknown keys are refused (a misspelt "pseudo_vertice" must not silently
// build the plain graph), and every error names the file, line and key.
#ifndef GEODESIC_SERVER_CONFIG_FILE_H_
#define GEODESIC_SERVER_CONFIG_FILE_H_

#include <string>
#include <vector>

#include "absl/status/statusor.h"

namespace geodesic::server {

struct DeclaredMesh {
  std::string name;
  std::string path;
  bool repair_non_manifold = false;
};

struct DeclaredGraph {
  std::string mesh;
  double epsilon = 0;    // 0 for a certified graph
  double max_error = 0;  // a certified graph's bound, or 0
  bool pseudo_vertices = false;
};

// One entry of `flags`: a serve flag's name (without dashes) and its value
// as text, with where it is written for error messages ("path:line:column").
struct DeclaredFlag {
  std::string name;
  std::string value;
  std::string where;
};

struct ServeConfig {
  std::vector<DeclaredMesh> meshes;
  std::vector<DeclaredGraph> graphs;
  std::vector<DeclaredFlag> flags;
};

absl::StatusOr<ServeConfig> ParseServeConfig(const std::string& text, const std::string& path);
absl::StatusOr<ServeConfig> LoadServeConfig(const std::string& path);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CONFIG_FILE_H_
