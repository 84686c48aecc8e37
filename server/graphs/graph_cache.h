// The daemon's graphs: one long-running operation per (mesh, build record)
// that maps the graph from --graph-dir or builds it in the background, and a
// cache of ready graphs under a memory budget.
//
// Each entry is a small state machine (after TensorFlow Serving's
// LoaderHarness): every change of state goes through Transition(), which
// checks a table of legal moves, so a worker, a cancel, an eviction and an
// unload racing for one entry cannot leave it somewhere no rule allows.
//
//   queued -> loading -> ready                 (the file in --graph-dir)
//   queued -> [loading ->] building -> persisting -> ready
//   loading | building | persisting -> failed | cancelled
//   ready -> evicted -> queued                 (mapped again on next use)
//   failed | cancelled -> queued               (requested again)
//
// - Single flight: one operation per key; later requests join it.
// - Immutable, shared, reference-counted: queries hold a
//   shared_ptr<const GeodesicEngine> for their duration, so eviction or a
//   rebuild never pulls a graph from under a running query (hot swap).
// - A worker publishes only into the entry it was started for: an entry
//   unloaded or replaced meanwhile (its mesh registered again) keeps nothing
//   of it.
// - Memory budget: when ready graphs exceed it, the least recently used ones
//   that no query holds are evicted; their files stay, so a later request
//   maps them again instead of rebuilding.
// - Persistence: built graphs are written atomically to --graph-dir; a file
//   that fails validation, or was built with other parameters, is moved
//   aside, reported and rebuilt, never served. A plain graph (no pseudo
//   vertices, not certified) is built into its file (GraphFileDraft): its
//   edges, most of its bytes, take page cache rather than the daemon's
//   memory while it builds, and the file appears whole when committed, or
//   not at all.
// - Admission and lanes: each request carries an estimate of its graph's
//   file bytes and build time (EstimateDggBuild). Admit() refuses, before
//   any work, a graph over --max-graph-bytes or one that cannot fit the
//   memory or disk limit. The queue runs the shortest builds first, and
//   builds estimated to take longer than large_build_seconds run in a lane
//   of their own (one worker beyond build_workers), so a huge build never
//   holds the workers small graphs need.
// - Replicas sharing --graph-dir build each graph once: a build holds an
//   exclusive flock on ".<graph file>.lock"; a replica that finds it held
//   waits queued ("waiting for another replica's build"), polling, and maps
//   the file once it appears, or builds itself if the holder died (the
//   kernel releases a dead process's flock).
// - Disk budget: a graph file whose write would take --graph-dir past
//   --disk-limit (after evicting what may go) is not written, and the
//   graph fails, naming the sizes.
// - Callbacks (on_readiness) always run outside the cache's lock, so they
//   may call back into it.
//
// One class, its members defined by concern in several files of this
// folder:
//   graph_cache.cc         construction, Transition, and the service's calls:
//                          Request, Get, WaitForChange, Cancel, DropMesh,
//                          Acquire (failed | cancelled | evicted -> queued)
//   graph_admission.cc     Admit and Estimate: refusals before any work
//   build_queue.cc         the queue, its lanes and workers, and the wait
//                          for another replica's build
//   graph_run.cc           one operation's run and its moves: queued ->
//                          loading -> building -> persisting -> ready,
//                          failed or cancelled (SetPhase, Publish, Abandon)
//   load_build_persist.cc  the steps that read and write --graph-dir, and the
//                          disk a build takes while it runs
//   graph_landmarks.cc     landmarks and exact landmarks of ready graphs, and
//                          their files
//   eviction.cc            ready -> evicted under the memory limit, the
//                          gauges, the files in use
//   graph_maker.h          the seam that opens, builds and writes graph files
//                          (tests substitute it)
//   replica_lock.h         the build lock replicas share
#ifndef GEODESIC_SERVER_GRAPH_CACHE_H_
#define GEODESIC_SERVER_GRAPH_CACHE_H_

#include <atomic>
#include <chrono>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <thread>
#include <tuple>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/time/time.h"
#include "core/dgg/dgg_build.h"
#include "core/dgg/graph_file.h"
#include "core/query/certified_graph.h"
#include "core/query/geodesic_engine.h"
#include "server/graphs/graph_key.h"
#include "server/graphs/graph_maker.h"
#include "server/meshes/mesh_registry.h"
#include "server/store/disk_budget.h"
#include "server/store/graph_files.h"

