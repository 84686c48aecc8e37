#include "server/grpc/geodesic_service.h"

#include <algorithm>
#include <bit>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <optional>
#include <string_view>
#include <thread>

#include "absl/cleanup/cleanup.h"
#include "absl/status/status.h"
#include "absl/strings/cord.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/base/status.h"
#include "core/dgg/dgg_build.h"
#include "server/api/convert.h"
#include "server/base/echo.h"
#include "server/base/log.h"
#include "server/limits/client_key.h"
#include "server/meshes/upload.h"

namespace geodesic::server {
namespace {

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

// A graph still being made, in an UNAVAILABLE refusal's trailing metadata:
// its state's name and its progress in [0, 1].
constexpr char kGraphStateTrailer[] = "graph-state";
constexpr char kGraphProgressTrailer[] = "graph-progress";

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

// The most a request's parts take on the wire when they are valid (a face
// point is 35 bytes, a pair of them 76), with room to spare for fields a
// newer client adds; what a request may hold besides them (names); and what
// a decoded request takes in memory per byte on the wire at most (measured:
// about 14 for pairs of vertex points).
constexpr uint64_t kPointWireBytes = 64;
constexpr uint64_t kPairWireBytes = 128;
constexpr uint64_t kRequestWireOverhead = 64 << 10;
constexpr uint64_t kDecodedBytesPerWireByte = 16;

// Room for a list that grows with a mesh: 4M ids of up to four bytes (a
// region of half an 8M-face mesh, a field's targets), and for an upload's
// messages.
constexpr uint64_t kMeshListRequestBytes = uint64_t{16} << 20;

uint64_t DistanceRequestBytes(const ServiceLimits& limits) {
  return limits.max_pairs * kPairWireBytes + kRequestWireOverhead;
}
uint64_t MatrixRequestBytes(const ServiceLimits& limits) {
  return (uint64_t(limits.max_sources) + limits.max_pairs) * kPointWireBytes + kRequestWireOverhead;
}
uint64_t SnapRequestBytes(const ServiceLimits& limits) {
  return limits.max_pairs * kPointWireBytes + kRequestWireOverhead;
}

// How long a query waits for admission when it is full, at most: long
// beside a light query's run, short beside a client's patience.
constexpr absl::Duration kAdmissionWait = absl::Seconds(1);

// Polled by long solves: the client went away or its deadline passed.
std::function<bool()> Cancelled(grpc::ServerContext* ctx) {
  return [ctx] { return ctx->IsCancelled() || ctx->deadline() < std::chrono::system_clock::now(); };
}

// How long a slice of a long call (exact pairs, sampling) holds its run
// slot before it lets a waiting client's query run: short beside the second
// a light query may wait, long beside the cost of queueing again.
constexpr absl::Duration kSlice = absl::Milliseconds(50);

// Streams hold a thread for as long as the client keeps them open: they are
// bounded on their own (--max-streams), apart from the control calls, also
// when they are queries too.
bool IsStream(std::string_view method) {
  return method == "GetGeometry" || method == "MatrixRows" || method == "DistanceField" ||
         method == "WatchGraph" || method == "UploadMesh";
}

// Control calls that may wait on a mesh's name or read a file (admission's
// changes); uploads are streams.
bool IsChange(std::string_view method) {
  return method == "RegisterMesh" || method == "RegisterRegion" || method == "UnloadMesh" ||
         method == "RequestGraph" || method == "CancelGraph";
}

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

// Error messages travel in trailing metadata, which clients cap (8 KiB by
// default): input echoed into them is cut, and so is the whole message.
constexpr size_t kEchoChars = 80;
constexpr size_t kMessageChars = 1024;

std::string Shorten(std::string_view text) {
  if (text.size() <= kEchoChars) return std::string(text);
  return absl::StrFormat("%s... (%u bytes)", text.substr(0, kEchoChars), text.size());
}

// Cuts the mesh name and any quoted run longer than kEchoChars, then the
// message to kMessageChars.
std::string CapMessage(std::string message, std::string_view mesh) {
  if (mesh.size() > kEchoChars) {
    const std::string cut = Shorten(mesh);
    for (size_t at = message.find(mesh); at != std::string::npos;
         at = message.find(mesh, at + cut.size())) {
      message.replace(at, mesh.size(), cut);
    }
  }
  // Names and paths are quoted; prose between two apostrophes has spaces.
  for (size_t open = message.find('\''); open != std::string::npos;) {
    size_t close = message.find('\'', open + 1);
    if (close == std::string::npos) break;
    const std::string_view quoted = std::string_view(message).substr(open + 1, close - open - 1);
    if (quoted.size() > kEchoChars && quoted.find(' ') == std::string_view::npos) {
      const std::string cut = Shorten(quoted);
      message.replace(open + 1, quoted.size(), cut);
      close = open + 1 + cut.size();
    }
    open = message.find('\'', close + 1);
  }
  if (message.size() > kMessageChars) {
    const size_t total = message.size();
    message.resize(kMessageChars);
    message += absl::StrFormat("... (%u bytes in all)", total);
  }
  return message;
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

// Packed matrices are the host's own bytes, which the wire format promises
// to be little-endian.
static_assert(std::endian::native == std::endian::little,
              "packed matrix values are copied as the host holds them");

// Bytes of one value of a packed dtype; 0 for MATRIX_DTYPE_DEFAULT, whose
// values travel as repeated doubles.
size_t PackedBytes(v1::MatrixDtype dtype) {
  switch (dtype) {
    case v1::MATRIX_DTYPE_FLOAT32:
      return sizeof(float);
    case v1::MATRIX_DTYPE_FLOAT64:
      return sizeof(double);
    default:
      return 0;
  }
}

// A sparse row's entries within the radius, as the chunk's bytes will
// hold them; +inf (unreachable) is never within a finite radius.
struct SparseRow {
  std::string indices, values;
  uint64_t count = 0;
};

// A row's entries within `radius` (exact rows come with every finite entry:
// their search has no limit).
SparseRow WithinRadius(absl::Span<const uint32_t> columns, absl::Span<const double> values,
                       double radius, bool narrow) {
  SparseRow kept;
  for (size_t e = 0; e < columns.size(); ++e) {
    if (!(values[e] <= radius)) continue;
    kept.indices.append(reinterpret_cast<const char*>(&columns[e]), sizeof(uint32_t));
    if (narrow) {
      const float value = static_cast<float>(values[e]);
      kept.values.append(reinterpret_cast<const char*>(&value), sizeof value);
    } else {
      kept.values.append(reinterpret_cast<const char*>(&values[e]), sizeof(double));
    }
    ++kept.count;
  }
  return kept;
}

// The first chunk->rows() staged rows as the chunk's CSR bytes (indptr,
// indices, values), each staged row emptied for the next block.
void MoveSparseRows(std::vector<SparseRow>& staged, v1::MatrixRowsChunk* chunk) {
  std::string* indptr = chunk->mutable_indptr();
  uint64_t offset = 0;
  indptr->append(reinterpret_cast<const char*>(&offset), sizeof offset);
  for (size_t k = 0; k < chunk->rows(); ++k) {
    SparseRow& row = staged[k];
    offset += row.count;
    indptr->append(reinterpret_cast<const char*>(&offset), sizeof offset);
    chunk->mutable_indices()->append(row.indices);
    chunk->mutable_values()->append(row.values);
    row = SparseRow();
  }
}

// Where the rows of a dense matrix go as they are computed: row i to
// `dense` (the reply's values, or the block's, as the block being filled
// sets it) at row i % block_rows, float32 rows as they come, rounded
// already (most straight from the sweep), float64 ones copied.
MatrixRowSink DenseSink(size_t block_rows, bool narrow, char* const& dense) {
  MatrixRowSink sink;
  if (narrow) {
    sink.float32_row = [=, &dense](size_t i, absl::Span<const float> row) {
      std::memcpy(dense + (i % block_rows) * row.size() * sizeof(float), row.data(),
                  row.size() * sizeof(float));
      return absl::OkStatus();
    };
  } else {
    sink.row = [=, &dense](size_t i, absl::Span<const double> row) {
      std::memcpy(dense + (i % block_rows) * row.size() * sizeof(double), row.data(),
                  row.size() * sizeof(double));
      return absl::OkStatus();
    };
  }
  return sink;
}

// Where a MatrixRows block's rows go as they are computed, in a block of
// `block_rows`: with a `radius` (> 0), the entries within it staged; else
// as DenseSink puts them.
MatrixRowSink BlockSink(size_t block_rows, double radius, bool narrow, char* const& dense,
                        std::vector<SparseRow>& staged) {
  MatrixRowSink sink;
  if (radius > 0) {
    sink.sparse_row = [=, &staged](size_t i, absl::Span<const uint32_t> columns,
                                   absl::Span<const double> values) {
      staged[i % block_rows] = WithinRadius(columns, values, radius, narrow);
      return absl::OkStatus();
    };
  } else {
    sink = DenseSink(block_rows, narrow, dense);
  }
  sink.batch_rows = block_rows;
  return sink;
}

// Serialized sizes, a little over: a double takes 9 bytes with its tag
// unless packed, a message adds its tag and length, and the echo and
// framing stay under a kilobyte.
constexpr uint64_t kAnswerOverhead = 1024;
constexpr uint64_t kPairResultBytes = 16;
// A path's points are known only once it is found: queries reserve this
// many per path, and the answer is checked as it grows.
constexpr uint64_t kPathPointsReserved = 128;
constexpr uint64_t kPathPointBytes = 72;

// The graph that answered, as echoes name it: with the epsilon it was built
// with, which for a certified graph the build chose.
GraphKey Built(GraphKey key, const GeodesicEngine& engine) {
  key.params.epsilon = engine.graph().params().epsilon;
  return key;
}

}  // namespace

uint64_t MaxRequestBytes(const ServiceLimits& limits) {
  return std::max({DistanceRequestBytes(limits), MatrixRequestBytes(limits),
                   SnapRequestBytes(limits), kMeshListRequestBytes});
}

GeodesicService::GeodesicService(MeshRegistry* meshes, GraphCache* graphs, Metrics* metrics,
                                 ServiceLimits limits)
    : meshes_(meshes),
      graphs_(graphs),
      metrics_(metrics),
      limits_(limits),
      admission_(AdmissionOptions{
          .max_inflight = limits.max_inflight,
          .query_threads = limits.query_threads > 0
                               ? limits.query_threads
                               : std::max(1, static_cast<int>(std::thread::hardware_concurrency())),
          .max_streams = limits.max_streams,
          .max_inflight_per_client = limits.max_inflight_per_client,
          .max_streams_per_client = limits.max_streams_per_client,
          .memory_limit = graphs->memory_limit(),
          .held =
              [this, meshes, graphs] {
                return meshes->resident_bytes() + graphs->resident_bytes() +
                       graphs->mapped_bytes() + (ledger_ ? ledger_->reserved() : 0);
              },
          .pinned = [meshes] { return meshes->resident_bytes(); },
          .pooled_scratch = [graphs] { return graphs->scratch_bytes(); },
      }),
      watchdog_(absl::Seconds(limits.idle_seconds)) {
  // The requests whose size the limits bound are read as bytes and measured
  // against that bound, and the memory their decoding takes reserved, before
  // any of them is decoded (a 57 MiB DistanceRequest of 6M pairs took
  // 820 MB and 24 s to decode before --max-pairs refused it).
  const uint64_t pairs = limits.max_pairs, sources = limits.max_sources;
  DecodeWithinLimits<v1::DistanceRequest, v1::DistanceResponse>(
      "Distance", DistanceRequestBytes(limits), absl::StrFormat("--max-pairs %u", pairs),
      &GeodesicService::Distance);
  DecodeWithinLimits<v1::MatrixRequest, v1::MatrixResponse>(
      "Matrix", MatrixRequestBytes(limits),
      absl::StrFormat("--max-sources %u sources and --max-pairs %u targets", sources, pairs),
      &GeodesicService::Matrix);
  DecodeWithinLimits<v1::SnapRequest, v1::SnapResponse>(
      "Snap", SnapRequestBytes(limits), absl::StrFormat("--max-pairs %u positions", pairs),
      &GeodesicService::Snap);
}

template <class Request, class Response>
void GeodesicService::DecodeWithinLimits(
    const char* method, uint64_t max_bytes, std::string limit,
    grpc::Status (GeodesicService::*handler)(grpc::ServerContext*, const Request*, Response*)) {
  const int index = v1::DistanceRequest::descriptor()
                        ->file()
                        ->FindServiceByName("Geodesic")
                        ->FindMethodByName(method)
                        ->index();
  using Streamer = grpc::ServerUnaryStreamer<grpc::ByteBuffer, Response>;
  MarkMethodStreamed(
      index, new grpc::internal::StreamedUnaryHandler<grpc::ByteBuffer, Response>(
                 [this, method, max_bytes, limit, handler](grpc::ServerContext* ctx,
                                                           Streamer* stream) -> grpc::Status {
                   grpc::ByteBuffer raw;
                   if (!stream->Read(&raw)) {
                     return grpc::Status(grpc::StatusCode::CANCELLED, "no request came");
                   }
                   Request req;
                   absl::StatusOr<std::shared_ptr<void>> decoding =
                       DecodeRequest(ctx, method, max_bytes, limit, raw, &req);
                   if (!decoding.ok()) {
                     return Handle(method, ctx, "", false, [&] { return decoding.status(); });
                   }
                   Response resp;
                   grpc::Status status = (this->*handler)(ctx, &req, &resp);
                   decoding->reset();
                   // The write returns once the answer is sent; one its client
                   // does not take within --idle-seconds is cancelled.
                   if (status.ok()) {
                     // As AnswerWatch watches unary answers.
                     StreamWatchdog::Watch watch = watchdog_.AddWaiting(
                         absl::StrFormat("the answer of /geodesic.v1.Geodesic/%s to %s", method,
                                         ctx->peer()),
                         [ctx] { ctx->TryCancel(); });
                     if (!stream->Write(resp)) {
                       status =
                           grpc::Status(grpc::StatusCode::CANCELLED, "the answer was not taken");
                     }
                   }
                   AnswerSent(ctx);
                   return status;
                 }));
}

template <class Request>
absl::StatusOr<std::shared_ptr<void>> GeodesicService::DecodeRequest(
    grpc::ServerContext* ctx, const char* method, uint64_t max_bytes, const std::string& limit,
    grpc::ByteBuffer& raw, Request* req) {
  RETURN_IF_ERROR(identity_.Authenticate(*ctx));
  const uint64_t bytes = raw.Length();
  if (bytes > max_bytes) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "the %s request is %u bytes, more than this server's limits let one be (%u bytes: "
        "%s); split it",
        method, bytes, max_bytes, limit));
  }
  std::shared_ptr<void> decoding;
  if (ledger_ != nullptr) {
    ASSIGN_OR_RETURN(decoding, ledger_->Reserve(bytes * kDecodedBytesPerWireByte,
                                                absl::StrFormat("decoding a %s request", method)));
  }
  // proto/request_traits.h's deserializer: INVALID_ARGUMENT naming the
  // message, the client's fault.
  if (const grpc::Status parsed = grpc::SerializationTraits<Request>::Deserialize(&raw, req);
      !parsed.ok()) {
    return absl::InvalidArgumentError(parsed.error_message());
  }
  return decoding;
}

