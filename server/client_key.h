// Who a call is, for fair shares: admission's turns and per-client share of
// slots, and the per-client build budget.
#ifndef GEODESIC_SERVER_CLIENT_KEY_H_
#define GEODESIC_SERVER_CLIENT_KEY_H_

#include <string>
#include <string_view>

#include "grpcpp/server_context.h"

namespace geodesic::server {

// Metadata the HTTP gateway adds to the calls it makes on the in-process
// channel, whose own peer says nothing of the HTTP client: the value of
// HttpClientValue(address).
inline constexpr char kHttpClientMetadata[] = "x-geodesic-http-client";
// The HTTP client's address behind a secret this process drew at random, so
// that a remote gRPC client cannot pose as another by sending the metadata.
std::string HttpClientValue(std::string_view address);

// The address a call comes from, without the port (a client's connections
// come from many), and the bearer token it sends, if any: clients that share
// one deployment token are still told apart by host, and clients behind one
// proxy by their tokens. The token stays in memory, in no message or log.
std::string ClientKey(const grpc::ServerContext& ctx);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CLIENT_KEY_H_
