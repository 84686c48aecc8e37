#include "server/grpc/rpc_support.h"

#include <algorithm>
#include <chrono>

#include "absl/strings/cord.h"
#include "absl/strings/str_cat.h"

namespace geodesic::server {

// A change of a mesh waited past the call's deadline for another change of
// the same mesh to finish.
absl::Status NameBusy(const std::string& mesh) {
  return absl::DeadlineExceededError(absl::StrFormat(
      "another change of mesh '%s' (a registration, unload or graph request) was still "
      "running when the deadline passed",
      mesh));
}

// States an operation leaves by itself, with the graph ready or failed.
bool InProgress(GraphState s) {
  return s == GraphState::kQueued || s == GraphState::kLoading || s == GraphState::kBuilding ||
         s == GraphState::kPersisting;
}

// When a wait must end for its refusal (an overload, a graph still being
// made) to reach the client before the call's deadline, as a retryable
// answer rather than DEADLINE_EXCEEDED: a tenth of the time left, between
// 20 ms and a quarter of a second, before the deadline.
absl::Time ReplyBy(const grpc::ServerContext* ctx) {
  const absl::Time deadline = absl::FromChrono(ctx->deadline());
  const absl::Duration margin =
      std::clamp((deadline - absl::Now()) / 10, absl::Milliseconds(20), absl::Milliseconds(250));
  return deadline - margin;
}

// A call over a per-call limit, refused RESOURCE_EXHAUSTED: each limit it
// passed rides as a trailer ("limit-max-pairs: 10000", "limit-max-sources",
// "limit-max-message-bytes"), so that a client splits its batch from them
// rather than from the message's prose.
absl::Status OverLimits(const std::string& message,
                        std::initializer_list<std::pair<const char*, uint64_t>> limits) {
  absl::Status refusal = absl::ResourceExhaustedError(message);
  for (const auto& [name, value] : limits) {
    refusal.SetPayload(absl::StrCat("limit-", name), absl::Cord(absl::StrCat(value)));
  }
  return refusal;
}

// Polled by long solves: the client went away or its deadline passed.
std::function<bool()> Cancelled(grpc::ServerContext* ctx) {
  return [ctx] { return ctx->IsCancelled() || ctx->deadline() < std::chrono::system_clock::now(); };
}

// What a query holds besides the graph, by kind (core/query/query_scratch.h): a
// field solve sizes its arrays to the graph's nodes and answers per mesh
// vertex; a point-to-point search keeps a 4-byte index per node and records
// for the few thousand nodes it touches.
uint64_t FieldScratchBytes(const GeodesicEngine& engine) {
  const uint64_t nodes = engine.graph().num_nodes();
  const uint64_t vertices = engine.mesh().num_vertices();
  constexpr uint64_t kPerNode = sizeof(double) + sizeof(FanRange) + sizeof(uint32_t) + 16;
  constexpr uint64_t kPerVertex = sizeof(double) + sizeof(uint32_t);
  return nodes * kPerNode + vertices * kPerVertex;
}

uint64_t PairScratchBytes(const GeodesicEngine& engine) {
  constexpr uint64_t kTouchedRecords = uint64_t{1} << 14;
  return uint64_t{engine.graph().num_nodes()} * sizeof(uint32_t) +
         kTouchedRecords * sizeof(PairTable::Record);
}

// Every vertex in file order: what a request's all_sources/all_targets stand for.
std::vector<SurfacePoint> AllVertices(const Mesh& mesh) {
  std::vector<SurfacePoint> points;
  points.reserve(mesh.num_vertices());
  for (VertexId v = 0; v < mesh.num_vertices(); ++v) points.push_back(SurfacePoint::Vertex(v));
  return points;
}

// The graph that answered, as echoes name it: with the epsilon it was built
// with, which for a certified graph the build chose.
GraphKey Built(GraphKey key, const GeodesicEngine& engine) {
  key.params.epsilon = engine.graph().params().epsilon;
  return key;
}

void FillMesh(const RegisteredMesh& m, v1::Mesh* out) {
  out->set_name(m.name);
  out->set_fingerprint(absl::StrFormat("%016x", m.fingerprint));
  out->set_source(m.source);
  out->set_restored(m.restored);
  out->set_repair_non_manifold(m.repair_non_manifold);
  for (const VertexCopy& c : m.vertex_copies) {
    auto* copy = out->add_vertex_copies();
    copy->set_original(c.original);
    copy->set_copy(c.copy);
  }
  ToProto(m.diagnostics, out->mutable_diagnostics());
  if (m.region) {
    out->set_parent(m.parent);
    out->set_parent_vertices(m.region->region_vertex.size());
    out->set_parent_faces(m.region->region_face.size());
  }
}

}  // namespace geodesic::server
