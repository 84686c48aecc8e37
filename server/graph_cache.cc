#include "server/graph_cache.h"

#include <chrono>
#include <cstdio>
#include <filesystem>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/dgg_build.h"
#include "core/graph_file.h"

namespace geodesic::server {

const char* GraphStateName(GraphState s) {
  switch (s) {
    case GraphState::kQueued:
      return "queued";
    case GraphState::kBuilding:
      return "building";
    case GraphState::kLoading:
      return "loading";
    case GraphState::kReady:
      return "ready";
    case GraphState::kFailed:
      return "failed";
    case GraphState::kCancelled:
      return "cancelled";
    case GraphState::kEvicted:
      return "evicted";
  }
  return "?";
}

namespace {

// A temporary file is what a writer killed mid-write leaves behind. Replicas
// may share the directory and be writing right now, so only files too old to
// belong to a live write are removed.
constexpr auto kStaleTemporaryAge = std::chrono::hours(1);

void RemoveStaleTemporaries(const std::string& dir) {
  std::error_code ec;
  const auto now = std::filesystem::file_time_type::clock::now();
  for (const auto& entry : std::filesystem::directory_iterator(dir, ec)) {
    const std::string name = entry.path().filename().string();
    // Graph files and the mesh snapshots the registry keeps beside them.
    if (name.find(".dgg.tmp.") == std::string::npos &&
        name.find(".mesh.tmp.") == std::string::npos) {
      continue;
    }
    auto written = entry.last_write_time(ec);
    if (ec || now - written < kStaleTemporaryAge) continue;
    if (std::filesystem::remove(entry.path(), ec)) {
      std::fprintf(stderr, "geodesicd: removed stale temporary file %s\n", entry.path().c_str());
    }
  }
}

}  // namespace

GraphCache::GraphCache(Options options) : options_(std::move(options)) {
  if (!options_.graph_dir.empty()) {
    std::filesystem::create_directories(options_.graph_dir);
    RemoveStaleTemporaries(options_.graph_dir);
  }
  for (int i = 0; i < std::max(1, options_.build_workers); ++i) {
    workers_.emplace_back([this] { Worker(); });
  }
}

GraphCache::~GraphCache() {
  {
    absl::MutexLock lock(&mu_);
    stopping_ = true;
    for (auto& [key, e] : entries_) e->cancel = true;
  }
  for (auto& t : workers_) t.join();
}

std::string GraphCache::GraphPath(const RegisteredMesh& mesh, double epsilon, bool pseudo) const {
  if (options_.graph_dir.empty()) return "";
  DggParams params;
  params.epsilon = epsilon;
  params.pseudo_vertices = pseudo;
  params.exact_fans = options_.exact_fans;
  return options_.graph_dir + "/" + GraphFileName(mesh.fingerprint, params);
}

void GraphCache::Bump(Entry& e) { ++e.status.version; }

void GraphCache::Touch(Entry& e) {
  e.last_used = absl::Now();
  e.status.last_used_unix_ms = absl::ToUnixMillis(e.last_used);
}

GraphStatus GraphCache::Request(std::shared_ptr<const RegisteredMesh> mesh, double epsilon,
                                bool pseudo_vertices) {
  absl::MutexLock lock(&mu_);
  Key key{mesh->name, epsilon};
  auto& slot = entries_[key];
  if (slot && slot->mesh->fingerprint == mesh->fingerprint &&
      slot->status.state != GraphState::kFailed && slot->status.state != GraphState::kCancelled &&
      slot->status.state != GraphState::kEvicted) {
    Touch(*slot);
    return slot->status;  // single flight: join the running or finished operation
  }
  auto e = std::make_shared<Entry>();
  e->mesh = std::move(mesh);
  e->pseudo_vertices = pseudo_vertices;
  e->status.mesh = key.first;
  e->status.epsilon = epsilon;
  e->status.state = GraphState::kQueued;
  e->status.version = slot ? slot->status.version + 1 : 1;
  Touch(*e);
  slot = e;
  Schedule(key);
  return e->status;
}

void GraphCache::Schedule(const Key& key) { queue_.push_back(key); }

void GraphCache::Worker() {
  while (true) {
    Key key;
    {
      absl::MutexLock lock(&mu_);
      mu_.Await(absl::Condition(
          +[](GraphCache* c)
               ABSL_EXCLUSIVE_LOCKS_REQUIRED(c->mu_) { return c->stopping_ || !c->queue_.empty(); },
          this));
      if (stopping_) return;
      key = queue_.front();
      queue_.pop_front();
    }
    Run(key);
  }
}

void GraphCache::Run(const Key& key) {
  std::shared_ptr<Entry> e;
  {
    absl::MutexLock lock(&mu_);
    auto it = entries_.find(key);
    if (it == entries_.end() || it->second->status.state != GraphState::kQueued) return;
    e = it->second;
    if (e->cancel) {
      e->status.state = GraphState::kCancelled;
      Bump(*e);
      return;
    }
  }
  const auto start = std::chrono::steady_clock::now();
  auto set = [&](GraphState state, std::string phase, double progress) {
    absl::MutexLock lock(&mu_);
    e->status.state = state;
    e->status.phase = std::move(phase);
    e->status.progress = progress;
    Bump(*e);
  };
  const std::string path = GraphPath(*e->mesh, key.second, e->pseudo_vertices);
  std::shared_ptr<const DggGraph> graph;
  std::string note;
  if (!path.empty() && std::filesystem::exists(path)) {
    set(GraphState::kLoading, "mapping", 0);
    auto opened = GraphFile::Open(path, *e->mesh->mesh, GraphFile::Check::kFull);
    if (opened.ok()) {
      graph = *opened;
    } else {
      // Never serve a file that fails validation: move it aside, rebuild.
      const std::string aside =
          absl::StrFormat("%s.rejected-%d", path, absl::ToUnixSeconds(absl::Now()));
      std::error_code ec;
      std::filesystem::rename(path, aside, ec);
      note = absl::StrFormat("rejected %s (%s), rebuilding", path, opened.status().message());
      std::fprintf(stderr, "geodesicd: %s\n", note.c_str());
    }
  }
  const bool from_file = graph != nullptr;
  if (!graph) {
    set(GraphState::kBuilding, "candidates", 0);
    ++builds_running_;
    DggBuildOptions options;
    options.params.epsilon = key.second;
    options.params.pseudo_vertices = e->pseudo_vertices;
    options.threads = options_.build_threads;
    options.params.exact_fans = options_.exact_fans;
    options.progress = [&](std::string_view phase, double fraction) {
      absl::MutexLock lock(&mu_);
      if (e->status.phase != phase || fraction - e->status.progress >= 0.01 || fraction >= 1) {
        e->status.phase = std::string(phase);
        e->status.progress = fraction;
        Bump(*e);
      }
      return !e->cancel.load();
    };
    auto built = BuildDgg(*e->mesh->mesh, options);
    --builds_running_;
    if (!built.ok()) {
      absl::MutexLock lock(&mu_);
      e->status.state = built.status().code() == absl::StatusCode::kCancelled
                            ? GraphState::kCancelled
                            : GraphState::kFailed;
      e->status.error = std::string(built.status().message());
      Bump(*e);
      if (options_.on_readiness) options_.on_readiness(key.first, key.second, false);
      return;
    }
    graph = *built;
    if (!path.empty()) {
      set(GraphState::kBuilding, "writing", 1);
      absl::Status written = GraphFile::Write(*graph, path);
      if (written.ok()) {
        // Serve the mapped copy: resident memory stays with the page cache.
        auto mapped = GraphFile::Open(path, *e->mesh->mesh, GraphFile::Check::kHeader);
        if (mapped.ok()) graph = *mapped;
      } else {
        note = absl::StrFormat("graph kept in memory only: %s", written.message());
        std::fprintf(stderr, "geodesicd: %s\n", note.c_str());
      }
    }
  }
  auto engine = std::make_shared<const GeodesicEngine>(e->mesh->mesh, graph);
  {
    absl::MutexLock lock(&mu_);
    e->engine = engine;
    e->status.state = GraphState::kReady;
    e->status.phase = "ready";
    e->status.progress = 1;
    e->status.error = note;
    e->status.bytes = graph->byte_size();
    e->status.landmark_bytes = 0;
    e->status.mapped = graph->is_mapped();
    e->status.from_file = from_file;
    e->status.nodes = graph->num_nodes();
    e->status.edges = graph->num_directed_edges() / 2;
    e->status.build_seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
    Touch(*e);
    Bump(*e);
    EvictOverBudget(key);
  }
  if (options_.on_readiness) options_.on_readiness(key.first, key.second, true);
  // Landmarks cut the nodes a point-to-point query settles several times;
  // queries that arrive before they are ready use straight-line bounds.
  absl::Status landmarks =
      engine->PrepareLandmarks(engine->DefaultLandmarkCount(), [e] { return e->cancel.load(); });
  absl::MutexLock lock(&mu_);
  if (!landmarks.ok() || e->engine != engine) return;
  e->status.landmark_bytes = engine->landmark_bytes();
  Bump(*e);
  EvictOverBudget(key);
}

void GraphCache::EvictOverBudget(const Key& keep) {
  if (options_.memory_limit == 0) return;
  while (true) {
    uint64_t total = 0;
    std::shared_ptr<Entry> victim;
    Key victim_key;
    for (auto& [key, e] : entries_) {
      if (e->status.state != GraphState::kReady) continue;
      total += e->status.bytes + e->status.landmark_bytes;
      // Only graphs no query holds; never the one just made ready.
      if (key == keep || e->engine.use_count() > 1) continue;
      if (!victim || e->last_used < victim->last_used) {
        victim = e;
        victim_key = key;
      }
    }
    if (total <= options_.memory_limit || !victim) return;
    victim->engine.reset();
    ++evictions_;
    victim->status.landmark_bytes = 0;
    victim->status.state = GraphState::kEvicted;
    victim->status.phase = "evicted";
    Bump(*victim);
    if (options_.on_readiness) options_.on_readiness(victim_key.first, victim_key.second, false);
  }
}

absl::StatusOr<GraphStatus> GraphCache::Get(const std::string& mesh, double epsilon) const {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find({mesh, epsilon});
  if (it == entries_.end()) {
    return absl::NotFoundError(
        absl::StrFormat("no graph was requested for mesh '%s' at epsilon %g", mesh, epsilon));
  }
  return it->second->status;
}

absl::StatusOr<GraphStatus> GraphCache::WaitForChange(const std::string& mesh, double epsilon,
                                                      uint64_t version, absl::Time deadline) const {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find({mesh, epsilon});
  if (it == entries_.end()) {
    return absl::NotFoundError(
        absl::StrFormat("no graph was requested for mesh '%s' at epsilon %g", mesh, epsilon));
  }
  std::shared_ptr<Entry> e = it->second;
  auto changed = [&]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return e->status.version != version; };
  mu_.AwaitWithDeadline(absl::Condition(&changed), deadline);
  return e->status;
}

