// The HTTP/JSON gateway and the web viewer: every /v1 call is translated to
// the gRPC service, called in-process, so that authentication, limits,
// validation and error codes are the gRPC API's own.
//
// JSON to proto, route by route. Protobuf's JSON mapping (JsonStringToMessage)
// reads a body only where the documented contract (docs/http.md,
// server/web/openapi.json) is the request message's own JSON: POST
// /v1/meshes naming a file, {"name", "path", "repair_non_manifold"}, is
// RegisterMeshRequest key for key. Every other route is mapped by hand,
// because its contract is not the proto's: the graph is chosen by "eps"
// (the proto's epsilon; "epsilon" is an alias that must agree) on the mesh
// the URL names, or by the query string on GET and DELETE .../graph, and
// goes into the request's `graph` through MakeSelector (server/api/convert.h),
// as the CLI's does; points are SPEC strings ("v:12", "f:7:0.2,0.3,0.5",
// "xyz:" positions snapped by Snap) or bare ids, not SurfacePoint objects;
// distance pairs are [SPEC, SPEC] and "path" is with_path; snap positions
// are [x, y, z] triples and uploaded arrays [[x, y, z], ...] rows, not
// objects and flat arrays, and an upload's size and SHA-256 are computed
// here; sample's "count" is required, which proto3 cannot say. Answers are
// hand-built too: the contract writes +inf as null (protobuf: "Infinity"),
// 64-bit counts as numbers (protobuf: strings), states as "READY", epsilon
// as "eps", matrices as rows. Protobuf's parser is also laxer than the
// contract (numbers and booleans as strings, "NaN"): on the one route it
// reads it may accept such spellings, where hand-mapped keys refuse them
// with a 400 naming the key.
#ifndef GEODESIC_SERVER_HTTP_GATEWAY_H_
#define GEODESIC_SERVER_HTTP_GATEWAY_H_

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "grpcpp/server.h"
#include "server/http/http_server.h"
#include "server/limits/memory_ledger.h"
#include "server/limits/service_limits.h"

namespace geodesic::server {

struct HttpGatewayOptions {
  std::string listen;  // HOST:PORT; port 0 picks a free one
  // Same files as the gRPC listener's flags: TLS when cert and key are set,
  // client certificates signed by the CA required when it is set too.
  std::string tls_cert, tls_key, tls_client_ca;
  // The viewer's files; empty: found beside the binary (see FindWebRoot).
  std::string web_root;
  std::string three_root = "/usr/share/javascript/three";  // Debian's libjs-three
  size_t max_body_bytes = size_t{16} << 20;
  // The gRPC service's tokens (empty: none). The gateway checks them as soon
  // as a request's headers are in, before reading its body; the service
  // checks them again on every call.
  std::vector<std::string> bearer_tokens;
  // A web origin (https://app.example.com, or * for any) whose pages may call
  // the /v1 API from the browser: answers carry Access-Control-Allow-Origin
  // and preflight OPTIONS requests are answered. Empty: same origin only.
  std::string cors_origin;
  // Deadlines, connection and worker limits (limits.max_body_bytes is
  // replaced by max_body_bytes above).
  HttpLimits limits;
  // --memory-limit's share for request bodies and geometry answers; null:
  // not counted. Must outlive the gateway.
  MemoryLedger* memory = nullptr;
  // The gRPC service's limits: its largest answer and request are what the
  // gateway's in-process channel must carry.
  ServiceLimits service;
};

// One row of the gateway's route table: what server/web/openapi.json must
// document (tests/server/openapi_routes_test.cc holds it to the table).
struct GatewayRoute {
  std::string method;  // GET, POST or DELETE (HEAD is GET's)
  // "/v1/meshes/{}/distance": a "{}" segment is one path segment, the mesh's
  // name ({name} in openapi.json).
  std::string path;
  // The keys a JSON body may hold, any other refused; empty: no JSON body.
  std::vector<std::string> body_keys;
};

class HttpGateway {
 public:
  // `grpc_server` must outlive the gateway: every route calls its service.
  static absl::StatusOr<std::unique_ptr<HttpGateway>> Start(const HttpGatewayOptions& options,
                                                            grpc::Server* grpc_server);
  // Shutdown in steps (HttpServer's): stop accepting and reading new
  // requests; wait for the answers of those being answered until a
  // deadline; and, once the calls still running were stopped, wait again
  // for their answers and close every connection.
  void StopAccepting();
  void WaitForAnswers(std::chrono::steady_clock::time_point deadline);
  void Finish(std::chrono::steady_clock::time_point deadline);
  // Closes every connection, then waits for running requests to return.
  ~HttpGateway();

  int port() const;
  bool tls() const;

  // The route table, in its order.
  static std::vector<GatewayRoute> Routes();

 private:
  struct Impl;
  explicit HttpGateway(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

// GEODESIC_WEB_DIR, server/web in the source tree the binary was built from,
// or an installed share/geodesicd/web; empty when none exists.
std::string FindWebRoot();

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_HTTP_GATEWAY_H_
