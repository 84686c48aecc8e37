// One call of the geodesic.v1.Geodesic service as its pipeline sees it
// (GeodesicService::Handle): what kind of RPC it is, from the one table of
// them, and who is calling, computed once.
#ifndef GEODESIC_SERVER_GRPC_CALL_H_
#define GEODESIC_SERVER_GRPC_CALL_H_

#include <span>
#include <string>
#include <string_view>

#include "grpcpp/server_context.h"

namespace geodesic::server {

// How admission treats an RPC before its handler runs.
struct RpcKind {
  const char* name;
  // Waits for a query's place among the admitted (--max-inflight and the
  // fair share). DistanceField and MatrixRows take theirs inside, once
  // their request is checked, since they hold a stream slot as well.
  bool query;
  // Holds a stream slot, and a thread, for as long as its client keeps it
  // open (--max-streams).
  bool stream;
  // May wait on a mesh's name or read a file: bounded apart, so that
  // listing, get and health always find a thread.
  bool change;
};

// Every RPC of the service, once (CallTest checks the table against the
// proto's service).
std::span<const RpcKind> Rpcs();
// The kind of `method`, one of Rpcs(); a name not in the table is a bug,
// and aborts.
const RpcKind& RpcNamed(std::string_view method);

// A call in the pipeline: its context, kind and client (client_key.h).
struct Call {
  grpc::ServerContext* ctx;
  const RpcKind& rpc;
  std::string client;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRPC_CALL_H_
