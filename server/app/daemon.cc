#include "server/app/daemon.h"

#include <malloc.h>
#include <signal.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>

#include "absl/strings/str_format.h"
#include "absl/time/time.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "core/base/version.h"
#include "nlohmann/json.hpp"
#include "server/base/log.h"
#include "server/grpc/reflection.h"
#include "server/limits/answer_watch.h"

namespace geodesic::server {
namespace {

// --disk-limit leaves files written this recently: the catalog it reads may
// not list them yet, and replicas sharing the directory write files this
// daemon does not know about.
constexpr auto kDiskGrace = std::chrono::minutes(2);

// How long the HTTP gateway may take, once the gRPC calls still running at
// the drain's end were cancelled, to write the answers they ended with.
constexpr auto kAnswerWriteGrace = std::chrono::seconds(1);

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

// The health-check name of a graph: "geodesic.v1.Geodesic/<mesh>@<eps>",
// with "+pseudo" for the graph with pseudo vertices; a certified graph's is
// "<mesh>@cert<max_error>", its epsilon being the build's choice.
std::string ServiceName(const GraphKey& key) {
  if (key.max_error > 0) {
    return absl::StrFormat("geodesic.v1.Geodesic/%s@cert%g%s", key.mesh, key.max_error,
                           key.params.pseudo_vertices ? "+pseudo" : "");
  }
  return absl::StrFormat("geodesic.v1.Geodesic/%s@%g%s", key.mesh, key.params.epsilon,
                         key.params.pseudo_vertices ? "+pseudo" : "");
}

// The health-check name that is NOT_SERVING while admission refuses calls.
constexpr char kCapacity[] = "geodesic.v1.Geodesic/capacity";

// gRPC threads beyond admission's: for the control calls and for gRPC's own
// pollers. Admission bounds the control calls that may wait (registrations,
// unloads, graph requests: AdmissionOptions::max_changes, half of these), so
// listing, get and health always find the other half.
constexpr int kControlThreads = 16;
constexpr int kPollerThreads = 8;

// gRPC's receive buffers beside one largest request: the messages of the
// other calls being read (uploads' chunks, small requests, their windows).
constexpr uint64_t kTransportSlackBytes = uint64_t{16} << 20;

// --port-file: {"grpc": P}, with "metrics": Q and "http": H when they listen, written once the
// ports are bound, by rename so that a reader never sees half of it.
bool WritePortFile(const std::string& path, int grpc_port, int metrics_port, int http_port) {
  nlohmann::json ports = {{"grpc", grpc_port}};
  if (metrics_port > 0) ports["metrics"] = metrics_port;
  if (http_port > 0) ports["http"] = http_port;
  const std::string text = ports.dump() + "\n";
  auto file = AtomicFileWriter::Create(path);
  absl::Status s = file.ok() ? file->Append(text.data(), text.size()) : file.status();
  if (s.ok()) s = std::move(*file).Commit();
  if (!s.ok()) {
    std::fprintf(stderr, "geodesicd serve: --port-file: %s\n", std::string(s.message()).c_str());
    return false;
  }
  return true;
}

}  // namespace

Daemon::Daemon(ServeOptions options)
    : options_(std::move(options)), sample_mesh_(absl::NotFoundError("no sample mesh")) {}

Daemon::~Daemon() = default;

int Daemon::Start() {
  RemoveStaleTemporaryMeshFiles();  // uploads a killed daemon was reading
  OpenGraphDir();
  // Built meshes are saved beside the graphs, so a restarted daemon restores
  // them rather than parsing and building them again; with a graph
  // directory a registration returns once its snapshot is on disk, since
  // the catalog then records it for restarts and replicas.
  meshes_ = std::make_unique<MeshRegistry>(options_.mesh_root, options_.graph_dir,
                                           /*durable=*/!options_.graph_dir.empty());
  meshes_->SetMemoryLimit(options_.memory_limit);
  if (disk_ && options_.disk_limit > 0) {
    meshes_->SetDiskReservation(
        [this](uint64_t bytes) { return disk_->Reserve(bytes); },
        [this](uint64_t reserved, uint64_t written) { disk_->Done(reserved, written); });
  }
  GraphCache::Options cache;
  cache.graph_dir = options_.graph_dir;
  cache.memory_limit = options_.memory_limit;
  cache.resident_bytes_outside = [this] {
    return meshes_->resident_bytes() + (memory_ ? memory_->reserved() : 0);
  };
  cache.on_file_used = MarkFileUsed;
  cache.build_workers = options_.build_workers;
  cache.build_threads = options_.build_threads;
  cache.pseudo_vertex_limit = options_.pseudo_vertex_limit;
  cache.build_memory_limit = options_.build_memory_limit;
  cache.large_build_seconds = options_.large_build_seconds;
  cache.max_graph_bytes = options_.max_graph_bytes;
  cache.exact_landmarks = options_.exact_landmarks;
  if (options_.disk_limit > 0) cache.disk = disk_.get();
  cache.on_readiness = [this](const GraphKey& key, bool ready) {
    std::lock_guard<std::mutex> lock(health_mu_);
    if (health_) health_->SetServingStatus(ServiceName(key), ready);
  };
  graphs_ = std::make_unique<GraphCache>(cache);
  OpenCatalog();
  AddMetrics();
  RegisterSample();
  service_ =
      std::make_unique<GeodesicService>(meshes_.get(), graphs_.get(), &metrics_, options_.limits);
  if (!options_.tokens.empty()) service_->RequireBearerTokens(options_.tokens);
  // Beside the meshes and the running queries' reservations; graphs make
  // room, being evictable.
  memory_ = std::make_unique<MemoryLedger>(options_.memory_limit, [this] {
    return meshes_->resident_bytes() + service_->admission().reserved_bytes();
  });
  service_->UseMemoryLedger(memory_.get());
  AddQueryMetrics();
  if (int rc = ListenGrpc(); rc != 0) return rc;
  int metrics_port = 0;
  if (int rc = ListenMetrics(&metrics_port); rc != 0) return rc;
  if (int rc = ListenHttp(); rc != 0) return rc;
  if (!options_.port_file.empty() &&
      !WritePortFile(options_.port_file, grpc_port_, metrics_port, http_ ? http_->port() : 0)) {
    return 1;
  }
  std::fprintf(stderr, "geodesicd: serving on %s (port %d, %s%s), graphs in %s, mesh root %s\n",
               options_.listen.c_str(), grpc_port_,
               options_.tls_cert.empty()        ? "plaintext"
               : options_.tls_client_ca.empty() ? "TLS"
                                                : "mutual TLS",
               options_.tokens.empty() ? "" : ", bearer token required", options_.graph_dir.c_str(),
               options_.mesh_root.empty() ? "(none)" : options_.mesh_root.c_str());
  signal(SIGTERM, OnSignal);
  signal(SIGINT, OnSignal);
  return 0;
}

void Daemon::OpenGraphDir() {
  const std::string& dir = options_.graph_dir;
  if (dir.empty()) return;
  std::error_code ec;
  std::filesystem::create_directories(dir, ec);
  // What writers and builders killed midway left (graphs, snapshots, the
  // catalog, build locks): old enough that no live replica is at work on
  // them.
  for (const std::string& name : RemoveStaleTemporaries(dir, kDiskGrace)) {
    Log(LogLevel::kInfo, "stale_temporary_removed", {{"file", name}});
  }
  for (const std::string& name : GraphCache::RemoveStaleBuildLocks(dir, kDiskGrace)) {
    Log(LogLevel::kInfo, "stale_build_lock_removed", {{"file", name}});
  }
  disk_ = std::make_unique<DiskBudget>(
      dir, options_.disk_limit, [this](uint64_t target) -> absl::StatusOr<uint64_t> {
        if (!can_sweep_) return absl::UnavailableError("starting");
        // A limit of 0 is none to the sweep: 1 byte asks for all it may remove.
        ASSIGN_OR_RETURN(DiskReport report, Sweep(std::max<uint64_t>(target, 1)));
        return report.bytes_after;
      });
  if (absl::Status s = disk_->Scan(); !s.ok()) {
    Log(LogLevel::kWarning, "disk_scan_failed", {{"error", s.ToString()}});
  }
}

void Daemon::OpenCatalog() {
  if (options_.graph_dir.empty()) return;
  catalog_ = std::make_unique<Catalog>(options_.graph_dir);
  if (absl::Status s = catalog_->EnsureReserve(); !s.ok()) {
    Log(LogLevel::kWarning, "catalog_reserve_missing", {{"error", s.ToString()}});
  }
  CatalogSync::Hooks hooks{
      .restore_mesh =
          [this](const CatalogMesh& m) {
            if (!m.parent.empty()) {
              return meshes_
                  ->RegisterRegion(m.name, m.parent,
                                   m.region_faces ? RegionMask::kFaces : RegionMask::kVertices,
                                   m.region_ids, m.fingerprint)
                  .status();
            }
            return meshes_
                ->RegisterRecorded(m.name, m.source, m.format, m.source_hash, m.fingerprint,
                                   m.repair_non_manifold)
                .status();
          },
      .drop_mesh =
          [this](const std::string& name) {
            meshes_->Remove(name).IgnoreError();
            graphs_->DropMesh(name);
          },
      .request_graph =
          [this](const std::string& mesh, const DggParams& params, double max_error) {
            if (auto m = meshes_->Get(mesh); m.ok()) graphs_->Request(*m, params, max_error);
          },
      .cancel_graph =
          [this](const std::string& mesh, const DggParams& params, double max_error) {
            graphs_->Cancel({mesh, params, max_error}).IgnoreError();
          },
  };
  sync_ = std::make_unique<CatalogSync>(catalog_.get(), std::move(hooks));
  can_sweep_ = true;
}

absl::StatusOr<DiskReport> Daemon::Sweep(uint64_t limit) {
  // A build persisting at shutdown must not reach the catalog and the
  // registry as they are destroyed.
  if (g_stop) return absl::UnavailableError("shutting down");
  ASSIGN_OR_RETURN(const CatalogState state, catalog_->Read());
  const CatalogFiles files = FilesOf(state);
  ASSIGN_OR_RETURN(DiskReport report,
                   EnforceDiskLimit(options_.graph_dir, limit, [&](const std::string& name) {
                     // Asked afresh each time, as EnforceDiskLimit asks again just before
                     // removing: a mesh registered since the listing has its snapshot.
                     bool in_use = graphs_->FileInUse(name);
                     for (const auto& m : meshes_->List())
                       in_use |= MeshRegistry::SnapshotName(*m) == name;
                     return GraphDirFileRole(options_.graph_dir, name, files, in_use, kDiskGrace);
                   }));
  disk_removed_ += report.removed.size();
  for (const std::string& name : report.removed) {
    Log(LogLevel::kInfo, "disk_file_removed", {{"file", name}});
  }
  return report;
}

void Daemon::AddMetrics() {
  metrics_.AddInfo("geodesicd_build_info", "The daemon's version and build type.",
                   {{"version", kVersion}, {"build_type", kBuildType}});
  metrics_.AddGauge("geodesicd_ready", "1 once start-up restored what the catalog holds.",
                    [this] { return ready_ ? 1.0 : 0.0; });
  metrics_.AddGauge("geodesicd_graph_dir_bytes", "Bytes of the files in --graph-dir.",
                    [this] { return double(disk_bytes_.load()); });
  metrics_.AddCounter("geodesicd_disk_files_removed_total",
                      "Graph files and mesh snapshots removed to stay within --disk-limit.",
                      [this] { return double(disk_removed_.load()); });
  if (sync_) {
    metrics_.AddGauge("geodesicd_catalog_generation", "Generation of the catalog last followed.",
                      [this] { return double(sync_->generation()); });
  }
  const GraphCache& graphs = *graphs_;
  metrics_.AddGauge("geodesicd_graph_resident_bytes",
                    "Resident bytes: graphs built in memory and landmark tables.",
                    [&graphs] { return double(graphs.resident_bytes()); });
  metrics_.AddGauge("geodesicd_mesh_resident_bytes",
                    "Bytes of registered meshes (counted in --memory-limit, never evicted).",
                    [this] { return double(meshes_->resident_bytes()); });
  metrics_.AddGauge("geodesicd_graph_mapped_bytes", "Bytes of memory-mapped graphs.",
                    [&graphs] { return double(graphs.mapped_bytes()); });
  metrics_.AddGauge("geodesicd_builds_running", "Graph builds running.",
                    [&graphs] { return double(graphs.builds_running()); });
  metrics_.AddCounter("geodesicd_graph_builds_total",
                      "Graph builds started here (not graphs mapped from --graph-dir).",
                      [&graphs] { return double(graphs.builds_started()); });
  metrics_.AddGauge(
      "geodesicd_query_scratch_bytes",
      "Query scratch held by the engines of ready graphs (pooled per query in flight).",
      [&graphs] { return double(graphs.scratch_bytes()); });
  metrics_.AddCounter("geodesicd_cache_hits_total", "Queries that found their graph ready.",
                      [&graphs] { return double(graphs.hits()); });
  metrics_.AddCounter("geodesicd_cache_misses_total", "Queries whose graph was not ready.",
                      [&graphs] { return double(graphs.misses()); });
  metrics_.AddCounter("geodesicd_graph_evictions_total",
                      "Ready graphs evicted to stay within --memory-limit.",
                      [&graphs] { return double(graphs.evictions()); });
  // Per-graph series would need labels the exposition does not carry
  // (metrics.h): the count, and the worst certificate, which an alert on a
  // bound compares against.
  metrics_.AddGauge(
      "geodesicd_certified_graphs",
      "Certified graphs (RequestGraph max_error) with a certificate: ready, or evicted.",
      [&graphs] {
        double n = 0;
        for (const GraphStatus& g : graphs.List()) n += g.certificate.has_value();
        return n;
      });
  metrics_.AddGauge("geodesicd_certified_graph_max_error",
                    "The largest measured max relative error of a certified graph (0: none).",
                    [&graphs] {
                      double worst = 0;
                      for (const GraphStatus& g : graphs.List()) {
                        if (g.certificate)
                          worst = std::max(worst, g.certificate->measured_max_error);
                      }
                      return worst;
                    });
  metrics_.AddGauge(
      "geodesicd_certified_graph_max_error_ratio",
      "The largest measured max error of a certified graph over its bound (below 1).", [&graphs] {
        double worst = 0;
        for (const GraphStatus& g : graphs.List()) {
          if (g.certificate && g.certificate->max_error_bound > 0) {
            worst =
                std::max(worst, g.certificate->measured_max_error / g.certificate->max_error_bound);
          }
        }
        return worst;
      });
}

void Daemon::AddQueryMetrics() {
  const Admission& admission = service_->admission();
  metrics_.AddGauge("geodesicd_queue_depth", "Queries admitted: running or waiting their turn.",
                    [&admission] { return double(admission.admitted()); });
  metrics_.AddGauge("geodesicd_queries_running", "Admitted queries running (--query-threads).",
                    [&admission] { return double(admission.running()); });
  metrics_.AddGauge("geodesicd_queries_waiting", "Admitted queries waiting for a running slot.",
                    [&admission] { return double(admission.waiting()); });
  metrics_.AddGauge("geodesicd_streams_open", "Server streams open (--max-streams).",
                    [&admission] { return double(admission.streams()); });
  const GeodesicService& service = *service_;
  metrics_.AddGauge("geodesicd_calls_in_progress",
                    "gRPC calls in a handler, each holding one of the server's threads.",
                    [&service] { return double(service.calls_in_progress()); });
  metrics_.AddCounter("geodesicd_streams_idle_closed_total",
                      "Streams closed after waiting on their client for --idle-seconds.",
                      [&service] { return double(service.watchdog().closed()); });
  metrics_.AddGauge("geodesicd_reserved_bytes",
                    "Answer and scratch bytes running queries reserved against --memory-limit.",
                    [&admission] { return double(admission.reserved_bytes()); });
  metrics_.AddGauge("geodesicd_overloaded",
                    "1 while admission is full or refused a call in the last second.",
                    [&admission] { return admission.overloaded() ? 1.0 : 0.0; });
  metrics_.AddCounter("geodesicd_overload_refusals_total",
                      "Calls answered RESOURCE_EXHAUSTED \"server overloaded\".",
                      [&admission] { return double(admission.refusals()); });
}

// Registered before the port opens, so that the first answer already lists
// it; its graph is requested once health reporting is up.
void Daemon::RegisterSample() {
  if (options_.no_sample) return;
  const std::string& path = options_.sample_path;
  if (path.empty()) {
    std::fprintf(stderr, "geodesicd: bundled sample mesh not found (set GEODESIC_DATA_DIR)\n");
    return;
  }
  sample_mesh_ = meshes_->RegisterTrustedPath("spot", path);
  if (sample_mesh_.ok()) {
    std::fprintf(stderr, "geodesicd: registered sample mesh 'spot' from %s\n", path.c_str());
  } else {
    std::fprintf(stderr, "geodesicd: sample mesh: %s\n",
                 std::string(sample_mesh_.status().message()).c_str());
  }
}

uint64_t Daemon::TransportBufferBytes() const {
  if (options_.memory_limit == 0) return 0;
  return MaxRequestBytes(options_.limits) + kTransportSlackBytes;
}

int Daemon::ListenGrpc() {
  grpc::EnableDefaultHealthCheckService(true);
  grpc::ServerBuilder builder;
  // Reflection v1 and v1alpha, ours rather than gRPC's plugin (reflection.h).
  AddReflection(builder);
  builder.AddListeningPort(options_.listen, options_.credentials, &grpc_port_);
  // A port taken by another daemon is refused (see listen_socket.h).
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  builder.RegisterService(service_.get());
  const ServiceLimits& limits = options_.limits;
  // A request larger than the limits allow is refused as it arrives; one
  // that fits is measured again by its handler (DecodeWithinLimits).
  const uint64_t max_request = MaxRequestBytes(limits);
  builder.SetMaxReceiveMessageSize(static_cast<int>(max_request));
  builder.SetMaxSendMessageSize(static_cast<int>(limits.max_message_bytes));
  AddIdleArguments(builder);
  // A unary answer its client does not take within --idle-seconds is
  // cancelled (answer_watch.h), as streams are.
  std::vector<std::unique_ptr<grpc::experimental::ServerInterceptorFactoryInterface>> watches;
  watches.push_back(std::make_unique<AnswerWatchFactory>(&service_->watchdog()));
  builder.experimental().SetInterceptorCreators(std::move(watches));
  grpc::ResourceQuota quota("geodesicd");
  quota.SetMaxThreads(ThreadQuota());
  // gRPC holds a request's bytes until the whole message has come, before
  // any handler or size check sees it (six 57 MiB requests held 342 MiB).
  // Its quota bounds those buffers: past it, gRPC cancels a stream
  // (RESOURCE_EXHAUSTED) rather than read more.
  if (const uint64_t buffers = TransportBufferBytes(); buffers > 0) quota.Resize(buffers);
  builder.SetResourceQuota(quota);
  server_ = builder.BuildAndStart();
  if (!server_ || grpc_port_ == 0) {
    std::fprintf(stderr, "geodesicd serve: cannot listen on %s: address in use or unavailable\n",
                 options_.listen.c_str());
    return 1;
  }
  std::lock_guard<std::mutex> lock(health_mu_);
  health_ = server_->GetHealthCheckService();
  // Serving once start-up has restored what the catalog holds.
  health_->SetServingStatus("", false);
  health_->SetServingStatus("geodesic.v1.Geodesic", false);
  health_->SetServingStatus(kCapacity, true);
  return 0;
}

// The synchronous server holds a thread per call in progress, and answers
// "Server Threadpool Exhausted" when the quota has none left: the quota
// covers every admitted query (running or waiting), every query waiting for
// admission (at most max_inflight of them, admission.h), every stream (streamed
// queries hold a stream slot throughout, and a query slot only while they
// compute their first answer), the HTTP gateway's workers (whose calls come in
// through the in-process channel), the control calls and gRPC's own
// pollers, so that the answer past a limit is ours (RESOURCE_EXHAUSTED
// "server overloaded", with a retry hint) and control calls always find a
// thread.
int Daemon::ThreadQuota() const {
  const ServiceLimits& limits = options_.limits;
  const int http_workers = options_.http_listen.empty() ? 0 : options_.http_limits.workers;
  return 2 * limits.max_inflight + limits.max_streams + http_workers + kControlThreads +
         kPollerThreads;
}

// A connection with no call for --idle-seconds is closed (a client
// reconnects when it calls again), and a quiet one is pinged, so that a
// peer that vanished does not keep its connection.
void Daemon::AddIdleArguments(grpc::ServerBuilder& builder) const {
  const double idle = options_.limits.idle_seconds;
  if (idle <= 0) return;
  const int ms = static_cast<int>(std::min(idle, 86400.0) * 1000);
  builder.AddChannelArgument(GRPC_ARG_MAX_CONNECTION_IDLE_MS, ms);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIME_MS, ms);
  builder.AddChannelArgument(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, ms);
}

