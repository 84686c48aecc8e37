#include "server/graphs/graph_cache.h"

#include <sys/stat.h>

#include <charconv>
#include <chrono>
#include <filesystem>
#include <set>

#include "absl/status/status.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "core/query/exact_landmarks_file.h"
#include "core/query/landmarks.h"
#include "server/base/log.h"
#include "server/graphs/replica_lock.h"
#include "server/offline/certificate_file.h"

namespace geodesic::server {

namespace {

// No worker holds an entry in these states.
bool Finished(GraphState s) {
  return s == GraphState::kReady || s == GraphState::kFailed || s == GraphState::kCancelled ||
         s == GraphState::kEvicted;
}

std::string Describe(const GraphKey& key) {
  if (key.max_error > 0) {
    return absl::StrFormat("the graph of '%s' certified to max error %g (first build: %s)",
                           key.mesh, key.max_error, DescribeParams(key.params));
  }
  return absl::StrFormat("the graph of '%s' (%s)", key.mesh, DescribeParams(key.params));
}

}  // namespace

GraphCache::GraphCache(Options options) : options_(std::move(options)) {
  if (!options_.maker) options_.maker = std::make_shared<GraphMaker>();
  if (!options_.graph_dir.empty()) std::filesystem::create_directories(options_.graph_dir);
  for (int i = 0; i < std::max(1, options_.build_workers); ++i) {
    workers_.emplace_back([this] { Worker(/*large_lane=*/false); });
  }
  workers_.emplace_back([this] { Worker(/*large_lane=*/true); });
}

GraphCache::~GraphCache() {
  {
    absl::MutexLock lock(&mu_);
    stopping_ = true;
    for (auto& [key, e] : entries_) e->cancel = true;
  }
  for (auto& t : workers_) t.join();
}

std::string GraphCache::GraphPath(uint64_t mesh_fingerprint, const DggParams& params,
                                  double max_error) const {
  if (options_.graph_dir.empty()) return "";
  return options_.graph_dir + "/" + CachedGraphFileName(mesh_fingerprint, params, max_error);
}

bool GraphCache::Transition(Entry& e, GraphState to) {
  const GraphState from = e.status.state;
  if (!LegalTransition(from, to)) {
    Log(LogLevel::kError, "graph_illegal_transition",
        {{"mesh", e.status.mesh}, {"from", GraphStateName(from)}, {"to", GraphStateName(to)}});
    return false;
  }
  e.status.state = to;
  ++e.status.version;
  return true;
}

bool GraphCache::Current(const GraphKey& key, const Entry& e) const {
  auto it = entries_.find(key);
  return it != entries_.end() && it->second.get() == &e;
}

void GraphCache::Enqueue(const GraphKey& key) {
  auto it = entries_.find(key);
  if (it != entries_.end()) {
    Entry& e = *it->second;
    // A graph whose file is there only needs mapping, however large.
    std::error_code ec;
    const bool have_file = !e.path.empty() && std::filesystem::exists(e.path, ec);
    e.large = !have_file && e.status.estimated_seconds > options_.large_build_seconds;
    e.not_before = absl::InfinitePast();
  }
  queue_.push_back(key);
  ++queue_changes_;
}

DggBuildEstimate GraphCache::Estimate(const RegisteredMesh& mesh, const DggParams& params) const {
  DggBuildEstimate estimate =
      EstimateDggBuild(mesh.mesh->num_vertices(), params.epsilon, params.pseudo_vertices);
  const int threads = options_.build_threads > 0
                          ? options_.build_threads
                          : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // Builds scale nearly linearly with threads (BENCHMARKS.md).
  if (threads > 1) estimate.seconds /= 0.95 * threads;
  return estimate;
}

absl::StatusOr<DggBuildEstimate> GraphCache::Admit(const RegisteredMesh& mesh,
                                                   const DggParams& params,
                                                   double max_error) const {
  DggBuildEstimate estimate = Estimate(mesh, params);
  uint64_t least = EstimateDggBytesLowerBound(mesh.mesh->num_vertices(), params.epsilon);
  uint64_t spill = 0;
  {
    absl::MutexLock lock(&mu_);
    if (auto it = known_bytes_.find(KnownBytesOf(mesh, params, max_error));
        it != known_bytes_.end()) {
      if (it->second.file > 0) estimate.bytes = least = it->second.file;
      spill = it->second.spill;
    }
  }
  const std::string what =
      max_error > 0
          ? absl::StrFormat("the graph of '%s' certified to max error %g (epsilon %g)%s", mesh.name,
                            max_error, params.epsilon,
                            params.pseudo_vertices ? " with pseudo vertices" : "")
          : absl::StrFormat("the graph of '%s' at epsilon %g%s", mesh.name, params.epsilon,
                            params.pseudo_vertices ? " with pseudo vertices" : "");
  if (options_.memory_limit > 0 && least > options_.memory_limit) {
    return absl::ResourceExhaustedError(
        absl::StrFormat("%s needs at least %u bytes, over the server's memory limit of %u bytes "
                        "(--memory-limit): use a larger epsilon",
                        what, least, options_.memory_limit));
  }
  const std::string path = GraphPath(mesh.fingerprint, params, max_error);
  std::error_code ec;
  if (!path.empty() && std::filesystem::exists(path, ec)) return estimate;
  if (options_.max_graph_bytes > 0 && estimate.bytes > options_.max_graph_bytes) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s is estimated at %u bytes (a %.0f s build), over the server's limit of %u bytes per "
        "graph (--max-graph-bytes): use a larger epsilon",
        what, estimate.bytes, estimate.seconds, options_.max_graph_bytes));
  }
  if (options_.disk && options_.disk->limit() > 0 && least > options_.disk->limit()) {
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s needs at least %u bytes on disk, over the server's disk limit of %u bytes "
        "(--disk-limit): use a larger epsilon",
        what, least, options_.disk->limit()));
  }
  if (options_.disk && options_.disk->limit() > 0 && spill > options_.disk->limit()) {
    // Its last build stopped there: building again would end the same way.
    return absl::ResourceExhaustedError(absl::StrFormat(
        "%s needs at least %u bytes of spill file on disk for its candidate edges past "
        "--build-memory-limit, over the server's disk limit of %u bytes (--disk-limit): raise "
        "--build-memory-limit or --disk-limit",
        what, spill, options_.disk->limit()));
  }
  return estimate;
}

