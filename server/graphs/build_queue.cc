// When each queued graph runs: the queue, its two lanes (small builds on
// build_workers, builds estimated past large_build_seconds on one worker of
// their own), the shortest estimate first, the workers that take from it,
// and the wait of an entry whose build another replica holds.
#include <algorithm>
#include <deque>
#include <filesystem>
#include <set>
#include <system_error>
#include <utility>

#include "server/base/log.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {

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

}  // namespace geodesic::server