// Calls are refused, or about to be: admission is full or refusing, or the
// control calls' threads are running out.
bool Daemon::Overloaded() const {
  const int calls = service_->calls_in_progress();
  return service_->admission().overloaded() ||
         calls >= ThreadQuota() - kPollerThreads - kControlThreads / 2;
}

int Daemon::ListenMetrics(int* port) {
  if (options_.metrics_listen.empty()) return 0;
  std::string error;
  metrics_http_ = MetricsHttpServer::Start(
      options_.metrics_listen, &metrics_, [this] { return ready_.load(); }, &error);
  if (!metrics_http_) {
    std::fprintf(stderr, "geodesicd serve: %s\n", error.c_str());
    return 1;
  }
  *port = metrics_http_->port();
  return 0;
}

int Daemon::ListenHttp() {
  if (options_.http_listen.empty()) return 0;
  HttpGatewayOptions gateway;
  gateway.listen = options_.http_listen;
  gateway.tls_cert = options_.tls_cert;
  gateway.tls_key = options_.tls_key;
  gateway.tls_client_ca = options_.tls_client_ca;
  gateway.bearer_tokens = options_.tokens;
  gateway.cors_origin = options_.http_cors_origin;
  gateway.limits = options_.http_limits;
  gateway.memory = memory_.get();
  gateway.service = options_.limits;
  auto started = HttpGateway::Start(gateway, server_.get());
  if (!started.ok()) {
    std::fprintf(stderr, "geodesicd serve: %s\n", std::string(started.status().message()).c_str());
    return 1;
  }
  http_ = std::move(*started);
  std::fprintf(stderr, "geodesicd: HTTP on %s (http port %d, %s)\n", options_.http_listen.c_str(),
               http_->port(), http_->tls() ? "TLS" : "plaintext");
  return 0;
}