void GraphCache::Touch(Entry& e) {
  e.last_used = absl::Now();
  e.status.last_used_unix_ms = absl::ToUnixMillis(e.last_used);
}

void GraphCache::Announce(const Notices& notices) const {
  if (!options_.on_readiness) return;
  for (const Notice& n : notices) options_.on_readiness(n.key, n.ready);
}

GraphStatus GraphCache::Request(std::shared_ptr<const RegisteredMesh> mesh, const DggParams& params,
                                double max_error) {
  absl::MutexLock lock(&mu_);
  GraphKey key{mesh->name, params, max_error};
  auto& slot = entries_[key];
  // An entry whose cancel a worker has not acted on yet would end cancelled
  // although this request was answered as building: it is replaced below.
  const bool cancelling = slot && slot->cancel && slot->status.state != GraphState::kQueued &&
                          !Finished(slot->status.state);
  if (slot && slot->mesh->fingerprint == mesh->fingerprint && !cancelling) {
    Entry& e = *slot;
    Touch(e);
    const GraphState s = e.status.state;
    if (s == GraphState::kFailed || s == GraphState::kCancelled || s == GraphState::kEvicted) {
      // No worker holds an entry in these states: it starts again in place.
      e.cancel = false;
      e.status.error.clear();
      e.status.phase.clear();
      e.status.progress = 0;
      if (Transition(e, GraphState::kQueued)) Enqueue(key);
    }
    return e.status;  // single flight: join the running or finished operation
  }
  const DggBuildEstimate estimate = Estimate(*mesh, params);
  // New, being cancelled, or the mesh was registered again with other
  // contents: a new entry, so that an operation still running for the old
  // one publishes nothing.
  auto e = std::make_shared<Entry>();
  e->mesh = std::move(mesh);
  e->path = GraphPath(e->mesh->fingerprint, params, max_error);
  e->status.mesh = key.mesh;
  e->status.params = params;
  e->status.epsilon = params.epsilon;
  e->status.max_error = max_error;
  e->status.state = GraphState::kQueued;
  e->status.estimated_bytes = estimate.bytes;
  e->status.estimated_seconds = estimate.seconds;
  e->status.version = slot ? slot->status.version + 1 : 1;
  if (slot) slot->cancel = true;
  Touch(*e);
  slot = e;
  Enqueue(key);
  return e->status;
}

bool GraphCache::TakeNext(bool large_lane, GraphKey* key, absl::Time* wake) {
  const absl::Time now = absl::Now();
  std::deque<GraphKey> live;
  const Entry* best = nullptr;
  size_t best_at = 0;
  std::set<GraphKey> seen;
  for (const GraphKey& k : queue_) {
    auto it = entries_.find(k);
    // Entries dropped, taken up already, or queued twice need no run.
    if (it == entries_.end() || it->second->status.state != GraphState::kQueued ||
        !seen.insert(k).second) {
      continue;
    }
    live.push_back(k);
    const Entry& e = *it->second;
    // build_workers count small builds only: the large lane is extra.
    if (e.large != large_lane) continue;
    if (e.not_before > now) {
      *wake = std::min(*wake, e.not_before);
      continue;
    }
    if (!best || e.status.estimated_seconds < best->status.estimated_seconds) {
      best = &e;
      best_at = live.size() - 1;
    }
  }
  queue_ = std::move(live);
  if (!best) return false;
  *key = queue_[best_at];
  queue_.erase(queue_.begin() + best_at);
  return true;
}

void GraphCache::Worker(bool large_lane) {
  while (true) {
    GraphKey key;
    bool exact_job = false;
    {
      absl::MutexLock lock(&mu_);
      while (true) {
        if (stopping_) return;
        absl::Time wake = absl::InfiniteFuture();
        if (TakeNext(large_lane, &key, &wake)) break;
        // Builds first: a client waits for them, not for landmarks.
        if (!exact_landmark_jobs_.empty()) {
          key = exact_landmark_jobs_.front();
          exact_landmark_jobs_.pop_front();
          exact_job = true;
          break;
        }
        const uint64_t seen = queue_changes_;
        auto changed = [this, seen]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) {
          return stopping_ || queue_changes_ != seen;
        };
        mu_.AwaitWithDeadline(absl::Condition(&changed), wake);
      }
    }
    if (exact_job) {
      AddExactLandmarks(key);
    } else {
      Run(key);
    }
  }
}

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

