// What the gateway decides before a request's body is read and around it:
// the bearer token from the headers alone, refusals the HTTP server asks
// for (too large, busy, malformed), and reservations within --memory-limit
// for bodies and answers. Apart from the route table so that what guards
// the daemon's memory and the token before the body reads as one piece.
#include <algorithm>
#include <string>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "server/api/convert.h"
#include "server/gateway/gateway_impl.h"

namespace geodesic::server {
// The gateway's helpers (gateway_call.h), unqualified as the handlers were
// written; this file is compiled alone, never in a unity batch.
using namespace gateway;  // NOLINT(build/namespaces)

// On an io thread, before the body is read: what can be answered from the
// headers alone is, so that a body nobody will use is never read.
std::optional<HttpResponse> HttpGateway::Impl::Admit(const HttpRequest& head,
                                                     size_t* body_limit) const {
  if (auto preflight = Preflight(head)) return preflight;
  if (head.header("Content-Type").starts_with("application/x-www-form-urlencoded")) {
    *body_limit = std::min(*body_limit, kFormBodyLimit);
  }
  std::vector<std::string> args;
  std::string allow;
  const Route* route = FindRoute(head, &args, &allow);
  if (!route) {
    if (!allow.empty()) return NotAllowed(head, allow);
    const bool maybe_file =
        (head.method == "GET" || head.method == "HEAD") && !head.path.starts_with("/v1/");
    if (maybe_file) return std::nullopt;
    return NotFound(head);
  }
  if (std::holds_alternative<Page>(route->handler)) return std::nullopt;
  // The service checks the token again on every call; this check spares the
  // body of a request that would be refused.
  const std::string value = head.header("Authorization");
  const absl::Status known =
      identity.Authenticate({.headers = head.header_count("Authorization"), .value = value});
  if (!known.ok()) return ErrorResponse(ToGrpc(known));
  return std::nullopt;
}

std::optional<HttpResponse> HttpGateway::Impl::ReserveBody(const HttpRequest& head,
                                                           size_t body_bytes,
                                                           std::shared_ptr<void>* hold) const {
  if (!options.memory) return std::nullopt;
  const bool is_json = head.header("Content-Type").starts_with("application/json");
  auto reserved = options.memory->Reserve(
      (is_json ? kJsonBodyMemoryFactor : kFileBodyMemoryFactor) * body_bytes,
      absl::StrFormat("a request body of %u bytes, with what is made of it", body_bytes));
  if (reserved.ok()) {
    *hold = *std::move(reserved);
    return std::nullopt;
  }
  HttpResponse res = ErrorResponse(ToGrpc(reserved.status()));
  // Never fits: too large, as an over-long body is; fits later: busy.
  if (absl::IsResourceExhausted(reserved.status())) res.status = 413;
  return res;
}

// `bytes` of --memory-limit for the answer, held until it is sent (see
// ApiRequest::hold); the limit's refusal otherwise.
grpc::Status HttpGateway::Impl::ReserveAnswer(const ApiRequest& r, uint64_t bytes,
                                              const std::string& what) {
  if (!options.memory) return grpc::Status::OK;
  auto reserved = options.memory->Reserve(bytes, what);
  if (!reserved.ok()) return ToGrpc(reserved.status());
  *r.hold = *std::move(reserved);
  return grpc::Status::OK;
}

HttpResponse HttpGateway::Impl::Refuse(HttpRefusal why, const HttpRequest& head,
                                       size_t body_limit) const {
  switch (why) {
    case HttpRefusal::kBodyTooLarge: {
      HttpResponse res = ErrorResponse(grpc::Status(
          grpc::StatusCode::RESOURCE_EXHAUSTED,
          head.header("Content-Type").starts_with("application/x-www-form-urlencoded")
              ? absl::StrFormat("a body sent as application/x-www-form-urlencoded (curl -d's "
                                "default) is limited to %u bytes; send it with Content-Type: "
                                "application/json",
                                body_limit)
              : absl::StrFormat("request body over the limit of %u bytes", body_limit)));
      res.status = 413;
      return res;
    }
    case HttpRefusal::kHeaderTooLarge: {
      HttpResponse res =
          ErrorResponse(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                                     absl::StrFormat("request headers over the limit of %u bytes",
                                                     options.limits.max_header_bytes)));
      res.status = 431;
      return res;
    }
    case HttpRefusal::kBusy:
      return ErrorResponse(grpc::Status(
          grpc::StatusCode::UNAVAILABLE,
          absl::StrFormat("the HTTP gateway is busy: %d requests wait for a worker; retry",
                          options.limits.max_queued)));
    case HttpRefusal::kBadRequest:
      return ErrorResponse(Invalid("malformed HTTP request"));
    case HttpRefusal::kInternal:
      break;
  }
  return ErrorResponse(grpc::Status(grpc::StatusCode::INTERNAL, "internal error"));
}

}  // namespace geodesic::server