// Start-up: what the catalog recorded (clients' meshes and graphs), what
// the config declares, and the sample's graph. Queries that arrive
// meanwhile restore what they name on demand (GeodesicService::FindMesh).
int Daemon::Restore() {
  RegisterConfigMeshes();
  if (int rc = RestoreCatalog(); rc != 0) return rc;
  RequestConfigGraphs();
  if (sample_mesh_.ok()) {
    graphs_->Request(*sample_mesh_, Params(options_.limits.default_epsilon, false));
  }
  const size_t restored = WaitForRestored();
  ready_ = true;
  SetHealth("", true);
  SetHealth("geodesic.v1.Geodesic", true);
  Log(LogLevel::kInfo, "ready",
      {{"meshes", meshes_->List().size()},
       {"graphs_ready", restored},
       {"graphs_restoring", restoring_.size()}});
  return 0;
}

// --config's meshes, before the catalog is applied: the catalog records
// their graphs (and the sample's), which it then requests again.
void Daemon::RegisterConfigMeshes() {
  for (const DeclaredMesh& m : options_.config.meshes) {
    auto registered = std::filesystem::path(m.path).is_absolute()
                          ? meshes_->RegisterTrustedPath(m.name, m.path, m.repair_non_manifold)
                          : meshes_->RegisterPath(m.name, m.path, m.repair_non_manifold);
    if (!registered.ok()) {
      Log(LogLevel::kError, "config_mesh_failed",
          {{"mesh", m.name}, {"path", m.path}, {"error", registered.status().ToString()}});
    } else if (sync_) {
      sync_->AddStartupMesh(m.name);
    }
  }
  if (sync_ && sample_mesh_.ok()) sync_->AddStartupMesh("spot");
}