void GraphCache::WaitForReplica(const GraphKey& key, const std::shared_ptr<Entry>& e) {
  absl::MutexLock hold(&mu_);
  if (!Current(key, *e) || e->status.state != GraphState::kQueued) return;
  if (e->cancel) {
    Transition(*e, GraphState::kCancelled);
    return;
  }
  if (e->status.phase != kWaitingForReplicaPhase) {
    Log(LogLevel::kInfo, "graph_build_waiting", {{"mesh", key.mesh}, {"path", e->path}});
  }
  e->status.phase = kWaitingForReplicaPhase;
  ++e->status.version;
  Enqueue(key);
  e->not_before = absl::Now() + options_.replica_poll;
}

namespace {

// GraphStatus::landmark_bytes: both kinds of landmarks.
uint64_t LandmarkBytes(const GeodesicEngine& engine) {
  return engine.landmark_bytes() + engine.exact_landmark_bytes();
}

}  // namespace

void GraphCache::AddLandmarks(const GraphKey& key, const std::shared_ptr<Entry>& e,
                              const std::shared_ptr<const GeodesicEngine>& engine) {
  // Landmarks cut the nodes a point-to-point query settles several times;
  // queries that arrive before they are ready use straight-line bounds.
  const int landmark_count = engine->DefaultLandmarkCount();
  Notices notices;
  {
    absl::MutexLock lock(&mu_);
    if (!Current(key, *e) || e->engine != engine) return;
    e->landmarks_pending = Landmarks::ComputeBytes(engine->graph(), landmark_count);
    EvictOverBudget(key, notices);
  }
  Announce(notices);
  notices.clear();
  absl::Status landmarks =
      engine->PrepareLandmarks(landmark_count, [e] { return e->cancel.load(); });
  {
    absl::MutexLock lock(&mu_);
    e->landmarks_pending = 0;
    if (!landmarks.ok() || !Current(key, *e) || e->engine != engine) return;
    e->status.landmark_bytes = LandmarkBytes(*engine);
    e->counted_exact = engine->exact_landmarks();
    ++e->status.version;
    EvictOverBudget(key, notices);
  }
  Announce(notices);
}

void GraphCache::WantExactLandmarks(const GraphKey& key) {
  if (options_.exact_landmarks <= 0) return;
  absl::MutexLock lock(&mu_);
  auto it = entries_.find(key);
  if (it == entries_.end() || it->second->status.state != GraphState::kReady ||
      it->second->exact_landmarks_asked) {
    return;
  }
  it->second->exact_landmarks_asked = true;
  exact_landmark_jobs_.push_back(key);
  ++queue_changes_;
}

std::shared_ptr<const ExactLandmarks> GraphCache::SiblingExactLandmarks(const GraphKey& key,
                                                                        const Entry& e,
                                                                        int count) const {
  for (const auto& [other_key, other] : entries_) {
    if (other_key == key || other->status.state != GraphState::kReady || !other->engine ||
        other->mesh->fingerprint != e.mesh->fingerprint) {
      continue;
    }
    std::shared_ptr<const ExactLandmarks> held = other->engine->shared_exact_landmarks();
    if (held && held->count() == count) return held;
  }
  return nullptr;
}

uint64_t GraphCache::CountedLandmarkBytes(const Entry& e,
                                          std::set<const ExactLandmarks*>& counted) {
  if (!e.counted_exact || counted.insert(e.counted_exact).second) return e.status.landmark_bytes;
  return e.status.landmark_bytes - e.counted_exact->byte_size();
}

bool GraphCache::RestoreExactLandmarks(const GraphKey& key, const Entry& e,
                                       const GeodesicEngine& engine, int count) {
  if (e.path.empty()) return false;
  const Mesh& mesh = *e.mesh->mesh;
  const std::string path = ExactLandmarksPathOf(e.path);
  auto read = ReadExactLandmarks(path, mesh, count);
  bool from_sibling = false;
  if (absl::IsNotFound(read.status())) {
    // The fields are the mesh's, whichever of its graphs spread the
    // landmarks: another graph of the mesh may keep them already.
    const std::string prefix = absl::StrFormat("%016x-", e.mesh->fingerprint);
    std::error_code ec;
    for (const auto& entry : std::filesystem::directory_iterator(options_.graph_dir, ec)) {
      const std::string name = entry.path().filename().string();
      if (!absl::StartsWith(name, prefix) || !absl::EndsWith(name, ".dgg.exact-landmarks")) {
        continue;
      }
      auto sibling = ReadExactLandmarks(entry.path().string(), mesh, count);
      if (!sibling.ok()) continue;
      read = std::move(sibling);
      from_sibling = true;
      break;
    }
  }
  if (!read.ok()) {
    // Another count, mesh or version, or damage: computed again and
    // written over.
    if (!absl::IsNotFound(read.status())) {
      Log(LogLevel::kWarning, "exact_landmarks_file_rejected",
          {{"mesh", key.mesh}, {"path", path}, {"error", read.status().ToString()}});
    }
    return false;
  }
  if (!engine.AdoptExactLandmarks(*std::move(read)).ok()) return false;
  // A copy of its own, since the disk budget removes the other graph's
  // with that graph.
  if (from_sibling) {
    SaveExactLandmarks(key, e, engine);
  } else if (options_.on_file_used) {
    options_.on_file_used(path);
  }
  return true;
}

