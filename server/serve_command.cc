// geodesicd serve: the daemon.
#include <malloc.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <unistd.h>

#include <cctype>
#include <chrono>
#include <condition_variable>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "core/atomic_file.h"
#include "core/mesh_snapshot.h"
#include "core/status.h"
#include "core/version.h"
#include "grpcpp/ext/proto_server_reflection_plugin.h"
#include "grpcpp/grpcpp.h"
#include "grpcpp/health_check_service_interface.h"
#include "nlohmann/json.hpp"
#include "server/byte_size.h"
#include "server/catalog.h"
#include "server/catalog_sync.h"
#include "server/config_file.h"
#include "server/disk_budget.h"
#include "server/geodesic_service.h"
#include "server/http_gateway.h"
#include "server/log.h"
#include "server/serve.h"

namespace geodesic::server {
namespace {

// --disk-limit leaves files written this recently: the catalog it reads may
// not list them yet, and replicas sharing the directory write files this
// daemon does not know about.
constexpr auto kDiskGrace = std::chrono::minutes(2);

std::atomic<bool> g_stop{false};
void OnSignal(int) { g_stop = true; }

std::string DefaultGraphDir() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) {
    return std::string(xdg) + "/geodesicd";
  }
  if (const char* home = std::getenv("HOME"); home && *home) {
    return std::string(home) + "/.cache/geodesicd";
  }
  return "/tmp/geodesicd-graphs";
}

// The bundled sample mesh: GEODESIC_DATA_DIR, or data/ next to the source
// tree the binary was built from (build/bin/../../data), or an install path.
std::string FindSampleMesh(const char* argv0) {
  std::vector<std::filesystem::path> candidates;
  if (const char* dir = std::getenv("GEODESIC_DATA_DIR"); dir && *dir) {
    candidates.push_back(std::filesystem::path(dir) / "spot.obj");
  }
  std::error_code ec;
  auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) exe = argv0;
  candidates.push_back(exe.parent_path() / "../../data/spot.obj");
  candidates.push_back(exe.parent_path() / "../share/geodesicd/spot.obj");
  candidates.push_back("/usr/share/geodesicd/spot.obj");
  for (const auto& c : candidates) {
    if (std::filesystem::exists(c)) return std::filesystem::weakly_canonical(c).string();
  }
  return "";
}

// The health-check name of a graph: "geodesic.v1.Geodesic/<mesh>@<eps>",
// with "+pseudo" for the graph with pseudo vertices.
std::string ServiceName(const GraphKey& key) {
  return absl::StrFormat("geodesic.v1.Geodesic/%s@%g%s", key.mesh, key.params.epsilon,
                         key.params.pseudo_vertices ? "+pseudo" : "");
}

// The health-check name that is NOT_SERVING while admission refuses calls.
constexpr char kCapacity[] = "geodesic.v1.Geodesic/capacity";

// Certificates, keys and tokens: small files read once at start.
bool ReadSecretFile(const std::string& flag, const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  if (in) text << in.rdbuf();
  if (!in || text.str().empty()) {
    std::fprintf(stderr, "geodesicd serve: %s %s: cannot read it or it is empty\n", flag.c_str(),
                 path.c_str());
    return false;
  }
  *out = text.str();
  return true;
}

struct SecurityFlags {
  std::string tls_cert, tls_key, tls_client_ca, auth_token_file;
};

