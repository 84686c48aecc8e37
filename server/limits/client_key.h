// Who a call is, for fair shares: admission's turns and per-client share of
// slots, and the per-client build budget.
//
// An identity must cost a client what it is worth, or one client could
// mint as many as it likes and take every share: a key is made only of what
// the client cannot multiply for free, its host and, on a daemon that
// requires tokens, which of the daemon's own tokens authenticated the call.
// A token the daemon does not require is ignored, and a call that sends two
// authorization headers is refused (a proxy and this server could each read
// a different one). The trade-off: clients behind one address (a NAT, a
// proxy) share one share unless they authenticate with tokens of their own;
// shares bind only while another client waits (admission.h), so a host
// alone still has the whole server.
#ifndef GEODESIC_SERVER_CLIENT_KEY_H_
#define GEODESIC_SERVER_CLIENT_KEY_H_

#include <string>
#include <string_view>
#include <vector>

#include "absl/status/status.h"
#include "grpcpp/server_context.h"

namespace geodesic::server {

// Metadata the HTTP gateway adds to the calls it makes on the in-process
// channel, whose own peer says nothing of the HTTP client: the value of
// HttpClientValue(address).
inline constexpr char kHttpClientMetadata[] = "x-geodesic-http-client";
// The HTTP client's address behind a secret this process drew at random, so
// that a remote gRPC client cannot pose as another by sending the metadata.
std::string HttpClientValue(std::string_view address);

// A call's authorization headers, from gRPC metadata or HTTP alike: how
// many it sent, and the first one's value.
struct Authorization {
  size_t headers = 0;
  std::string_view value;
};

// The bearer tokens a daemon accepts (--auth-token-file, one a line), each
// a client of its own on every host; none: calls need no token. The gRPC
// service and the HTTP gateway (before it reads a body) check a token here,
// with one message for each way to fail.
class ClientIdentity {
 public:
  explicit ClientIdentity(std::vector<std::string> tokens = {}) : tokens_(std::move(tokens)) {}

  bool tokens_required() const { return !tokens_.empty(); }

  // UNAUTHENTICATED when tokens are required and the call does not send
  // exactly one 'authorization: Bearer <token>' with one of them.
  absl::Status Authenticate(Authorization auth) const;
  absl::Status Authenticate(const grpc::ServerContext& ctx) const;

  // The call's client: its host (the address without the port: a client's
  // connections come from many), or for the gateway's calls its HTTP
  // client's address, and the number of the token that authenticated it.
  // The token itself stays in memory, in no key, message or log.
  std::string Key(const grpc::ServerContext& ctx) const;

 private:
  // The index of the one token the call's single authorization header
  // names; -1 for none, or for two or more headers.
  int TokenIndex(Authorization auth) const;

  std::vector<std::string> tokens_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CLIENT_KEY_H_