StreamWatchdog::Watch GeodesicService::WatchStream(const char* method, grpc::ServerContext* ctx) {
  return watchdog_.Add(absl::StrFormat("%s from %s", method, ctx->peer()),
                       [ctx] { ctx->TryCancel(); });
}

absl::StatusOr<Admission::Ticket> GeodesicService::AdmitQuery(grpc::ServerContext* ctx,
                                                              const std::string& client) {
  return admission_.AdmitQuery(client, std::min(ReplyBy(ctx), absl::Now() + kAdmissionWait),
                               Cancelled(ctx));
}

absl::StatusOr<Admission::Ticket> GeodesicService::StartQuery(grpc::ServerContext* ctx,
                                                              uint64_t answer_bytes,
                                                              uint64_t scratch_bytes) {
  // A refusal sent a little before the deadline reaches the client as an
  // overload, with its retry hint, not as DEADLINE_EXCEEDED.
  const absl::Time deadline = ReplyBy(ctx);
  return admission_.Run(answer_bytes, scratch_bytes, deadline, Cancelled(ctx), identity_.Key(*ctx));
}

void GeodesicService::HoldUntilSent(grpc::ServerContext* ctx, Admission::Ticket run) {
  Admission::Ticket answer = admission_.KeepAnswer(std::move(run));
  absl::MutexLock lock(&sending_mu_);
  sending_[ctx] = std::move(answer);
}

