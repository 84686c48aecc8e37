// The gateway's JSON readers: a request body parsed with its limits (depth,
// duplicate keys), the keys a route takes, and each key or query parameter
// the routes share read into its request field with a 400 naming it. Apart
// from the handlers so that every route reads a key the same way and
// refuses it with the same words.
#ifndef GEODESIC_SERVER_GATEWAY_JSON_REQUESTS_H_
#define GEODESIC_SERVER_GATEWAY_JSON_REQUESTS_H_

#include <cstdint>
#include <string>
#include <type_traits>
#include <vector>

#include "absl/strings/str_format.h"
#include "geodesic/v1/geodesic.pb.h"
#include "google/protobuf/message.h"
#include "grpcpp/grpcpp.h"
#include "nlohmann/json.hpp"
#include "server/api/convert.h"
#include "server/gateway/gateway_call.h"
#include "server/http/http_server.h"

namespace geodesic::server::gateway {

// The body as a JSON object ({} when empty); one nested too deep to read
// safely, or giving a key twice, is refused.
grpc::Status ParseBody(const HttpRequest& req, json* body);

// A key the route does not take is refused rather than ignored (see the
// route table in http_gateway.cc).
grpc::Status OnlyKeys(const json& body, const std::vector<std::string>& keys);

// Epsilon from the body's "eps" (or "epsilon"); absent means the server's
// default, which the service applies to 0.
grpc::Status BodyEpsilon(const json& body, double* eps);

grpc::Status QueryEpsilon(const HttpRequest& req, double* eps);

// The body's "max_error" (absent or 0: not a certified graph).
grpc::Status BodyMaxError(const json& body, double* max_error);

grpc::Status QueryMaxError(const HttpRequest& req, double* max_error);

grpc::Status BoolField(const json& body, const char* key, bool* out);

// A request for the graph of `mesh` (the path's) that the body chooses:
// "eps" (or "epsilon"; absent: the server's default), "pseudo_vertices"
// (the graph with pseudo vertices, a separate graph) and "max_error" (a
// certified graph, whose epsilon the server chooses). It goes in the
// request's `graph`, made by the conversion the CLI uses too.
template <typename Request>
grpc::Status ForGraphOf(const std::string& mesh, const json& body, Request* req) {
  double epsilon, max_error;
  bool pseudo_vertices;
  if (grpc::Status s = BodyEpsilon(body, &epsilon); !s.ok()) return s;
  if (grpc::Status s = BoolField(body, "pseudo_vertices", &pseudo_vertices); !s.ok()) return s;
  if (grpc::Status s = BodyMaxError(body, &max_error); !s.ok()) return s;
  *req->mutable_graph() = MakeSelector(mesh, epsilon, pseudo_vertices);
  req->mutable_graph()->set_max_error(max_error);
  return grpc::Status::OK;
}

// The same from the query string: ?eps=E&pseudo_vertices=true&max_error=M.
template <typename Request>
grpc::Status ForGraphOfQuery(const std::string& mesh, const HttpRequest& http, Request* req) {
  double epsilon, max_error;
  if (grpc::Status s = QueryEpsilon(http, &epsilon); !s.ok()) return s;
  if (grpc::Status s = QueryMaxError(http, &max_error); !s.ok()) return s;
  bool pseudo_vertices = false;
  if (http.has_param("pseudo_vertices")) {
    const std::string text = http.param("pseudo_vertices");
    if (text == "true" || text == "1") {
      pseudo_vertices = true;
    } else if (text != "false" && text != "0") {
      return Invalid(
          absl::StrFormat("query parameter pseudo_vertices=%s: expected true or false", text));
    }
  }
  *req->mutable_graph() = MakeSelector(mesh, epsilon, pseudo_vertices);
  req->mutable_graph()->set_max_error(max_error);
  return grpc::Status::OK;
}

// A body whose keys are a request message's fields, under the fields' names
// and with their JSON types, read by protobuf's JSON mapping. Keys the route
// does not take were refused before (OnlyKeys); those of the route's other
// form are left to it.
grpc::Status MessageOf(const json& body, google::protobuf::Message* out);

grpc::Status ArrayField(const json& body, const char* key, const json** out);

// "key": [[a, b, c], ...] as a flat array of T (doubles, or vertex ids).
template <typename T>
grpc::Status Rows(const json& body, const char* key, std::vector<T>* out) {
  auto it = body.find(key);
  if (it == body.end() || !it->is_array()) {
    return Invalid(absl::StrFormat("\"%s\" must be an array of [a, b, c] rows", key));
  }
  out->reserve(3 * it->size());
  for (size_t i = 0; i < it->size(); ++i) {
    const json& row = (*it)[i];
    bool ok = row.is_array() && row.size() == 3;
    for (size_t k = 0; ok && k < 3; ++k) {
      ok = std::is_floating_point_v<T>
               ? row[k].is_number()
               : row[k].is_number_unsigned() && row[k].template get<uint64_t>() <= UINT32_MAX;
      if (ok) out->push_back(row[k].template get<T>());
    }
    if (!ok) {
      return Invalid(absl::StrFormat("%s row %u: expected three %s, got %s", key, i,
                                     std::is_floating_point_v<T> ? "numbers" : "vertex ids",
                                     Quote(row)));
    }
  }
  return grpc::Status::OK;
}

// The client asked for a matrix as NumPy bytes rather than JSON.
bool WantsNpy(const HttpRequest& http);

// The body's "dtype": "float32" or "float64" (absent: float64).
grpc::Status BodyDtype(const json& body, v1::MatrixDtype* dtype);

}  // namespace geodesic::server::gateway

#endif  // GEODESIC_SERVER_GATEWAY_JSON_REQUESTS_H_
