// The daemon `geodesicd serve` runs, in the order of its life: Start (the
// graph directory, registry, cache and catalog, then the gRPC, metrics and
// HTTP listeners), Restore (what --config declares and the catalog
// records; then ready), Serve (follow the catalog and keep --graph-dir in
// budget until SIGTERM or SIGINT), Drain (let running calls finish).
#ifndef GEODESIC_SERVER_DAEMON_H_
#define GEODESIC_SERVER_DAEMON_H_

#include <atomic>
#include <cstdint>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "absl/status/statusor.h"
#include "grpcpp/grpcpp.h"
#include "grpcpp/health_check_service_interface.h"
#include "server/app/serve_options.h"
#include "server/base/metrics.h"
#include "server/gateway/http_gateway.h"
#include "server/graphs/graph_cache.h"
#include "server/grpc/geodesic_service.h"
#include "server/http/metrics_listener.h"
#include "server/limits/memory_ledger.h"
#include "server/meshes/mesh_registry.h"
#include "server/store/catalog.h"
#include "server/store/catalog_sync.h"
#include "server/store/disk_budget.h"

namespace geodesic::server {

class Daemon {
 public:
  explicit Daemon(ServeOptions options);
  // Members go in the reverse of their declaration: the listeners before
  // the service, the cache (which cancels and joins its builds) before the
  // registry, the gRPC server (whose health service the cache reports to)
  // last but the metrics.
  ~Daemon();

  // Each returns the exit code to end with, 0 to go on. Start and Restore
  // print why they fail.
  int Start();
  int Restore();
  // Until SIGTERM or SIGINT.
  void Serve();
  void Drain();

 private:
  // Start's steps.
  void OpenGraphDir();
  void OpenCatalog();
  void AddMetrics();
  void AddQueryMetrics();
  void RegisterSample();
  int ListenGrpc();
  // gRPC's receive buffers under --memory-limit, bounded by its resource
  // quota (0 without a limit): room for one largest request beside the
  // other calls' messages. Like gRPC's threads, a fixed overhead beside
  // what the limit counts, whatever clients send.
  uint64_t TransportBufferBytes() const;
  // gRPC's thread quota (--max-inflight, --max-streams and the rest).
  int ThreadQuota() const;
  // --idle-seconds for gRPC's connections.
  void AddIdleArguments(grpc::ServerBuilder& builder) const;
  int ListenMetrics(int* port);
  int ListenHttp();
  // Restore's steps.
  void RegisterConfigMeshes();
  int RestoreCatalog();
  void RequestConfigGraphs();
  size_t WaitForRestored();
  DggParams Params(double epsilon, bool pseudo_vertices) const;
  // Serve's: one pass of following the catalog and applying --disk-limit.
  void FollowCatalog();
  // Removes files from --graph-dir down to `limit` bytes (see
  // EnforceDiskLimit), logging each.
  absl::StatusOr<DiskReport> Sweep(uint64_t limit);
  void SetHealth(const std::string& service, bool serving);
  // What the capacity health status reports: calls refused, or about to be.
  bool Overloaded() const;

  const ServeOptions options_;
  Metrics metrics_;
  std::unique_ptr<grpc::Server> server_;
  grpc::HealthCheckServiceInterface* health_ = nullptr;
  std::mutex health_mu_;
  std::unique_ptr<DiskBudget> disk_;
  std::atomic<uint64_t> disk_removed_{0};
  std::unique_ptr<MeshRegistry> meshes_;
  // The HTTP gateway's bodies and answers within --memory-limit (made once
  // the service is); outlives the cache and the gateway, which count it.
  std::unique_ptr<MemoryLedger> memory_;
  std::unique_ptr<GraphCache> graphs_;
  std::unique_ptr<Catalog> catalog_;
  std::unique_ptr<CatalogSync> sync_;
  // Set once the catalog, the registry and the cache exist: the disk budget
  // asks for sweeps only then.
  std::atomic<bool> can_sweep_{false};
  std::atomic<bool> ready_{false};
  std::atomic<uint64_t> disk_bytes_{0};
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> sample_mesh_;
  std::unique_ptr<GeodesicService> service_;
  std::unique_ptr<MetricsHttpServer> metrics_http_;
  std::unique_ptr<HttpGateway> http_;
  int grpc_port_ = 0;
  // The graphs start-up waits for before it reports ready.
  std::vector<GraphKey> restoring_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_DAEMON_H_