void GeodesicService::AnswerSent(const grpc::ServerContext* ctx) {
  Admission::Ticket sent;
  absl::MutexLock lock(&sending_mu_);
  if (auto it = sending_.find(ctx); it != sending_.end()) {
    sent = std::move(it->second);
    sending_.erase(it);
  }
}

absl::Status GeodesicService::NextSlice(grpc::ServerContext* ctx, Admission::Ticket& run,
                                        absl::Time& slice_start, uint64_t scratch_bytes) {
  if (absl::Now() - slice_start < kSlice || !admission_.OthersWaiting(identity_.Key(*ctx))) {
    return absl::OkStatus();
  }
  // The answer built so far stays reserved while the call waits its turn.
  Admission::Ticket kept = admission_.KeepAnswer(std::move(run));
  ASSIGN_OR_RETURN(Admission::Ticket next, StartQuery(ctx, 0, scratch_bytes));
  run = admission_.Adopt(std::move(next), std::move(kept));
  slice_start = absl::Now();
  return absl::OkStatus();
}

absl::Status GeodesicService::CheckMatrixLimits(const v1::MatrixRequest& req, bool streamed) {
  if (!std::isfinite(req.radius()) || req.radius() < 0) {
    return absl::InvalidArgumentError(
        absl::StrFormat("radius %g is not a finite distance >= 0 (0: dense rows)", req.radius()));
  }
  if (!v1::MatrixDtype_IsValid(req.dtype())) {
    return absl::InvalidArgumentError(
        absl::StrFormat("dtype %d is not a MatrixDtype", req.dtype()));
  }
  if (req.all_sources() && req.sources_size() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "all_sources and %d explicit sources: give one or the other", req.sources_size()));
  }
  if (req.all_targets() && req.targets_size() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "all_targets and %d explicit targets: give one or the other", req.targets_size()));
  }
  if (!streamed && req.radius() > 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "radius %g asks for sparse rows, which only MatrixRows answers", req.radius()));
  }
  uint64_t rows = req.sources_size(), cols = req.targets_size();
  if (!streamed && (req.all_sources() || req.all_targets())) {
    // Counted before any graph is waited for or built, so that a refusal
    // costs nothing.
    ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> mesh, FindMesh(SelectorOf(req).mesh()));
    if (req.all_sources()) rows = mesh->mesh->num_vertices();
    if (req.all_targets()) cols = mesh->mesh->num_vertices();
  }
  if (rows <= uint64_t(limits_.max_sources) && cols <= uint64_t(limits_.max_pairs)) {
    return absl::OkStatus();
  }
  return OverLimits(
      absl::StrFormat("matrix of %u x %u exceeds the limits (%d sources, %d targets)%s", rows, cols,
                      limits_.max_sources, limits_.max_pairs,
                      req.all_sources() || req.all_targets()
                          ? "; MatrixRows streams all_sources and all_targets of any mesh"
                          : ""),
      {{"max-sources", limits_.max_sources}, {"max-pairs", limits_.max_pairs}});
}

absl::Status GeodesicService::CheckAnswerSize(const std::string& what, uint64_t bytes) const {
  if (bytes <= limits_.max_message_bytes) return absl::OkStatus();
  return OverLimits(absl::StrFormat("the answer of %s would take about %u bytes, over the "
                                    "message cap of %u bytes: split it into row blocks (fewer "
                                    "sources or targets per call)",
                                    what, bytes, limits_.max_message_bytes),
                    {{"max-message-bytes", limits_.max_message_bytes}});
}

absl::StatusOr<double> GeodesicService::Epsilon(double requested) const {
  const double eps = requested == 0 ? limits_.default_epsilon : requested;
  if (!(eps >= 1e-6 && eps <= 0.5)) {
    return absl::InvalidArgumentError(absl::StrFormat("epsilon %g is outside [1e-6, 0.5]", eps));
  }
  return eps;
}

absl::StatusOr<GraphKey> GeodesicService::Key(const v1::GraphSelector& graph) const {
  GraphKey key{graph.mesh(), DggParams{}};
  if (graph.max_error() != 0) {
    // A certified graph: the bound chooses the epsilon, whatever the
    // selector says (a query's echo names the one it was built with).
    const double bound = graph.max_error();
    if (!IsCertifiableBound(bound)) {
      return absl::InvalidArgumentError(
          absl::StrFormat("max_error %g is outside %s", bound, kMaxErrorRange));
    }
    key.max_error = bound;
    key.params.epsilon = CertifiedKeyEpsilon(bound);
  } else {
    ASSIGN_OR_RETURN(key.params.epsilon, Epsilon(graph.epsilon()));
  }
  key.params.pseudo_vertices = graph.pseudo_vertices();
  key.params.exact_fans = limits_.exact_fans;
  return key;
}

absl::Status GeodesicService::Record(const RegisteredMesh& m, bool existed) {
  if (!catalog_) return absl::OkStatus();
  absl::Status s = catalog_->RecordMesh({m.name, m.source, m.format, m.source_hash, m.fingerprint,
                                         m.repair_non_manifold, m.parent,
                                         m.region_mask == RegionMask::kFaces, m.region_ids});
  // Not recorded, not registered: a client told of an error must not find
  // the mesh answering here and gone after a restart.
  if (!s.ok() && !existed) meshes_->Remove(m.name).IgnoreError();
  return s;
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> GeodesicService::FindMesh(
    const std::string& name) {
  auto m = meshes_->Get(name);
  if (m.ok() || !absl::IsNotFound(m.status()) || !catalog_) return m;
  // Registered on another replica sharing the graph directory, perhaps.
  RETURN_IF_ERROR(catalog_->ReconcileIfChanged());
  m = meshes_->Get(name);
  if (m.ok() || !absl::IsNotFound(m.status())) return m;
  if (std::optional<std::string> failure = catalog_->Failure(name)) {
    return absl::UnavailableError(absl::StrFormat(
        "mesh '%s' is in the catalog but could not be restored here (%s); the server tries "
        "again as it follows the catalog, or unload the mesh and register it again",
        name, *failure));
  }
  return m;
}

absl::Status GeodesicService::CheckBuildBudget(const GraphKey& key, const RegisteredMesh& mesh,
                                               const std::string& client) {
  auto estimate = [&](const DggParams& params) {
    const DggBuildEstimate e = graphs_->Estimate(mesh, params);
    return absl::StrFormat("estimated at %u bytes and %.0f s to build", e.bytes, e.seconds);
  };
  if (key.max_error > 0 && key.max_error < limits_.min_max_error) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "max_error %g is below %g, the smallest bound this server builds graphs for "
        "(--min-max-error): its first build alone is %s",
        key.max_error, limits_.min_max_error, estimate(key.params)));
  }
  if (key.max_error == 0 && key.params.epsilon < limits_.min_epsilon) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "epsilon %g is below %g, the smallest this server builds graphs at (--min-epsilon): "
        "the graph of mesh '%s' is %s",
        key.params.epsilon, limits_.min_epsilon, key.mesh, estimate(key.params)));
  }
  int queued = 0, mine = 0;
  for (const GraphStatus& g : graphs_->List()) {
    if (!InProgress(g.state)) continue;
    ++queued;
    const GraphKey other{g.mesh, g.params, g.max_error};
    // Being made, a certified graph still lists its key's epsilon.
    auto by = started_by_.find(other);
    mine += by != started_by_.end() && by->second == client;
  }
  if (queued >= limits_.max_queued_builds) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%d graphs are queued or being made, the most this server takes (--max-queued-builds): "
        "retry once one is ready, or follow them with WatchGraph",
        queued));
  }
  if (mine >= limits_.max_queued_builds_per_client) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "this client has %d graphs queued or being made, its share of the build queue "
        "(--max-queued-builds-per-client): retry once one of them is ready",
        mine));
  }
  return absl::OkStatus();
}

