// What every /v1 call of the HTTP gateway shares: the Call that carries an
// HTTP request's token, client address and timeout into the gRPC calls it
// makes, what a route's handler reads (ApiRequest), and how a gRPC status
// becomes an HTTP error answer. Apart from the route handlers
// (gateway_impl.h) so that the JSON readers and the handlers of each
// resource use one copy.
#ifndef GEODESIC_SERVER_GATEWAY_GATEWAY_CALL_H_
#define GEODESIC_SERVER_GATEWAY_GATEWAY_CALL_H_

#include <chrono>
#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "grpcpp/grpcpp.h"
#include "nlohmann/json.hpp"
#include "server/http/http_server.h"

// The gateway's own helpers, in a namespace of their own: server/grpc/call.h
// has a Call of its own in geodesic::server.
namespace geodesic::server::gateway {

using json = nlohmann::json;

grpc::Status Invalid(const std::string& message);

// JSON text of a reply. Error messages quote request paths and values, which
// need not be UTF-8: those bytes become U+FFFD instead of an exception.
std::string Dump(const json& j);

// An offending request value as an error message quotes it, as JSON cut
// to kMaxEcho (base/echo.h): a huge body is not echoed back (or logged) whole.
std::string Quote(const json& j);

// `retry_after_ms`: the service's hint (its retry-after-ms trailer), sent
// as Retry-After in whole seconds; without one, UNAVAILABLE says a second.
HttpResponse ErrorResponse(const grpc::Status& s, std::optional<int64_t> retry_after_ms = {});

// A call's context: the HTTP bearer token travels as the gRPC metadata the
// service checks, so a wrong or missing token fails exactly as over gRPC.
// `?timeout=SECONDS` becomes the calls' deadline, which long solves poll.
class Call {
 public:
  // `segments`: the path's parts the route captured (mesh names).
  Call(const HttpRequest& req, const std::vector<std::string>& segments);
  // A fresh context per RPC (gRPC contexts are single-use), kept for the
  // HTTP request's life so that the last RPC's trailers can be read; the
  // deadline is the whole HTTP request's.
  grpc::ClientContext* Context() const;
  // The retry hint (milliseconds) of the last RPC's refusal, if it sent one.
  std::optional<int64_t> RetryAfterMs() const;
  // The deadline passed: an answer now comes too late for the client, as a
  // gRPC client's call fails once its deadline passes, whatever the server.
  bool expired() const { return deadline_ && std::chrono::system_clock::now() > *deadline_; }
  // Not OK when the request itself is unusable.
  const grpc::Status& status() const { return status_; }

 private:
  std::string auth_;
  std::string client_address_;
  std::optional<std::chrono::system_clock::time_point> deadline_;
  grpc::Status status_;
  mutable std::vector<std::unique_ptr<grpc::ClientContext>> contexts_;
};

// What a route's handler reads: the mesh its path names (empty when it
// names none), the HTTP request, and the JSON body the route takes (an
// empty object for routes that take none).
struct ApiRequest {
  const std::string& mesh;
  const HttpRequest& http;
  const json& body;
  // Set by a handler that answers in another format than JSON (a matrix as
  // .npy bytes): sent as it is instead of the handler's JSON.
  std::optional<HttpResponse>* raw = nullptr;
  // The answer's reservation within --memory-limit (ReserveAnswer), held
  // until the answer is sent.
  std::shared_ptr<void>* hold = nullptr;
};

}  // namespace geodesic::server::gateway

#endif  // GEODESIC_SERVER_GATEWAY_GATEWAY_CALL_H_
