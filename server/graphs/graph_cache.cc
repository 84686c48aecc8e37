// The cache's front: construction, the one door of every state change
// (Transition), and the calls the service makes on entries: request, look,
// wait, cancel, drop, acquire. What runs an entry's operation is in
// graph_run.cc and load_build_persist.cc; the queue that starts it in
// build_queue.cc (graph_cache.h lists every file).
#include "server/graphs/graph_cache.h"

#include <algorithm>
#include <filesystem>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "server/base/log.h"

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
  // CancelGraph returns before the worker stops (it notices at its next
  // progress step): the graph will not be ready, so a query whose deadline
  // comes first is told so, as once it is cancelled, rather than
  // UNAVAILABLE with a hint to retry.
  if (e.cancel && !stopping_ && !Finished(e.status.state)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s is being cancelled: request it again", Describe(key)));
  }
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

}  // namespace geodesic::server
