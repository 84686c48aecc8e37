// The geodesic.v1.Geodesic gRPC service: thin handlers over the mesh
// registry, the graph cache and core queries.
#ifndef GEODESIC_SERVER_GEODESIC_SERVICE_H_
#define GEODESIC_SERVER_GEODESIC_SERVICE_H_

#include <atomic>
#include <chrono>
#include <functional>
#include <map>
#include <string>
#include <vector>

#include "absl/container/flat_hash_map.h"
#include "absl/functional/function_ref.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "server/base/metrics.h"
#include "server/base/name_locks.h"
#include "server/graphs/graph_cache.h"
#include "server/grpc/call.h"
#include "server/limits/admission.h"
#include "server/limits/client_key.h"
#include "server/limits/memory_ledger.h"
#include "server/limits/service_limits.h"
#include "server/limits/stream_watchdog.h"
#include "server/meshes/mesh_registry.h"
#include "server/store/catalog_sync.h"

namespace geodesic::server {

class GeodesicService final : public v1::Geodesic::Service {
 public:
  // Queries reserve memory against the cache's memory limit, beside the
  // meshes, graphs and idle scratch it counts.
  GeodesicService(MeshRegistry* meshes, GraphCache* graphs, Metrics* metrics, ServiceLimits limits);

  // Queries admitted and running, streams open, bytes reserved: for gauges
  // and the overload health status.
  const Admission& admission() const { return admission_; }
  // Streams watched for idling, and how many were closed.
  const StreamWatchdog& watchdog() const { return watchdog_; }
  StreamWatchdog& watchdog() { return watchdog_; }
  // Calls in a handler now: each holds one of gRPC's threads.
  int calls_in_progress() const { return calls_in_progress_.load(std::memory_order_relaxed); }

  // From now on every call must carry the metadata "authorization: Bearer
  // <token>" with one of `tokens`, each a client of its own (client_key.h);
  // others fail with UNAUTHENTICATED. Health checks and reflection are
  // separate services and stay open, so that probes need no secret.
  void RequireBearerTokens(std::vector<std::string> tokens) {
    identity_ = ClientIdentity(std::move(tokens));
  }
  // Records registrations and graph requests in the catalog before
  // answering, and follows it for meshes and graphs this daemon lacks
  // (registered through another replica, or before a restart).
  void UseCatalog(CatalogSync* catalog) { catalog_ = catalog; }
  // Memory the limit covers outside queries: the HTTP gateway's bodies and
  // answers, and this service's upload payloads while they arrive and are
  // parsed. Queries wait for it, or run beside it, as for graphs. Set before
  // serving; without it uploads are bounded by --max-upload-bytes alone.
  void UseMemoryLedger(MemoryLedger* ledger) { ledger_ = ledger; }

  grpc::Status RegisterMesh(grpc::ServerContext*, const v1::RegisterMeshRequest*,
                            v1::Mesh*) override;
  grpc::Status UploadMesh(grpc::ServerContext*, grpc::ServerReader<v1::UploadMeshRequest>*,
                          v1::Mesh*) override;
  grpc::Status RegisterRegion(grpc::ServerContext*, const v1::RegisterRegionRequest*,
                              v1::Mesh*) override;
  grpc::Status ListMeshes(grpc::ServerContext*, const v1::ListMeshesRequest*,
                          v1::ListMeshesResponse*) override;
  grpc::Status GetMesh(grpc::ServerContext*, const v1::GetMeshRequest*, v1::Mesh*) override;
  grpc::Status UnloadMesh(grpc::ServerContext*, const v1::UnloadMeshRequest*,
                          v1::UnloadMeshResponse*) override;
  grpc::Status GetGeometry(grpc::ServerContext*, const v1::GetMeshRequest*,
                           grpc::ServerWriter<v1::GeometryChunk>*) override;
  grpc::Status RequestGraph(grpc::ServerContext*, const v1::RequestGraphRequest*,
                            v1::Graph*) override;
  grpc::Status GetGraph(grpc::ServerContext*, const v1::GetGraphRequest*, v1::Graph*) override;
  grpc::Status WatchGraph(grpc::ServerContext*, const v1::GetGraphRequest*,
                          grpc::ServerWriter<v1::Graph>*) override;
  grpc::Status CancelGraph(grpc::ServerContext*, const v1::CancelGraphRequest*,
                           v1::Graph*) override;
  grpc::Status ListGraphs(grpc::ServerContext*, const v1::ListGraphsRequest*,
                          v1::ListGraphsResponse*) override;
  grpc::Status DistanceField(grpc::ServerContext*, const v1::DistanceFieldRequest*,
                             grpc::ServerWriter<v1::DistanceFieldChunk>*) override;
  grpc::Status Distance(grpc::ServerContext*, const v1::DistanceRequest*,
                        v1::DistanceResponse*) override;
  grpc::Status Matrix(grpc::ServerContext*, const v1::MatrixRequest*, v1::MatrixResponse*) override;
  grpc::Status MatrixRows(grpc::ServerContext*, const v1::MatrixRequest*,
                          grpc::ServerWriter<v1::MatrixRowsChunk>*) override;
  grpc::Status Snap(grpc::ServerContext*, const v1::SnapRequest*, v1::SnapResponse*) override;
  grpc::Status SamplePoints(grpc::ServerContext*, const v1::SamplePointsRequest*,
                            v1::SamplePointsResponse*) override;