int Daemon::RestoreCatalog() {
  if (!sync_) return 0;
  if (absl::Status s = sync_->Reconcile(); !s.ok()) {
    Log(LogLevel::kError, "catalog_unreadable", {{"error", s.ToString()}});
    std::fprintf(stderr, "geodesicd serve: %s (fix or move the file; it is left as it is)\n",
                 std::string(s.message()).c_str());
    return 1;
  }
  if (auto state = catalog_->Read(); state.ok()) {
    for (const CatalogGraph& g : state->graphs) {
      restoring_.push_back({g.mesh, g.params, g.max_error});
    }
  }
  service_->UseCatalog(sync_.get());
  return 0;
}

void Daemon::RequestConfigGraphs() {
  for (const DeclaredGraph& g : options_.config.graphs) {
    if (auto m = meshes_->Get(g.mesh); m.ok()) {
      // A certified graph's key carries the epsilon its bound decides.
      const DggParams params =
          Params(g.max_error > 0 ? CertifiedKeyEpsilon(g.max_error) : g.epsilon, g.pseudo_vertices);
      graphs_->Request(*m, params, g.max_error);
      restoring_.push_back({g.mesh, params, g.max_error});
    }
  }
}

// The build record of the graphs this daemon requests itself.
DggParams Daemon::Params(double epsilon, bool pseudo_vertices) const {
  DggParams params;
  params.epsilon = epsilon;
  params.pseudo_vertices = pseudo_vertices;
  params.exact_fans = options_.limits.exact_fans;
  return params;
}

