// Landmarks of ready graphs: the default ones computed once a graph is
// published, and the exact ones a worker computes when a graph is first asked
// for exact answers, shared between graphs of one mesh, kept beside the
// graph's file for a restart. Their bytes count against the memory limit
// from the moment they start, since on a large graph they fill in for
// minutes.
#include <chrono>
#include <filesystem>
#include <set>
#include <string>
#include <system_error>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/query/exact_landmarks_file.h"
#include "core/query/landmarks.h"
#include "server/base/log.h"
#include "server/graphs/graph_cache.h"

namespace geodesic::server {

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

}  // namespace geodesic::server