namespace geodesic::server {

class GraphCache {
 public:
  struct Options {
    std::string graph_dir;  // empty: graphs are not persisted
    // Bytes of ready graphs, their landmarks and query scratch, and
    // resident_bytes_outside; 0: no limit.
    uint64_t memory_limit = 0;
    // Memory the limit covers that the cache cannot evict (the registered
    // meshes): ready graphs make room for it.
    std::function<uint64_t()> resident_bytes_outside;
    // Graphs built at once, beside the one lane for builds estimated to
    // take longer than large_build_seconds.
    int build_workers = 1;
    double large_build_seconds = 60;
    // RequestGraph refuses graphs estimated larger (0: no limit).
    uint64_t max_graph_bytes = 0;
    // --disk-limit's accounting for graph files written; null: none.
    DiskBudget* disk = nullptr;
    // How often a replica waiting for another's build looks again.
    absl::Duration replica_poll = absl::Milliseconds(500);
    int build_threads = 0;  // threads per build (0: all cores)
    // DggBuildOptions::pseudo_vertex_limit.
    double pseudo_vertex_limit = 0;
    // Candidate edges a build keeps in memory before spilling them to an
    // unlinked file in graph_dir (DggBuildOptions); 0: no limit.
    uint64_t build_memory_limit = 0;
    // Exact landmarks a ready graph computes once it is asked for exact
    // answers (GeodesicEngine::PrepareExactLandmarks); 0: none.
    int exact_landmarks = 0;
    // Called whenever a graph becomes ready or stops being, outside the lock.
    std::function<void(const GraphKey&, bool ready)> on_readiness;
    // Called with a graph's file when it is mapped or written (for the
    // directory's least-recently-used order).
    std::function<void(const std::string& path)> on_file_used;
    std::shared_ptr<GraphMaker> maker;  // null: the real build and files
  };
  explicit GraphCache(Options options);
  ~GraphCache();

  // Whether the graph of `mesh` with `params` (certified for `max_error`
  // when it is not 0) may be requested, and its estimate: RESOURCE_EXHAUSTED, naming the estimate
  // and the limit, when its estimated bytes pass max_graph_bytes, or its least possible bytes the
  // memory limit or the disk limit (its real bytes, for both, once this cache has built it). A
  // graph whose file is in
  // --graph-dir needs no build: only the memory limit applies.
  absl::StatusOr<DggBuildEstimate> Admit(const RegisteredMesh& mesh, const DggParams& params,
                                         double max_error = 0) const;
  // EstimateDggBuild, seconds on this cache's build threads.
  DggBuildEstimate Estimate(const RegisteredMesh& mesh, const DggParams& params) const;

  // Starts (or joins) the operation that makes the graph of `mesh` with
  // `params`, certified for `max_error` unless it is 0 (its params'
  // epsilon must then be CertifiedKeyEpsilon(max_error)). A failed,
  // cancelled or evicted graph starts again.
  GraphStatus Request(std::shared_ptr<const RegisteredMesh> mesh, const DggParams& params,
                      double max_error = 0);
  // NOT_FOUND if the graph was never requested.
  absl::StatusOr<GraphStatus> Get(const GraphKey& key) const;
  // Waits until the status differs from `version` or the deadline passes.
  absl::StatusOr<GraphStatus> WaitForChange(const GraphKey& key, uint64_t version,
                                            absl::Time deadline) const;
  absl::StatusOr<GraphStatus> Cancel(const GraphKey& key);
  // Shutdown: cancels every queued and running operation, and the workers
  // take no more, so that queries waiting for a graph are answered at once
  // and no build outlives the drain.
  void CancelAll();
  std::vector<GraphStatus> List() const;
  uint64_t memory_limit() const { return options_.memory_limit; }
  // Drops every graph of a mesh (unload); their operations are cancelled and
  // publish nothing.
  void DropMesh(const std::string& mesh);

  // The engine for queries: UNAVAILABLE while it is being made (an evicted
  // graph is mapped again), FAILED_PRECONDITION if never requested, and the
  // build's error if it failed.
  absl::StatusOr<std::shared_ptr<const GeodesicEngine>> Acquire(const GraphKey& key);
  // Tells the cache that a graph answers exact queries: the first time, a
  // ready graph gets its exact landmarks on a build worker (once no build
  // waits), counted in its landmark bytes. Exact answers before then prune
  // by the straight line alone, as exact, only slower.
  void WantExactLandmarks(const GraphKey& key);