 private:
  // Serves `method` from its request's bytes: a request over `max_bytes`
  // (what `limit`, the flags bounding it, allow) is refused before it is
  // decoded, and the memory its decoding takes is reserved first.
  template <class Request, class Response>
  void DecodeWithinLimits(const char* method, uint64_t max_bytes, std::string limit,
                          grpc::Status (GeodesicService::*handler)(grpc::ServerContext*,
                                                                   const Request*, Response*));
  // `raw` decoded into `req` once authenticated, measured and reserved for:
  // the reservation, held while the request is.
  template <class Request>
  absl::StatusOr<std::shared_ptr<void>> DecodeRequest(grpc::ServerContext* ctx, const char* method,
                                                      uint64_t max_bytes, const std::string& limit,
                                                      grpc::ByteBuffer& raw, Request* req);
  // Keeps `run`'s answer bytes reserved until AnswerSent(ctx); its thread
  // slot and scratch are given back now.
  void HoldUntilSent(grpc::ServerContext* ctx, Admission::Ticket run);
  // The answer of `ctx`'s call is written (DecodeWithinLimits's write
  // returned): what HoldUntilSent kept is given back.
  void AnswerSent(const grpc::ServerContext* ctx);
  // A query's place among the admitted, waiting for one a short while
  // when admission is full (admission.h).
  absl::StatusOr<Admission::Ticket> AdmitQuery(const Call& call);
  // Waits for an admitted query's turn to run with `answer_bytes` and
  // `scratch_bytes` reserved (Admission::Run), until shortly before the
  // call's deadline.
  absl::StatusOr<Admission::Ticket> StartQuery(const Call& call, uint64_t answer_bytes,
                                               uint64_t scratch_bytes);
  // The stream `ctx` watched for idling (--idle-seconds) until the result
  // is destroyed.
  StreamWatchdog::Watch WatchStream(const char* method, grpc::ServerContext* ctx);
  // Between two slices of a long call: once `run` has been held a slice's
  // time while another client waits, gives its thread and scratch back and
  // waits for the call's next turn; its answer bytes stay reserved.
  absl::Status NextSlice(const Call& call, Admission::Ticket& run, absl::Time& slice_start,
                         uint64_t scratch_bytes);
  // RESOURCE_EXHAUSTED naming the size and the cap when an answer of
  // `bytes` cannot fit one message.
  absl::Status CheckAnswerSize(const std::string& what, uint64_t bytes) const;
  // A matrix request's radius, dtype and selectors checked
  // (INVALID_ARGUMENT), then its size: RESOURCE_EXHAUSTED past --max-sources
  // rows or --max-pairs columns, an `all` selector counting as its mesh's
  // vertices. `streamed` (MatrixRows): `all` selectors are not held to those
  // limits, since no list travels and the rows go out in bounded blocks.
  absl::Status CheckMatrixLimits(const v1::MatrixRequest& req, bool streamed);
  // What Matrix and MatrixRows both start from: the graph's engine (waited
  // for or started, as any query's) and the request's points on its mesh.
  struct MatrixQuery {
    GraphKey key;
    std::shared_ptr<const GeodesicEngine> engine;
    std::vector<SurfacePoint> sources, targets;
  };
  absl::StatusOr<MatrixQuery> PrepareMatrix(const v1::MatrixRequest& req, const Call& call);
  // The memory a matrix's rows may use at once, exact rows' windows included.
  uint64_t MatrixScratchBytes(const MatrixQuery& q, const v1::MatrixRequest& req) const;
  MatrixOptions MatrixOptionsOf(const v1::MatrixRequest& req, grpc::ServerContext* ctx) const;

