// What ready graphs hold, and giving it back: the eviction of the least
// recently used graphs no query holds once the memory limit is passed, the
// gauges of resident, mapped and scratch bytes, and which files in
// --graph-dir a ready graph maps (those the disk budget must leave).
#include <filesystem>
#include <memory>
#include <set>

#include "server/base/log.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {

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
