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
#include "absl/functional/function_ref.h"
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
#include "server/grpc/rpc_support.h"
#include "server/limits/client_key.h"
#include "server/meshes/upload.h"

namespace geodesic::server {
namespace {

// How long a query waits for admission when it is full, at most: long
// beside a light query's run, short beside a client's patience.
constexpr absl::Duration kAdmissionWait = absl::Seconds(1);

// Error messages travel in trailing metadata, which clients cap (8 KiB by
// default): input echoed into them is cut, and so is the whole message.
constexpr size_t kMessageChars = 1024;

// Cuts the mesh name and any quoted run longer than kMaxEcho, then the
// message to kMessageChars.
std::string CapMessage(std::string message, std::string_view mesh) {
  if (mesh.size() > kMaxEcho) {
    const std::string cut = Cut(mesh);
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
    if (quoted.size() > kMaxEcho && quoted.find(' ') == std::string_view::npos) {
      const std::string cut = Cut(quoted);
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

}  // namespace

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
      index,
      new grpc::internal::StreamedUnaryHandler<grpc::ByteBuffer, Response>(
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
              return Answer(method, ctx, "", decoding.status(), std::chrono::steady_clock::now());
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
                status = grpc::Status(grpc::StatusCode::CANCELLED, "the answer was not taken");
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

absl::StatusOr<Admission::Ticket> GeodesicService::AdmitQuery(const Call& call) {
  return admission_.AdmitQuery(
      call.client, std::min(ReplyBy(call.ctx), absl::Now() + kAdmissionWait), Cancelled(call.ctx));
}

absl::StatusOr<Admission::Ticket> GeodesicService::StartQuery(const Call& call,
                                                              uint64_t answer_bytes,
                                                              uint64_t scratch_bytes) {
  // A refusal sent a little before the deadline reaches the client as an
  // overload, with its retry hint, not as DEADLINE_EXCEEDED.
  const absl::Time deadline = ReplyBy(call.ctx);
  return admission_.Run(answer_bytes, scratch_bytes, deadline, Cancelled(call.ctx), call.client);
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

absl::Status GeodesicService::NextSlice(const Call& call, Admission::Ticket& run,
                                        absl::Time& slice_start, uint64_t scratch_bytes) {
  if (absl::Now() - slice_start < kSlice || !admission_.OthersWaiting(call.client)) {
    return absl::OkStatus();
  }
  // The answer built so far stays reserved while the call waits its turn.
  Admission::Ticket kept = admission_.KeepAnswer(std::move(run));
  ASSIGN_OR_RETURN(Admission::Ticket next, StartQuery(call, 0, scratch_bytes));
  run = admission_.Adopt(std::move(next), std::move(kept));
  slice_start = absl::Now();
  return absl::OkStatus();
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
    const GraphKey& key, const Call& call) {
  grpc::ServerContext* ctx = call.ctx;
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
      RETURN_IF_ERROR(StartGraph(key, mesh, call.client).status());
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

grpc::Status GeodesicService::Handle(const char* method, grpc::ServerContext* ctx,
                                     const std::string& mesh,
                                     absl::FunctionRef<absl::Status(const Call&)> body) {
  const auto start = std::chrono::steady_clock::now();
  calls_in_progress_.fetch_add(1, std::memory_order_relaxed);
  absl::Cleanup left = [this] { calls_in_progress_.fetch_sub(1, std::memory_order_relaxed); };
  const Call call{.ctx = ctx, .rpc = RpcNamed(method), .client = identity_.Key(*ctx)};
  absl::Status result;
  // Given back when the handler returns.
  absl::StatusOr<Admission::Ticket> query, stream, change;
  if (absl::Status known = identity_.Authenticate(*ctx); !known.ok()) {
    result = known;
  } else if (call.rpc.query && !(query = AdmitQuery(call)).ok()) {
    result = query.status();
  } else if (call.rpc.stream && !(stream = admission_.OpenStream(call.client)).ok()) {
    result = stream.status();
  } else if (call.rpc.change && !(change = admission_.StartChange(call.client)).ok()) {
    result = change.status();
  } else {
    result = body(call);
    // A solve stopped because the call's deadline passed reports that, not a
    // cancellation by the client.
    if (absl::IsCancelled(result) && !ctx->IsCancelled() &&
        ctx->deadline() < std::chrono::system_clock::now()) {
      result = absl::DeadlineExceededError(absl::StrCat("deadline exceeded: ", result.message()));
    }
  }
  return Answer(method, ctx, mesh, result, start);
}

grpc::Status GeodesicService::Answer(const char* method, grpc::ServerContext* ctx,
                                     const std::string& mesh, const absl::Status& result,
                                     std::chrono::steady_clock::time_point start) {
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
           {"mesh", Cut(mesh)},
           {"code", "OK"},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()}});
    } else {
      Log(LogLevel::kInfo, "request",
          {{"method", method},
           {"mesh", Cut(mesh)},
           {"code", CodeName(status.error_code())},
           {"ms", 1e3 * seconds},
           {"peer", ctx->peer()},
           {"error", status.error_message()}});
    }
  }
  return status;
}

}  // namespace geodesic::server