absl::StatusOr<GraphStatus> GraphCache::Cancel(const std::string& mesh, double epsilon) {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find({mesh, epsilon});
  if (it == entries_.end()) {
    return absl::NotFoundError(
        absl::StrFormat("no graph was requested for mesh '%s' at epsilon %g", mesh, epsilon));
  }
  Entry& e = *it->second;
  e.cancel = true;
  if (e.status.state == GraphState::kQueued) {
    e.status.state = GraphState::kCancelled;
    Bump(e);
  }
  return e.status;
}

std::vector<GraphStatus> GraphCache::List() const {
  absl::MutexLock lock(&mu_);
  std::vector<GraphStatus> out;
  for (const auto& [key, e] : entries_) out.push_back(e->status);
  return out;
}

void GraphCache::DropMesh(const std::string& mesh) {
  std::vector<double> dropped;
  {
    absl::MutexLock lock(&mu_);
    for (auto it = entries_.begin(); it != entries_.end();) {
      if (it->first.first == mesh) {
        it->second->cancel = true;
        dropped.push_back(it->first.second);
        it = entries_.erase(it);
      } else {
        ++it;
      }
    }
  }
  if (options_.on_readiness) {
    for (double eps : dropped) options_.on_readiness(mesh, eps, false);
  }
}