absl::StatusOr<GraphStatus> GeodesicService::StartGraph(
    const GraphKey& key, const std::shared_ptr<const RegisteredMesh>& mesh,
    const std::string& client) {
  absl::MutexLock lock(&builds_mu_);
  // A graph being made or made already is joined, not built again: only a
  // new build (never requested, failed, cancelled) counts against the budget.
  auto known = graphs_->Get(key);
  const bool joins =
      known.ok() && (InProgress(known->state) || known->state == GraphState::kReady ||
                     known->state == GraphState::kEvicted);
  if (!joins) RETURN_IF_ERROR(CheckBuildBudget(key, *mesh, client));
  // Refused at once, before the catalog records it: a graph that cannot fit
  // the limits would otherwise hold a build worker for nothing.
  RETURN_IF_ERROR(graphs_->Admit(*mesh, key.params, key.max_error).status());
  if (catalog_) {
    RETURN_IF_ERROR(catalog_->RecordGraph(key.mesh, key.params, key.max_error).status());
  }
  GraphStatus started = graphs_->Request(mesh, key.params, key.max_error);
  if (!joins) {
    // Graphs no longer being made no longer count: forget them here.
    std::erase_if(started_by_, [&](const auto& entry) {
      auto g = graphs_->Get(entry.first);
      return !g.ok() || !InProgress(g->state);
    });
    started_by_[key] = client;
  }
  return started;
}

absl::StatusOr<std::shared_ptr<const GeodesicEngine>> GeodesicService::AcquireEngine(
    const GraphKey& key, grpc::ServerContext* ctx) {
  // An unknown mesh is named as such, and one only the catalog knows is
  // restored, before the graph is looked for.
  RETURN_IF_ERROR(FindMesh(key.mesh).status());
  auto engine = graphs_->Acquire(key);
  if (engine.ok()) return engine;
  const absl::Time started = absl::Now();
  const absl::Time deadline =
      std::min(ReplyBy(ctx), absl::Now() + absl::Seconds(limits_.build_wait_seconds));
  if (catalog_ && !graphs_->Get(key).ok()) {
    // Requested on another replica, perhaps: follow the catalog.
    RETURN_IF_ERROR(catalog_->ReconcileIfChanged());
  }
  if (!graphs_->Get(key).ok()) {
    // Never requested: a query starts the graph as RequestGraph would
    // (unless the operator preloads graphs and wants no builds on demand).
    if (!limits_.build_on_query) return engine;
    const bool default_graph = key.max_error == 0 && !key.params.pseudo_vertices &&
                               key.params.epsilon == limits_.default_epsilon;
    if (!default_graph && !limits_.auto_build_any_epsilon) {
      return absl::FailedPreconditionError(absl::StrFormat(
          "the graph of mesh '%s' %s was never requested: queries start a graph only at the "
          "server's default epsilon %g without pseudo vertices (--auto-build-any-epsilon allows "
          "any); ask for it with RequestGraph first",
          key.mesh,
          key.max_error > 0
              ? absl::StrFormat("certified to max error %g", key.max_error)
              : absl::StrFormat("at epsilon %g%s", key.params.epsilon,
                                key.params.pseudo_vertices ? " with pseudo vertices" : ""),
          limits_.default_epsilon));
    }
    NameLocks::Hold hold(names_, key.mesh, deadline);
    if (!hold.held()) return NameBusy(key.mesh);
    if (!graphs_->Get(key).ok()) {
      // Found again under the name: the mesh may have been unloaded or
      // registered anew while this call waited for it.
      ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> mesh, FindMesh(key.mesh));
      RETURN_IF_ERROR(StartGraph(key, mesh, identity_.Key(*ctx)).status());
    }
  }
  // Queued, built, mapped (an evicted graph is mapped again by Acquire):
  // wait for it within the call's deadline.
  auto status = graphs_->Get(key);
  while (status.ok() && InProgress(status->state) && absl::Now() < deadline &&
         !ctx->IsCancelled()) {
    status = graphs_->WaitForChange(key, status->version,
                                    std::min(deadline, absl::Now() + absl::Seconds(1)));
  }
  engine = graphs_->Acquire(key);
  if (engine.ok() || !absl::IsUnavailable(engine.status()) || !status.ok() ||
      !InProgress(status->state)) {
    return engine;
  }
  const std::string which = key.max_error > 0
                                ? absl::StrFormat("certified to max error %g", key.max_error)
                                : absl::StrFormat("at epsilon %g", key.params.epsilon);
  absl::Status unavailable = absl::UnavailableError(
      absl::StrFormat("the graph of mesh '%s' %s%s is still %s (%s, %.0f%%) after waiting what the "
                      "call allows: retry, or follow it with WatchGraph",
                      key.mesh, which, key.params.pseudo_vertices ? " with pseudo vertices" : "",
                      GraphStateName(status->state), status->phase, 100 * status->progress));
  // What a client needs to retry without reading the prose (Handle sends
  // these as trailing metadata): the graph's state and progress, and a hint
  // as long as the call waited, at least a second at most ten.
  const absl::Duration waited = absl::Now() - started;
  unavailable.SetPayload(kRetryAfterMsTrailer,
                         absl::Cord(std::to_string(absl::ToInt64Milliseconds(
                             std::clamp(waited, absl::Seconds(1), absl::Seconds(10))))));
  unavailable.SetPayload(kGraphStateTrailer, absl::Cord(GraphStateName(status->state)));
  unavailable.SetPayload(kGraphProgressTrailer,
                         absl::Cord(absl::StrFormat("%.4f", status->progress)));
  return unavailable;
}

template <typename Body>
grpc::Status GeodesicService::Handle(const char* method, grpc::ServerContext* ctx,
                                     const std::string& mesh, bool is_query, Body body) {
  const auto start = std::chrono::steady_clock::now();
  calls_in_progress_.fetch_add(1, std::memory_order_relaxed);
  absl::Cleanup left = [this] { calls_in_progress_.fetch_sub(1, std::memory_order_relaxed); };
  absl::Status result;
  // Given back when the handler returns.
  absl::StatusOr<Admission::Ticket> query, stream, change;
  const std::string client = identity_.Key(*ctx);
  if (absl::Status known = identity_.Authenticate(*ctx); !known.ok()) {
    result = known;
  } else if (is_query && !(query = AdmitQuery(ctx, client)).ok()) {
    result = query.status();
  } else if (IsStream(method) && !(stream = admission_.OpenStream(client)).ok()) {
    result = stream.status();
  } else if (IsChange(method) && !(change = admission_.StartChange(client)).ok()) {
    result = change.status();
  } else {
    result = body();
    // A solve stopped because the call's deadline passed reports that, not a
    // cancellation by the client.
    if (absl::IsCancelled(result) && !ctx->IsCancelled() &&
        ctx->deadline() < std::chrono::system_clock::now()) {
      result = absl::DeadlineExceededError(absl::StrCat("deadline exceeded: ", result.message()));
    }
  }
  // What a refusal tells a client beyond its prose (a retry hint, a graph's
  // progress) travels as trailing metadata named by the payload.
  result.ForEachPayload([ctx](absl::string_view trailer, const absl::Cord& value) {
    ctx->AddTrailingMetadata(std::string(trailer), std::string(value));
  });
  grpc::Status status = ToGrpc(result);
  if (!status.ok()) {
    status = grpc::Status(status.error_code(), CapMessage(status.error_message(), mesh));
  }
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  metrics_->Record(method, CodeName(status.error_code()), seconds);
  if (limits_.log_requests) {
    if (status.ok()) {
      Log(LogLevel::kInfo, "request",
          {{"method", method},
           {"mesh", Shorten(mesh)},
           {"code", "OK"},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()}});
    } else {
      Log(LogLevel::kInfo, "request",
          {{"method", method},
           {"mesh", Shorten(mesh)},
           {"code", CodeName(status.error_code())},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()},
           {"error", status.error_message()}});
    }
  }
  return status;
}

namespace {

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

}  // namespace

