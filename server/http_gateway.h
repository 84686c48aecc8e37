// The HTTP/JSON gateway and the web viewer: every /v1 call is translated to
// the gRPC service, called in-process, so that authentication, limits,
// validation and error codes are the gRPC API's own.
#ifndef GEODESIC_SERVER_HTTP_GATEWAY_H_
#define GEODESIC_SERVER_HTTP_GATEWAY_H_

#include <memory>
#include <string>

#include "absl/status/statusor.h"
#include "grpcpp/server.h"
#include "server/http_server.h"
#include "server/mesh_registry.h"

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
  // The gRPC service's token (empty: none). The gateway checks it as soon as
  // a request's headers are in, before reading its body; the service checks
  // it again on every call.
  std::string bearer_token;
  // A web origin (https://app.example.com, or * for any) whose pages may call
  // the /v1 API from the browser: answers carry Access-Control-Allow-Origin
  // and preflight OPTIONS requests are answered. Empty: same origin only.
  std::string cors_origin;
  // Deadlines, connection and worker limits (limits.max_body_bytes is
  // replaced by max_body_bytes above).
  HttpLimits limits;
};

class HttpGateway {
 public:
  // `grpc_server` must outlive the gateway; `meshes` is read directly only
  // for GET /v1/meshes/{name}/geometry, after GetMesh has authorised it.
  static absl::StatusOr<std::unique_ptr<HttpGateway>> Start(const HttpGatewayOptions& options,
                                                            grpc::Server* grpc_server,
                                                            const MeshRegistry* meshes);
  // Stops accepting, finishes queued and running requests, closes every
  // connection.
  ~HttpGateway();

  int port() const;
  bool tls() const;

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
