// What the service's RPC files share (server/grpc/*_rpcs.cc): deadlines and
// cancellation, refusals and their trailers, stream reads and writes under
// the idle watch, scratch estimates and answer sizes, points and meshes as
// the API's messages.
#ifndef GEODESIC_SERVER_GRPC_RPC_SUPPORT_H_
#define GEODESIC_SERVER_GRPC_RPC_SUPPORT_H_

#include <cstdint>
#include <functional>
#include <initializer_list>
#include <string>
#include <utility>
#include <vector>

#include "absl/status/status.h"
#include "absl/status/statusor.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/base/status.h"
#include "core/query/geodesic_engine.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "grpcpp/grpcpp.h"
#include "server/api/convert.h"
#include "server/graphs/graph_key.h"
#include "server/limits/stream_watchdog.h"
#include "server/meshes/mesh_registry.h"

namespace geodesic::server {

// A graph still being made, in an UNAVAILABLE refusal's trailing metadata:
// its state's name and its progress in [0, 1].
inline constexpr char kGraphStateTrailer[] = "graph-state";
inline constexpr char kGraphProgressTrailer[] = "graph-progress";

// How long a slice of a long call (exact pairs, sampling) holds its run
// slot before it lets a waiting client's query run: short beside the second
// a light query may wait, long beside the cost of queueing again.
inline constexpr absl::Duration kSlice = absl::Milliseconds(50);

// Serialized sizes, a little over: a double takes 9 bytes with its tag
// unless packed, a message adds its tag and length, and the echo and
// framing stay under a kilobyte.
inline constexpr uint64_t kAnswerOverhead = 1024;
inline constexpr uint64_t kPairResultBytes = 16;
// A path's points are known only once it is found: queries reserve this
// many per path, and the answer is checked as it grows.
inline constexpr uint64_t kPathPointsReserved = 128;
inline constexpr uint64_t kPathPointBytes = 72;

// A change of a mesh waited past the call's deadline for another change of
// the same mesh to finish.
absl::Status NameBusy(const std::string& mesh);

// States an operation leaves by itself, with the graph ready or failed.
bool InProgress(GraphState s);

// When a wait must end for its refusal (an overload, a graph still being
// made) to reach the client before the call's deadline, as a retryable
// answer rather than DEADLINE_EXCEEDED: a tenth of the time left, between
// 20 ms and a quarter of a second, before the deadline.
absl::Time ReplyBy(const grpc::ServerContext* ctx);

// A call over a per-call limit, refused RESOURCE_EXHAUSTED: each limit it
// passed rides as a trailer ("limit-max-pairs: 10000", "limit-max-sources",
// "limit-max-message-bytes"), so that a client splits its batch from them
// rather than from the message's prose.
absl::Status OverLimits(const std::string& message,
                        std::initializer_list<std::pair<const char*, uint64_t>> limits);

// Polled by long solves: the client went away or its deadline passed.
std::function<bool()> Cancelled(grpc::ServerContext* ctx);

// What a query holds besides the graph, by kind (core/query/query_scratch.h): a
// field solve sizes its arrays to the graph's nodes and answers per mesh
// vertex; a point-to-point search keeps a 4-byte index per node and records
// for the few thousand nodes it touches.
uint64_t FieldScratchBytes(const GeodesicEngine& engine);

uint64_t PairScratchBytes(const GeodesicEngine& engine);

// Every vertex in file order: what a request's all_sources/all_targets stand for.
std::vector<SurfacePoint> AllVertices(const Mesh& mesh);

// The graph that answered, as echoes name it: with the epsilon it was built
// with, which for a certified graph the build chose.
GraphKey Built(GraphKey key, const GeodesicEngine& engine);

// One message of a stream written, the time the client takes to make room
// for it watched.
template <typename Message>
absl::Status Send(StreamWatchdog::Watch& watch, grpc::ServerWriter<Message>* writer,
                  const Message& message) {
  bool sent;
  {
    auto waiting = watch.WaitingOnClient();
    sent = writer->Write(message);
  }
  return sent ? absl::OkStatus() : watch.Ended();
}

// The next message of a stream read, the time the client takes to send it
// watched.
template <typename Message>
bool Receive(StreamWatchdog::Watch& watch, grpc::ServerReader<Message>* reader, Message* message) {
  auto waiting = watch.WaitingOnClient();
  return reader->Read(message);
}

// A request's points, each checked against the mesh; errors name the
// point ("source 3").
template <typename Points>
absl::StatusOr<std::vector<SurfacePoint>> PointsFromProto(const Points& points, const Mesh& mesh,
                                                          const char* what) {
  std::vector<SurfacePoint> out;
  out.reserve(points.size());
  for (int i = 0; i < points.size(); ++i) {
    ASSIGN_OR_RETURN(out.emplace_back(),
                     FromProto(points[i], mesh, absl::StrFormat("%s %d", what, i)));
  }
  return out;
}

// The API's view of a registered mesh.
void FillMesh(const RegisteredMesh& m, v1::Mesh* out);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRPC_RPC_SUPPORT_H_
