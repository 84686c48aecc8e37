// One operation, from queued to ready, failed or cancelled: the order of
// its steps (map the file, or take the replica lock, build and persist) and
// the transitions between them. Every move of a running entry is here
// (SetPhase, Publish, Abandon); the steps themselves, outside the lock, are
// in load_build_persist.cc.
#include <chrono>
#include <filesystem>
#include <optional>
#include <string>
#include <system_error>
#include <utility>

#include "absl/status/status.h"
#include "server/base/log.h"
#include "server/graphs/graph_cache.h"
#include "server/graphs/replica_lock.h"

namespace geodesic::server {

bool GraphCache::SetPhase(const GraphKey& key, const std::shared_ptr<Entry>& e, GraphState state,
                          std::string phase, double progress) {
  absl::MutexLock lock(&mu_);
  if (!Current(key, *e)) return false;
  if (e->cancel) {
    Transition(*e, GraphState::kCancelled);
    Log(LogLevel::kInfo, "graph_cancelled", {{"mesh", key.mesh}, {"eps", key.params.epsilon}});
    return false;
  }
  if (e->status.state != state && !Transition(*e, state)) return false;
  e->status.phase = std::move(phase);
  e->status.progress = progress;
  ++e->status.version;
  return true;
}

void GraphCache::Run(const GraphKey& key) {
  std::shared_ptr<Entry> e;
  {
    absl::MutexLock lock(&mu_);
    auto it = entries_.find(key);
    if (it == entries_.end() || it->second->status.state != GraphState::kQueued) return;
    e = it->second;
  }
  const auto start = std::chrono::steady_clock::now();
  std::string note;
  std::shared_ptr<const DggGraph> graph;
  std::optional<GraphCertificate> certificate;
  ReplicaLock building;
  if (!e->path.empty()) {
    std::error_code ec;
    if (!std::filesystem::exists(e->path, ec)) {
      // No file: this replica builds it, unless another is building it.
      auto lock = ReplicaLock::TryAcquire(BuildLockPath(e->path));
      if (lock.ok() && !lock->held()) return WaitForReplica(key, e);
      if (lock.ok()) {
        building = *std::move(lock);
      } else {
        Log(LogLevel::kWarning, "graph_lock_failed", {{"error", lock.status().ToString()}});
      }
    }
    if (!SetPhase(key, e, GraphState::kLoading, "mapping", 0)) return;
    // Also when the lock was just taken: the holder before may have
    // written the file between the look and the lock.
    graph = Load(key, *e, &note, &certificate);
  }
  const bool from_file = graph != nullptr;
  if (!graph) {
    if (!SetPhase(key, e, GraphState::kBuilding, "candidates", 0)) return;
    // Every return before Persist drops the draft, and its temporary file.
    std::optional<GraphFileDraft> draft;
    auto built = Build(key, *e, &draft, &certificate);
    if (!built.ok()) {
      // Nothing of the build is left once it is seen failed or cancelled.
      draft.reset();
      building.Release();
      Abandon(key, e, built.status());
      return;
    }
    graph = *std::move(built);
    if (!e->path.empty()) {
      if (!SetPhase(key, e, GraphState::kPersisting, "writing", 1)) return;
      auto persisted = Persist(key, *e, std::move(graph), std::move(draft), certificate, &note);
      if (!persisted.ok()) {
        building.Release();
        Abandon(key, e, persisted.status());
        return;
      }
      graph = *std::move(persisted);
    }
  }
  building.Release();
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::shared_ptr<const GeodesicEngine> engine = Publish(
      key, e, std::move(graph), std::move(certificate), from_file, std::move(note), seconds);
  if (engine) AddLandmarks(key, e, engine);
}

std::shared_ptr<const GeodesicEngine> GraphCache::Publish(
    const GraphKey& key, const std::shared_ptr<Entry>& e, std::shared_ptr<const DggGraph> graph,
    std::optional<GraphCertificate> certificate, bool from_file, std::string note, double seconds) {
  // The engine is made outside the lock: it reads every node's position.
  auto engine = std::make_shared<const GeodesicEngine>(e->mesh->mesh, graph);
  Notices notices;
  {
    absl::MutexLock lock(&mu_);
    if (!Current(key, *e)) return nullptr;
    if (e->cancel) {
      Transition(*e, GraphState::kCancelled);
      return nullptr;
    }
    if (!Transition(*e, GraphState::kReady)) return nullptr;
    e->engine = engine;
    e->status.phase = "ready";
    e->status.progress = 1;
    e->status.error = std::move(note);
    e->status.bytes = graph->byte_size();
    e->status.landmark_bytes = 0;
    e->counted_exact = nullptr;
    e->status.mapped = graph->is_mapped();
    e->status.from_file = from_file;
    e->status.nodes = graph->num_nodes();
    e->status.edges = graph->num_directed_edges() / 2;
    e->status.build_seconds = seconds;
    // A certified graph's build record is its build's, epsilon included.
    if (key.max_error > 0) {
      e->status.params = graph->params();
      e->status.epsilon = graph->params().epsilon;
    }
    e->status.certificate = std::move(certificate);
    Touch(*e);
    notices.push_back({key, true});
    EvictOverBudget(key, notices);
  }
  Log(LogLevel::kInfo, "graph_ready",
      {{"mesh", key.mesh},
       {"eps", key.params.epsilon},
       {"from_file", from_file ? "true" : "false"},
       {"seconds", seconds}});
  Announce(notices);
  return engine;
}

void GraphCache::Abandon(const GraphKey& key, const std::shared_ptr<Entry>& e,
                         const absl::Status& why) {
  const bool cancelled = absl::IsCancelled(why);
  {
    absl::MutexLock lock(&mu_);
    if (!Current(key, *e)) return;
    if (!Transition(*e, cancelled ? GraphState::kCancelled : GraphState::kFailed)) return;
    e->status.error = std::string(why.message());
  }
  Log(cancelled ? LogLevel::kInfo : LogLevel::kError,
      cancelled ? "graph_cancelled" : "graph_build_failed",
      {{"mesh", key.mesh}, {"eps", key.params.epsilon}, {"error", why.ToString()}});
}

}  // namespace geodesic::server
