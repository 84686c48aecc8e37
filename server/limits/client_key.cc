#include "server/limits/client_key.h"

#include <random>

#include "absl/strings/str_format.h"
#include "server/base/constant_time.h"

namespace geodesic::server {
namespace {

const std::string& ProcessSecret() {
  static const std::string* secret = [] {
    std::random_device random;
    return new std::string(
        absl::StrFormat("%08x%08x%08x%08x", random(), random(), random(), random()));
  }();
  return *secret;
}

std::string_view FirstMetadata(const grpc::ServerContext& ctx, std::string_view key) {
  auto [begin, end] = ctx.client_metadata().equal_range(grpc::string_ref(key.data(), key.size()));
  if (begin == end) return {};
  return std::string_view(begin->second.data(), begin->second.size());
}

Authorization AuthorizationOf(const grpc::ServerContext& ctx) {
  return {.headers = ctx.client_metadata().count("authorization"),
          .value = FirstMetadata(ctx, "authorization")};
}

// "ipv4:10.0.0.7:52814" -> "ipv4:10.0.0.7"; "ipv6:[::1]:52814" -> "ipv6:[::1]".
std::string WithoutPort(std::string peer) {
  const size_t colon = peer.rfind(':');
  if (colon != std::string::npos && colon + 1 < peer.size() &&
      peer.find_first_not_of("0123456789", colon + 1) == std::string::npos) {
    peer.resize(colon);
  }
  return peer;
}

}  // namespace

std::string HttpClientValue(std::string_view address) {
  return absl::StrFormat("%s %s", ProcessSecret(), std::string(address));
}

int ClientIdentity::TokenIndex(Authorization auth) const {
  if (auth.headers != 1) return -1;
  constexpr std::string_view kBearer = "Bearer ";
  if (!auth.value.starts_with(kBearer)) return -1;
  const std::string_view sent = auth.value.substr(kBearer.size());
  // Every token is compared, so that the time taken says nothing of which
  // one (or how much of one) matched.
  int found = -1;
  for (size_t i = 0; i < tokens_.size(); ++i) {
    if (ConstantTimeEquals(sent, tokens_[i])) found = static_cast<int>(i);
  }
  return found;
}

absl::Status ClientIdentity::Authenticate(Authorization auth) const {
  if (tokens_.empty()) return absl::OkStatus();
  if (auth.headers > 1) {
    return absl::UnauthenticatedError(absl::StrFormat(
        "%u authorization headers: send exactly one, 'authorization: Bearer <token>'",
        auth.headers));
  }
  if (TokenIndex(auth) < 0) {
    return absl::UnauthenticatedError(
        "missing or wrong bearer token: send 'authorization: Bearer <token>'");
  }
  return absl::OkStatus();
}

absl::Status ClientIdentity::Authenticate(const grpc::ServerContext& ctx) const {
  return Authenticate(AuthorizationOf(ctx));
}

std::string ClientIdentity::Key(const grpc::ServerContext& ctx) const {
  std::string key = WithoutPort(ctx.peer());
  const std::string secret = ProcessSecret() + " ";
  if (const std::string_view http = FirstMetadata(ctx, kHttpClientMetadata);
      http.starts_with(secret)) {
    key = "http ";
    key += http.substr(secret.size());
  }
  if (tokens_.empty()) return key;
  if (const int token = TokenIndex(AuthorizationOf(ctx)); token >= 0)
    key += absl::StrFormat(" token %d", token);
  return key;
}

}  // namespace geodesic::server
