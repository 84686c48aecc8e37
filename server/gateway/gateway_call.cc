// The gateway's call context and its status mapping (gateway_call.h).
#include "server/gateway/gateway_call.h"

#include <cstdlib>

#include "absl/strings/escaping.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "server/api/convert.h"
#include "server/base/echo.h"
#include "server/limits/admission.h"
#include "server/limits/client_key.h"

namespace geodesic::server::gateway {
namespace {

// FAILED_PRECONDITION means "request the graph first": the resource's state
// conflicts with the call (409), not a failed conditional header (412).
int HttpStatus(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK:
      return 200;
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::OUT_OF_RANGE:
      return 400;
    case grpc::StatusCode::UNAUTHENTICATED:
      return 401;
    case grpc::StatusCode::PERMISSION_DENIED:
      return 403;
    case grpc::StatusCode::NOT_FOUND:
      return 404;
    case grpc::StatusCode::ALREADY_EXISTS:
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::ABORTED:
      return 409;
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
      return 429;
    case grpc::StatusCode::CANCELLED:
      return 499;
    case grpc::StatusCode::UNIMPLEMENTED:
      return 501;
    case grpc::StatusCode::UNAVAILABLE:
      return 503;
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return 504;
    default:
      return 500;
  }
}

// Whether text is UTF-8, as protobuf requires of every string field (the
// JSON library's strict serialiser checks it).
bool IsUtf8(const std::string& text) {
  try {
    (void)json(text).dump();
    return true;
  } catch (const json::type_error&) {
    return false;
  }
}

}  // namespace

grpc::Status Invalid(const std::string& message) {
  return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, message);
}

std::string Dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

std::string Quote(const json& j) { return Cut(Dump(j)); }

HttpResponse ErrorResponse(const grpc::Status& s, std::optional<int64_t> retry_after_ms) {
  HttpResponse res;
  res.status = HttpStatus(s.error_code());
  if (s.error_code() == grpc::StatusCode::UNAUTHENTICATED) {
    res.headers.emplace_back("WWW-Authenticate", "Bearer");
  }
  // A client without the right credentials gets its answer and the
  // connection's end: kept alive, its connections would fill the cap.
  res.close = s.error_code() == grpc::StatusCode::UNAUTHENTICATED;
  if (retry_after_ms) {
    res.headers.emplace_back("Retry-After", std::to_string((*retry_after_ms + 999) / 1000));
  } else if (s.error_code() == grpc::StatusCode::UNAVAILABLE) {
    res.headers.emplace_back("Retry-After", "1");
  }
  json body = {{"error", {{"code", CodeName(s.error_code())}, {"message", s.error_message()}}}};
  res.body = Dump(body);
  res.content_type = "application/json";
  return res;
}

Call::Call(const HttpRequest& req, const std::vector<std::string>& segments)
    : client_address_(req.remote_address) {
  const std::string auth = req.header("Authorization");
  for (char c : auth) {
    if (c < 0x20 || c > 0x7e) {
      status_ = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                             "the Authorization header holds non-printable characters");
      return;
    }
  }
  auth_ = auth;
  for (const std::string& segment : segments) {
    if (!IsUtf8(segment)) {
      status_ = grpc::Status(
          grpc::StatusCode::INVALID_ARGUMENT,
          absl::StrFormat("path segment '%s' is not UTF-8", absl::CHexEscape(segment)));
      return;
    }
  }
  if (req.has_param("timeout")) {
    const std::string text = req.param("timeout");
    char* end = nullptr;
    const double seconds = std::strtod(text.c_str(), &end);
    if (text.empty() || end != text.c_str() + text.size() || !(seconds > 0 && seconds < 1e6)) {
      status_ = grpc::Status(
          grpc::StatusCode::INVALID_ARGUMENT,
          absl::StrFormat("query parameter timeout=%s is not a number of seconds in (0, 1e6)",
                          text));
      return;
    }
    deadline_ = std::chrono::system_clock::now() +
                std::chrono::microseconds(static_cast<int64_t>(seconds * 1e6));
  }
}

grpc::ClientContext* Call::Context() const {
  grpc::ClientContext* ctx = contexts_.emplace_back(std::make_unique<grpc::ClientContext>()).get();
  if (!auth_.empty()) ctx->AddMetadata("authorization", auth_);
  // Fair shares go by the HTTP client, not by the gateway's one channel.
  if (!client_address_.empty())
    ctx->AddMetadata(kHttpClientMetadata, HttpClientValue(client_address_));
  if (deadline_) ctx->set_deadline(*deadline_);
  return ctx;
}

std::optional<int64_t> Call::RetryAfterMs() const {
  if (contexts_.empty()) return std::nullopt;
  const auto& trailers = contexts_.back()->GetServerTrailingMetadata();
  auto it = trailers.find(kRetryAfterMsTrailer);
  int64_t ms;
  if (it == trailers.end() ||
      !absl::SimpleAtoi(absl::string_view(it->second.data(), it->second.size()), &ms) || ms < 0) {
    return std::nullopt;
  }
  return ms;
}

}  // namespace geodesic::server::gateway
