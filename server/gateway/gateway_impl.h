// The HTTP gateway's state and route handlers: HttpGateway's Impl, one
// class whose members are defined by job, in routes_meshes.cc (meshes and
// graphs), routes_queries.cc (queries and their points),
// gateway_admission.cc (the token before the body, refusals, memory) and
// http_gateway.cc (the route table, static files, CORS and start-up). Only
// server/gateway/ includes it.
#ifndef GEODESIC_SERVER_GATEWAY_GATEWAY_IMPL_H_
#define GEODESIC_SERVER_GATEWAY_GATEWAY_IMPL_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <variant>
#include <vector>

#include "geodesic/v1/geodesic.grpc.pb.h"
#include "grpcpp/grpcpp.h"
#include "server/gateway/gateway_call.h"
#include "server/gateway/http_gateway.h"
#include "server/http/http_server.h"
#include "server/limits/client_key.h"

namespace geodesic::server {

struct HttpGateway::Impl {
  using json = gateway::json;
  using Call = gateway::Call;
  using ApiRequest = gateway::ApiRequest;

  std::unique_ptr<v1::Geodesic::Stub> stub;
  HttpGatewayOptions options;
  ClientIdentity identity;  // of options.bearer_tokens
  std::string web_root;
  bool has_three = false;
  // Destroyed first: its workers call the members above.
  std::unique_ptr<HttpServer> server;

  // Points of a request (routes_queries.cc).
  grpc::Status Resolve(const Call& call, const std::string& mesh, const std::vector<json>& specs,
                       const std::string& what, std::vector<v1::SurfacePoint>* out);
  grpc::Status Specs(const Call& call, const std::string& mesh, const json& body, const char* key,
                     const std::string& what, std::vector<v1::SurfacePoint>* out);

  // Meshes and their graphs (routes_meshes.cc).
  grpc::Status ListMeshes(const Call& call, const ApiRequest&, json* out);
  grpc::Status GetMesh(const Call& call, const ApiRequest& r, json* out);
  grpc::Status RegisterMesh(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Upload(const Call& call, v1::UploadMeshRequest header, std::string_view data,
                      const std::vector<double>& vertices, const std::vector<uint32_t>& faces,
                      v1::Mesh* mesh);
  grpc::Status RegisterRegion(const Call& call, const ApiRequest& r, json* out);
  grpc::Status UnloadMesh(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Geometry(const Call& call, const ApiRequest& r, json*);
  grpc::Status RequestGraph(const Call& call, const ApiRequest& r, json* out);
  grpc::Status GetGraph(const Call& call, const ApiRequest& r, json* out);
  grpc::Status CancelGraph(const Call& call, const ApiRequest& r, json* out);
  grpc::Status ListGraphs(const Call& call, const ApiRequest&, json* out);

  // Queries (routes_queries.cc).
  grpc::Status Distance(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Field(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Matrix(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Sample(const Call& call, const ApiRequest& r, json* out);
  grpc::Status Snap(const Call& call, const ApiRequest& r, json* out);

  // The API, one row per path and method: a "{}" segment matches one path
  // segment (a mesh name), handed to the handler. A Handler answers JSON
  // from the gRPC service once the Call's checks (token, timeout) pass; a
  // Page answers by itself, with no token. A POST body is parsed before the
  // handler runs when the row lists the keys it takes: a key not listed is
  // refused rather than ignored, since a typo such as "pseudo_vertex" would
  // otherwise quietly answer from another graph. HttpGateway::Routes() gives
  // the table to the test that holds server/web/openapi.json to it.
  using Handler = grpc::Status (Impl::*)(const Call&, const ApiRequest&, json* out);
  using Page = HttpResponse (Impl::*)() const;
  struct Route {
    const char* method;
    const char* pattern;
    std::variant<Handler, Page> handler;
    std::vector<std::string> body_keys = {};
    // The body is the handler's to read (POST /v1/meshes also takes a mesh
    // file's bytes): body_keys are still the keys its JSON form takes.
    bool reads_own_body = false;
  };

  // What POST /v1/meshes takes as JSON: a file under --mesh-root or arrays.
  static inline const std::vector<std::string> kRegisterMeshKeys = {"name", "path", "vertices",
                                                                    "faces", "repair_non_manifold"};

  // The route table, static files and CORS (http_gateway.cc).
  static std::vector<std::string> WithGraph(std::vector<std::string> keys);
  static const std::vector<Route>& Routes();
  HttpResponse Answer(const Route& route, const HttpRequest& req,
                      const std::vector<std::string>& args);
  static bool Matches(std::string_view pattern, std::string_view path,
                      std::vector<std::string>* args);
  static const Route* FindRoute(const HttpRequest& req, std::vector<std::string>* args,
                                std::string* allow);
  HttpResponse OpenApi() const;
  HttpResponse NotFound(const HttpRequest& req) const;
  static HttpResponse NotAllowed(const HttpRequest& req, const std::string& allow);
  std::optional<HttpResponse> StaticFile(const HttpRequest& req) const;
  static std::string MimeType(const std::string& extension);
  HttpResponse Handle(const HttpRequest& req);
  HttpResponse WithCors(const HttpRequest& req, HttpResponse res) const;
  std::optional<HttpResponse> Preflight(const HttpRequest& head) const;

  // Before and around the body (gateway_admission.cc).
  std::optional<HttpResponse> Admit(const HttpRequest& head, size_t* body_limit) const;

  // A body and what is made of it, reserved within --memory-limit before it
  // is read. A JSON body becomes a tree of values, then copies of its
  // points, then the request message on both sides of the in-process
  // channel: a body of short tokens takes tens of times its text, and the
  // reservation covers that worst case. The daemon's peak resident memory
  // over idle for one 8 MiB body, measured: pairs of one-digit "v:ID"
  // strings 51 times its length, of four-digit ones 37, field or matrix
  // sources "v:1" 36, snap positions [0,0,0] 35, a list of {} 36 (the tree
  // alone); fairness_memory_test.py checks the first under --memory-limit.
  // A mesh file's bytes are copied a few times whole.
  static constexpr uint64_t kJsonBodyMemoryFactor = 64;
  static constexpr uint64_t kFileBodyMemoryFactor = 8;
  std::optional<HttpResponse> ReserveBody(const HttpRequest& head, size_t body_bytes,
                                          std::shared_ptr<void>* hold) const;
  grpc::Status ReserveAnswer(const ApiRequest& r, uint64_t bytes, const std::string& what);
  HttpResponse Refuse(HttpRefusal why, const HttpRequest& head, size_t body_limit) const;

  // Bodies sent as forms (curl -d's default content type) are capped as the
  // HTTP library the gateway used to run on capped them, so that a client
  // that forgot its JSON content type hears so rather than nothing.
  static constexpr size_t kFormBodyLimit = 8192;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GATEWAY_GATEWAY_IMPL_H_