grpc::Status GeodesicService::RegisterMesh(grpc::ServerContext* ctx,
                                           const v1::RegisterMeshRequest* req, v1::Mesh* resp) {
  return Handle("RegisterMesh", ctx, req->name(), false, [&]() -> absl::Status {
    // Refused before the name is held: a name no mesh can have must not
    // wait for, or hold up, anything.
    RETURN_IF_ERROR(MeshRegistry::ValidateName(req->name()));
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    const bool existed = meshes_->Get(req->name()).ok();
    auto m = meshes_->RegisterPath(req->name(), req->path(), req->repair_non_manifold());
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UploadMesh(grpc::ServerContext* ctx,
                                         grpc::ServerReader<v1::UploadMeshRequest>* reader,
                                         v1::Mesh* resp) {
  std::string name;
  return Handle("UploadMesh", ctx, name, false, [&]() -> absl::Status {
    UploadAssembler upload(limits_.max_upload_bytes);
    v1::UploadMeshRequest chunk;
    StreamWatchdog::Watch watch = WatchStream("UploadMesh", ctx);
    // A message that cannot be parsed ends the reads as the stream's end
    // does: the declared size tells the two apart.
    // The payload's bytes are counted against --memory-limit as they come,
    // until the mesh is registered (or refused): an upload declaring much
    // and sending little (one byte every few seconds, inside --idle-seconds)
    // holds only what it sent, and one that sends too slowly is closed.
    std::vector<std::shared_ptr<void>> payload;
    uint64_t counted = 0;
    const absl::Time started = absl::Now();
    while (Receive(watch, reader, &chunk)) {
      RETURN_IF_ERROR(upload.Add(chunk));
      name = upload.name();
      RETURN_IF_ERROR(CheckUploadRate(upload, absl::Now() - started));
      if (ledger_ != nullptr && upload.received_bytes() > counted) {
        ASSIGN_OR_RETURN(payload.emplace_back(),
                         ledger_->Reserve(upload.received_bytes() - counted,
                                          absl::StrFormat("the upload of '%s'", name)));
        counted = upload.received_bytes();
      }
    }
    // A cancelled stream ends the reads too: nothing of it is registered,
    // however much of it came.
    if (watch.closed()) return watch.Ended();
    if (ctx->IsCancelled()) {
      return absl::CancelledError("the upload was cancelled; nothing was registered");
    }
    RETURN_IF_ERROR(upload.Finish());
    NameLocks::Hold hold(names_, name, absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(name);
    const bool existed = meshes_->Get(name).ok();
    auto m = upload.arrays()
                 ? meshes_->RegisterArrays(name, upload.vertices(), upload.faces(), upload.repair())
                 : meshes_->RegisterBytes(name, upload.format(), upload.bytes(), upload.repair());
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::RegisterRegion(grpc::ServerContext* ctx,
                                             const v1::RegisterRegionRequest* req, v1::Mesh* resp) {
  return Handle("RegisterRegion", ctx, req->name(), false, [&]() -> absl::Status {
    RETURN_IF_ERROR(MeshRegistry::ValidateName(req->name()));
    if (req->vertex_ids().empty() == req->face_ids().empty()) {
      return absl::InvalidArgumentError(
          "a region is given by vertex_ids or by face_ids: exactly one of the two");
    }
    // The region's name and its parent's, in one order for every caller (no
    // two calls wait on each other): an unload of the parent cannot slip in
    // between the parent being found and the region being registered, which
    // left a region whose parent was gone.
    const absl::Time deadline = absl::FromChrono(ctx->deadline());
    const std::string& first = std::min(req->name(), req->parent());
    const std::string& second = std::max(req->name(), req->parent());
    NameLocks::Hold hold(names_, first, deadline);
    if (!hold.held()) return NameBusy(first);
    std::optional<NameLocks::Hold> hold_second;
    if (second != first) {
      hold_second.emplace(names_, second, deadline);
      if (!hold_second->held()) return NameBusy(second);
    }
    // The parent may have been registered on another replica.
    RETURN_IF_ERROR(FindMesh(req->parent()).status());
    const bool existed = meshes_->Get(req->name()).ok();
    const bool by_faces = !req->face_ids().empty();
    const auto& ids = by_faces ? req->face_ids() : req->vertex_ids();
    auto m = meshes_->RegisterRegion(req->name(), req->parent(),
                                     by_faces ? RegionMask::kFaces : RegionMask::kVertices,
                                     absl::MakeConstSpan(ids.data(), ids.size()));
    if (!m.ok()) return m.status();
    RETURN_IF_ERROR(Record(**m, existed));
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListMeshes(grpc::ServerContext* ctx, const v1::ListMeshesRequest*,
                                         v1::ListMeshesResponse* resp) {
  return Handle("ListMeshes", ctx, "", false, [&]() -> absl::Status {
    for (const auto& m : meshes_->List()) FillMesh(*m, resp->add_meshes());
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetMesh(grpc::ServerContext* ctx, const v1::GetMeshRequest* req,
                                      v1::Mesh* resp) {
  return Handle("GetMesh", ctx, req->name(), false, [&]() -> absl::Status {
    auto m = FindMesh(req->name());
    if (!m.ok()) return m.status();
    FillMesh(**m, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::UnloadMesh(grpc::ServerContext* ctx, const v1::UnloadMeshRequest* req,
                                         v1::UnloadMeshResponse*) {
  return Handle("UnloadMesh", ctx, req->name(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, req->name(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(req->name());
    // A region is cut again from its parent at every restart.
    for (const auto& m : meshes_->List()) {
      if (m->parent == req->name()) {
        return absl::FailedPreconditionError(
            absl::StrFormat("mesh '%s' has the region '%s' registered: unload the region first",
                            req->name(), m->name));
      }
    }
    // The catalog first: once it no longer lists the mesh, no restart or
    // replica brings it back.
    bool catalogued = false;
    if (catalog_) {
      ASSIGN_OR_RETURN(catalogued, catalog_->ForgetMesh(req->name()));
    }
    absl::Status s = meshes_->Remove(req->name());
    graphs_->DropMesh(req->name());
    return catalogued ? absl::OkStatus() : s;
  });
}

grpc::Status GeodesicService::RequestGraph(grpc::ServerContext* ctx,
                                           const v1::RequestGraphRequest* req, v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("RequestGraph", ctx, graph.mesh(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, graph.mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(graph.mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto m = FindMesh(key.mesh);
    if (!m.ok()) return m.status();
    ASSIGN_OR_RETURN(const GraphStatus started, StartGraph(key, *m, identity_.Key(*ctx)));
    ToProto(started, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                       v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("GetGraph", ctx, graph.mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto g = graphs_->Get(key);
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::WatchGraph(grpc::ServerContext* ctx, const v1::GetGraphRequest* req,
                                         grpc::ServerWriter<v1::Graph>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("WatchGraph", ctx, graph.mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    StreamWatchdog::Watch watch = WatchStream("WatchGraph", ctx);
    auto g = graphs_->Get(key);
    while (g.ok()) {
      v1::Graph out;
      ToProto(*g, &out);
      RETURN_IF_ERROR(Send(watch, writer, out));
      if (g->state != GraphState::kQueued && g->state != GraphState::kBuilding &&
          g->state != GraphState::kLoading && g->state != GraphState::kPersisting) {
        return absl::OkStatus();
      }
      if (Cancelled(ctx)()) return absl::CancelledError("watch cancelled");
      g = graphs_->WaitForChange(key, g->version, absl::Now() + absl::Seconds(1));
    }
    return g.status();
  });
}

grpc::Status GeodesicService::CancelGraph(grpc::ServerContext* ctx,
                                          const v1::CancelGraphRequest* req, v1::Graph* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("CancelGraph", ctx, graph.mesh(), false, [&]() -> absl::Status {
    NameLocks::Hold hold(names_, graph.mesh(), absl::FromChrono(ctx->deadline()));
    if (!hold.held()) return NameBusy(graph.mesh());
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto g = graphs_->Cancel(key);
    // A ready graph has no operation to cancel: it stays catalogued and
    // served. Anything else is forgotten, also when only another replica
    // requested it.
    const bool ready =
        g.ok() && (g->state == GraphState::kReady || g->state == GraphState::kEvicted);
    if (catalog_ && !ready) {
      RETURN_IF_ERROR(catalog_->ForgetGraph(key.mesh, key.params, key.max_error).status());
    }
    if (!g.ok()) return g.status();
    ToProto(*g, resp);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::ListGraphs(grpc::ServerContext* ctx, const v1::ListGraphsRequest*,
                                         v1::ListGraphsResponse* resp) {
  return Handle("ListGraphs", ctx, "", false, [&]() -> absl::Status {
    for (const auto& g : graphs_->List()) ToProto(g, resp->add_graphs());
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::DistanceField(grpc::ServerContext* ctx,
                                            const v1::DistanceFieldRequest* req,
                                            grpc::ServerWriter<v1::DistanceFieldChunk>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  // A query, admitted in the body: the stream gives its place back once the
  // field is computed.
  return Handle("DistanceField", ctx, graph.mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(Admission::Ticket admitted, AdmitQuery(ctx, identity_.Key(*ctx)));
    if (req->sources_size() == 0) return absl::InvalidArgumentError("a field needs a source");
    if (req->sources_size() > limits_.max_sources) {
      return OverLimits(absl::StrFormat("%d sources exceed the limit of %d per field",
                                        req->sources_size(), limits_.max_sources),
                        {{"max-sources", limits_.max_sources}});
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto engine = AcquireEngine(key, ctx);
    if (!engine.ok()) return engine.status();
    const Mesh& mesh = (*engine)->mesh();
    ASSIGN_OR_RETURN(const std::vector<SurfacePoint> sources,
                     PointsFromProto(req->sources(), mesh, "source"));
    FieldOptions options;
    options.method =
        req->method() == "dijkstra" ? FieldMethod::kDijkstra : FieldMethod::kLabelCorrecting;
    if (!req->method().empty() && req->method() != "lc" && req->method() != "dijkstra") {
      return absl::InvalidArgumentError("method must be \"lc\" or \"dijkstra\"");
    }
    if (!(req->max_distance() >= 0)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "max_distance %g is not a distance >= 0 (0: no limit)", req->max_distance()));
    }
    if (req->max_distance() > 0) options.max_distance = req->max_distance();
    options.nearest_source = req->nearest_source();
    options.cancelled = Cancelled(ctx);
    for (uint32_t t : req->targets()) {
      if (t >= mesh.num_vertices()) {
        return absl::OutOfRangeError(absl::StrFormat(
            "target vertex %u is out of range: the mesh has %u vertices", t, mesh.num_vertices()));
      }
    }
    // The field is streamed: its answer's peak is one chunk beside the
    // solver's arrays, which the scratch counts.
    const uint64_t chunk_bytes = uint64_t(limits_.field_chunk) *
                                     ((req->float32() ? 5 : 9) + (req->nearest_source() ? 6 : 0)) +
                                 kAnswerOverhead;
    ASSIGN_OR_RETURN(Admission::Ticket run,
                     StartQuery(ctx, 2 * chunk_bytes + uint64_t(req->targets_size()) * 4,
                                FieldScratchBytes(**engine)));
    auto field = (*engine)->Field(sources, options);
    if (!field.ok()) return field.status();
    // What is left is sending: the places go to other queries while the
    // client takes its chunks, however slowly; the answer's bytes stay
    // counted.
    const Admission::Ticket sending = admission_.KeepAnswer(std::move(run));
    admitted.Release();
    StreamWatchdog::Watch watch = WatchStream("DistanceField", ctx);
    std::vector<uint32_t> order(req->targets().begin(), req->targets().end());
    const size_t total = order.empty() ? field->distance.size() : order.size();
    for (size_t offset = 0; offset < total || offset == 0; offset += limits_.field_chunk) {
      v1::DistanceFieldChunk chunk;
      if (offset == 0) {
        FillEcho(Built(key, **engine), options.method == FieldMethod::kDijkstra ? "dijkstra" : "lc",
                 chunk.mutable_echo());
      }
      chunk.set_offset(offset);
      chunk.set_total(total);
      const size_t end = std::min(total, offset + limits_.field_chunk);
      for (size_t i = offset; i < end; ++i) {
        const uint32_t v = order.empty() ? i : order[i];
        if (req->float32()) {
          chunk.add_values_f32(static_cast<float>(field->distance[v]));
        } else {
          chunk.add_values(field->distance[v]);
        }
        if (req->nearest_source()) chunk.add_nearest_source(field->nearest_source[v]);
      }
      RETURN_IF_ERROR(Send(watch, writer, chunk));
      if (total == 0) break;
    }
    return absl::OkStatus();
  });
}

namespace {

void FillPath(const GeodesicPath& path, v1::Path* out) {
  out->set_length(path.length);
  for (const PathPoint& p : path.points) {
    auto* q = out->add_points();
    *q->mutable_point() = ToProto(p.point);
    q->mutable_xyz()->set_x(p.xyz.x);
    q->mutable_xyz()->set_y(p.xyz.y);
    q->mutable_xyz()->set_z(p.xyz.z);
  }
}

}  // namespace

grpc::Status GeodesicService::Distance(grpc::ServerContext* ctx, const v1::DistanceRequest* req,
                                       v1::DistanceResponse* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("Distance", ctx, graph.mesh(), true, [&]() -> absl::Status {
    if (req->pairs_size() > limits_.max_pairs) {
      return OverLimits(absl::StrFormat("%d pairs exceed the limit of %d per call",
                                        req->pairs_size(), limits_.max_pairs),
                        {{"max-pairs", limits_.max_pairs}});
    }
    if (req->exact() && req->pairs_size() > limits_.max_exact_pairs) {
      return OverLimits(absl::StrFormat("%d exact pairs exceed the limit of %d exact pairs per "
                                        "call (--max-exact-pairs): split the batch",
                                        req->pairs_size(), limits_.max_exact_pairs),
                        {{"max-exact-pairs", limits_.max_exact_pairs}});
    }
    const uint64_t pairs = req->pairs_size();
    RETURN_IF_ERROR(CheckAnswerSize(absl::StrFormat("%u pairs", pairs),
                                    pairs * kPairResultBytes + kAnswerOverhead));
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    auto engine = AcquireEngine(key, ctx);
    if (!engine.ok()) return engine.status();
    if (req->exact()) graphs_->WantExactLandmarks(key);
    const Mesh& mesh = (*engine)->mesh();
    // The reply and, once the handler returns, its serialized copy.
    const uint64_t per_pair =
        kPairResultBytes + (req->with_path() ? kPathPointsReserved * kPathPointBytes : 0);
    const uint64_t answer =
        std::min<uint64_t>(pairs * per_pair + kAnswerOverhead, limits_.max_message_bytes);
    std::vector<SurfacePoint> from, to;
    for (int i = 0; i < req->pairs_size(); ++i) {
      ASSIGN_OR_RETURN(from.emplace_back(),
                       FromProto(req->pairs(i).from(), mesh, absl::StrFormat("pair %d, from", i)));
      ASSIGN_OR_RETURN(to.emplace_back(),
                       FromProto(req->pairs(i).to(), mesh, absl::StrFormat("pair %d, to", i)));
    }
    // A request's pairs are spread over the cores, each on its own scratch.
    const uint64_t lanes = std::clamp<uint64_t>(pairs, 1, std::thread::hardware_concurrency());
    // An exact pair may hold up to max_exact_bytes of windows on each lane.
    const uint64_t exact_bytes = req->exact() ? limits_.max_exact_bytes : 0;
    const uint64_t scratch = lanes * (PairScratchBytes(**engine) + exact_bytes);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(ctx, 2 * answer, scratch));
    absl::Time slice_start = absl::Now();
    uint64_t answer_bytes = kAnswerOverhead;
    FillEcho(Built(key, **engine), req->exact() ? "exact" : "bidirectional-astar",
             resp->mutable_echo());
    PairOptions options;
    options.want_path = req->with_path();
    options.exact = req->exact();
    options.exact_max_bytes = limits_.max_exact_bytes;
    options.cancelled = Cancelled(ctx);
    // The pairs go in blocks, between which a call that has used its slice
    // gives its slot to a waiting client's query: an exact pair per lane at
    // a time, graph pairs a few dozen per lane (a batch of --max-pairs takes
    // seconds). With paths, which are as long as they are, the answer is
    // refused as soon as it cannot be sent, not after them all.
    const size_t block = req->exact() ? lanes : req->with_path() ? 8 * lanes : 64 * lanes;
    for (size_t begin = 0; begin < from.size(); begin += block) {
      if (begin > 0) RETURN_IF_ERROR(NextSlice(ctx, run, slice_start, scratch));
      const size_t count = std::min(block, from.size() - begin);
      ASSIGN_OR_RETURN(
          std::vector<PairResult> results,
          (*engine)->Distances(absl::MakeConstSpan(from).subspan(begin, count),
                               absl::MakeConstSpan(to).subspan(begin, count), options));
      for (size_t k = 0; k < results.size(); ++k) {
        const PairResult& r = results[k];
        auto* out = resp->add_results();
        out->set_distance(r.distance);
        out->set_reachable(r.distance < kInfinity);
        out->set_exact(r.exact);
        if (!r.path) continue;
        FillPath(*r.path, out->mutable_path());
        answer_bytes += out->ByteSizeLong() + 4;
        if (answer_bytes > limits_.max_message_bytes) {
          return OverLimits(absl::StrFormat("the answer with paths grew larger than max message "
                                            "size: %u bytes at pair %u of %d, over the cap of %u "
                                            "bytes; split the batch",
                                            answer_bytes, begin + k + 1, req->pairs_size(),
                                            limits_.max_message_bytes),
                            {{"max-message-bytes", limits_.max_message_bytes}});
        }
      }
    }
    HoldUntilSent(ctx, std::move(run));
    return absl::OkStatus();
  });
}

absl::StatusOr<GeodesicService::MatrixQuery> GeodesicService::PrepareMatrix(
    const v1::MatrixRequest& req, grpc::ServerContext* ctx) {
  MatrixQuery q;
  ASSIGN_OR_RETURN(q.key, Key(SelectorOf(req)));
  ASSIGN_OR_RETURN(q.engine, AcquireEngine(q.key, ctx));
  if (req.exact()) graphs_->WantExactLandmarks(q.key);
  const Mesh& mesh = q.engine->mesh();
  ASSIGN_OR_RETURN(q.sources, PointsFromProto(req.sources(), mesh, "source"));
  ASSIGN_OR_RETURN(q.targets, PointsFromProto(req.targets(), mesh, "target"));
  if (req.all_sources()) q.sources = AllVertices(mesh);
  if (req.all_targets()) q.targets = AllVertices(mesh);
  return q;
}

uint64_t GeodesicService::MatrixScratchBytes(const MatrixQuery& q,
                                             const v1::MatrixRequest& req) const {
  const uint64_t lanes =
      std::clamp<uint64_t>(q.sources.size(), 1, std::thread::hardware_concurrency());
  return FieldScratchBytes(*q.engine) + q.targets.size() * sizeof(double) +
         (req.exact() ? lanes * limits_.max_exact_bytes : 0);
}

MatrixOptions GeodesicService::MatrixOptionsOf(const v1::MatrixRequest& req,
                                               grpc::ServerContext* ctx) const {
  MatrixOptions options;
  options.cancelled = Cancelled(ctx);
  options.exact = req.exact();
  options.exact_max_bytes = limits_.max_exact_bytes;
  // Sparse rows: the search stops at the radius. Not for exact rows, whose
  // graph entries just past it may still be exact ones within it.
  if (req.radius() > 0 && !req.exact()) options.max_distance = req.radius();
  return options;
}

grpc::Status GeodesicService::Matrix(grpc::ServerContext* ctx, const v1::MatrixRequest* req,
                                     v1::MatrixResponse* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("Matrix", ctx, graph.mesh(), true, [&]() -> absl::Status {
    RETURN_IF_ERROR(CheckMatrixLimits(*req, /*streamed=*/false));
    const size_t value_bytes = PackedBytes(req->dtype());
    auto answer_of = [&](uint64_t rows, uint64_t cols) {
      return rows * cols * (value_bytes > 0 ? value_bytes : 9) + kAnswerOverhead;
    };
    if (!req->all_sources() && !req->all_targets()) {
      // Sized before the graph is waited for: a refusal costs nothing.
      RETURN_IF_ERROR(CheckAnswerSize(
          absl::StrFormat("a %d x %d matrix", req->sources_size(), req->targets_size()),
          answer_of(req->sources_size(), req->targets_size())));
    }
    ASSIGN_OR_RETURN(MatrixQuery q, PrepareMatrix(*req, ctx));
    const GraphKey& key = q.key;
    const std::vector<SurfacePoint>& sources = q.sources;
    const std::vector<SurfacePoint>& targets = q.targets;
    const uint64_t answer = answer_of(sources.size(), targets.size());
    RETURN_IF_ERROR(CheckAnswerSize(
        absl::StrFormat("a %u x %u matrix", sources.size(), targets.size()), answer));
    // The solver's distances, then the reply beside them and, once the
    // handler returns, the reply's serialized copy.
    const uint64_t scratch = MatrixScratchBytes(q, *req);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(ctx, 2 * answer, scratch));
    absl::Time slice_start = absl::Now();
    // One fan-restricted field per row (the "lc" solver), joined at the
    // targets as Distance joins its points; "exact" when rows are made exact.
    FillEcho(Built(key, *q.engine), req->exact() ? "exact" : "lc", resp->mutable_echo());
    resp->set_rows(sources.size());
    resp->set_cols(targets.size());
    // Rows go straight into the reply's values or bytes, each where it
    // belongs.
    char* base = nullptr;
    const bool narrow = req->dtype() == v1::MATRIX_DTYPE_FLOAT32;
    if (value_bytes == 0) {
      resp->mutable_distances()->Resize(static_cast<int>(sources.size() * targets.size()), 0.0);
      base = reinterpret_cast<char*>(resp->mutable_distances()->mutable_data());
    } else {
      resp->set_dtype(req->dtype());
      std::string* packed = resp->mutable_packed();
      packed->resize(sources.size() * targets.size() * value_bytes);
      base = packed->data();
    }
    MatrixRowSink sink = DenseSink(std::max<size_t>(1, sources.size()), narrow, base);
    if (req->exact()) {
      // Exact rows go a lane group per core at a time, each batch a slice
      // after which a waiting client's query may run.
      sink.batch_rows = size_t{kFieldLanes} * std::max(1u, std::thread::hardware_concurrency());
      sink.batch_done = [&](size_t) { return NextSlice(ctx, run, slice_start, scratch); };
    }
    RETURN_IF_ERROR(q.engine->StreamMatrix(sources, targets, MatrixOptionsOf(*req, ctx), sink));
    HoldUntilSent(ctx, std::move(run));
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::MatrixRows(grpc::ServerContext* ctx, const v1::MatrixRequest* req,
                                         grpc::ServerWriter<v1::MatrixRowsChunk>* writer) {
  const v1::GraphSelector graph = SelectorOf(*req);
  // A query, admitted in the body: the stream gives its place back once its
  // first block is computed.
  return Handle("MatrixRows", ctx, graph.mesh(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(Admission::Ticket admitted, AdmitQuery(ctx, identity_.Key(*ctx)));
    RETURN_IF_ERROR(CheckMatrixLimits(*req, /*streamed=*/true));
    ASSIGN_OR_RETURN(MatrixQuery q, PrepareMatrix(*req, ctx));
    const std::vector<SurfacePoint>& sources = q.sources;
    const std::vector<SurfacePoint>& targets = q.targets;
    const bool sparse = req->radius() > 0;
    const bool narrow = req->dtype() == v1::MATRIX_DTYPE_FLOAT32;
    const size_t value_bytes = PackedBytes(req->dtype());
    // What the values travel as: a sparse request without a dtype gets
    // float64 bytes, since it has no repeated form to fall back on.
    const v1::MatrixDtype dtype =
        sparse && value_bytes == 0 ? v1::MATRIX_DTYPE_FLOAT64 : req->dtype();
    // Wire bytes per entry, at most: a repeated double with its share of
    // tags, a packed value, or a sparse entry's column and value.
    const uint64_t entry_bytes = sparse            ? sizeof(uint32_t) + (narrow ? 4 : 8)
                                 : value_bytes > 0 ? value_bytes
                                                   : 9;
    // Blocks small enough that the server holds one at a time, large
    // enough that framing stays negligible.
    constexpr uint64_t kBlockBytes = uint64_t{4} << 20;
    const size_t cols = std::max<size_t>(1, targets.size());
    const size_t block_rows = std::max<size_t>(1, kBlockBytes / (entry_bytes * cols));
    const uint64_t block_answer =
        block_rows * (cols * entry_bytes + (sparse ? sizeof(uint64_t) : 0)) + kAnswerOverhead;
    RETURN_IF_ERROR(
        CheckAnswerSize(absl::StrFormat("a block of %u rows", block_rows), block_answer));
    // A block's rows as computed (sparse ones staged per row), then the
    // chunk's serialized copy. Held while a block is computed, not while it
    // is sent: a client that reads slowly, or not at all, keeps no slot.
    // Later blocks wait their turn without being admitted again, so that a
    // stream once started is not refused halfway (--max-streams bounds them).
    auto start_block = [&] {
      return StartQuery(ctx, 2 * block_answer, MatrixScratchBytes(q, *req));
    };
    ASSIGN_OR_RETURN(Admission::Ticket run, start_block());
    StreamWatchdog::Watch watch = WatchStream("MatrixRows", ctx);
    v1::MatrixRowsChunk chunk;
    char* dense = nullptr;  // the block's rows, written in place by the threads computing them
    std::vector<SparseRow> staged(sparse ? block_rows : 0);
    auto begin_block = [&](size_t first) {
      const size_t n = std::min(block_rows, sources.size() - first);
      chunk.Clear();
      if (first == 0) {
        FillEcho(Built(q.key, *q.engine), req->exact() ? "exact" : "lc", chunk.mutable_echo());
      }
      chunk.set_first_row(first);
      chunk.set_rows(n);
      chunk.set_cols(targets.size());
      chunk.set_total_rows(sources.size());
      chunk.set_dtype(dtype);
      if (sparse) return;
      if (value_bytes == 0) {
        chunk.mutable_distances()->Resize(static_cast<int>(n * targets.size()), 0.0);
        dense = reinterpret_cast<char*>(chunk.mutable_distances()->mutable_data());
      } else {
        std::string* packed = chunk.mutable_packed();
        packed->resize(n * targets.size() * value_bytes);
        dense = packed->data();
      }
    };
    MatrixRowSink sink = BlockSink(block_rows, sparse ? req->radius() : 0, narrow, dense, staged);
    sink.batch_done = [&](size_t end) -> absl::Status {
      if (sparse) MoveSparseRows(staged, &chunk);
      {
        // The block's bytes stay counted while the client takes them.
        const Admission::Ticket sending = admission_.KeepAnswer(std::move(run));
        admitted.Release();
        RETURN_IF_ERROR(Send(watch, writer, chunk));
      }
      if (end == sources.size()) return absl::OkStatus();
      begin_block(end);
      ASSIGN_OR_RETURN(run, start_block());
      return absl::OkStatus();
    };
    begin_block(0);
    if (sources.empty()) {
      // No batch runs: the one block says the matrix has no rows.
      run.Release();
      admitted.Release();
      return Send(watch, writer, chunk);
    }
    return q.engine->StreamMatrix(sources, targets, MatrixOptionsOf(*req, ctx), sink);
  });
}

grpc::Status GeodesicService::Snap(grpc::ServerContext* ctx, const v1::SnapRequest* req,
                                   v1::SnapResponse* resp) {
  return Handle("Snap", ctx, req->mesh(), true, [&]() -> absl::Status {
    if (req->positions_size() > limits_.max_pairs) {
      return OverLimits(absl::StrFormat("%d positions exceed the limit of %d per call",
                                        req->positions_size(), limits_.max_pairs),
                        {{"max-pairs", limits_.max_pairs}});
    }
    auto m = FindMesh(req->mesh());
    if (!m.ok()) return m.status();
    constexpr uint64_t kSnapBytes = 48;  // a point and its distance
    ASSIGN_OR_RETURN(
        Admission::Ticket run,
        StartQuery(ctx, 2 * (req->positions_size() * kSnapBytes + kAnswerOverhead), 0));
    for (const auto& p : req->positions()) {
      const Vec3 position{p.x(), p.y(), p.z()};
      auto s = (*m)->locator->Snap(position);
      if (!s.ok()) return s.status();
      *resp->add_points() = ToProto(*s);
      resp->add_distances(geodesic::Distance(position, PositionOf(*(*m)->mesh, *s)));
    }
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::SamplePoints(grpc::ServerContext* ctx,
                                           const v1::SamplePointsRequest* req,
                                           v1::SamplePointsResponse* resp) {
  const v1::GraphSelector graph = SelectorOf(*req);
  return Handle("SamplePoints", ctx, graph.mesh(), true, [&]() -> absl::Status {
    // Each point costs a field.
    if (req->count() > static_cast<uint32_t>(limits_.max_samples)) {
      return OverLimits(absl::StrFormat("%u points exceed the limit of %d per call (--max-samples)",
                                        req->count(), limits_.max_samples),
                        {{"max-samples", limits_.max_samples}});
    }
    ASSIGN_OR_RETURN(const GraphKey key, Key(graph));
    ASSIGN_OR_RETURN(std::shared_ptr<const GeodesicEngine> engine, AcquireEngine(key, ctx));
    // A field's arrays and each vertex's distance to the samples so far.
    const uint64_t answer = 2 * (uint64_t(req->count()) * 6 + kAnswerOverhead);
    const uint64_t scratch =
        FieldScratchBytes(*engine) + uint64_t(engine->mesh().num_vertices()) * sizeof(double);
    ASSIGN_OR_RETURN(Admission::Ticket run, StartQuery(ctx, answer, scratch));
    absl::Time slice_start = absl::Now();
    SampleOptions options;
    options.seed = req->seed();
    options.cancelled = Cancelled(ctx);
    options.between_points = [&] { return NextSlice(ctx, run, slice_start, scratch); };
    ASSIGN_OR_RETURN(SampleResult sample, engine->SamplePoints(req->count(), options));
    FillEcho(Built(key, *engine), "farthest-point", resp->mutable_echo());
    for (VertexId v : sample.vertices) resp->add_vertices(v);
    resp->set_covering_radius(sample.covering_radius);
    return absl::OkStatus();
  });
}

grpc::Status GeodesicService::GetGeometry(grpc::ServerContext* ctx, const v1::GetMeshRequest* req,
                                          grpc::ServerWriter<v1::GeometryChunk>* writer) {
  return Handle("GetGeometry", ctx, req->name(), false, [&]() -> absl::Status {
    ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> m, FindMesh(req->name()));
    const Mesh& mesh = *m->mesh;
    // Small chunks, whatever the mesh's size: a stream whose client does not
    // read holds one, and its serialized copy, until it is closed.
    constexpr int kValuesPerChunk = 1 << 16;
    v1::GeometryChunk chunk;
    chunk.set_name(m->name);
    chunk.set_fingerprint(absl::StrFormat("%016x", m->fingerprint));
    chunk.set_total_vertices(mesh.num_vertices());
    chunk.set_total_faces(mesh.corners().size() / 3);
    StreamWatchdog::Watch watch = WatchStream("GetGeometry", ctx);
    auto flush = [&](bool last) -> absl::Status {
      const int values = chunk.vertices_size() + chunk.faces_size();
      if (last ? chunk.ByteSizeLong() == 0 : values < kValuesPerChunk) return absl::OkStatus();
      RETURN_IF_ERROR(Send(watch, writer, chunk));
      chunk.Clear();
      return absl::OkStatus();
    };
    for (const Vec3& p : mesh.positions()) {
      chunk.add_vertices(p.x);
      chunk.add_vertices(p.y);
      chunk.add_vertices(p.z);
      RETURN_IF_ERROR(flush(false));
    }
    for (VertexId v : mesh.corners()) {
      chunk.add_faces(v);
      RETURN_IF_ERROR(flush(false));
    }
    return flush(true);
  });
}

}  // namespace geodesic::server
