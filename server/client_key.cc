#include "server/client_key.h"

#include <random>

#include "absl/strings/str_format.h"

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

std::string ClientKey(const grpc::ServerContext& ctx) {
  std::string key = WithoutPort(ctx.peer());
  const std::string secret = ProcessSecret() + " ";
  if (const std::string_view http = FirstMetadata(ctx, kHttpClientMetadata);
      http.starts_with(secret)) {
    key = "http ";
    key += http.substr(secret.size());
  }
  constexpr std::string_view kBearer = "Bearer ";
  if (const std::string_view auth = FirstMetadata(ctx, "authorization");
      auth.starts_with(kBearer)) {
    key += " token ";
    key += auth.substr(kBearer.size());
  }
  return key;
}

}  // namespace geodesic::server