void GraphCache::SaveExactLandmarks(const GraphKey& key, const Entry& e,
                                    const GeodesicEngine& engine) {
  const ExactLandmarks* landmarks = engine.exact_landmarks();
  // Only beside a graph file: the disk budget removes them with it, and
  // a graph kept in memory only would leave them behind.
  std::error_code ec;
  if (e.path.empty() || !landmarks || !std::filesystem::exists(e.path, ec)) return;
  // Best effort: without the file they are only computed again.
  const std::string path = ExactLandmarksPathOf(e.path);
  const uint64_t bytes = ExactLandmarksFileBytes(*landmarks);
  if (options_.disk) {
    if (absl::Status room = options_.disk->Reserve(bytes); !room.ok()) {
      Log(LogLevel::kWarning, "exact_landmarks_not_saved",
          {{"mesh", key.mesh}, {"path", path}, {"error", room.ToString()}});
      return;
    }
  }
  const absl::Status written = WriteExactLandmarks(*landmarks, *e.mesh->mesh, path);
  if (options_.disk) options_.disk->Done(bytes, written.ok() ? bytes : 0);
  if (!written.ok()) {
    Log(LogLevel::kWarning, "exact_landmarks_not_saved",
        {{"mesh", key.mesh}, {"path", path}, {"error", written.ToString()}});
  }
}

void GraphCache::AddExactLandmarks(const GraphKey& key) {
  const int count = options_.exact_landmarks;
  std::shared_ptr<Entry> e;
  std::shared_ptr<const GeodesicEngine> engine;
  std::shared_ptr<const ExactLandmarks> sibling;
  Notices notices;
  bool fits = true;
  {
    absl::MutexLock lock(&mu_);
    auto it = entries_.find(key);
    if (it == entries_.end() || it->second->status.state != GraphState::kReady) return;
    e = it->second;
    engine = e->engine;
    // Shared from another graph of the mesh, they take no memory more.
    sibling = SiblingExactLandmarks(key, *e, count);
    if (!sibling) {
      e->exact_landmarks_pending = engine->ExactLandmarkComputeBytes(count, options_.build_threads);
      fits = EvictOverBudget(key, notices);
    }
    if (!fits) {
      Log(LogLevel::kWarning, "exact_landmarks_skipped",
          {{"mesh", key.mesh},
           {"eps", key.params.epsilon},
           {"bytes", e->exact_landmarks_pending},
           {"reason", "over --memory-limit even after evicting every graph no query holds"}});
      e->exact_landmarks_pending = 0;
    }
  }
  Announce(notices);
  notices.clear();
  if (!fits) return;
  const auto start = std::chrono::steady_clock::now();
  const bool shared = sibling && engine->AdoptExactLandmarks(std::move(sibling)).ok();
  const bool restored = shared || RestoreExactLandmarks(key, *e, *engine, count);
  // A build worker's job: no more threads than a build on it takes.
  absl::Status made = restored
                          ? absl::OkStatus()
                          : engine->PrepareExactLandmarks(
                                count, [e] { return e->cancel.load(); }, options_.build_threads);
  // Shared ones too get a copy beside this graph's file, for a restart:
  // the disk budget removes the other graph's with that graph.
  std::error_code ec;
  const bool kept = shared && std::filesystem::exists(ExactLandmarksPathOf(e->path), ec);
  if (made.ok() && (!restored || (shared && !kept))) SaveExactLandmarks(key, *e, *engine);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  {
    absl::MutexLock lock(&mu_);
    e->exact_landmarks_pending = 0;
    if (!Current(key, *e) || e->engine != engine) return;
    if (!made.ok()) {
      Log(LogLevel::kWarning, "exact_landmarks_failed",
          {{"mesh", key.mesh}, {"eps", key.params.epsilon}, {"error", made.ToString()}});
      return;
    }
    e->status.landmark_bytes = LandmarkBytes(*engine);
    e->counted_exact = engine->exact_landmarks();
    ++e->status.version;
    Log(LogLevel::kInfo, "exact_landmarks_ready",
        {{"mesh", key.mesh},
         {"eps", key.params.epsilon},
         {"landmarks", count},
         {"seconds", seconds},
         {"from_file", restored && !shared},
         {"shared", shared},
         {"bytes", engine->exact_landmark_bytes()}});
    EvictOverBudget(key, notices);
  }
  Announce(notices);
}