  // The one pipeline every RPC goes through: its Call made once (its kind
  // from the table in call.h, its client's identity), then authentication,
  // admission as its kind asks (a query's place, a stream's or a change's
  // slot), `body`, and the answer's trailers, metrics and log line.
  grpc::Status Handle(const char* method, grpc::ServerContext* ctx, const std::string& mesh,
                      absl::FunctionRef<absl::Status(const Call&)> body);
  // The pipeline's end, also for a request refused before it is decoded:
  // `result`'s payloads as trailers, its message capped, metrics, the log.
  grpc::Status Answer(const char* method, grpc::ServerContext* ctx, const std::string& mesh,
                      const absl::Status& result, std::chrono::steady_clock::time_point start);
  // The epsilon a request asks for: zero (unset in proto3) means the
  // server's default; anything else, negative and NaN included, must lie in
  // [1e-6, 0.5] (INVALID_ARGUMENT otherwise). Every RPC that takes one checks
  // it here, before it reaches the cache, whose ordered lookup a NaN breaks.
  absl::StatusOr<double> Epsilon(double requested) const;
  // The graph a request names (SelectorOf, in convert.h): its mesh, and the
  // build record this daemon makes for that epsilon and pseudo vertices.
  absl::StatusOr<GraphKey> Key(const v1::GraphSelector& graph) const;
  // Records a registered mesh in the catalog (if any); on failure a mesh
  // that did not exist before is unregistered again.
  absl::Status Record(const RegisteredMesh& m, bool existed);
  // The registry's mesh, or the catalog's if another replica registered it.
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> FindMesh(const std::string& name);
  // Admits, records and requests a graph (RequestGraph, and queries that
  // start the graph they need).
  absl::StatusOr<GraphStatus> StartGraph(const GraphKey& key,
                                         const std::shared_ptr<const RegisteredMesh>& mesh,
                                         const std::string& client);
  // Whether `client` may start a new graph of `key`: its epsilon or bound
  // within --min-epsilon / --min-max-error, and the build queue within its
  // bounds. Errors name the flag, and the graph's estimate.
  absl::Status CheckBuildBudget(const GraphKey& key, const RegisteredMesh& mesh,
                                const std::string& client)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(builds_mu_);
  // The engine of a ready graph; FindMesh's error when its mesh is not
  // registered. A graph being made (built, mapped, known only to the
  // catalog) is waited for within the call's deadline, and one never
  // requested is started first (ServiceLimits::build_on_query).
  absl::StatusOr<std::shared_ptr<const GeodesicEngine>> AcquireEngine(const GraphKey& key,
                                                                      const Call& call);

  MeshRegistry* meshes_;
  GraphCache* graphs_;
  Metrics* metrics_;
  ServiceLimits limits_;
  ClientIdentity identity_;
  CatalogSync* catalog_ = nullptr;
  NameLocks names_;  // a mesh's changes, one at a time
  // The client that started each graph (for the per-client build budget);
  // held while a build is checked and queued.
  absl::Mutex builds_mu_;
  std::map<GraphKey, std::string> started_by_ ABSL_GUARDED_BY(builds_mu_);

  MemoryLedger* ledger_ = nullptr;
  Admission admission_;
  StreamWatchdog watchdog_;
  std::atomic<int> calls_in_progress_{0};
  // The answers of Distance and Matrix between their handler's return and
  // their write: the reply and its serialized copy live until a client that
  // reads slowly (or never) has taken it, so their reservations stay until
  // AnswerSent.
  absl::Mutex sending_mu_;
  absl::flat_hash_map<const grpc::ServerContext*, Admission::Ticket> sending_
      ABSL_GUARDED_BY(sending_mu_);
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GEODESIC_SERVICE_H_