absl::StatusOr<std::shared_ptr<const GeodesicEngine>> GraphCache::Acquire(const std::string& mesh,
                                                                          double epsilon) {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find({mesh, epsilon});
  if (it == entries_.end()) {
    ++misses_;
    return absl::FailedPreconditionError(absl::StrFormat(
        "no graph for mesh '%s' at epsilon %g: request one first (RequestGraph)", mesh, epsilon));
  }
  Entry& e = *it->second;
  switch (e.status.state) {
    case GraphState::kReady:
      ++hits_;
      Touch(e);
      return e.engine;
    case GraphState::kFailed:
      ++misses_;
      return absl::FailedPreconditionError(absl::StrFormat(
          "the graph for '%s' at epsilon %g failed: %s", mesh, epsilon, e.status.error));
    case GraphState::kCancelled:
      ++misses_;
      return absl::FailedPreconditionError(absl::StrFormat(
          "the graph for '%s' at epsilon %g was cancelled: request it again", mesh, epsilon));
    case GraphState::kEvicted:
      // Map it again (it was persisted) and let the client retry.
      ++misses_;
      e.status.state = GraphState::kQueued;
      e.cancel = false;
      Bump(e);
      Schedule(it->first);
      [[fallthrough]];
    default:
      ++misses_;
      return absl::UnavailableError(
          absl::StrFormat("the graph for '%s' at epsilon %g is %s (%.0f%%): retry shortly", mesh,
                          epsilon, GraphStateName(e.status.state), 100 * e.status.progress));
  }
}

uint64_t GraphCache::resident_bytes() const {
  absl::MutexLock lock(&mu_);
  uint64_t total = 0;
  for (const auto& [key, e] : entries_) {
    if (e->status.state != GraphState::kReady) continue;
    total += e->status.landmark_bytes + (e->status.mapped ? 0 : e->status.bytes);
  }
  return total;
}

uint64_t GraphCache::mapped_bytes() const {
  absl::MutexLock lock(&mu_);
  uint64_t total = 0;
  for (const auto& [key, e] : entries_) {
    if (e->status.state == GraphState::kReady && e->status.mapped) total += e->status.bytes;
  }
  return total;
}

}  // namespace geodesic::server