std::shared_ptr<const DggGraph> GraphCache::Load(const GraphKey& key, Entry& e, std::string* note,
                                                 std::optional<GraphCertificate>* certificate) {
  absl::StatusOr<std::shared_ptr<const DggGraph>> opened;
  if (key.max_error > 0) {
    auto certified = options_.maker->OpenCertified(e.path, *e.mesh->mesh, key.params, key.max_error,
                                                   GraphFile::Check::kFull);
    if (certified.ok()) {
      *certificate = certified->certificate;
      opened = std::move(certified->graph);
    } else {
      opened = certified.status();
    }
  } else {
    opened = options_.maker->Open(e.path, *e.mesh->mesh, key.params, GraphFile::Check::kFull);
  }
  if (opened.ok()) {
    if (options_.on_file_used) options_.on_file_used(e.path);
    Log(LogLevel::kInfo, "graph_loaded", {{"mesh", e.status.mesh}, {"path", e.path}});
    return *std::move(opened);
  }
  if (absl::IsNotFound(opened.status())) return nullptr;
  // Never serve a file that fails validation or was built otherwise: move
  // it aside (for a post-mortem), rebuild.
  const std::string aside =
      absl::StrFormat("%s.rejected-%d", e.path, absl::ToUnixSeconds(absl::Now()));
  std::error_code ec;
  std::filesystem::rename(e.path, aside, ec);
  // Nor a certificate that was not the file's (or that a rebuild would
  // not replace, were its write to fail).
  if (key.max_error > 0) offline::RemoveCertificate(e.path).IgnoreError();
  *note = absl::StrFormat("rejected %s (%s), rebuilt", e.path, opened.status().message());
  Log(LogLevel::kWarning, "graph_file_rejected",
      {{"mesh", e.status.mesh}, {"path", e.path}, {"error", opened.status().ToString()}});
  return nullptr;
}

namespace {

// The file a plain build keeps its edges in as it makes them
// (GraphFileDraft), so that they take page cache, which the kernel writes
// back and reclaims, instead of the daemon's memory; Persist commits it.
// None without a graph directory; none with pseudo vertices, whose node
// count, which lays the file out, the build decides; none for a certified
// graph, whose builds are several, at epsilons it picks as it goes: it
// stays built in memory and is written whole.
absl::StatusOr<std::optional<GraphFileDraft>> DraftFor(const GraphKey& key, const std::string& path,
                                                       const Mesh& mesh, DggBuildOptions& options) {
  if (path.empty() || key.params.pseudo_vertices || key.max_error > 0) return std::nullopt;
  auto draft = GraphFileDraft::Create(path, mesh.num_vertices());
  if (!draft.ok()) return draft.status();
  draft->AttachTo(options);
  return std::optional<GraphFileDraft>(*std::move(draft));
}

// The disk a build writes while it runs, its draft's edges and the spill
// file of --build-memory-limit: the budget admits each growth before it
// happens, so the directory stays within --disk-limit during the build
// instead of passing it until the file is admitted afterwards. The spill's
// admission is given back when the spill is read back, the edges' when the
// build ends; Persist then admits the file, with the draft counted as on
// disk (BytesToAdmit).
class BuildAdmission {
 public:
  BuildAdmission(DiskBudget* disk, DggBuildOptions& options) : disk_(disk) {
    if (!disk_) return;
    if (options.edge_file.fd >= 0) {
      options.edge_file.admit_growth = [this](uint64_t bytes) -> absl::Status {
        absl::Status room = Admit(edges_, bytes);
        if (room.ok()) return room;
        refused_ = bytes;
        return absl::ResourceExhaustedError(absl::StrFormat(
            "its edges need %u bytes on disk: %s; use a larger epsilon or raise --disk-limit",
            bytes, room.message()));
      };
    }
    options.admit_spill = [this](uint64_t bytes) -> absl::Status {
      absl::Status room = Admit(spill_, bytes);
      if (room.ok()) return room;
      spill_refused_ = bytes;
      return absl::ResourceExhaustedError(absl::StrFormat(
          "its candidate edges past --build-memory-limit need %u bytes of spill file on disk: %s; "
          "raise --build-memory-limit or --disk-limit",
          bytes, room.message()));
    };
  }
  ~BuildAdmission() {
    Admit(edges_, 0).IgnoreError();
    Admit(spill_, 0).IgnoreError();
  }
  BuildAdmission(const BuildAdmission&) = delete;
  BuildAdmission& operator=(const BuildAdmission&) = delete;

  // The edge bytes a refused growth asked for (0: none refused): at least
  // the graph's file size.
  uint64_t refused() const { return refused_; }
  // The same for the spill file.
  uint64_t spill_refused() const { return spill_refused_; }

 private:
  // Makes what is admitted for one file `bytes`: reserves its growth, or
  // gives everything back at 0. Each file's hook is called by one build
  // thread at a time.
  absl::Status Admit(uint64_t& reserved, uint64_t bytes) {
    if (bytes == 0) {
      if (reserved > 0) disk_->Done(reserved, 0);
      reserved = 0;
      return absl::OkStatus();
    }
    if (bytes <= reserved) return absl::OkStatus();
    RETURN_IF_ERROR(disk_->Reserve(bytes - reserved));
    reserved = bytes;
    return absl::OkStatus();
  }

