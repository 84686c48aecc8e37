// `geodesicd serve`'s command line, read once into ServeOptions: flags
// parsed and checked, byte sizes and durations converted, secrets and the
// --config file read (its `flags` parsed by the same parser, under the
// command line's). The daemon (daemon.h) starts from the result and
// never sees a flag.
#ifndef GEODESIC_SERVER_SERVE_OPTIONS_H_
#define GEODESIC_SERVER_SERVE_OPTIONS_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "grpcpp/security/server_credentials.h"
#include "server/app/config_file.h"
#include "server/http/http_server.h"
#include "server/limits/service_limits.h"

namespace geodesic::server {

struct ServeOptions {
  std::string listen;     // gRPC, HOST:PORT
  std::string port_file;  // empty: none
  std::string graph_dir;  // empty: graphs and meshes stay in memory
  std::string mesh_root;  // RegisterMesh paths lie under it (empty: anywhere)
  uint64_t memory_limit = 0;
  uint64_t disk_limit = 0;
  double catalog_poll_seconds = 2;
  int build_threads = 0;
  double pseudo_vertex_limit = 1;  // DggBuildOptions::pseudo_vertex_limit
  int build_workers = 1;
  uint64_t build_memory_limit = 0;
  double large_build_seconds = 60;
  uint64_t max_graph_bytes = 0;
  int exact_landmarks = 128;  // GraphCache::Options::exact_landmarks
  ServiceLimits limits;       // query_threads resolved to the cores when 0
  ServeConfig config;         // --config's meshes and graphs (none without it)

  std::string http_listen;  // empty: no HTTP gateway
  HttpLimits http_limits;
  std::string http_cors_origin;
  std::string metrics_listen;  // empty: no metrics listener

  // The mesh registered as 'spot': --sample-mesh, else the bundled one
  // (empty when --no-sample, or when none was found).
  bool no_sample = false;
  std::string sample_path;
  double drain_seconds = 10;

  // TLS files as given (the HTTP gateway reads them again), the gRPC
  // listener's credentials made from them, and the bearer tokens, one a
  // client (empty: none required).
  std::string tls_cert, tls_key, tls_client_ca;
  std::shared_ptr<grpc::ServerCredentials> credentials;
  std::vector<std::string> tokens;
};

// Reads `geodesicd serve`'s arguments into *out, and sets the log level and
// format and the malloc arenas they ask for. Returns the exit code when the
// command ends here (--help: 0; a flag CLI11 refuses: its code; a value or
// file that cannot be used: 2, with the reason on stderr), nothing when the
// daemon is to start.
std::optional<int> ParseServeOptions(int argc, char** argv, ServeOptions* out);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_SERVE_OPTIONS_H_