// Ready once every restored graph whose file was there is mapped (a
// missing or invalid one rebuilds in the background, and one another
// replica is building is mapped once it is done: neither is waited for),
// or after a minute at most. Returns how many are ready.
size_t Daemon::WaitForRestored() {
  const absl::Time deadline = absl::Now() + absl::Seconds(60);
  size_t ready = 0;
  for (const GraphKey& key : restoring_) {
    auto status = graphs_->Get(key);
    while (status.ok() && !g_stop &&
           (status->state == GraphState::kQueued || status->state == GraphState::kLoading) &&
           // Another replica's build may take long: serve meanwhile.
           status->phase != kWaitingForReplicaPhase && absl::Now() < deadline) {
      status = graphs_->WaitForChange(key, status->version, absl::Now() + absl::Milliseconds(200));
    }
    ready += status.ok() && status->state == GraphState::kReady;
  }
  return ready;
}

void Daemon::Serve() {
  // Follows the catalog (replicas' changes) and keeps --graph-dir in budget.
  std::thread follower([this] {
    while (!g_stop) {
      for (int i = 0; i < options_.catalog_poll_seconds * 10 && !g_stop; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
      if (!g_stop && !options_.graph_dir.empty()) FollowCatalog();
    }
  });
  // Probes of "" and "geodesic.v1.Geodesic" keep SERVING under load (a
  // restart would only lose the resident graphs); kCapacity tells balancers
  // that this replica is refusing queries now.
  bool overloaded = false;
  for (int tick = 0; !g_stop; ++tick) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (Overloaded() != overloaded) {
      overloaded = !overloaded;
      SetHealth(kCapacity, !overloaded);
    }
    // Memory that queries and their answers freed goes back to the system,
    // not only to malloc's free lists, so resident memory follows what the
    // limit counts.
    if (tick % 10 == 0) malloc_trim(0);
  }
  follower.join();
}