  DiskBudget* const disk_;
  uint64_t edges_ = 0, spill_ = 0;  // bytes reserved for each
  uint64_t refused_ = 0;            // set by the thread that grows the edges, read after
  uint64_t spill_refused_ = 0;      // set by the thread that writes the spill, read after
};

// What the disk budget must admit for a graph file of `bytes`. A draft's
// edges are on disk since its build made them, under a temporary name, which
// the budget's last count of the directory may or may not have seen: it
// counts the directory now, draft included, and admits what the file adds.
uint64_t BytesToAdmit(DiskBudget& disk, uint64_t bytes,
                      const std::optional<GraphFileDraft>& draft) {
  struct stat st;
  if (!draft || !disk.Scan().ok() || ::fstat(draft->edge_file().fd, &st) != 0) return bytes;
  return bytes - std::min<uint64_t>(bytes, st.st_size);
}

}  // namespace

DggBuildOptions GraphCache::BuildOptions(const GraphKey& key, Entry& e) {
  DggBuildOptions options;
  options.params = key.params;
  options.threads = options_.build_threads;
  options.pseudo_vertex_limit = options_.pseudo_vertex_limit;
  options.candidate_memory_limit = options_.build_memory_limit;
  options.spill_dir = options_.graph_dir.empty() ? std::filesystem::temp_directory_path().string()
                                                 : options_.graph_dir;
  auto logged_quarter = std::make_shared<int>(0);  // under mu_
  options.progress = [this, &e, key, logged_quarter](std::string_view phase, double fraction) {
    absl::MutexLock lock(&mu_);
    if (e.status.phase != phase || fraction - e.status.progress >= 0.01 || fraction >= 1) {
      e.status.phase = std::string(phase);
      e.status.progress = fraction;
      ++e.status.version;
    }
    if (static_cast<int>(4 * fraction) > *logged_quarter && fraction < 1) {
      *logged_quarter = static_cast<int>(4 * fraction);
      Log(LogLevel::kInfo, "graph_build_progress",
          {{"mesh", key.mesh},
           {"eps", key.params.epsilon},
           {"percent", 25 * *logged_quarter},
           {"phase", std::string(phase)}});
    }
    return !e.cancel.load();
  };
  return options;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::BuildCertified(
    const GraphKey& key, Entry& e, const DggBuildOptions& options,
    std::optional<GraphCertificate>* certificate) {
  // Build, check against the exact engine, rebuild tighter if it missed:
  // the phases of each build and then "check", the fraction of each
  // build-and-check; later builds say which they are.
  CertifyOptions certify;
  certify.build = options;
  certify.build.progress = nullptr;
  certify.progress = [&](uint32_t build, std::string_view phase, double fraction) {
    const std::string name =
        build <= 1 ? std::string(phase) : absl::StrFormat("%s (build %u)", phase, build);
    return options.progress(name, fraction);
  };
  certify.cancelled = [&e] { return e.cancel.load(); };
  auto certified = options_.maker->BuildCertified(e.mesh->mesh, key.max_error, certify);
  if (!certified.ok()) return certified.status();
  *certificate = certified->certificate;
  Log(LogLevel::kInfo, "graph_certified",
      {{"mesh", key.mesh},
       {"max_error", key.max_error},
       {"eps", certified->certificate.epsilon},
       {"measured_max_error", certified->certificate.measured_max_error},
       {"measured_mean_error", certified->certificate.measured_mean_error},
       {"sources", certified->certificate.sources},
       {"builds", certified->certificate.builds}});
  return std::move(certified->graph);
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::Build(
    const GraphKey& key, Entry& e, std::optional<GraphFileDraft>* draft,
    std::optional<GraphCertificate>* certificate) {
  Log(LogLevel::kInfo, "graph_build_started",
      {{"mesh", key.mesh}, {"params", DescribeParams(key.params)}, {"max_error", key.max_error}});
  DggBuildOptions options = BuildOptions(key, e);
  // A directory that cannot take the file fails the graph before its build.
  auto drafted = DraftFor(key, e.path, *e.mesh->mesh, options);
  if (!drafted.ok()) return drafted.status();
  if (drafted->has_value()) draft->emplace(*std::move(*drafted));
  BuildAdmission admission(options_.disk, options);
  ++builds_started_;
  ++builds_running_;
  const auto start = std::chrono::steady_clock::now();
  absl::StatusOr<std::shared_ptr<const DggGraph>> built;
  if (key.max_error > 0) {
    built = BuildCertified(key, e, options, certificate);
  } else {
    built = options_.maker->Build(*e.mesh->mesh, options);
    if (*draft && absl::IsResourceExhausted(built.status())) {
      built = absl::ResourceExhaustedError(
          absl::StrFormat("building %s: %s", e.path, built.status().message()));
    }
  }
  if (admission.refused() > 0 || admission.spill_refused() > 0) {
    // Asked again, the graph is refused at once for those sizes (Admit).
    absl::MutexLock lock(&mu_);
    KnownBytes& known = known_bytes_[KnownBytesOf(*e.mesh, key.params, key.max_error)];
    if (admission.refused() > 0) known.file = admission.refused();
    if (admission.spill_refused() > 0) known.spill = admission.spill_refused();
  }
  --builds_running_;
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (built.ok()) {
    Log(LogLevel::kInfo, "graph_build_finished",
        {{"mesh", key.mesh},
         {"eps", key.params.epsilon},
         {"seconds", seconds},
         {"edges", (*built)->num_directed_edges() / 2},
         {"bytes", (*built)->byte_size()}});
  }
  return built;
}

absl::StatusOr<std::shared_ptr<const DggGraph>> GraphCache::Persist(
    const GraphKey& key, Entry& e, std::shared_ptr<const DggGraph> graph,
    std::optional<GraphFileDraft> draft, const std::optional<GraphCertificate>& certificate,
    std::string* note) {
  // The arrays are the file but for its header and alignment.
  const uint64_t bytes = graph->byte_size();
  {
    absl::MutexLock lock(&mu_);
    known_bytes_[KnownBytesOf(*e.mesh, key.params, key.max_error)].file = bytes;
  }
  const bool drafted = draft.has_value();
  const uint64_t admitted = options_.disk ? BytesToAdmit(*options_.disk, bytes, draft) : bytes;
  if (options_.disk) {
    if (absl::Status room = options_.disk->Reserve(admitted); !room.ok()) {
      Log(LogLevel::kWarning, "graph_write_refused",
          {{"mesh", key.mesh}, {"path", e.path}, {"error", room.ToString()}});
      draft.reset();
      if (drafted) options_.disk->Scan().IgnoreError();  // without the draft now
      return absl::ResourceExhaustedError(absl::StrFormat(
          "the graph was built but its file %s was not kept: %s; use a larger epsilon or raise "
          "--disk-limit",
          e.path, room.message()));
    }
  }
  absl::Status written = drafted ? options_.maker->Finish(*std::move(draft), *graph)
                                 : options_.maker->Write(*graph, e.path);
  if (options_.disk && drafted) {
    // The draft became the file or went: the directory says which.
    const bool scanned = options_.disk->Scan().ok();
    options_.disk->Done(admitted, scanned || !written.ok() ? 0 : admitted);
  } else if (options_.disk) {
    std::error_code ec;
    const uint64_t on_disk = written.ok() ? std::filesystem::file_size(e.path, ec) : 0;
    options_.disk->Done(bytes, ec ? bytes : on_disk);
  }
  if (!written.ok()) {
    Log(LogLevel::kWarning, "graph_write_failed",
        {{"mesh", key.mesh}, {"path", e.path}, {"error", written.ToString()}});
    // A graph built into its file is served from that file or not at all:
    // the directory could not hold it.
    if (drafted) {
      return absl::Status(written.code(),
                          absl::StrFormat("the graph was built but its file %s was not kept: %s",
                                          e.path, written.message()));
    }
    *note = absl::StrFormat("graph kept in memory only: %s", written.message());
    return graph;
  }
  if (certificate) {
    // Without its sidecar the file would be rebuilt after a restart, not
    // believed: the graph is still served, from memory or its file.
    if (absl::Status c = options_.maker->WriteCertificate(*graph, e.path, *certificate); !c.ok()) {
      *note = absl::StrFormat("certificate not written beside the file: %s", c.message());
      Log(LogLevel::kWarning, "graph_certificate_write_failed",
          {{"mesh", key.mesh}, {"path", e.path}, {"error", c.ToString()}});
    }
  }
  if (options_.on_file_used) options_.on_file_used(e.path);
  // Serve the file mapped as a restart would map it, not the graph the
  // build returned: read-only, its pages the page cache's, and counted the
  // same (mapped, the file's bytes) whether built here or loaded. A draft's
  // graph has only its edges in the file (a writable mapping of it) and
  // the rest in memory, which goes with it. A certified graph's epsilon is
  // its build's, not its key's.
  auto mapped =
      options_.maker->Open(e.path, *e.mesh->mesh, graph->params(), GraphFile::Check::kHeader);
  return mapped.ok() ? *std::move(mapped) : graph;
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

bool GraphCache::EvictOverBudget(const GraphKey& keep, Notices& notices) {
  if (options_.memory_limit == 0) return true;
  const uint64_t outside = options_.resident_bytes_outside ? options_.resident_bytes_outside() : 0;
  while (true) {
    uint64_t total = outside;
    std::shared_ptr<Entry> victim;
    const GraphKey* victim_key = nullptr;
    std::set<const ExactLandmarks*> counted;
    for (auto& [key, e] : entries_) {
      if (e->status.state != GraphState::kReady) continue;
      total += e->status.bytes + CountedLandmarkBytes(*e, counted) + e->landmarks_pending +
               e->exact_landmarks_pending + e->engine->scratch_bytes();
      // Only graphs no query holds; never the one just made ready.
      if (key == keep || e->engine.use_count() > 1) continue;
      if (!victim || e->last_used < victim->last_used) {
        victim = e;
        victim_key = &key;
      }
    }
    if (total <= options_.memory_limit || !victim) return total <= options_.memory_limit;
    if (!Transition(*victim, GraphState::kEvicted)) return false;
    victim->engine.reset();
    ++evictions_;
    victim->status.landmark_bytes = 0;
    victim->counted_exact = nullptr;
    victim->status.phase = "evicted";
    notices.push_back({*victim_key, false});
    Log(LogLevel::kInfo, "graph_evicted",
        {{"mesh", victim_key->mesh}, {"eps", victim_key->params.epsilon}});
  }
}

absl::StatusOr<GraphStatus> GraphCache::Get(const GraphKey& key) const {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find(key);
  if (it == entries_.end()) {
    return absl::NotFoundError(absl::StrFormat("%s was never requested", Describe(key)));
  }
  return it->second->status;
}

absl::StatusOr<GraphStatus> GraphCache::WaitForChange(const GraphKey& key, uint64_t version,
                                                      absl::Time deadline) const {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find(key);
  if (it == entries_.end()) {
    return absl::NotFoundError(absl::StrFormat("%s was never requested", Describe(key)));
  }
  std::shared_ptr<Entry> e = it->second;
  auto changed = [&]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_) { return e->status.version != version; };
  mu_.AwaitWithDeadline(absl::Condition(&changed), deadline);
  return e->status;
}

absl::StatusOr<GraphStatus> GraphCache::Cancel(const GraphKey& key) {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find(key);
  if (it == entries_.end()) {
    return absl::NotFoundError(absl::StrFormat("%s was never requested", Describe(key)));
  }
  Entry& e = *it->second;
  // A finished operation has nothing to cancel: a ready graph stays served
  // (an evicted one is mapped again on use), and no landmark preparation of
  // it is stopped.
  if (Finished(e.status.state)) return e.status;
  e.cancel = true;
  // A queued entry has no worker to notice; one at work ends in cancelled
  // at its next step.
  if (e.status.state == GraphState::kQueued) Transition(e, GraphState::kCancelled);
  return e.status;
}

void GraphCache::CancelAll() {
  absl::MutexLock lock(&mu_);
  stopping_ = true;
  for (auto& [key, e] : entries_) {
    if (Finished(e->status.state)) continue;
    e->cancel = true;
    if (e->status.state == GraphState::kQueued) Transition(*e, GraphState::kCancelled);
  }
}

std::vector<GraphStatus> GraphCache::List() const {
  absl::MutexLock lock(&mu_);
  std::vector<GraphStatus> out;
  for (const auto& [key, e] : entries_) out.push_back(e->status);
  return out;
}

void GraphCache::DropMesh(const std::string& mesh) {
  Notices notices;
  {
    absl::MutexLock lock(&mu_);
    for (auto it = entries_.begin(); it != entries_.end();) {
      if (it->first.mesh != mesh) {
        ++it;
        continue;
      }
      it->second->cancel = true;
      if (it->second->status.state == GraphState::kReady) notices.push_back({it->first, false});
      it = entries_.erase(it);
    }
  }
  Announce(notices);
}

absl::StatusOr<std::shared_ptr<const GeodesicEngine>> GraphCache::Acquire(const GraphKey& key) {
  absl::MutexLock lock(&mu_);
  auto it = entries_.find(key);
  if (it == entries_.end()) {
    ++misses_;
    return absl::FailedPreconditionError(
        absl::StrFormat("%s was never requested: request it first (RequestGraph)", Describe(key)));
  }
  Entry& e = *it->second;
  if (e.status.state == GraphState::kReady) {
    ++hits_;
    Touch(e);
    return e.engine;
  }
  ++misses_;
  switch (e.status.state) {
    case GraphState::kFailed:
      return absl::FailedPreconditionError(
          absl::StrFormat("%s failed: %s", Describe(key), e.status.error));
    case GraphState::kCancelled:
      // At shutdown (CancelAll) another replica, or this one restarted,
      // can answer: unavailable, not the client's to fix.
      if (stopping_) {
        return absl::UnavailableError(
            absl::StrFormat("%s was cancelled: the server is shutting down; retry", Describe(key)));
      }
      return absl::FailedPreconditionError(
          absl::StrFormat("%s was cancelled: request it again", Describe(key)));
    case GraphState::kEvicted:
      // Map it again (it was persisted) and let the client retry.
      e.cancel = false;
      if (Transition(e, GraphState::kQueued)) Enqueue(key);
      break;
    default:
      break;
  }
  return absl::UnavailableError(absl::StrFormat("%s is %s (%.0f%%): retry shortly", Describe(key),
                                                GraphStateName(e.status.state),
                                                100 * e.status.progress));
}

bool GraphCache::FileInUse(const std::string& file_name) const {
  absl::MutexLock lock(&mu_);
  for (const auto& [key, e] : entries_) {
    const GraphState s = e->status.state;
    if (s == GraphState::kFailed || s == GraphState::kCancelled || s == GraphState::kEvicted) {
      continue;
    }
    if (!e->path.empty() && std::filesystem::path(e->path).filename() == file_name) return true;
  }
  return false;
}

uint64_t GraphCache::resident_bytes() const {
  absl::MutexLock lock(&mu_);
  uint64_t total = 0;
  std::set<const ExactLandmarks*> counted;
  for (const auto& [key, e] : entries_) {
    if (e->status.state != GraphState::kReady) continue;
    total += CountedLandmarkBytes(*e, counted) + e->landmarks_pending + e->exact_landmarks_pending +
             (e->status.mapped ? 0 : e->status.bytes);
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

uint64_t GraphCache::scratch_bytes() const {
  absl::MutexLock lock(&mu_);
  uint64_t total = 0;
  for (const auto& [key, e] : entries_) {
    if (e->status.state == GraphState::kReady) total += e->engine->scratch_bytes();
  }
  return total;
}

}  // namespace geodesic::server