  // The lock a replica holds while it builds the graph of `graph_path`.
  static std::string BuildLockFile(const std::string& graph_path);
  // Removes the build locks in `dir` that builders killed mid-build left
  // (none holds them), those older than `min_age`; returns their names.
  static std::vector<std::string> RemoveStaleBuildLocks(const std::string& dir,
                                                        std::chrono::seconds min_age);

  // The file a graph has (or would have) in --graph-dir; empty without one.
  std::string GraphPath(uint64_t mesh_fingerprint, const DggParams& params,
                        double max_error = 0) const;
  // Whether a ready graph is mapped from `file_name` (a name in --graph-dir):
  // such a file is in use and must stay.
  bool FileInUse(const std::string& file_name) const;

  uint64_t resident_bytes() const;
  uint64_t mapped_bytes() const;
  // Query scratch held by the engines of ready graphs.
  uint64_t scratch_bytes() const;
  uint64_t hits() const { return hits_; }
  uint64_t misses() const { return misses_; }
  uint64_t evictions() const { return evictions_; }
  int builds_running() const { return builds_running_; }
  // Builds this cache started (not files it mapped).
  uint64_t builds_started() const { return builds_started_; }

 private:
  struct Entry {
    GraphStatus status;
    std::shared_ptr<const RegisteredMesh> mesh;
    std::shared_ptr<const GeodesicEngine> engine;
    std::string path;  // in --graph-dir, or empty
    std::atomic<bool> cancel{false};
    absl::Time last_used;
    // Landmarks being computed, counted from the start: on a large graph
    // they fill in for minutes, and other graphs make room for them first.
    uint64_t landmarks_pending = 0;
    // Exact landmarks: asked for once, and their bytes while computed.
    bool exact_landmarks_asked = false;
    uint64_t exact_landmarks_pending = 0;
    // The exact landmarks status.landmark_bytes counts: other graphs of the
    // mesh may share them, and the memory limit counts them once.
    const ExactLandmarks* counted_exact = nullptr;
    // Scheduling: the large lane's, and not before (a replica's build
    // being waited for).
    bool large = false;
    absl::Time not_before = absl::InfinitePast();
  };
  // A readiness change to announce once the lock is released.
  struct Notice {
    GraphKey key;
    bool ready;
  };
  using Notices = std::vector<Notice>;