void Daemon::FollowCatalog() {
  if (absl::Status s = sync_->Reconcile(); !s.ok()) {
    Log(LogLevel::kError, "catalog_unreadable", {{"error", s.ToString()}});
  }
  // A reserve the catalog used on a full disk comes back once there is
  // room.
  catalog_->EnsureReserve().IgnoreError();
  auto report = Sweep(options_.disk_limit);
  if (!report.ok()) {
    Log(LogLevel::kError, "disk_limit_failed", {{"error", report.status().ToString()}});
    return;
  }
  disk_bytes_ = report->bytes_after;
  disk_->Set(report->bytes_after);
  if (report->over_limit) {
    Log(LogLevel::kWarning, "disk_over_limit",
        {{"bytes", report->bytes_after}, {"limit", options_.disk_limit}});
  }
}

void Daemon::Drain() {
  std::fprintf(stderr, "geodesicd: shutting down (draining up to %.0f s)\n",
               options_.drain_seconds);
  const auto drain = std::chrono::milliseconds(static_cast<int64_t>(options_.drain_seconds * 1000));
  const auto drain_end = std::chrono::steady_clock::now() + drain;
  SetHealth("", false);
  // No new requests over HTTP; those being answered go on.
  if (http_) http_->StopAccepting();
  // Queries waiting for a build are answered now instead of when it ends;
  // no build outlives the drain. Graph writes are atomic (temp + rename):
  // an interrupted build leaves no file a restart would trust.
  graphs_->CancelAll();
  // The gateway's calls go through the in-process channel, which the gRPC
  // server's shutdown ends at once ("transport closed") rather than letting
  // them finish: its requests get the drain first, then the server's own
  // calls what is left of it (the health status already sends balancers
  // elsewhere).
  if (http_) http_->WaitForAnswers(drain_end);
  // Calls still running then are cancelled.
  const auto left = std::max(drain_end - std::chrono::steady_clock::now(),
                             std::chrono::steady_clock::duration::zero());
  server_->Shutdown(std::chrono::system_clock::now() +
                    std::chrono::duration_cast<std::chrono::system_clock::duration>(left));
  // The gateway's requests whose calls were cancelled answer so within a
  // moment; then every connection closes.
  if (http_) http_->Finish(std::chrono::steady_clock::now() + kAnswerWriteGrace);
  http_.reset();
}

void Daemon::SetHealth(const std::string& service, bool serving) {
  std::lock_guard<std::mutex> lock(health_mu_);
  health_->SetServingStatus(service, serving);
}

}  // namespace geodesic::server