// Plaintext unless a certificate is given; with a client CA, clients must
// present a certificate it signed (mutual TLS).
std::shared_ptr<grpc::ServerCredentials> ServerCredentials(const SecurityFlags& flags) {
  if (flags.tls_cert.empty() && flags.tls_key.empty()) {
    if (!flags.tls_client_ca.empty()) {
      std::fprintf(stderr, "geodesicd serve: --tls-client-ca needs --tls-cert and --tls-key\n");
      return nullptr;
    }
    return grpc::InsecureServerCredentials();
  }
  grpc::SslServerCredentialsOptions::PemKeyCertPair pair;
  if (!ReadSecretFile("--tls-cert", flags.tls_cert, &pair.cert_chain) ||
      !ReadSecretFile("--tls-key", flags.tls_key, &pair.private_key)) {
    return nullptr;
  }
  grpc::SslServerCredentialsOptions options;
  options.pem_key_cert_pairs.push_back(std::move(pair));
  if (!flags.tls_client_ca.empty()) {
    if (!ReadSecretFile("--tls-client-ca", flags.tls_client_ca, &options.pem_root_certs)) {
      return nullptr;
    }
    options.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(options);
}

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

int RunServe(int argc, char** argv) {
  // Buffers of a megabyte or more (a field's distances, a long query's
  // records, a mesh being loaded) get mappings of their own, returned to the
  // system when freed. By default glibc raises this threshold after the first
  // such free, then serves them from per-thread arenas that keep the memory:
  // on a 3.2M-vertex graph resident memory drifted 0.9 GB past what
  // --memory-limit counts after a minute of concurrent queries (0.1 GB so).
  mallopt(M_MMAP_THRESHOLD, 1 << 20);
  CLI::App app{"Serve geodesic queries over gRPC", "geodesicd serve"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  std::string http_listen;
  std::string listen = "127.0.0.1:50051", graph_dir = DefaultGraphDir(), mesh_root, metrics_listen,
              log_level = "info", sample;
  std::string memory_limit_text = "0", disk_limit_text = "0", config_path, log_format = "text";
  double catalog_poll_seconds = 2;
  int build_threads = 0, build_workers = 1, query_threads = 0;
  bool exact_fans = false;
  ServiceLimits limits;
  bool no_sample = false;
  double drain_seconds = 10;
  std::string port_file;
  app.add_option("--listen", listen, "address to serve gRPC on (HOST:PORT; port 0: any free port)");
  app.add_option(
      "--port-file", port_file,
      "once listening, write the bound ports here as JSON, {\"grpc\": P} and, with "
      "--metrics-listen or --http-listen, \"metrics\": Q or \"http\": H (replaced atomically: the "
      "file appears complete or not at all); for HOST:0 addresses");
  app.add_option("--graph-dir", graph_dir,
                 "where graphs, and snapshots of registered meshes, are written and read back");
  app.add_option("--mesh-root", mesh_root, "RegisterMesh paths must lie under this directory");
  app.add_option("--memory-limit", memory_limit_text,
                 "bytes of registered meshes, ready graphs and their query scratch to keep, e.g. "
                 "6G or 512M: least recently used graphs no query holds are evicted to stay "
                 "within it; meshes are not. Running queries reserve their answer and scratch "
                 "bytes within it before they start (0: no limit)");
  app.add_option(
      "--disk-limit", disk_limit_text,
      "bytes --graph-dir may hold, e.g. 50G: least recently used graph files and mesh "
      "snapshots no catalog entry names go first, then catalogued ones (rebuilt when "
      "needed); never a file in use, an uploaded mesh's snapshot or a file written in the "
      "last two minutes. A graph file or snapshot that would still pass it is not written: "
      "the graph fails, the upload is refused (0: no limit)");
  app.add_option("--config", config_path,
                 "YAML file of meshes to register and graphs to build at start (see "
                 "server/config_file.h)")
      ->check(CLI::ExistingFile);
  app.add_option("--catalog-poll-seconds", catalog_poll_seconds,
                 "how often to follow the graph directory's catalog (meshes and graphs other "
                 "replicas registered or unloaded), and to apply --disk-limit");
  app.add_option("--build-threads", build_threads, "threads per graph build (0: all cores)");
  std::string build_memory_limit_text = "0";
  app.add_option("--build-memory-limit", build_memory_limit_text,
                 "candidate edges a build keeps in memory, e.g. 2G; beyond it they go to an "
                 "unlinked file in --graph-dir (the system's temporary directory without one) "
                 "(0: no limit)");
  app.add_option("--build-workers", build_workers,
                 "graphs built at once, besides one build estimated to take longer than "
                 "--large-build-seconds, which runs in a lane of its own");
  double large_build_seconds = 60;
  app.add_option("--large-build-seconds", large_build_seconds,
                 "builds estimated to take longer than this (on --build-threads) run one at a "
                 "time in their own lane, so they never hold the workers small graphs need");
  std::string max_graph_bytes_text = "0";
  app.add_option("--max-graph-bytes", max_graph_bytes_text,
                 "RequestGraph refuses graphs whose estimated file passes this, e.g. 4G, with "
                 "RESOURCE_EXHAUSTED naming the estimate (0: no limit; a graph already in "
                 "--graph-dir is always mapped)");
  app.add_flag("--exact-fans", exact_fans,
               "build graphs with fans from exact local distances: 2-3x faster fields, longer "
               "builds (graphs found in --graph-dir are used as they are)");
  app.add_option("--query-threads", query_threads,
                 "admitted queries running at once, the rest waiting their turn in arrival "
                 "order (0: the cores)");
  app.add_option("--max-inflight", limits.max_inflight,
                 "queries admitted, running or waiting; beyond them a query is answered "
                 "RESOURCE_EXHAUSTED \"server overloaded\" at once, with a retry-after-ms hint");
  app.add_option("--max-streams", limits.max_streams,
                 "WatchGraph and UploadMesh streams open at once; beyond them a stream is answered "
                 "RESOURCE_EXHAUSTED at once (health, listing, get and cancel keep their own "
                 "threads)");
  app.add_option("--max-pairs", limits.max_pairs, "pairs per Distance call");
  app.add_option("--max-sources", limits.max_sources, "sources per field");
  app.add_option("--max-upload-bytes", limits.max_upload_bytes, "largest mesh upload");
  app.add_option("--default-epsilon", limits.default_epsilon, "epsilon when a request gives none");
  bool no_build_on_query = false;
  app.add_flag("--no-build-on-query", no_build_on_query,
               "a query on a graph nobody requested fails (FAILED_PRECONDITION) instead of "
               "starting its build and waiting for it: for daemons whose graphs are built ahead");
  app.add_option("--build-wait-seconds", limits.build_wait_seconds,
                 "longest a query waits for its graph to be built or mapped (within its own "
                 "deadline); then UNAVAILABLE with the build's progress, to retry")
      ->check(CLI::Range(0.0, 86400.0));
  app.add_option("--http-listen", http_listen,
                 "serve the HTTP/JSON API and the web viewer on HOST:PORT (same TLS and token; "
                 "port 0: any free port)");
  HttpLimits http_limits;
  double http_header_seconds = std::chrono::duration<double>(http_limits.header_timeout).count();
  double http_body_seconds = std::chrono::duration<double>(http_limits.body_timeout).count();
  double http_idle_seconds = std::chrono::duration<double>(http_limits.idle_timeout).count();
  app.add_option("--http-header-timeout", http_header_seconds,
                 "seconds a client has to send a request's headers (TLS handshake included)")
      ->capture_default_str();
  app.add_option("--http-body-timeout", http_body_seconds,
                 "seconds a client has to send a request's body")
      ->capture_default_str();
  app.add_option("--http-idle-timeout", http_idle_seconds,
                 "seconds a kept-alive HTTP connection may wait for its next request")
      ->capture_default_str();
  app.add_option("--http-max-connections", http_limits.max_connections,
                 "open HTTP connections; more are answered 503 and closed")
      ->capture_default_str();
  app.add_option("--http-max-connections-per-ip", http_limits.max_connections_per_ip,
                 "open HTTP connections per client address")
      ->capture_default_str();
  std::string http_cors_origin;
  app.add_option("--http-cors-origin", http_cors_origin,
                 "a web origin (https://host[:port], or *) whose pages may call the HTTP API "
                 "from a browser (CORS); empty: only pages this gateway serves");
  app.add_option("--http-workers", http_limits.workers,
                 "threads answering HTTP requests (sockets are served apart from them)")
      ->capture_default_str();
  app.add_option("--metrics-listen", metrics_listen,
                 "serve Prometheus metrics on HOST:PORT (port 0: any free port)");
  app.add_option("--log-level", log_level, "debug, info (one line per request), warning or error")
      ->check(CLI::IsMember({"debug", "info", "warning", "error"}));
  app.add_option("--log-format", log_format,
                 "text (timestamped key=value lines) or json (one object per line)")
      ->check(CLI::IsMember({"text", "json"}));
  app.add_option("--sample-mesh", sample, "mesh registered as 'spot' at start (default: bundled)");
  app.add_flag("--no-sample", no_sample, "do not register the bundled sample mesh");
  app.add_option("--drain-seconds", drain_seconds, "grace period for running calls at shutdown");
  SecurityFlags security;
  app.add_option("--tls-cert", security.tls_cert, "PEM certificate chain: serve TLS")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", security.tls_key, "PEM private key of --tls-cert")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-client-ca", security.tls_client_ca,
                 "PEM CA: require client certificates signed by it (mutual TLS)")
      ->check(CLI::ExistingFile);
  app.add_option("--auth-token-file", security.auth_token_file,
                 "file holding a bearer token every geodesic.v1 call must send as "
                 "'authorization: Bearer <token>' (health and reflection stay open)")
      ->check(CLI::ExistingFile);
  CLI11_PARSE(app, argc, argv);
  SetLogLevel(*ParseLogLevel(log_level));
  SetLogFormat(*ParseLogFormat(log_format));
  limits.log_requests = LogEnabled(LogLevel::kInfo);
  limits.build_on_query = !no_build_on_query;
  if (limits.max_inflight < 1 || limits.max_streams < 1 || query_threads < 0) {
    std::fprintf(stderr,
                 "geodesicd serve: --max-inflight and --max-streams must be at least 1, "
                 "--query-threads at least 0\n");
    return 2;
  }
  limits.query_threads = query_threads > 0
                             ? query_threads
                             : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // One malloc arena per running query, not one per gRPC thread: memory a
  // query frees in its arena is reused by the next query there instead of
  // staying with an idle thread's arena, where the limit cannot see it.
  mallopt(M_ARENA_MAX, std::max(2, limits.query_threads));
  auto memory_limit = ParseByteSize(memory_limit_text, "--memory-limit");
  auto disk_limit = ParseByteSize(disk_limit_text, "--disk-limit");
  auto build_memory_limit = ParseByteSize(build_memory_limit_text, "--build-memory-limit");
  auto max_graph_bytes = ParseByteSize(max_graph_bytes_text, "--max-graph-bytes");
  for (const auto* size : {&memory_limit, &disk_limit, &build_memory_limit, &max_graph_bytes}) {
    if (!size->ok()) {
      std::fprintf(stderr, "geodesicd serve: %s\n", std::string(size->status().message()).c_str());
      return 2;
    }
  }
  absl::StatusOr<ServeConfig> config = ServeConfig{};
  if (!config_path.empty()) config = LoadServeConfig(config_path);
  if (!config.ok()) {
    std::fprintf(stderr, "geodesicd serve: %s\n", std::string(config.status().message()).c_str());
    return 2;
  }
  limits.exact_fans = exact_fans;
  if (security.tls_cert.empty() != security.tls_key.empty()) {
    std::fprintf(stderr, "geodesicd serve: --tls-cert and --tls-key go together\n");
    return 2;
  }
  std::shared_ptr<grpc::ServerCredentials> credentials = ServerCredentials(security);
  if (!credentials) return 2;
  std::string token;
  if (!security.auth_token_file.empty()) {
    if (!ReadSecretFile("--auth-token-file", security.auth_token_file, &token)) return 2;
    while (!token.empty() && std::isspace(static_cast<unsigned char>(token.back()))) {
      token.pop_back();
    }
    if (token.empty()) {
      std::fprintf(stderr, "geodesicd serve: --auth-token-file %s holds only whitespace\n",
                   security.auth_token_file.c_str());
      return 2;
    }
  }
  if (mesh_root.empty() && !no_sample) {
    // With no --mesh-root, clients may register the bundled meshes.
    std::string found = FindSampleMesh(argv[0]);
    if (!found.empty()) mesh_root = std::filesystem::path(found).parent_path().string();
  }

  Metrics metrics;
  std::unique_ptr<grpc::Server> server;
  grpc::HealthCheckServiceInterface* health = nullptr;
  std::mutex health_mu;
  std::unique_ptr<DiskBudget> disk;
  std::atomic<uint64_t> disk_removed{0};
  // The sweep --disk-limit's rule makes, down to a number of bytes; set
  // once the catalog, the registry and the cache exist.
  std::function<absl::StatusOr<DiskReport>(uint64_t limit)> sweep;
  if (!graph_dir.empty()) {
    std::error_code ec;
    std::filesystem::create_directories(graph_dir, ec);
    // What writers and builders killed midway left (graphs, snapshots, the
    // catalog, build locks): old enough that no live replica is at work on
    // them.
    for (const std::string& name : RemoveStaleTemporaries(graph_dir, kDiskGrace)) {
      Log(LogLevel::kInfo, "stale_temporary_removed", {{"file", name}});
    }
    for (const std::string& name : GraphCache::RemoveStaleBuildLocks(graph_dir, kDiskGrace)) {
      Log(LogLevel::kInfo, "stale_build_lock_removed", {{"file", name}});
    }
    disk = std::make_unique<DiskBudget>(
        graph_dir, *disk_limit, [&](uint64_t target) -> absl::StatusOr<uint64_t> {
          if (!sweep) return absl::UnavailableError("starting");
          // A limit of 0 is none to the sweep: 1 byte asks for all it may remove.
          ASSIGN_OR_RETURN(DiskReport report, sweep(std::max<uint64_t>(target, 1)));
          disk_removed += report.removed.size();
          for (const std::string& name : report.removed) {
            Log(LogLevel::kInfo, "disk_file_removed", {{"file", name}});
          }
          return report.bytes_after;
        });
    if (absl::Status s = disk->Scan(); !s.ok()) {
      Log(LogLevel::kWarning, "disk_scan_failed", {{"error", s.ToString()}});
    }
  }
  // Built meshes are saved beside the graphs, so a restarted daemon restores
  // them rather than parsing and building them again; with a graph
  // directory a registration returns once its snapshot is on disk, since
  // the catalog then records it for restarts and replicas.
  MeshRegistry meshes(mesh_root, graph_dir, /*durable=*/!graph_dir.empty());
  if (disk && *disk_limit > 0) {
    meshes.SetDiskReservation(
        [&](uint64_t bytes) { return disk->Reserve(bytes); },
        [&](uint64_t reserved, uint64_t written) { disk->Done(reserved, written); });
  }
  GraphCache::Options cache_options;
  cache_options.graph_dir = graph_dir;
  cache_options.memory_limit = *memory_limit;
  cache_options.resident_bytes_outside = [&meshes] { return meshes.resident_bytes(); };
  cache_options.on_file_used = MarkFileUsed;
  cache_options.build_workers = build_workers;
  cache_options.build_threads = build_threads;
  cache_options.build_memory_limit = *build_memory_limit;
  cache_options.large_build_seconds = large_build_seconds;
  cache_options.max_graph_bytes = *max_graph_bytes;
  if (*disk_limit > 0) cache_options.disk = disk.get();
  cache_options.on_readiness = [&](const GraphKey& key, bool ready) {
    std::lock_guard<std::mutex> lock(health_mu);
    if (health) health->SetServingStatus(ServiceName(key), ready);
  };
  GraphCache graphs(cache_options);
  std::unique_ptr<Catalog> catalog;
  std::unique_ptr<CatalogSync> sync;
  if (!graph_dir.empty()) {
    catalog = std::make_unique<Catalog>(graph_dir);
    if (absl::Status s = catalog->EnsureReserve(); !s.ok()) {
      Log(LogLevel::kWarning, "catalog_reserve_missing", {{"error", s.ToString()}});
    }
    sync = std::make_unique<CatalogSync>(
        catalog.get(), CatalogSync::Hooks{
                           .restore_mesh =
                               [&](const CatalogMesh& m) {
                                 return meshes
                                     .RegisterRecorded(m.name, m.source, m.format, m.source_hash,
                                                       m.fingerprint, m.repair_non_manifold)
                                     .status();
                               },
                           .drop_mesh =
                               [&](const std::string& name) {
                                 meshes.Remove(name).IgnoreError();
                                 graphs.DropMesh(name);
                               },
                           .request_graph =
                               [&](const std::string& mesh, const DggParams& params) {
                                 if (auto m = meshes.Get(mesh); m.ok()) graphs.Request(*m, params);
                               },
                           .cancel_graph =
                               [&](const std::string& mesh, const DggParams& params) {
                                 graphs.Cancel({mesh, params}).IgnoreError();
                               },
                       });
  }
  if (catalog) {
    sweep = [&](uint64_t limit) -> absl::StatusOr<DiskReport> {
      // A build persisting at shutdown must not reach the catalog and the
      // registry as they are destroyed.
      if (g_stop) return absl::UnavailableError("shutting down");
      ASSIGN_OR_RETURN(const CatalogState state, catalog->Read());
      const CatalogFiles files = FilesOf(state);
      return EnforceDiskLimit(graph_dir, limit, [&](const std::string& name) {
        // Asked afresh each time, as EnforceDiskLimit asks again just before
        // removing: a mesh registered since the listing has its snapshot.
        bool in_use = graphs.FileInUse(name);
        for (const auto& m : meshes.List()) in_use |= MeshRegistry::SnapshotName(*m) == name;
        return GraphDirFileRole(graph_dir, name, files, in_use, kDiskGrace);
      });
    };
  }
  std::atomic<bool> ready{false};
  std::atomic<uint64_t> disk_bytes{0};
  metrics.AddInfo("geodesicd_build_info", "The daemon's version and build type.",
                  {{"version", kVersion}, {"build_type", kBuildType}});
  metrics.AddGauge("geodesicd_ready", "1 once start-up restored what the catalog holds.",
                   [&] { return ready ? 1.0 : 0.0; });
  metrics.AddGauge("geodesicd_graph_dir_bytes", "Bytes of the files in --graph-dir.",
                   [&] { return double(disk_bytes.load()); });
  metrics.AddCounter("geodesicd_disk_files_removed_total",
                     "Graph files and mesh snapshots removed to stay within --disk-limit.",
                     [&] { return double(disk_removed.load()); });
  if (sync) {
    metrics.AddGauge("geodesicd_catalog_generation", "Generation of the catalog last followed.",
                     [&] { return double(sync->generation()); });
  }
  metrics.AddGauge("geodesicd_graph_resident_bytes",
                   "Resident bytes: graphs built in memory and landmark tables.",
                   [&] { return double(graphs.resident_bytes()); });
  metrics.AddGauge("geodesicd_mesh_resident_bytes",
                   "Bytes of registered meshes (counted in --memory-limit, never evicted).",
                   [&] { return double(meshes.resident_bytes()); });
  metrics.AddGauge("geodesicd_graph_mapped_bytes", "Bytes of memory-mapped graphs.",
                   [&] { return double(graphs.mapped_bytes()); });
  metrics.AddGauge("geodesicd_builds_running", "Graph builds running.",
                   [&] { return double(graphs.builds_running()); });
  metrics.AddCounter("geodesicd_graph_builds_total",
                     "Graph builds started here (not graphs mapped from --graph-dir).",
                     [&] { return double(graphs.builds_started()); });
  metrics.AddGauge(
      "geodesicd_query_scratch_bytes",
      "Query scratch held by the engines of ready graphs (pooled per query in flight).",
      [&] { return double(graphs.scratch_bytes()); });
  metrics.AddCounter("geodesicd_cache_hits_total", "Queries that found their graph ready.",
                     [&] { return double(graphs.hits()); });
  metrics.AddCounter("geodesicd_cache_misses_total", "Queries whose graph was not ready.",
                     [&] { return double(graphs.misses()); });
  metrics.AddCounter("geodesicd_graph_evictions_total",
                     "Ready graphs evicted to stay within --memory-limit.",
                     [&] { return double(graphs.evictions()); });

  // Registered before the port opens, so that the first answer already lists
  // it; its graph is requested once health reporting is up.
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> sample_mesh =
      absl::NotFoundError("no sample mesh");
  if (!no_sample) {
    std::string path = sample.empty() ? FindSampleMesh(argv[0]) : sample;
    if (path.empty()) {
      std::fprintf(stderr, "geodesicd: bundled sample mesh not found (set GEODESIC_DATA_DIR)\n");
    } else {
      sample_mesh = meshes.RegisterTrustedPath("spot", path);
      if (sample_mesh.ok()) {
        std::fprintf(stderr, "geodesicd: registered sample mesh 'spot' from %s\n", path.c_str());
      } else {
        std::fprintf(stderr, "geodesicd: sample mesh: %s\n",
                     std::string(sample_mesh.status().message()).c_str());
      }
    }
  }
  GeodesicService service(&meshes, &graphs, &metrics, limits);
  if (!token.empty()) service.RequireBearerToken(token);
  const Admission& admission = service.admission();
  metrics.AddGauge("geodesicd_queue_depth", "Queries admitted: running or waiting their turn.",
                   [&] { return double(admission.admitted()); });
  metrics.AddGauge("geodesicd_queries_running", "Admitted queries running (--query-threads).",
                   [&] { return double(admission.running()); });
  metrics.AddGauge("geodesicd_queries_waiting", "Admitted queries waiting for a running slot.",
                   [&] { return double(admission.waiting()); });
  metrics.AddGauge("geodesicd_streams_open", "WatchGraph and UploadMesh streams (--max-streams).",
                   [&] { return double(admission.streams()); });
  metrics.AddGauge("geodesicd_reserved_bytes",
                   "Answer and scratch bytes running queries reserved against --memory-limit.",
                   [&] { return double(admission.reserved_bytes()); });
  metrics.AddGauge("geodesicd_overloaded",
                   "1 while admission is full or refused a call in the last second.",
                   [&] { return admission.overloaded() ? 1.0 : 0.0; });
  metrics.AddCounter("geodesicd_overload_refusals_total",
                     "Calls answered RESOURCE_EXHAUSTED \"server overloaded\".",
                     [&] { return double(admission.refusals()); });
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int bound_port = 0;
  builder.AddListeningPort(listen, credentials, &bound_port);
  // A port taken by another daemon is refused (see listen_socket.h).
  builder.AddChannelArgument(GRPC_ARG_ALLOW_REUSEPORT, 0);
  builder.RegisterService(&service);
  builder.SetMaxReceiveMessageSize(static_cast<int>(limits.max_message_bytes));
  builder.SetMaxSendMessageSize(static_cast<int>(limits.max_message_bytes));
  // The synchronous server holds a thread per call in progress, and answers
  // "Server Threadpool Exhausted" when the quota has none left: the quota
  // covers every admitted query (running or waiting), every stream, the
  // control calls and gRPC's own pollers, so that the answer past a limit is
  // ours (RESOURCE_EXHAUSTED "server overloaded", with a retry hint).
  constexpr int kControlThreads = 16;
  constexpr int kPollerThreads = 8;
  grpc::ResourceQuota quota("geodesicd");
  quota.SetMaxThreads(limits.max_inflight + limits.max_streams + kControlThreads + kPollerThreads);
  builder.SetResourceQuota(quota);
  server = builder.BuildAndStart();
  if (!server || bound_port == 0) {
    std::fprintf(stderr, "geodesicd serve: cannot listen on %s: address in use or unavailable\n",
                 listen.c_str());
    return 1;
  }
  {
    std::lock_guard<std::mutex> lock(health_mu);
    health = server->GetHealthCheckService();
    // Serving once start-up has restored what the catalog holds.
    health->SetServingStatus("", false);
    health->SetServingStatus("geodesic.v1.Geodesic", false);
    health->SetServingStatus(kCapacity, true);
  }
  std::unique_ptr<MetricsHttpServer> metrics_http;
  int metrics_port = 0;
  if (!metrics_listen.empty()) {
    std::string error;
    metrics_http = MetricsHttpServer::Start(
        metrics_listen, &metrics, [&] { return ready.load(); }, &error);
    if (!metrics_http) {
      std::fprintf(stderr, "geodesicd serve: %s\n", error.c_str());
      return 1;
    }
    metrics_port = metrics_http->port();
  }
  std::unique_ptr<HttpGateway> http;
  if (!http_listen.empty()) {
    HttpGatewayOptions options;
    options.listen = http_listen;
    options.tls_cert = security.tls_cert;
    options.tls_key = security.tls_key;
    options.tls_client_ca = security.tls_client_ca;
    options.bearer_token = token;
    options.cors_origin = http_cors_origin;
    options.limits = http_limits;
    const auto ms = [](double seconds) {
      return std::chrono::milliseconds(static_cast<int64_t>(std::max(0.001, seconds) * 1000));
    };
    options.limits.header_timeout = ms(http_header_seconds);
    options.limits.body_timeout = ms(http_body_seconds);
    options.limits.idle_timeout = ms(http_idle_seconds);
    auto started = HttpGateway::Start(options, server.get(), &meshes);
    if (!started.ok()) {
      std::fprintf(stderr, "geodesicd serve: %s\n",
                   std::string(started.status().message()).c_str());
      return 1;
    }
    http = std::move(*started);
    std::fprintf(stderr, "geodesicd: HTTP on %s (http port %d, %s)\n", http_listen.c_str(),
                 http->port(), http->tls() ? "TLS" : "plaintext");
  }
  if (!port_file.empty() &&
      !WritePortFile(port_file, bound_port, metrics_port, http ? http->port() : 0)) {
    return 1;
  }
  std::fprintf(stderr, "geodesicd: serving on %s (port %d, %s%s), graphs in %s, mesh root %s\n",
               listen.c_str(), bound_port,
               security.tls_cert.empty()        ? "plaintext"
               : security.tls_client_ca.empty() ? "TLS"
                                                : "mutual TLS",
               token.empty() ? "" : ", bearer token required", graph_dir.c_str(),
               mesh_root.empty() ? "(none)" : mesh_root.c_str());
  auto daemon_params = [&](double epsilon, bool pseudo) {
    DggParams params;
    params.epsilon = epsilon;
    params.pseudo_vertices = pseudo;
    params.exact_fans = exact_fans;
    return params;
  };
  signal(SIGTERM, OnSignal);
  signal(SIGINT, OnSignal);
  // Start-up: what the catalog recorded (clients' meshes and graphs), what
  // the config declares, and the sample's graph. Queries that arrive
  // meanwhile restore what they name on demand (GeodesicService::FindMesh).
  std::vector<GraphKey> restoring;
  // --config's meshes, before the catalog is applied: the catalog records
  // their graphs (and the sample's), which it then requests again.
  for (const DeclaredMesh& m : config->meshes) {
    auto registered = std::filesystem::path(m.path).is_absolute()
                          ? meshes.RegisterTrustedPath(m.name, m.path, m.repair_non_manifold)
                          : meshes.RegisterPath(m.name, m.path, m.repair_non_manifold);
    if (!registered.ok()) {
      Log(LogLevel::kError, "config_mesh_failed",
          {{"mesh", m.name}, {"path", m.path}, {"error", registered.status().ToString()}});
    } else if (sync) {
      sync->AddStartupMesh(m.name);
    }
  }
  if (sync && sample_mesh.ok()) sync->AddStartupMesh("spot");
  if (sync) {
    if (absl::Status s = sync->Reconcile(); !s.ok()) {
      Log(LogLevel::kError, "catalog_unreadable", {{"error", s.ToString()}});
      std::fprintf(stderr, "geodesicd serve: %s (fix or move the file; it is left as it is)\n",
                   std::string(s.message()).c_str());
      return 1;
    }
    if (auto state = catalog->Read(); state.ok()) {
      for (const CatalogGraph& g : state->graphs) restoring.push_back({g.mesh, g.params});
    }
    service.UseCatalog(sync.get());
  }
  for (const DeclaredGraph& g : config->graphs) {
    if (auto m = meshes.Get(g.mesh); m.ok()) {
      const DggParams params = daemon_params(g.epsilon, g.pseudo_vertices);
      graphs.Request(*m, params);
      restoring.push_back({g.mesh, params});
    }
  }
  if (sample_mesh.ok()) graphs.Request(*sample_mesh, daemon_params(limits.default_epsilon, false));
  // Ready once every restored graph whose file was there is mapped (a
  // missing or invalid one rebuilds in the background, and one another
  // replica is building is mapped once it is done: neither is waited for),
  // or after a minute at most.
  const absl::Time restore_deadline = absl::Now() + absl::Seconds(60);
  size_t restored_graphs = 0;
  for (const GraphKey& key : restoring) {
    auto status = graphs.Get(key);
    while (status.ok() && !g_stop &&
           (status->state == GraphState::kQueued || status->state == GraphState::kLoading) &&
           // Another replica's build may take long: serve meanwhile.
           status->phase != kWaitingForReplicaPhase && absl::Now() < restore_deadline) {
      status = graphs.WaitForChange(key, status->version, absl::Now() + absl::Milliseconds(200));
    }
    restored_graphs += status.ok() && status->state == GraphState::kReady;
  }
  ready = true;
  {
    std::lock_guard<std::mutex> lock(health_mu);
    health->SetServingStatus("", true);
    health->SetServingStatus("geodesic.v1.Geodesic", true);
  }
  Log(LogLevel::kInfo, "ready",
      {{"meshes", meshes.List().size()},
       {"graphs_ready", restored_graphs},
       {"graphs_restoring", restoring.size()}});
  // Follows the catalog (replicas' changes) and keeps --graph-dir in budget.
  std::thread follower([&] {
    while (!g_stop) {
      for (int i = 0; i < catalog_poll_seconds * 10 && !g_stop; ++i) {
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      }
      if (g_stop || graph_dir.empty()) continue;
      if (absl::Status s = sync->Reconcile(); !s.ok()) {
        Log(LogLevel::kError, "catalog_unreadable", {{"error", s.ToString()}});
      }
      // A reserve the catalog used on a full disk comes back once there is
      // room.
      catalog->EnsureReserve().IgnoreError();
      auto report = sweep(*disk_limit);
      if (!report.ok()) {
        Log(LogLevel::kError, "disk_limit_failed", {{"error", report.status().ToString()}});
        continue;
      }
      disk_bytes = report->bytes_after;
      disk->Set(report->bytes_after);
      disk_removed += report->removed.size();
      for (const std::string& name : report->removed) {
        Log(LogLevel::kInfo, "disk_file_removed", {{"file", name}});
      }
      if (report->over_limit) {
        Log(LogLevel::kWarning, "disk_over_limit",
            {{"bytes", report->bytes_after}, {"limit", *disk_limit}});
      }
    }
  });
  // Probes of "" and "geodesic.v1.Geodesic" keep SERVING under load (a
  // restart would only lose the resident graphs); kCapacity tells balancers
  // that this replica is refusing queries now.
  bool overloaded = false;
  for (int tick = 0; !g_stop; ++tick) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (admission.overloaded() != overloaded) {
      overloaded = !overloaded;
      std::lock_guard<std::mutex> lock(health_mu);
      health->SetServingStatus(kCapacity, !overloaded);
    }
    // Memory that queries and their answers freed goes back to the system,
    // not only to malloc's free lists, so resident memory follows what the
    // limit counts.
    if (tick % 10 == 0) malloc_trim(0);
  }
  follower.join();
  std::fprintf(stderr, "geodesicd: shutting down (draining up to %.0f s)\n", drain_seconds);
  {
    std::lock_guard<std::mutex> lock(health_mu);
    health->SetServingStatus("", false);
  }
  http.reset();  // its calls go through `server`
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(drain_seconds * 1000)));
  // Graph writes are atomic (temp + rename): an interrupted build leaves no
  // file a restart would trust. The cache's destructor cancels and joins.
  return 0;
}

}  // namespace geodesic::server
