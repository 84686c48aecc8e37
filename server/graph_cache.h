// The daemon's graphs: one long-running operation per (mesh, epsilon) that
// maps the graph from --graph-dir or builds it in the background, and a cache
// of ready graphs under a memory budget.
//
// - Single flight: one build or load per key; later requests join it.
// - Immutable, shared, reference-counted: queries hold a
//   shared_ptr<const GeodesicEngine> for their duration, so eviction or a
//   rebuild never pulls a graph from under a running query (hot swap).
// - Memory budget: when ready graphs exceed it, the least recently used ones
//   that no query holds are evicted; their files stay, so a later request
//   maps them again instead of rebuilding.
// - Persistence: built graphs are written atomically to --graph-dir; a file
//   that fails validation is moved aside, reported and rebuilt, never served.
#ifndef GEODESIC_SERVER_GRAPH_CACHE_H_
#define GEODESIC_SERVER_GRAPH_CACHE_H_

#include <atomic>
#include <condition_variable>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "core/queries.h"
#include "server/mesh_registry.h"

namespace geodesic::server {

enum class GraphState { kQueued, kBuilding, kLoading, kReady, kFailed, kCancelled, kEvicted };
const char* GraphStateName(GraphState s);

struct GraphStatus {
  std::string mesh;
  double epsilon = 0;
  GraphState state = GraphState::kQueued;
  std::string phase;
  double progress = 0;
  std::string error;
  uint64_t bytes = 0;  // the graph's arrays, resident or mapped
  // Resident memory for point-to-point bounds (core/landmarks.h), computed in
  // the background once the graph is ready.
  uint64_t landmark_bytes = 0;
  bool mapped = false;
  bool from_file = false;
  uint64_t nodes = 0;
  uint64_t edges = 0;
  double build_seconds = 0;
  int64_t last_used_unix_ms = 0;
  uint64_t version = 0;  // increases on every change
};

class GraphCache {
 public:
  struct Options {
    std::string graph_dir;      // empty: graphs are not persisted
    uint64_t memory_limit = 0;  // bytes of ready graphs; 0: no limit
    int build_workers = 1;      // graphs built at once
    int build_threads = 0;      // threads per build (0: all cores)
    bool exact_fans = false;    // DggBuildOptions::exact_fans
    // Called with (mesh, epsilon, ready) whenever a graph becomes ready or stops being.
    std::function<void(const std::string&, double, bool)> on_readiness;
  };
  explicit GraphCache(Options options);
  ~GraphCache();

  GraphStatus Request(std::shared_ptr<const RegisteredMesh> mesh, double epsilon,
                      bool pseudo_vertices);
  absl::StatusOr<GraphStatus> Get(const std::string& mesh, double epsilon) const;
  // Waits until the status differs from `version` or the deadline passes.
  absl::StatusOr<GraphStatus> WaitForChange(const std::string& mesh, double epsilon,
                                            uint64_t version, absl::Time deadline) const;
  absl::StatusOr<GraphStatus> Cancel(const std::string& mesh, double epsilon);
  std::vector<GraphStatus> List() const;
  uint64_t memory_limit() const { return options_.memory_limit; }
  // Drops every graph of a mesh (unload).
  void DropMesh(const std::string& mesh);

  // The engine for queries: UNAVAILABLE while building or loading (an
  // evicted graph is mapped again), FAILED_PRECONDITION if never requested,
  // and the build's error if it failed.
  absl::StatusOr<std::shared_ptr<const GeodesicEngine>> Acquire(const std::string& mesh,
                                                                double epsilon);

  uint64_t resident_bytes() const;
  uint64_t mapped_bytes() const;
  uint64_t hits() const { return hits_; }
  uint64_t misses() const { return misses_; }
  uint64_t evictions() const { return evictions_; }
  int builds_running() const { return builds_running_; }

  std::string GraphPath(const RegisteredMesh& mesh, double epsilon, bool pseudo) const;

 private:
  struct Entry {
    GraphStatus status;
    std::shared_ptr<const RegisteredMesh> mesh;
    bool pseudo_vertices = false;
    std::shared_ptr<const GeodesicEngine> engine;
    std::atomic<bool> cancel{false};
    absl::Time last_used;
  };
  using Key = std::pair<std::string, double>;

  void Schedule(const Key& key) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Run(const Key& key);
  void Touch(Entry& e) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Bump(Entry& e) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void EvictOverBudget(const Key& keep) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Worker();

  Options options_;
  mutable absl::Mutex mu_;
  std::map<Key, std::shared_ptr<Entry>> entries_ ABSL_GUARDED_BY(mu_);
  std::deque<Key> queue_ ABSL_GUARDED_BY(mu_);
  bool stopping_ ABSL_GUARDED_BY(mu_) = false;
  std::vector<std::thread> workers_;
  std::atomic<uint64_t> hits_{0}, misses_{0}, evictions_{0};
  std::atomic<int> builds_running_{0};
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRAPH_CACHE_H_