  // The one way an entry changes state. An illegal move is a bug: it is
  // logged and refused, and the entry keeps its state.
  bool Transition(Entry& e, GraphState to) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Whether `e` is still the entry for `key` (not unloaded or replaced).
  bool Current(const GraphKey& key, const Entry& e) const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Enqueue(const GraphKey& key) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // The queued graph a worker of the lane runs next (shortest estimate
  // first); false, with the time one becomes due in `wake`, if none is.
  bool TakeNext(bool large_lane, GraphKey* key, absl::Time* wake)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Worker(bool large_lane);
  void Run(const GraphKey& key);
  // The steps of Run, each outside the lock except where it changes state.
  // A certified graph's certificate comes with it through `certificate`.
  std::shared_ptr<const DggGraph> Load(const GraphKey& key, Entry& e, std::string* note,
                                       std::optional<GraphCertificate>* certificate);
  // A plain graph with a file to go to is built into `draft`, which the
  // build leaves for Persist to commit; dropped, it leaves no file.
  absl::StatusOr<std::shared_ptr<const DggGraph>> Build(
      const GraphKey& key, Entry& e, std::optional<GraphFileDraft>* draft,
      std::optional<GraphCertificate>* certificate);
  // The options of the entry's build, progress reports and cancel included.
  DggBuildOptions BuildOptions(const GraphKey& key, Entry& e);
  absl::StatusOr<std::shared_ptr<const DggGraph>> BuildCertified(
      const GraphKey& key, Entry& e, const DggBuildOptions& options,
      std::optional<GraphCertificate>* certificate);
  // The written file's mapping; RESOURCE_EXHAUSTED if the disk budget
  // refused the write. A graph built into `draft` fails if its file cannot
  // be committed; one built in memory is then kept in memory. A certificate
  // is written beside the file.
  absl::StatusOr<std::shared_ptr<const DggGraph>> Persist(
      const GraphKey& key, Entry& e, std::shared_ptr<const DggGraph> graph,
      std::optional<GraphFileDraft> draft, const std::optional<GraphCertificate>& certificate,
      std::string* note);
  // Makes `graph` the entry's, if the entry is still current and not
  // cancelled; returns the engine published, or null.
  std::shared_ptr<const GeodesicEngine> Publish(const GraphKey& key,
                                                const std::shared_ptr<Entry>& e,
                                                std::shared_ptr<const DggGraph> graph,
                                                std::optional<GraphCertificate> certificate,
                                                bool from_file, std::string note, double seconds);
  // Another replica holds the graph's build lock: the entry waits, queued,
  // to look again after Options::replica_poll (or ends if cancelled).
  void WaitForReplica(const GraphKey& key, const std::shared_ptr<Entry>& e);
  // Computes the landmarks of a published engine, counting their bytes
  // against the memory limit from the start.
  void AddLandmarks(const GraphKey& key, const std::shared_ptr<Entry>& e,
                    const std::shared_ptr<const GeodesicEngine>& engine);
  // Runs on a worker: the exact landmarks WantExactLandmarks asked for,
  // counted the same way.
  void AddExactLandmarks(const GraphKey& key);
  // The exact landmarks of `count` fields another ready graph of e's mesh
  // holds (null if none): they are the mesh's, whatever the graph.
  std::shared_ptr<const ExactLandmarks> SiblingExactLandmarks(const GraphKey& key, const Entry& e,
                                                              int count) const
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // What a ready entry's landmarks add to the resident total: exact
  // landmarks shared by several graphs of a mesh count once, with the
  // first entry that has them in `counted`.
  static uint64_t CountedLandmarkBytes(const Entry& e, std::set<const ExactLandmarks*>& counted);
  // Reads the landmarks kept beside the graph's file (or, when it has none,
  // beside another graph of its mesh, then kept beside its own too), when
  // they are this mesh's and count's, into `engine`; false to compute them.
  bool RestoreExactLandmarks(const GraphKey& key, const Entry& e, const GeodesicEngine& engine,
                             int count);
  // Keeps the engine's landmarks beside the graph's file for a restart,
  // within the disk budget; logged and skipped when they do not fit.
  void SaveExactLandmarks(const GraphKey& key, const Entry& e, const GeodesicEngine& engine);
  // Ends the entry's operation in failed or cancelled.
  void Abandon(const GraphKey& key, const std::shared_ptr<Entry>& e, const absl::Status& why);
  // Moves `e` to a phase of its current state (progress reports).
  bool SetPhase(const GraphKey& key, const std::shared_ptr<Entry>& e, GraphState state,
                std::string phase, double progress);
  void Touch(Entry& e) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Evicts the least recently used graphs no query holds until what is
  // resident fits the memory limit; false if it still does not.
  bool EvictOverBudget(const GraphKey& keep, Notices& notices) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  void Announce(const Notices& notices) const ABSL_LOCKS_EXCLUDED(mu_);

  Options options_;
  mutable absl::Mutex mu_;
  std::map<GraphKey, std::shared_ptr<Entry>> entries_ ABSL_GUARDED_BY(mu_);
  std::deque<GraphKey> queue_ ABSL_GUARDED_BY(mu_);
  std::deque<GraphKey> exact_landmark_jobs_ ABSL_GUARDED_BY(mu_);
  uint64_t queue_changes_ ABSL_GUARDED_BY(mu_) = 0;
  bool stopping_ ABSL_GUARDED_BY(mu_) = false;
  std::vector<std::thread> workers_;
  std::atomic<uint64_t> hits_{0}, misses_{0}, evictions_{0};
  // What builds of a graph taught about its bytes, by mesh fingerprint and
  // build record: once a graph was refused for its real size, asking again
  // is refused at once rather than built again to the same end.
  struct KnownBytes {
    // The graph's file (or, for a build stopped when its edges found no room
    // on disk, those edges' bytes: at least the file's); 0: not known.
    uint64_t file = 0;
    // The spill file of --build-memory-limit that a build stopped for asked
    // for (0: none): disk, not memory, and refused at once only while the
    // disk limit could never hold it.
    uint64_t spill = 0;
  };
  // The mesh by its content, not its name: the same surface registered again
  // under another name is the same graph.
  using KnownBytesKey = std::tuple<uint64_t, DggParams, double>;
  static KnownBytesKey KnownBytesOf(const RegisteredMesh& mesh, const DggParams& params,
                                    double max_error) {
    return {mesh.fingerprint, params, max_error};
  }
  std::map<KnownBytesKey, KnownBytes> known_bytes_ ABSL_GUARDED_BY(mu_);
  std::atomic<int> builds_running_{0};
  std::atomic<uint64_t> builds_started_{0};
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_GRAPH_CACHE_H_
