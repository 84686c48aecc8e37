// The graph cache's state machine, driven through every state with a maker
// that holds each step (load, build, persist) until the test lets it go.
#include "server/graphs/graph_cache.h"

#include <fcntl.h>
#include <sys/file.h>
#include <unistd.h>

#include <atomic>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <set>
#include <vector>

#include "absl/strings/str_cat.h"
#include "absl/synchronization/notification.h"
#include "core/base/atomic_file.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/exact_landmarks_file.h"
#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "server/api/convert.h"

namespace geodesic::server {

// Trails of states print by name.
void PrintTo(GraphState s, std::ostream* os) { *os << GraphStateName(s); }

namespace {

namespace fs = std::filesystem;
using ::testing::HasSubstr;

// A flat n x n grid of unit squares, two triangles each.
std::shared_ptr<const RegisteredMesh> GridMesh(const std::string& name, int n, double z = 0) {
  TriangleSoup soup;
  for (int y = 0; y <= n; ++y) {
    for (int x = 0; x <= n; ++x) soup.positions.push_back({double(x), double(y), z * x * y});
  }
  auto at = [&](int x, int y) { return static_cast<VertexId>(y * (n + 1) + x); };
  for (int y = 0; y < n; ++y) {
    for (int x = 0; x < n; ++x) {
      soup.triangles.push_back({at(x, y), at(x + 1, y), at(x + 1, y + 1)});
      soup.triangles.push_back({at(x, y), at(x + 1, y + 1), at(x, y + 1)});
    }
  }
  auto m = std::make_shared<RegisteredMesh>();
  m->name = name;
  m->mesh = std::make_shared<const Mesh>(*Mesh::Build(std::move(soup), name));
  m->fingerprint = MeshFingerprint(*m->mesh);
  return m;
}

DggParams Eps(double eps, bool pseudo = false) {
  DggParams p;
  p.epsilon = eps;
  p.pseudo_vertices = pseudo;
  return p;
}

// The real steps, each of which can be held at its start until released,
// and made to fail.
class HeldMaker : public GraphMaker {
 public:
  enum Step { kOpen, kBuild, kWrite, kSteps };

  void Hold(Step s) {
    absl::MutexLock lock(&mu_);
    gates_[s] = std::make_shared<Gate>();
  }
  // Waits until the step is reached; false (and the test fails) if it is
  // not within 30 s, so that a step never taken cannot hang the test.
  bool AwaitReached(Step s) {
    std::shared_ptr<Gate> gate = GateOf(s);
    if (gate && gate->reached.WaitForNotificationWithTimeout(absl::Seconds(30))) return true;
    ADD_FAILURE() << "step " << s << " was not reached";
    return false;
  }
  // Lets a held step go on (or pass unheld, if not reached yet).
  void Release(Step s) {
    std::shared_ptr<Gate> gate = GateOf(s);
    if (gate && !gate->release.HasBeenNotified()) gate->release.Notify();
  }
  // A test that stops early must not leave a worker held for the cache's
  // destructor to wait on.
  void ReleaseAll() {
    for (int s = 0; s < kSteps; ++s) Release(Step(s));
  }
  void FailBuild(bool fail) { fail_build_ = fail; }
  // Writes and commits of drafts fail, after their step is passed.
  void FailWrite(bool fail) { fail_write_ = fail; }
  // Called after each real build with its options and result, on the
  // build's worker.
  using BuiltHook = std::function<void(const DggBuildOptions&,
                                       const absl::StatusOr<std::shared_ptr<const DggGraph>>&)>;
  void OnBuilt(BuiltHook hook) {
    absl::MutexLock lock(&mu_);
    on_built_ = std::move(hook);
  }
  // Called before each real build with its options, on the build's worker.
  void BeforeBuild(std::function<void(const DggBuildOptions&)> hook) {
    absl::MutexLock lock(&mu_);
    before_build_ = std::move(hook);
  }
  int calls(Step s) const { return calls_[s]; }

  absl::StatusOr<std::shared_ptr<const DggGraph>> Open(const std::string& path, const Mesh& mesh,
                                                       const DggParams& params,
                                                       GraphFile::Check check) override {
    // Only the first open of a file (loading) is held, not the reopening
    // of a freshly written one.
    if (check == GraphFile::Check::kFull) Pass(kOpen);
    return GraphMaker::Open(path, mesh, params, check);
  }
  absl::StatusOr<std::shared_ptr<const DggGraph>> Build(const Mesh& mesh,
                                                        const DggBuildOptions& options) override {
    Pass(kBuild);
    if (fail_build_) return absl::InternalError("the build broke on purpose");
    BuiltHook hook;
    std::function<void(const DggBuildOptions&)> before;
    {
      absl::MutexLock lock(&mu_);
      hook = on_built_;
      before = before_build_;
    }
    if (before) before(options);
    auto built = GraphMaker::Build(mesh, options);
    if (hook) hook(options, built);
    return built;
  }
  absl::Status Write(const DggGraph& graph, const std::string& path) override {
    Pass(kWrite);
    if (fail_write_) return absl::InternalError("the write broke on purpose");
    return GraphMaker::Write(graph, path);
  }
  // Committing a graph built into its file is the same step.
  absl::Status Finish(GraphFileDraft draft, const DggGraph& graph) override {
    Pass(kWrite);
    if (fail_write_) return absl::InternalError("the write broke on purpose");
    return GraphMaker::Finish(std::move(draft), graph);
  }
  // A certified graph's build and file take the same steps.
  absl::StatusOr<CertifiedGraph> BuildCertified(std::shared_ptr<const Mesh> mesh, double max_error,
                                                const CertifyOptions& options) override {
    Pass(kBuild);
    if (fail_build_) {
      return absl::FailedPreconditionError("no graph kept the bound, on purpose");
    }
    return GraphMaker::BuildCertified(std::move(mesh), max_error, options);
  }
  absl::StatusOr<Certified> OpenCertified(const std::string& path, const Mesh& mesh,
                                          const DggParams& params, double max_error,
                                          GraphFile::Check check) override {
    if (check == GraphFile::Check::kFull) Pass(kOpen);
    return GraphMaker::OpenCertified(path, mesh, params, max_error, check);
  }

 private:
  struct Gate {
    absl::Notification reached, release;
    bool taken = false;  // only the first call to pass is held
  };
  std::shared_ptr<Gate> GateOf(Step s) {
    absl::MutexLock lock(&mu_);
    return gates_[s];
  }
  void Pass(Step s) {
    ++calls_[s];
    std::shared_ptr<Gate> gate;
    {
      absl::MutexLock lock(&mu_);
      if (gates_[s] && !gates_[s]->taken) {
        gate = gates_[s];
        gate->taken = true;
      }
    }
    if (!gate) return;
    gate->reached.Notify();
    gate->release.WaitForNotification();
    absl::MutexLock lock(&mu_);
    if (gates_[s] == gate) gates_[s].reset();
  }
  absl::Mutex mu_;
  std::shared_ptr<Gate> gates_[kSteps] ABSL_GUARDED_BY(mu_);
  std::atomic<int> calls_[kSteps] = {};
  std::atomic<bool> fail_build_{false};
  std::atomic<bool> fail_write_{false};
  BuiltHook on_built_ ABSL_GUARDED_BY(mu_);
  std::function<void(const DggBuildOptions&)> before_build_ ABSL_GUARDED_BY(mu_);
};

class GraphCacheTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() /
           absl::StrCat("graph_cache_test.", getpid(), ".",
                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    maker_ = std::make_shared<HeldMaker>();
  }
  void TearDown() override {
    maker_->ReleaseAll();
    cache_.reset();
    fs::remove_all(dir_);
  }
  GraphCache& Cache(bool persist = true, uint64_t memory_limit = 0, DiskBudget* disk = nullptr) {
    GraphCache::Options options;
    if (persist) options.graph_dir = dir_;
    options.memory_limit = memory_limit;
    options.disk = disk;
    options.resident_bytes_outside = [this] { return outside_bytes_.load(); };
    options.build_threads = 1;
    options.exact_landmarks = exact_landmarks_;
    options.build_memory_limit = build_memory_limit_;
    options.maker = maker_;
    // The callback asks the cache that calls it (not cache_, which the test
    // may be replacing meanwhile).
    auto self = std::make_shared<GraphCache*>(nullptr);
    options.on_readiness = [this, self](const GraphKey& key, bool ready) {
      // Outside the lock: calling back into the cache must not deadlock.
      auto status = (*self)->Get(key);
      absl::MutexLock lock(&notices_mu_);
      notices_.push_back(absl::StrCat(key.mesh, "@", key.params.epsilon,
                                      key.params.pseudo_vertices ? "+pseudo" : "",
                                      ready ? " ready" : " gone", status.ok() ? "" : " (dropped)"));
    };
    cache_.reset();  // one cache on the directory at a time, as daemons
    cache_ = std::make_unique<GraphCache>(options);
    *self = cache_.get();
    return *cache_;
  }
  // Waits until the graph's state is `want` (or fails the test after 30 s).
  GraphStatus WaitFor(const GraphKey& key, GraphState want) {
    const absl::Time deadline = absl::Now() + absl::Seconds(30);
    auto s = cache_->Get(key);
    while (s.ok() && s->state != want && absl::Now() < deadline) {
      s = cache_->WaitForChange(key, s->version, deadline);
    }
    EXPECT_TRUE(s.ok()) << s.status();
    EXPECT_EQ(s.ok() ? s->state : GraphState::kFailed, want)
        << GraphStateName(s.ok() ? s->state : GraphState::kFailed);
    return s.ok() ? *s : GraphStatus{};
  }
  // A new cache on an empty directory, with a maker of its own.
  GraphCache& Fresh(bool persist = true, uint64_t memory_limit = 0, DiskBudget* disk = nullptr) {
    if (maker_) maker_->ReleaseAll();
    cache_.reset();
    fs::remove_all(dir_);
    maker_ = std::make_shared<HeldMaker>();
    return Cache(persist, memory_limit, disk);
  }
  // Whether, within 30 s, `cache`'s status of the graph comes to count both
  // kinds of `engine`'s landmarks: its own, and exact ones of `exact_bytes`
  // (0 for none). Both are made in the background.
  static bool LandmarksCounted(GraphCache& cache, const GraphKey& key, const GeodesicEngine& engine,
                               uint64_t exact_bytes) {
    const absl::Time deadline = absl::Now() + absl::Seconds(30);
    auto s = cache.Get(key);
    auto counted = [&] {
      return s.ok() && engine.landmark_bytes() > 0 &&
             s->landmark_bytes == engine.landmark_bytes() + exact_bytes;
    };
    while (!counted() && absl::Now() < deadline) {
      s = cache.WaitForChange(key, s->version, std::min(deadline, absl::Now() + absl::Seconds(1)));
    }
    return counted();
  }
  // The state the graph comes to rest in (ready, failed, cancelled or
  // evicted: no worker holds it), or the last seen after 30 s.
  GraphState Settle(const GraphKey& key) {
    const absl::Time deadline = absl::Now() + absl::Seconds(30);
    auto s = cache_->Get(key);
    auto resting = [](GraphState g) {
      return g == GraphState::kReady || g == GraphState::kFailed || g == GraphState::kCancelled ||
             g == GraphState::kEvicted;
    };
    while (s.ok() && !resting(s->state) && absl::Now() < deadline) {
      s = cache_->WaitForChange(key, s->version, deadline);
    }
    EXPECT_TRUE(s.ok()) << s.status();
    EXPECT_TRUE(s.ok() && resting(s->state))
        << "still " << (s.ok() ? GraphStateName(s->state) : "gone") << " after 30 s";
    return s.ok() ? s->state : GraphState::kFailed;
  }
  // Requests the graph and follows it: each step in `held` is held in turn
  // and the graph's state noted there, `at_last` runs while the last one
  // is held, and the state it comes to rest in ends the trail. Holding
  // every step the graph takes makes every state it passes through seen.
  std::vector<GraphState> Walk(std::shared_ptr<const RegisteredMesh> mesh, const GraphKey& key,
                               std::vector<HeldMaker::Step> held,
                               const std::function<void()>& at_last = {}) {
    for (HeldMaker::Step s : held) maker_->Hold(s);
    // Request's answer, not a later look: the worker may have moved on.
    std::vector<GraphState> trail = {cache_->Request(mesh, key.params).state};
    for (size_t i = 0; i < held.size(); ++i) {
      if (!maker_->AwaitReached(held[i])) {
        maker_->ReleaseAll();
        return trail;
      }
      trail.push_back(cache_->Get(key)->state);
      if (i + 1 == held.size() && at_last) at_last();
      maker_->Release(held[i]);
    }
    trail.push_back(Settle(key));
    return trail;
  }

  // The names in the graph directory.
  std::set<std::string> Files() {
    std::set<std::string> names;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(dir_, ec)) {
      names.insert(entry.path().filename().string());
    }
    return names;
  }
  // Those of them that are AtomicFileWriter temporaries (drafts included).
  std::set<std::string> Temporaries() {
    std::set<std::string> names;
    for (const std::string& name : Files()) {
      if (IsAtomicTemporaryName(name)) names.insert(name);
    }
    return names;
  }

  std::vector<std::string> Notices() {
    absl::MutexLock lock(&notices_mu_);
    return notices_;
  }
  // Readiness is announced just after the state changes: waits for it.
  bool Announced(const std::string& notice) {
    absl::MutexLock lock(&notices_mu_);
    auto seen = [&]() ABSL_EXCLUSIVE_LOCKS_REQUIRED(notices_mu_) {
      return std::find(notices_.begin(), notices_.end(), notice) != notices_.end();
    };
    return notices_mu_.AwaitWithTimeout(absl::Condition(&seen), absl::Seconds(30));
  }

  fs::path dir_;
  std::shared_ptr<HeldMaker> maker_;
  std::unique_ptr<GraphCache> cache_;
  std::atomic<uint64_t> outside_bytes_{0};  // "meshes" the limit covers
  int exact_landmarks_ = 0;                 // for the next Cache()
  uint64_t build_memory_limit_ = 0;         // for the next Cache()
  absl::Mutex notices_mu_;
  std::vector<std::string> notices_;
};

TEST_F(GraphCacheTest, BuildsPersistsAndARestartLoadsTheFile) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  EXPECT_EQ(cache.Request(mesh, key.params).state, GraphState::kQueued);
  const GraphStatus ready = WaitFor(key, GraphState::kReady);
  EXPECT_FALSE(ready.from_file);
  EXPECT_TRUE(ready.mapped);
  EXPECT_EQ(ready.params, key.params);
  EXPECT_TRUE(fs::exists(cache.GraphPath(mesh->fingerprint, key.params)));
  EXPECT_TRUE(cache.FileInUse(fs::path(cache.GraphPath(mesh->fingerprint, key.params)).filename()));
  ASSERT_TRUE(cache.Acquire(key).ok());
  EXPECT_EQ(cache.hits(), 1u);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);

  // A new cache on the same directory maps the file instead of building.
  GraphCache& again = Cache();
  again.Request(mesh, key.params);
  EXPECT_TRUE(WaitFor(key, GraphState::kReady).from_file);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
  EXPECT_TRUE(Announced("grid@0.05 ready")) << ::testing::PrintToString(Notices());
}

TEST_F(GraphCacheTest, PseudoAndPlainGraphsAreDifferentEntries) {
  auto mesh = GridMesh("grid", 5, 0.1);
  GraphCache& cache = Cache(/*persist=*/false);
  cache.Request(mesh, Eps(0.1));
  cache.Request(mesh, Eps(0.1, /*pseudo=*/true));
  WaitFor({"grid", Eps(0.1)}, GraphState::kReady);
  const GraphStatus pseudo = WaitFor({"grid", Eps(0.1, true)}, GraphState::kReady);
  EXPECT_TRUE(pseudo.params.pseudo_vertices);
  EXPECT_EQ(cache.List().size(), 2u);
  auto plain = cache.Acquire({"grid", Eps(0.1)});
  auto with_pseudo = cache.Acquire({"grid", Eps(0.1, true)});
  ASSERT_TRUE(plain.ok() && with_pseudo.ok());
  EXPECT_FALSE((*plain)->graph().params().pseudo_vertices);
  EXPECT_TRUE((*with_pseudo)->graph().params().pseudo_vertices);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 2);
}

TEST_F(GraphCacheTest, ACertifiedGraphIsItsOwnWithACertificateThatARestartReadsBack) {
  auto mesh = GridMesh("grid", 6, 0.1);
  const double bound = 0.05;
  const DggParams params = Eps(CertifiedKeyEpsilon(bound));
  const GraphKey certified{"grid", params, bound};
  const GraphKey plain{"grid", params};  // the plain graph of the first build's epsilon
  GraphCache& cache = Cache();
  cache.Request(mesh, plain.params);
  EXPECT_EQ(cache.Request(mesh, params, bound).max_error, bound);
  const GraphStatus plain_ready = WaitFor(plain, GraphState::kReady);
  const GraphStatus ready = WaitFor(certified, GraphState::kReady);
  EXPECT_FALSE(plain_ready.certificate.has_value());
  EXPECT_EQ(plain_ready.max_error, 0);
  ASSERT_TRUE(ready.certificate.has_value());
  const GraphCertificate& c = *ready.certificate;
  EXPECT_TRUE(c.sound);
  EXPECT_EQ(c.max_error_bound, bound);
  EXPECT_LE(c.measured_max_error, bound);
  EXPECT_LT(c.epsilon, bound);
  EXPECT_GT(c.sources, 0u);
  EXPECT_GE(c.builds, 1u);
  EXPECT_EQ(ready.epsilon, c.epsilon);
  EXPECT_EQ(ready.params.epsilon, c.epsilon);
  EXPECT_EQ(ready.max_error, bound);
  EXPECT_EQ(cache.List().size(), 2u);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 2);
  auto engine = cache.Acquire(certified);
  ASSERT_TRUE(engine.ok()) << engine.status();
  EXPECT_EQ((*engine)->graph().params().epsilon, c.epsilon);

  // Its file is named by the bound, beside its certificate.
  const std::string path = cache.GraphPath(mesh->fingerprint, params, bound);
  EXPECT_THAT(path, HasSubstr("-cert0.05-"));
  EXPECT_NE(path, cache.GraphPath(mesh->fingerprint, params));
  EXPECT_TRUE(fs::exists(path));
  EXPECT_TRUE(fs::exists(path + ".certificate.json"));

  // A restart maps it with the same certificate, without building.
  GraphCache& again = Cache();
  again.Request(mesh, params, bound);
  const GraphStatus mapped = WaitFor(certified, GraphState::kReady);
  EXPECT_TRUE(mapped.from_file);
  ASSERT_TRUE(mapped.certificate.has_value());
  EXPECT_EQ(mapped.certificate->measured_max_error, c.measured_max_error);
  EXPECT_EQ(mapped.certificate->measured_mean_error, c.measured_mean_error);
  EXPECT_EQ(mapped.certificate->epsilon, c.epsilon);
  EXPECT_EQ(mapped.certificate->sources, c.sources);
  EXPECT_EQ(mapped.certificate->seed, c.seed);
  EXPECT_EQ(mapped.epsilon, c.epsilon);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 2);

  // Without its certificate the file is not believed: it is rebuilt.
  fs::remove(path + ".certificate.json");
  GraphCache& third = Cache();
  third.Request(mesh, params, bound);
  const GraphStatus rebuilt = WaitFor(certified, GraphState::kReady);
  EXPECT_FALSE(rebuilt.from_file);
  EXPECT_THAT(rebuilt.error, HasSubstr("no certificate"));
  ASSERT_TRUE(rebuilt.certificate.has_value());
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 3);
  EXPECT_TRUE(fs::exists(path + ".certificate.json"));
}

TEST_F(GraphCacheTest, AFailedCertificationFailsTheGraphWithItsMessage) {
  auto mesh = GridMesh("grid", 4, 0.1);
  const double bound = 0.05;
  const GraphKey key{"grid", Eps(CertifiedKeyEpsilon(bound)), bound};
  GraphCache& cache = Cache();
  maker_->FailBuild(true);
  cache.Request(mesh, key.params, bound);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  EXPECT_THAT(failed.error, HasSubstr("no graph kept the bound"));
  EXPECT_FALSE(failed.certificate.has_value());
  auto engine = cache.Acquire(key);
  EXPECT_TRUE(absl::IsFailedPrecondition(engine.status())) << engine.status();
  EXPECT_THAT(engine.status().message(), HasSubstr("certified to max error 0.05"));
}

// Unloading a mesh while its graph is in each state of its making: nothing
// is published for it, and no readiness is announced.
TEST_F(GraphCacheTest, UnloadDuringEachStepPublishesNothing) {
  for (HeldMaker::Step step : {HeldMaker::kOpen, HeldMaker::kBuild, HeldMaker::kWrite}) {
    SCOPED_TRACE(step);
    maker_ = std::make_shared<HeldMaker>();
    auto mesh = GridMesh("grid", 5);
    const GraphKey key{"grid", Eps(0.05)};
    GraphCache& cache = Cache();
    if (step == HeldMaker::kOpen) {
      // A file to load: built by an earlier cache.
      cache.Request(mesh, key.params);
      WaitFor(key, GraphState::kReady);
      Cache();
    }
    {
      absl::MutexLock lock(&notices_mu_);
      notices_.clear();
    }
    maker_->Hold(step);
    cache_->Request(mesh, key.params);
    maker_->AwaitReached(step);
    const GraphState during = cache_->Get(key)->state;
    EXPECT_EQ(during, step == HeldMaker::kOpen    ? GraphState::kLoading
                      : step == HeldMaker::kBuild ? GraphState::kBuilding
                                                  : GraphState::kPersisting);
    cache_->DropMesh("grid");
    maker_->Release(step);
    EXPECT_EQ(cache_->Get(key).status().code(), absl::StatusCode::kNotFound);
    EXPECT_EQ(cache_->Acquire(key).status().code(), absl::StatusCode::kFailedPrecondition);
    // Let the worker finish its (now orphaned) operation: it announces
    // nothing.
    cache_.reset();
    EXPECT_THAT(Notices(), ::testing::IsEmpty());
    fs::remove_all(dir_);
  }
}

TEST_F(GraphCacheTest, CancelDuringEachStepEndsCancelledAndARequestStartsAgain) {
  for (HeldMaker::Step step : {HeldMaker::kOpen, HeldMaker::kBuild, HeldMaker::kWrite}) {
    SCOPED_TRACE(step);
    maker_ = std::make_shared<HeldMaker>();
    auto mesh = GridMesh("grid", 5);
    const GraphKey key{"grid", Eps(0.05)};
    Cache();
    if (step == HeldMaker::kOpen) {
      cache_->Request(mesh, key.params);
      WaitFor(key, GraphState::kReady);
      Cache();
    }
    maker_->Hold(step);
    cache_->Request(mesh, key.params);
    maker_->AwaitReached(step);
    ASSERT_TRUE(cache_->Cancel(key).ok());
    maker_->Release(step);
    WaitFor(key, GraphState::kCancelled);
    EXPECT_THAT(std::string(cache_->Acquire(key).status().message()), HasSubstr("cancelled"));
    // Asked again, it is made again, from the same entry.
    EXPECT_EQ(cache_->Request(mesh, key.params).state, GraphState::kQueued);
    WaitFor(key, GraphState::kReady);
    cache_.reset();
    fs::remove_all(dir_);
  }
}

// A request that comes between a cancel and the worker's noticing it was
// answered as under way: it must end ready, not cancelled.
TEST_F(GraphCacheTest, ARequestRightAfterACancelEndsReady) {
  for (HeldMaker::Step step : {HeldMaker::kBuild, HeldMaker::kWrite}) {
    SCOPED_TRACE(step);
    maker_ = std::make_shared<HeldMaker>();
    auto mesh = GridMesh("grid", 5);
    const GraphKey key{"grid", Eps(0.05)};
    Cache();
    maker_->Hold(step);
    cache_->Request(mesh, key.params);
    maker_->AwaitReached(step);
    ASSERT_TRUE(cache_->Cancel(key).ok());
    const GraphStatus again = cache_->Request(mesh, key.params);
    EXPECT_EQ(again.state, GraphState::kQueued);
    maker_->Release(step);
    WaitFor(key, GraphState::kReady);
    EXPECT_TRUE(cache_->Acquire(key).ok());
    cache_.reset();
    fs::remove_all(dir_);
  }
}

TEST_F(GraphCacheTest, CancellingAReadyGraphChangesNothing) {
  auto mesh = GridMesh("grid", 5);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache(false);
  cache.Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  auto cancelled = cache.Cancel(key);
  ASSERT_TRUE(cancelled.ok());
  EXPECT_EQ(cancelled->state, GraphState::kReady);
  EXPECT_TRUE(cache.Acquire(key).ok());
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
}

TEST_F(GraphCacheTest, CancelWhileQueuedNeedsNoWorker) {
  auto mesh = GridMesh("grid", 5);
  GraphCache& cache = Cache(false);
  maker_->Hold(HeldMaker::kBuild);
  cache.Request(mesh, Eps(0.05));  // takes the only worker
  maker_->AwaitReached(HeldMaker::kBuild);
  cache.Request(mesh, Eps(0.1));  // waits in the queue
  auto cancelled = cache.Cancel({"grid", Eps(0.1)});
  ASSERT_TRUE(cancelled.ok());
  EXPECT_EQ(cancelled->state, GraphState::kCancelled);
  maker_->Release(HeldMaker::kBuild);
  WaitFor({"grid", Eps(0.05)}, GraphState::kReady);
  EXPECT_EQ(cache.Get({"grid", Eps(0.1)})->state, GraphState::kCancelled);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
}

TEST_F(GraphCacheTest, AFailedBuildReportsAndARequestRetries) {
  auto mesh = GridMesh("grid", 5);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache(false);
  maker_->FailBuild(true);
  cache.Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  EXPECT_THAT(failed.error, HasSubstr("broke on purpose"));
  EXPECT_THAT(std::string(cache.Acquire(key).status().message()), HasSubstr("broke on purpose"));
  maker_->FailBuild(false);
  cache.Request(mesh, key.params);
  EXPECT_TRUE(WaitFor(key, GraphState::kReady).error.empty());
}

// Over the budget, the least recently used graph that no query holds goes;
// its file stays, so using it again maps it. Each Acquire that finds no
// ready graph is one miss.
TEST_F(GraphCacheTest, EvictionSparesHeldGraphsAndEvictedOnesComeBackFromTheirFile) {
  auto mesh = GridMesh("grid", 8);
  GraphCache& cache = Cache(true, /*memory_limit=*/1);
  const GraphKey a{"grid", Eps(0.05)}, b{"grid", Eps(0.1)};
  cache.Request(mesh, a.params);
  WaitFor(a, GraphState::kReady);
  auto held = cache.Acquire(a);  // a query holds a
  ASSERT_TRUE(held.ok());
  cache.Request(mesh, b.params);
  WaitFor(b, GraphState::kReady);
  EXPECT_EQ(cache.Get(a)->state, GraphState::kReady);  // held: spared
  EXPECT_EQ(cache.evictions(), 0u);
  held = absl::UnavailableError("released");
  cache.Request(mesh, Eps(0.2));
  WaitFor({"grid", Eps(0.2)}, GraphState::kReady);
  EXPECT_GE(cache.evictions(), 1u);
  const GraphKey evicted = cache.Get(a)->state == GraphState::kEvicted ? a : b;
  ASSERT_EQ(cache.Get(evicted)->state, GraphState::kEvicted);
  EXPECT_TRUE(fs::exists(cache.GraphPath(mesh->fingerprint, evicted.params)));
  const uint64_t misses = cache.misses();
  EXPECT_EQ(cache.Acquire(evicted).status().code(), absl::StatusCode::kUnavailable);
  EXPECT_EQ(cache.misses(), misses + 1);
  EXPECT_TRUE(WaitFor(evicted, GraphState::kReady).from_file);
  EXPECT_THAT(Notices(),
              ::testing::Contains(absl::StrCat("grid@", evicted.params.epsilon, " gone")));
}

// A graph asked for exact answers gets its exact landmarks on a worker,
// counted in its landmark bytes; a cache set to none computes none.
TEST_F(GraphCacheTest, AGraphAskedForExactAnswersGetsItsExactLandmarks) {
  auto mesh = GridMesh("grid", 8);
  const GraphKey key{"grid", Eps(0.05)};
  for (int count : {0, 4}) {
    SCOPED_TRACE(absl::StrCat(count, " exact landmarks"));
    exact_landmarks_ = count;
    GraphCache& cache = Fresh(/*persist=*/false);
    cache.Request(mesh, key.params);
    WaitFor(key, GraphState::kReady);
    auto engine = cache.Acquire(key);
    ASSERT_TRUE(engine.ok()) << engine.status();
    cache.WantExactLandmarks(key);
    cache.WantExactLandmarks(key);  // asked twice, made once
    const uint64_t want = count == 0 ? 0
                                     : ExactLandmarks::ByteSize(mesh->mesh->num_vertices(),
                                                                mesh->mesh->num_halfedges(), count);
    ASSERT_TRUE(LandmarksCounted(cache, key, **engine, want)) << cache.Get(key)->landmark_bytes;
    EXPECT_EQ((*engine)->exact_landmark_bytes(), want);
  }
}

// The exact landmarks of a graph in --graph-dir are kept beside its file:
// a restarted cache reads them back instead of computing them again (here,
// landmarks written there from other vertices come back as written), and a
// damaged file is computed again and written over.
TEST_F(GraphCacheTest, ExactLandmarksAreKeptBesideTheGraphAndReadBackAfterARestart) {
  auto mesh = GridMesh("grid", 8);
  const GraphKey key{"grid", Eps(0.05)};
  exact_landmarks_ = 4;
  // The landmarks the cache holds once it has them (nullptr after 30 s).
  auto landmarks_of = [&]() -> std::shared_ptr<const GeodesicEngine> {
    cache_->Request(mesh, key.params);
    WaitFor(key, GraphState::kReady);
    auto engine = cache_->Acquire(key);
    EXPECT_TRUE(engine.ok()) << engine.status();
    if (!engine.ok()) return nullptr;
    cache_->WantExactLandmarks(key);
    const absl::Time deadline = absl::Now() + absl::Seconds(30);
    while ((*engine)->exact_landmarks() == nullptr && absl::Now() < deadline) {
      absl::SleepFor(absl::Milliseconds(5));
    }
    EXPECT_NE((*engine)->exact_landmarks(), nullptr);
    return *engine;
  };
  auto fields = [](const GeodesicEngine& engine) {
    std::span<const float> f = engine.exact_landmarks()->fields();
    return std::vector<float>(f.begin(), f.end());
  };
  Fresh();
  auto computed = landmarks_of();
  ASSERT_NE(computed, nullptr);
  ASSERT_NE(computed->exact_landmarks(), nullptr);
  const std::string path = ExactLandmarksPathOf(cache_->GraphPath(mesh->fingerprint, key.params));
  // Written just after the engine has them.
  auto kept_file = [&] {
    const absl::Time deadline = absl::Now() + absl::Seconds(30);
    auto read = ReadExactLandmarks(path, *mesh->mesh, 4);
    while (!read.ok() && absl::Now() < deadline) {
      absl::SleepFor(absl::Milliseconds(5));
      read = ReadExactLandmarks(path, *mesh->mesh, 4);
    }
    return read;
  };
  auto kept = kept_file();
  ASSERT_TRUE(kept.ok()) << kept.status();
  EXPECT_EQ(std::vector<float>((*kept)->fields().begin(), (*kept)->fields().end()),
            fields(*computed));

  const std::vector<VertexId> others = {0, 7, 40, 63};
  auto other = ExactLandmarks::Compute(*mesh->mesh, others);
  ASSERT_TRUE(other.ok()) << other.status();
  const absl::Status written = WriteExactLandmarks(**other, *mesh->mesh, path);
  ASSERT_TRUE(written.ok()) << written;
  ASSERT_NE(fields(*computed),
            std::vector<float>((*other)->fields().begin(), (*other)->fields().end()));
  Cache();  // a restart on the same directory
  auto restored = landmarks_of();
  ASSERT_NE(restored, nullptr);
  ASSERT_NE(restored->exact_landmarks(), nullptr);
  EXPECT_EQ(fields(*restored),
            std::vector<float>((*other)->fields().begin(), (*other)->fields().end()));

  std::filesystem::resize_file(path, 100);
  Cache();
  auto recomputed = landmarks_of();
  ASSERT_NE(recomputed, nullptr);
  ASSERT_NE(recomputed->exact_landmarks(), nullptr);
  EXPECT_EQ(fields(*recomputed), fields(*computed));
  EXPECT_TRUE(kept_file().ok());
}

// A graph of a mesh whose other graph keeps exact landmarks reads those
// (they are the mesh's fields) and keeps a copy beside its own file.
TEST_F(GraphCacheTest, ExactLandmarksOfAnotherGraphOfTheMeshAreReadAndCopied) {
  auto mesh = GridMesh("grid", 8);
  const GraphKey coarse{"grid", Eps(0.1)}, fine{"grid", Eps(0.05)};
  exact_landmarks_ = 4;
  Fresh();
  fs::create_directories(dir_);
  // Planted beside the coarse graph's file: landmarks from vertices no
  // sampling of the fine graph would pick all of.
  auto planted = ExactLandmarks::Compute(*mesh->mesh, std::vector<VertexId>{0, 7, 40, 63});
  ASSERT_TRUE(planted.ok()) << planted.status();
  const std::string coarse_kept =
      ExactLandmarksPathOf(cache_->GraphPath(mesh->fingerprint, coarse.params));
  const absl::Status written = WriteExactLandmarks(**planted, *mesh->mesh, coarse_kept);
  ASSERT_TRUE(written.ok()) << written;

  cache_->Request(mesh, fine.params);
  WaitFor(fine, GraphState::kReady);
  auto engine = cache_->Acquire(fine);
  ASSERT_TRUE(engine.ok()) << engine.status();
  cache_->WantExactLandmarks(fine);
  const std::string fine_kept =
      ExactLandmarksPathOf(cache_->GraphPath(mesh->fingerprint, fine.params));
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (!fs::exists(fine_kept) && absl::Now() < deadline) absl::SleepFor(absl::Milliseconds(5));
  ASSERT_NE((*engine)->exact_landmarks(), nullptr);
  const std::span<const float> got = (*engine)->exact_landmarks()->fields();
  const std::span<const float> want = (*planted)->fields();
  ASSERT_FALSE(want.empty());
  EXPECT_TRUE(std::equal(got.begin(), got.end(), want.begin(), want.end()));
  auto copy = ReadExactLandmarks(fine_kept, *mesh->mesh, 4);
  EXPECT_TRUE(copy.ok()) << copy.status();
}

// Graphs of one mesh share its exact landmarks in memory (they are the
// mesh's fields, whatever the graph): the second graph asked for exact
// answers takes the first's, each reports them in its landmark bytes, and
// what is resident counts them once.
TEST_F(GraphCacheTest, GraphsOfOneMeshShareItsExactLandmarksAndCountThemOnce) {
  auto mesh = GridMesh("grid", 8);
  const GraphKey coarse{"grid", Eps(0.1)}, fine{"grid", Eps(0.05)};
  exact_landmarks_ = 4;
  GraphCache& cache = Fresh(/*persist=*/false);
  const uint64_t exact =
      ExactLandmarks::ByteSize(mesh->mesh->num_vertices(), mesh->mesh->num_halfedges(), 4);
  // The graph's engine once both kinds of landmarks are counted in its
  // status (nullptr after 30 s).
  auto with_exact_landmarks = [&](const GraphKey& key) -> std::shared_ptr<const GeodesicEngine> {
    cache.Request(mesh, key.params);
    WaitFor(key, GraphState::kReady);
    auto engine = cache.Acquire(key);
    EXPECT_TRUE(engine.ok()) << engine.status();
    if (!engine.ok()) return nullptr;
    cache.WantExactLandmarks(key);
    const bool counted = LandmarksCounted(cache, key, **engine, exact);
    EXPECT_TRUE(counted) << key.params.epsilon;
    return counted ? *engine : nullptr;
  };
  auto first = with_exact_landmarks(coarse);
  auto second = with_exact_landmarks(fine);
  ASSERT_NE(first, nullptr);
  ASSERT_NE(second, nullptr);
  ASSERT_NE(first->exact_landmarks(), nullptr);
  EXPECT_EQ(second->exact_landmarks(), first->exact_landmarks());
  EXPECT_EQ(first->exact_landmark_bytes(), exact);
  auto a = cache.Get(coarse), b = cache.Get(fine);
  ASSERT_TRUE(a.ok() && b.ok());
  ASSERT_FALSE(a->mapped || b->mapped);
  // The first graph's worker may still hold its exact landmarks' pending
  // bytes for a moment after they are counted.
  const uint64_t want = a->bytes + b->bytes + a->landmark_bytes + b->landmark_bytes - exact;
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (cache.resident_bytes() != want && absl::Now() < deadline) {
    absl::SleepFor(absl::Milliseconds(5));
  }
  EXPECT_EQ(cache.resident_bytes(), want);
}

// Exact landmarks that cannot fit the memory limit, even with every graph no
// query holds evicted, are skipped: the graph keeps serving without them.
TEST_F(GraphCacheTest, ExactLandmarksOverTheMemoryLimitAreSkipped) {
  auto mesh = GridMesh("grid", 8);
  const GraphKey key{"grid", Eps(0.05)};
  exact_landmarks_ = 4;
  GraphCache& cache = Cache(/*persist=*/false, /*memory_limit=*/1);
  cache.Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  auto engine = cache.Acquire(key);
  ASSERT_TRUE(engine.ok()) << engine.status();
  cache.WantExactLandmarks(key);
  // On this grid they take milliseconds: two seconds would show them.
  absl::SleepFor(absl::Seconds(2));
  EXPECT_EQ((*engine)->exact_landmark_bytes(), 0u);
  EXPECT_EQ(cache.Get(key)->state, GraphState::kReady);
}

// Meshes count against --memory-limit: graphs that fit beside no meshes are
// evicted once the meshes take the room.
TEST_F(GraphCacheTest, MeshBytesCountAgainstTheMemoryLimit) {
  auto mesh = GridMesh("grid", 8);
  GraphCache& cache = Cache(true, /*memory_limit=*/64 << 20);
  const GraphKey a{"grid", Eps(0.05)}, b{"grid", Eps(0.1)}, c{"grid", Eps(0.2)};
  cache.Request(mesh, a.params);
  WaitFor(a, GraphState::kReady);
  cache.Request(mesh, b.params);
  WaitFor(b, GraphState::kReady);
  EXPECT_EQ(cache.evictions(), 0u);  // two small graphs fit
  outside_bytes_ = 64 << 20;         // the meshes now fill the limit
  cache.Request(mesh, c.params);
  WaitFor(c, GraphState::kReady);
  EXPECT_EQ(cache.evictions(), 2u);  // all but the graph just made ready
  EXPECT_EQ(cache.Get(a)->state, GraphState::kEvicted);
  EXPECT_EQ(cache.Get(b)->state, GraphState::kEvicted);
  EXPECT_EQ(cache.Get(c)->state, GraphState::kReady);
}

TEST_F(GraphCacheTest, AnInvalidFileIsMovedAsideAndRebuilt) {
  auto mesh = GridMesh("grid", 5);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  fs::create_directories(dir_);
  const std::string path = cache.GraphPath(mesh->fingerprint, key.params);
  std::ofstream(path) << "not a graph";
  cache.Request(mesh, key.params);
  const GraphStatus ready = WaitFor(key, GraphState::kReady);
  EXPECT_FALSE(ready.from_file);
  EXPECT_THAT(ready.error, HasSubstr("rejected"));
  bool aside = false;
  for (const auto& f : fs::directory_iterator(dir_)) {
    aside |= f.path().string().find(".rejected-") != std::string::npos;
  }
  EXPECT_TRUE(aside);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
}

// A mesh registered again with other contents replaces the entry: the old
// operation, still running, publishes nothing over the new one.
TEST_F(GraphCacheTest, AReplacedMeshsOldOperationPublishesNothing) {
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache(false);
  maker_->Hold(HeldMaker::kBuild);
  cache.Request(GridMesh("grid", 5), key.params);
  maker_->AwaitReached(HeldMaker::kBuild);
  auto other = GridMesh("grid", 7);
  EXPECT_EQ(cache.Request(other, key.params).state, GraphState::kQueued);
  maker_->Release(HeldMaker::kBuild);
  WaitFor(key, GraphState::kReady);
  auto engine = cache.Acquire(key);
  ASSERT_TRUE(engine.ok());
  EXPECT_EQ((*engine)->mesh().num_vertices(), other->mesh->num_vertices());
}

// A build estimated to take long runs in a lane of its own: with one build
// worker, a small graph requested while a huge build runs is made at once.
TEST_F(GraphCacheTest, ASmallGraphBuildsWhileAHugeOneRuns) {
  auto big = GridMesh("big", 8), small = GridMesh("small", 4);
  const GraphKey huge{"big", Eps(0.01)}, quick{"small", Eps(0.2)};
  GraphCache::Options options;
  options.build_threads = 1;
  options.build_workers = 1;
  options.maker = maker_;
  cache_ = std::make_unique<GraphCache>(options);
  const double huge_seconds = cache_->Estimate(*big, huge.params).seconds;
  const double quick_seconds = cache_->Estimate(*small, quick.params).seconds;
  ASSERT_GT(huge_seconds, 4 * quick_seconds);
  options.large_build_seconds = std::sqrt(huge_seconds * quick_seconds);
  cache_ = std::make_unique<GraphCache>(options);

  maker_->Hold(HeldMaker::kBuild);
  cache_->Request(big, huge.params);
  maker_->AwaitReached(HeldMaker::kBuild);  // the huge build holds a worker
  cache_->Request(small, quick.params);
  WaitFor(quick, GraphState::kReady);
  EXPECT_EQ(cache_->Get(huge)->state, GraphState::kBuilding);
  maker_->Release(HeldMaker::kBuild);
  WaitFor(huge, GraphState::kReady);
}

// While a worker is busy, the queue runs the shortest estimated build first.
TEST_F(GraphCacheTest, TheQueueRunsTheShortestBuildFirst) {
  auto mesh = GridMesh("grid", 6);
  GraphCache::Options options;
  options.build_threads = 1;
  options.build_workers = 1;
  options.large_build_seconds = 1e9;  // one lane: only the order counts
  options.maker = maker_;
  std::vector<double> order;
  absl::Mutex order_mu;
  options.on_readiness = [&](const GraphKey& key, bool ready) {
    absl::MutexLock lock(&order_mu);
    if (ready) order.push_back(key.params.epsilon);
  };
  cache_ = std::make_unique<GraphCache>(options);
  maker_->Hold(HeldMaker::kBuild);
  cache_->Request(mesh, Eps(0.3));
  maker_->AwaitReached(HeldMaker::kBuild);
  for (double eps : {0.01, 0.05, 0.02, 0.2}) cache_->Request(mesh, Eps(eps));
  EXPECT_GT(cache_->Get({"grid", Eps(0.01)})->estimated_seconds,
            cache_->Get({"grid", Eps(0.2)})->estimated_seconds);
  maker_->Release(HeldMaker::kBuild);
  WaitFor({"grid", Eps(0.01)}, GraphState::kReady);
  // Readiness is announced after the state changes.
  absl::MutexLock lock(&order_mu);
  order_mu.AwaitWithTimeout(absl::Condition(
                                +[](std::vector<double>* o) { return o->size() == 5; }, &order),
                            absl::Seconds(30));
  EXPECT_THAT(order, ::testing::ElementsAre(0.3, 0.2, 0.05, 0.02, 0.01));
}

TEST_F(GraphCacheTest, AdmitRefusesAGraphOverTheLimitNamingItsEstimate) {
  auto mesh = GridMesh("grid", 20);
  GraphCache::Options options;
  options.maker = maker_;
  options.max_graph_bytes = 1 << 20;
  cache_ = std::make_unique<GraphCache>(options);
  const DggBuildEstimate fine = *cache_->Admit(*mesh, Eps(0.1));
  EXPECT_GT(fine.bytes, 0u);
  EXPECT_GT(fine.seconds, 0);
  auto refused = cache_->Admit(*mesh, Eps(1e-6));
  EXPECT_EQ(refused.status().code(), absl::StatusCode::kResourceExhausted);
  const std::string estimate = std::to_string(cache_->Estimate(*mesh, Eps(1e-6)).bytes);
  EXPECT_THAT(std::string(refused.status().message()),
              ::testing::AllOf(HasSubstr(estimate), HasSubstr("1048576"),
                               HasSubstr("--max-graph-bytes"), HasSubstr("larger epsilon")));
  // The estimate is part of the graph's status.
  const GraphStatus queued = cache_->Request(mesh, Eps(0.1));
  EXPECT_EQ(queued.estimated_bytes, fine.bytes);
  EXPECT_DOUBLE_EQ(queued.estimated_seconds, fine.seconds);
  v1::Graph answer;  // what RequestGraph and GetGraph answer
  ToProto(queued, &answer);
  EXPECT_EQ(answer.estimated_bytes(), fine.bytes);
  EXPECT_DOUBLE_EQ(answer.estimated_seconds(), fine.seconds);
}

TEST_F(GraphCacheTest, AGraphFileOverTheDiskLimitIsNotWrittenAndTheGraphFails) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  fs::create_directories(dir_);
  DiskBudget disk(dir_, /*limit=*/4096);
  ASSERT_TRUE(disk.Scan().ok());
  GraphCache::Options options;
  options.graph_dir = dir_;
  options.maker = maker_;
  options.disk = &disk;
  cache_ = std::make_unique<GraphCache>(options);
  cache_->Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  const std::string path = cache_->GraphPath(mesh->fingerprint, key.params);
  EXPECT_THAT(failed.error,
              ::testing::AllOf(HasSubstr("--disk-limit"), HasSubstr("4096"), HasSubstr(path)));
  EXPECT_EQ(maker_->calls(HeldMaker::kWrite), 0);
  EXPECT_FALSE(fs::exists(path));
  // Nor the draft the graph was built into.
  EXPECT_THAT(Temporaries(), ::testing::IsEmpty());
  EXPECT_EQ(disk.used(), 0u);
}

// A plain graph's edges fill its draft during the build: the budget admits
// them before they are written, so a build the directory has no room for
// stops there, naming what it needed, instead of passing --disk-limit until
// its file is refused after the build.
TEST_F(GraphCacheTest, ABuildWhoseEdgesTheDiskLimitHasNoRoomForStopsBeforeWritingThem) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  fs::create_directories(dir_);
  constexpr uint64_t kFiller = 100000;
  std::ofstream(dir_ / "filler") << std::string(kFiller, 'x');
  DiskBudget disk(dir_, kFiller + 4096);
  ASSERT_TRUE(disk.Scan().ok());
  Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
  std::optional<absl::Status> built;  // the build's own result
  maker_->OnBuilt([&](const DggBuildOptions&, const auto& result) { built = result.status(); });
  cache_->Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  const std::string path = cache_->GraphPath(mesh->fingerprint, key.params);
  EXPECT_THAT(failed.error, ::testing::AllOf(HasSubstr("its edges need"), HasSubstr("--disk-limit"),
                                             HasSubstr(path)));
  ASSERT_TRUE(built.has_value());
  EXPECT_TRUE(absl::IsResourceExhausted(*built)) << *built;
  EXPECT_FALSE(fs::exists(path));
  EXPECT_THAT(Temporaries(), ::testing::IsEmpty());
  // The admission was given back: only the filler is counted.
  ASSERT_TRUE(disk.Scan().ok());
  EXPECT_EQ(disk.used(), kFiller);
  cache_.reset();  // before the budget it points to goes
}

// A draft's edges are on disk before its file is admitted: the budget counts
// them once, also when a sweep counted the directory, draft and all, during
// the build, and a file that fits beside what is there is kept.
TEST_F(GraphCacheTest, TheDiskBudgetCountsADraftsEdgesOnce) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  Cache().Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  const uint64_t file_bytes = fs::file_size(cache_->GraphPath(mesh->fingerprint, key.params));

  Fresh();
  fs::create_directories(dir_);
  constexpr uint64_t kFiller = 100000;
  std::ofstream(dir_ / "filler") << std::string(kFiller, 'x');
  // Room for the file, not for the file and its edges again.
  DiskBudget disk(dir_, kFiller + file_bytes + 1024);
  ASSERT_TRUE(disk.Scan().ok());
  Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
  uint64_t counted_with_draft = 0;
  maker_->OnBuilt([&](const DggBuildOptions&, const auto&) {
    EXPECT_TRUE(disk.Scan().ok());  // a sweep while the draft holds the edges
    counted_with_draft = disk.used();
  });
  cache_->Request(mesh, key.params);
  const GraphStatus ready = WaitFor(key, GraphState::kReady);
  EXPECT_GT(counted_with_draft, kFiller + 1024) << ready.error;
  std::error_code ec;
  const uint64_t kept = fs::file_size(cache_->GraphPath(mesh->fingerprint, key.params), ec);
  EXPECT_FALSE(ec) << ec.message();
  EXPECT_EQ(disk.used(), kFiller + kept);
  cache_.reset();  // before the budget it points to goes
}

std::shared_ptr<const RegisteredMesh> SpotMesh() {
  auto mesh = LoadMesh(std::string(GEODESIC_SOURCE_DIR) + "/data/spot.obj");
  EXPECT_TRUE(mesh.ok()) << mesh.status();
  auto m = std::make_shared<RegisteredMesh>();
  m->name = "spot";
  m->mesh = std::make_shared<const Mesh>(*std::move(mesh));
  m->fingerprint = MeshFingerprint(*m->mesh);
  return m;
}

// The bytes a one-thread build like the cache's (with build_memory_limit_
// 1: every sealed chunk of candidates spills) writes to its spill file.
uint64_t OneThreadSpillBytes(const Mesh& mesh, const DggParams& params) {
  DggBuildOptions probe;
  probe.params = params;
  probe.threads = 1;
  probe.candidate_memory_limit = 1;
  probe.spill_dir = fs::temp_directory_path().string();
  DggBuildStats stats;
  absl::Status built = BuildDgg(mesh, probe, &stats).status();
  EXPECT_TRUE(built.ok()) << built;
  return stats.spilled_bytes;
}

std::string FileBytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), {});
}

// The spill file of --build-memory-limit lies in the graph directory, which
// --disk-limit bounds: a build admits each spill before writing it, and stops
// there, naming the spill, when the directory has no room for it.
TEST_F(GraphCacheTest, ABuildWhoseSpillTheDiskLimitHasNoRoomForStopsBeforeWritingIt) {
  auto mesh = SpotMesh();
  const GraphKey key{"spot", Eps(1e-3)};
  fs::create_directories(dir_);
  constexpr uint64_t kFiller = 100000;
  std::ofstream(dir_ / "filler") << std::string(kFiller, 'x');
  DiskBudget disk(dir_, kFiller + 4096);
  ASSERT_TRUE(disk.Scan().ok());
  build_memory_limit_ = 1;  // every sealed chunk of candidates spills
  Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
  cache_->Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  EXPECT_THAT(failed.error,
              ::testing::AllOf(HasSubstr("spill file"), HasSubstr("--build-memory-limit"),
                               HasSubstr("--disk-limit")));
  EXPECT_THAT(Temporaries(), ::testing::IsEmpty());
  ASSERT_TRUE(disk.Scan().ok());
  EXPECT_EQ(disk.used(), kFiller);  // the admissions were given back
  cache_.reset();                   // before the budget it points to goes
}

// A build stopped because its spill could never fit within --disk-limit is
// not run again to the same end: asked again, the graph is refused at once,
// naming the spill and both flags, as a graph refused for its edges is.
TEST_F(GraphCacheTest, AGraphWhoseSpillTheDiskLimitCanNeverHoldIsRefusedAtOnceWhenAskedAgain) {
  auto mesh = SpotMesh();
  const GraphKey key{"spot", Eps(1e-3)};
  // A limit above the least file Admit expects and below the whole spill.
  const uint64_t spill_bytes = OneThreadSpillBytes(*mesh->mesh, key.params);
  const uint64_t least = EstimateDggBytesLowerBound(mesh->mesh->num_vertices(), 1e-3);
  ASSERT_LT(least, spill_bytes);
  const uint64_t limit = (least + spill_bytes) / 2;
  fs::create_directories(dir_);
  DiskBudget disk(dir_, limit);
  ASSERT_TRUE(disk.Scan().ok());
  build_memory_limit_ = 1;  // every sealed chunk of candidates spills
  Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
  ASSERT_TRUE(cache_->Admit(*mesh, key.params, 0).ok());
  cache_->Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  ASSERT_THAT(failed.error, HasSubstr("spill file"));
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
  auto again = cache_->Admit(*mesh, key.params, 0);
  EXPECT_EQ(again.status().code(), absl::StatusCode::kResourceExhausted);
  EXPECT_THAT(std::string(again.status().message()),
              ::testing::AllOf(HasSubstr("spill file"), HasSubstr("--build-memory-limit"),
                               HasSubstr("--disk-limit"), HasSubstr(std::to_string(limit))));
  // Another graph of the mesh is still admitted.
  EXPECT_TRUE(cache_->Admit(*mesh, Eps(1e-2), 0).ok());
  cache_.reset();  // before the budget it points to goes
}

// The spill and the draft's edges are on disk together (the draft grows
// once the runs are counted, and is filled as they are read back): a
// directory with room for both takes the build, and the spill is given back
// once read, so that only the file stays counted.
TEST_F(GraphCacheTest, ABuildsSpillIsCountedBesideItsEdgesAndGivenBack) {
  auto mesh = SpotMesh();
  const GraphKey key{"spot", Eps(1e-3)};
  Cache().Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  const uint64_t file_bytes = fs::file_size(cache_->GraphPath(mesh->fingerprint, key.params));
  const uint64_t spill_bytes = OneThreadSpillBytes(*mesh->mesh, key.params);
  ASSERT_GT(spill_bytes, 0u);

  Fresh();
  fs::create_directories(dir_);
  constexpr uint64_t kFiller = 100000;
  std::ofstream(dir_ / "filler") << std::string(kFiller, 'x');
  DiskBudget disk(dir_, kFiller + spill_bytes + file_bytes + 4096);
  ASSERT_TRUE(disk.Scan().ok());
  build_memory_limit_ = 1;
  Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
  cache_->Request(mesh, key.params);
  const GraphStatus ready = WaitFor(key, GraphState::kReady);
  EXPECT_EQ(ready.error, "");
  std::error_code ec;
  const uint64_t kept = fs::file_size(cache_->GraphPath(mesh->fingerprint, key.params), ec);
  EXPECT_FALSE(ec) << ec.message();
  EXPECT_EQ(disk.used(), kFiller + kept);
  cache_.reset();
}

// A plain graph is built into its file: the build keeps its edges there (page
// cache, not the daemon's memory), and the file committed is the one the same
// build made in memory writes, byte for byte. What is served is that file,
// mapped, and counted at its bytes as a graph loaded from it would be.
TEST_F(GraphCacheTest, APlainGraphIsBuiltIntoItsFileTheSameBytesAsWrittenAfterwards) {
  auto mesh = SpotMesh();
  const GraphKey key{"spot", Eps(1e-2)};
  GraphCache& cache = Cache();
  const std::string path = cache.GraphPath(mesh->fingerprint, key.params);
  std::optional<DggEdgeFile> edge_file;
  uint64_t edge_bytes = 0, draft_bytes = 0;
  maker_->OnBuilt([&](const DggBuildOptions& options, const auto& built) {
    edge_file = options.edge_file;
    if (built.ok()) edge_bytes = (*built)->edges().size_bytes();
    // Before the commit, the edges are in the draft beside the file.
    for (const std::string& name : Temporaries()) {
      draft_bytes = std::max<uint64_t>(draft_bytes, fs::file_size(dir_ / name));
    }
  });
  cache.Request(mesh, key.params);
  const GraphStatus ready = WaitFor(key, GraphState::kReady);
  ASSERT_TRUE(edge_file.has_value());
  EXPECT_GE(edge_file->fd, 0);
  EXPECT_GT(edge_file->offset, 0u);
  EXPECT_GT(edge_bytes, 0u);
  EXPECT_GE(draft_bytes, edge_file->offset + edge_bytes);
  EXPECT_TRUE(ready.mapped);
  EXPECT_EQ(ready.bytes, fs::file_size(path));
  EXPECT_EQ(cache.mapped_bytes(), ready.bytes);
  // Only the graph is left: no draft, no build lock.
  EXPECT_THAT(Files(), ::testing::ElementsAre(fs::path(path).filename().string()));

  DggBuildOptions options;
  options.params = key.params;
  options.threads = 1;
  auto in_memory = BuildDgg(*mesh->mesh, options);
  ASSERT_TRUE(in_memory.ok()) << in_memory.status();
  const std::string written = dir_.string() + ".written.dgg";
  ASSERT_TRUE(GraphFile::Write(**in_memory, written).ok());
  const std::string built_bytes = FileBytes(path), written_bytes = FileBytes(written);
  fs::remove(written);
  EXPECT_EQ(built_bytes.size(), written_bytes.size());
  EXPECT_TRUE(built_bytes == written_bytes) << "the file built into differs from the one written";
}

// A build cancelled midway leaves neither the graph's file nor the draft it
// was built into; asked again, the graph is built and committed.
TEST_F(GraphCacheTest, ACancelledBuildLeavesNoFileNorDraft) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  maker_->Hold(HeldMaker::kBuild);
  cache.Request(mesh, key.params);
  ASSERT_TRUE(maker_->AwaitReached(HeldMaker::kBuild));
  EXPECT_THAT(Temporaries(), ::testing::SizeIs(1)) << "no draft while building";
  ASSERT_TRUE(cache.Cancel(key).ok());
  maker_->Release(HeldMaker::kBuild);
  WaitFor(key, GraphState::kCancelled);
  const std::string path = cache.GraphPath(mesh->fingerprint, key.params);
  EXPECT_FALSE(fs::exists(path));
  EXPECT_THAT(Temporaries(), ::testing::IsEmpty());

  cache.Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  EXPECT_THAT(Files(), ::testing::ElementsAre(fs::path(path).filename().string()));
}

// A daemon starting on the directory removes temporaries it finds unwritten
// for a while; a build's progress keeps its draft's time current, even in
// phases that write nothing to it.
TEST_F(GraphCacheTest, ABuildsProgressKeepsItsDraftFresh) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  const auto an_hour_ago = fs::file_time_type::clock::now() - std::chrono::hours(1);
  std::optional<fs::file_time_type> before, after;
  maker_->BeforeBuild([&](const DggBuildOptions& options) {
    const std::set<std::string> drafts = Temporaries();
    if (drafts.size() != 1) return;
    const fs::path draft = dir_ / *drafts.begin();
    fs::last_write_time(draft, an_hour_ago);
    before = fs::last_write_time(draft);
    options.progress("candidates", 0);
    after = fs::last_write_time(draft);
  });
  cache.Request(mesh, key.params);
  WaitFor(key, GraphState::kReady);
  ASSERT_TRUE(before.has_value() && after.has_value()) << "no draft while building";
  EXPECT_LT(*before, an_hour_ago + std::chrono::minutes(1));
  EXPECT_GT(*after, an_hour_ago + std::chrono::minutes(30));
}

// A graph built into its file that cannot be committed fails, naming the
// file, and leaves nothing behind: it is not served from memory instead.
TEST_F(GraphCacheTest, AGraphWhoseFileCannotBeCommittedFailsNamingIt) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  maker_->FailWrite(true);
  cache.Request(mesh, key.params);
  const GraphStatus failed = WaitFor(key, GraphState::kFailed);
  const std::string path = cache.GraphPath(mesh->fingerprint, key.params);
  EXPECT_THAT(failed.error, ::testing::AllOf(HasSubstr(path), HasSubstr("on purpose")));
  EXPECT_FALSE(fs::exists(path));
  EXPECT_THAT(Temporaries(), ::testing::IsEmpty());
  EXPECT_EQ(cache.Acquire(key).status().code(), absl::StatusCode::kFailedPrecondition);
}

// Graphs whose node count the build decides (pseudo vertices) are built in
// memory and written whole, as before.
TEST_F(GraphCacheTest, APseudoVertexGraphIsBuiltInMemoryAndWrittenWhole) {
  auto mesh = GridMesh("grid", 6, /*z=*/0.3);
  const GraphKey key{"grid", Eps(0.05, /*pseudo=*/true)};
  GraphCache& cache = Cache();
  std::optional<DggEdgeFile> edge_file;
  maker_->OnBuilt(
      [&](const DggBuildOptions& options, const auto&) { edge_file = options.edge_file; });
  cache.Request(mesh, key.params);
  EXPECT_TRUE(WaitFor(key, GraphState::kReady).mapped);
  ASSERT_TRUE(edge_file.has_value());
  EXPECT_EQ(edge_file->fd, -1);
  EXPECT_EQ(maker_->calls(HeldMaker::kWrite), 1);
}

// Two caches on one directory (two replicas) asking for one graph: one
// builds it, the other waits for that build and maps the file.
TEST_F(GraphCacheTest, ReplicasOnOneDirectoryBuildAGraphOnce) {
  auto mesh = GridMesh("grid", 6);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& first = Cache();
  auto other_maker = std::make_shared<HeldMaker>();
  GraphCache::Options options;
  options.graph_dir = dir_;
  options.maker = other_maker;
  options.replica_poll = absl::Milliseconds(20);
  GraphCache second(options);

  maker_->Hold(HeldMaker::kBuild);
  first.Request(mesh, key.params);
  maker_->AwaitReached(HeldMaker::kBuild);
  second.Request(mesh, key.params);
  auto waiting = second.Get(key);
  for (int i = 0; i < 500 && waiting->phase.find("another replica") == std::string::npos; ++i) {
    absl::SleepFor(absl::Milliseconds(10));
    waiting = second.Get(key);
  }
  EXPECT_EQ(waiting->state, GraphState::kQueued);
  EXPECT_THAT(waiting->phase, HasSubstr("waiting for another replica's build"));
  maker_->Release(HeldMaker::kBuild);
  EXPECT_FALSE(WaitFor(key, GraphState::kReady).from_file);
  auto s = second.Get(key);
  const absl::Time deadline = absl::Now() + absl::Seconds(30);
  while (s.ok() && s->state != GraphState::kReady && absl::Now() < deadline) {
    s = second.WaitForChange(key, s->version, deadline);
  }
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->state, GraphState::kReady);
  EXPECT_TRUE(s->from_file);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild) + other_maker->calls(HeldMaker::kBuild), 1);
  EXPECT_EQ(first.builds_started() + second.builds_started(), 1u);
  // The lock file goes with the build.
  EXPECT_FALSE(
      fs::exists(GraphCache::BuildLockFile(first.GraphPath(mesh->fingerprint, key.params))));
}

// A replica that held the lock and died (its flock released) leaves the
// build to whoever asks next.
TEST_F(GraphCacheTest, ALockLeftByADeadReplicaDoesNotBlockTheBuild) {
  auto mesh = GridMesh("grid", 5);
  const GraphKey key{"grid", Eps(0.05)};
  GraphCache& cache = Cache();
  fs::create_directories(dir_);
  const std::string lock =
      GraphCache::BuildLockFile(cache.GraphPath(mesh->fingerprint, key.params));
  std::ofstream(lock) << "";
  cache.Request(mesh, key.params);
  EXPECT_FALSE(WaitFor(key, GraphState::kReady).from_file);
  EXPECT_EQ(maker_->calls(HeldMaker::kBuild), 1);
  EXPECT_FALSE(fs::exists(lock));
}

TEST_F(GraphCacheTest, StartUpRemovesOnlyOldBuildLocksNobodyHolds) {
  fs::create_directories(dir_);
  auto add = [&](const std::string& name, int age_s) {
    std::ofstream(dir_ / name) << "";
    fs::last_write_time(dir_ / name,
                        fs::file_time_type::clock::now() - std::chrono::seconds(age_s));
  };
  add(".dead-eps0.01-r2.dgg.lock", 600);
  add(".young-eps0.01-r2.dgg.lock", 5);
  add(".held-eps0.01-r2.dgg.lock", 600);
  add("graph-eps0.01-r2.dgg", 600);
  const int held = ::open((dir_ / ".held-eps0.01-r2.dgg.lock").c_str(), O_RDWR);
  ASSERT_EQ(::flock(held, LOCK_EX), 0);  // a live builder
  EXPECT_THAT(GraphCache::RemoveStaleBuildLocks(dir_, std::chrono::seconds(120)),
              ::testing::ElementsAre(".dead-eps0.01-r2.dgg.lock"));
  ::close(held);
  EXPECT_TRUE(fs::exists(dir_ / ".young-eps0.01-r2.dgg.lock"));
  EXPECT_TRUE(fs::exists(dir_ / ".held-eps0.01-r2.dgg.lock"));
  EXPECT_TRUE(fs::exists(dir_ / "graph-eps0.01-r2.dgg"));
}

// The moves of each graph's state machine, taken by driving a cache through
// requests, builds that finish or fail, cancels, evictions and requests
// again. Each walk returns the states one graph passed through, in order.
class GraphMovesTest : public GraphCacheTest {
 protected:
  using S = GraphState;
  using Trail = std::vector<GraphState>;
  static constexpr HeldMaker::Step kOpen = HeldMaker::kOpen, kBuild = HeldMaker::kBuild,
                                   kWrite = HeldMaker::kWrite;

  // A graph whose file is already in --graph-dir: mapped, not built.
  Trail MapsAFile() {
    Fresh();
    cache_->Request(mesh_, key_.params);
    WaitFor(key_, S::kReady);
    maker_ = std::make_shared<HeldMaker>();
    Cache();
    return Walk(mesh_, key_, {kOpen});
  }
  // With --graph-dir but no file: looked for, built, written.
  Trail BuildsAndWrites() {
    Fresh();
    return Walk(mesh_, key_, {kOpen, kBuild, kWrite});
  }
  // Without --graph-dir: built and served from memory.
  Trail BuildsInMemory() {
    Fresh(/*persist=*/false);
    return Walk(mesh_, key_, {kBuild});
  }
  // A build that fails, then a request that starts it again.
  Trail FailsAndIsRequestedAgain() {
    Fresh(/*persist=*/false);
    maker_->FailBuild(true);
    Trail trail = Walk(mesh_, key_, {kBuild});
    maker_->FailBuild(false);
    Trail again = Walk(mesh_, key_, {kBuild});
    trail.insert(trail.end(), again.begin(), again.end());
    return trail;
  }
  // A graph file the disk budget has no room for: the graph fails while
  // persisting. The budget's eviction, asked for room, looks at the state.
  Trail FailsWhilePersisting() {
    DggBuildOptions options;
    options.params = key_.params;
    auto graph = BuildDgg(*mesh_->mesh, options);
    EXPECT_TRUE(graph.ok()) << graph.status();
    if (!graph.ok()) return {};
    Fresh();
    fs::create_directories(dir_);
    constexpr uint64_t kLimit = 1 << 20;
    // The directory all but full: room for the edges the build writes into
    // its draft, not for the file around them. The graph alone would fit,
    // so the budget asks for room, and none is made.
    const uint64_t edges = (*graph)->num_directed_edges() * sizeof(DggHalfEdge);
    std::ofstream(dir_ / "filler") << std::string(kLimit - edges, 'x');
    std::vector<GraphState> seen;
    absl::Mutex seen_mu;
    DiskBudget disk(dir_, kLimit, [&](uint64_t) -> absl::StatusOr<uint64_t> {
      absl::MutexLock lock(&seen_mu);
      seen.push_back(cache_->Get(key_)->state);
      return DirectoryBytes(dir_);
    });
    EXPECT_TRUE(disk.Scan().ok());
    Cache(/*persist=*/true, /*memory_limit=*/0, &disk);
    Trail trail = Walk(mesh_, key_, {kOpen, kBuild});
    absl::MutexLock lock(&seen_mu);
    EXPECT_EQ(seen.size(), 1u) << "the budget was not asked for room";
    trail.insert(trail.end() - 1, seen.begin(), seen.end());
    cache_.reset();  // before the budget it points to goes
    return trail;
  }
  // A cancel while queued behind another build (no worker to tell), then a
  // request that makes it after all.
  Trail CancelledWhileQueued() {
    Fresh(/*persist=*/false);
    const GraphKey blocker{"grid", Eps(0.1)};
    maker_->Hold(kBuild);
    cache_->Request(mesh_, blocker.params);
    Trail trail;
    if (!maker_->AwaitReached(kBuild)) return trail;
    trail.push_back(cache_->Request(mesh_, key_.params).state);
    auto cancelled = cache_->Cancel(key_);
    trail.push_back(cancelled.ok() ? cancelled->state : S::kFailed);
    maker_->Release(kBuild);
    EXPECT_EQ(Settle(blocker), S::kReady);
    Trail again = Walk(mesh_, key_, {kBuild});
    trail.insert(trail.end(), again.begin(), again.end());
    return trail;
  }
  // A cancel while the worker is at `step` (a file to map for kOpen), then
  // a request that makes the graph after all.
  Trail CancelledAt(HeldMaker::Step step) {
    std::vector<HeldMaker::Step> held = {kOpen, kBuild, kWrite};
    if (step == kOpen) {
      MapsAFile();
      // A new cache, so that the graph is loading again.
      maker_ = std::make_shared<HeldMaker>();
      Cache();
      held = {kOpen};
    } else {
      Fresh();
      held.resize(step == kBuild ? 2 : 3);
    }
    Trail trail = Walk(mesh_, key_, held, [&] { ASSERT_TRUE(cache_->Cancel(key_).ok()); });
    // Only a graph cancelled mid-build has no file to map: a cancel while
    // writing comes too late to stop the file.
    Trail again =
        Walk(mesh_, key_, step == kBuild ? std::vector{kOpen, kBuild, kWrite} : std::vector{kOpen});
    trail.insert(trail.end(), again.begin(), again.end());
    return trail;
  }
  // Evicted over the memory budget by another graph, then requested again:
  // mapped from its file.
  Trail EvictedAndMappedAgain() {
    Fresh(/*persist=*/true, /*memory_limit=*/1);
    Trail trail = Walk(mesh_, key_, {kOpen, kBuild, kWrite});
    const GraphKey other{"grid", Eps(0.1)};
    EXPECT_EQ(Walk(mesh_, other, {kOpen, kBuild, kWrite}).back(), S::kReady);
    trail.push_back(cache_->Get(key_)->state);
    Trail again = Walk(mesh_, key_, {kOpen});
    trail.insert(trail.end(), again.begin(), again.end());
    return trail;
  }

  std::shared_ptr<const RegisteredMesh> mesh_ = GridMesh("grid", 5);
  const GraphKey key_{"grid", Eps(0.05)};
};

TEST_F(GraphMovesTest, AGraphWhoseFileIsThereIsMappedNotBuilt) {
  EXPECT_THAT(MapsAFile(), ::testing::ElementsAre(S::kQueued, S::kLoading, S::kReady));
  EXPECT_TRUE(cache_->Get(key_)->from_file);
  EXPECT_EQ(maker_->calls(kBuild), 0);
}

TEST_F(GraphMovesTest, ANewGraphIsLookedForThenBuiltThenWritten) {
  EXPECT_THAT(BuildsAndWrites(), ::testing::ElementsAre(S::kQueued, S::kLoading, S::kBuilding,
                                                        S::kPersisting, S::kReady));
  EXPECT_FALSE(cache_->Get(key_)->from_file);
  EXPECT_TRUE(fs::exists(cache_->GraphPath(mesh_->fingerprint, key_.params)));
}

TEST_F(GraphMovesTest, WithoutAGraphDirAGraphIsBuiltAndNotWritten) {
  EXPECT_THAT(BuildsInMemory(), ::testing::ElementsAre(S::kQueued, S::kBuilding, S::kReady));
  EXPECT_EQ(maker_->calls(kWrite), 0);
  EXPECT_FALSE(cache_->Get(key_)->mapped);
}

TEST_F(GraphMovesTest, AFailedBuildIsFailedUntilRequestedAgain) {
  EXPECT_THAT(FailsAndIsRequestedAgain(),
              ::testing::ElementsAre(S::kQueued, S::kBuilding, S::kFailed, S::kQueued, S::kBuilding,
                                     S::kReady));
}

TEST_F(GraphMovesTest, AGraphFileTheDiskHasNoRoomForFailsTheGraphWhilePersisting) {
  EXPECT_THAT(FailsWhilePersisting(), ::testing::ElementsAre(S::kQueued, S::kLoading, S::kBuilding,
                                                             S::kPersisting, S::kFailed));
  EXPECT_EQ(maker_->calls(kWrite), 0);
}

TEST_F(GraphMovesTest, ACancelWhileQueuedTakesEffectAtOnce) {
  EXPECT_THAT(CancelledWhileQueued(), ::testing::ElementsAre(S::kQueued, S::kCancelled, S::kQueued,
                                                             S::kBuilding, S::kReady));
}

TEST_F(GraphMovesTest, ACancelAtEachStepEndsCancelledAndARequestMakesItAgain) {
  EXPECT_THAT(CancelledAt(kOpen), ::testing::ElementsAre(S::kQueued, S::kLoading, S::kCancelled,
                                                         S::kQueued, S::kLoading, S::kReady));
  EXPECT_THAT(CancelledAt(kBuild), ::testing::ElementsAre(S::kQueued, S::kLoading, S::kBuilding,
                                                          S::kCancelled, S::kQueued, S::kLoading,
                                                          S::kBuilding, S::kPersisting, S::kReady));
  EXPECT_THAT(CancelledAt(kWrite),
              ::testing::ElementsAre(S::kQueued, S::kLoading, S::kBuilding, S::kPersisting,
                                     S::kCancelled, S::kQueued, S::kLoading, S::kReady));
}

TEST_F(GraphMovesTest, AnEvictedGraphIsMappedAgainWhenRequested) {
  EXPECT_THAT(EvictedAndMappedAgain(),
              ::testing::ElementsAre(S::kQueued, S::kLoading, S::kBuilding, S::kPersisting,
                                     S::kReady, S::kEvicted, S::kQueued, S::kLoading, S::kReady));
  EXPECT_TRUE(cache_->Get(key_)->from_file);
}

// Every move the walks take is one the table allows, and every move the
// table allows is one some walk takes: the table has no rule the cache
// never uses, and the cache no move the table refuses.
TEST_F(GraphMovesTest, TheCacheTakesEveryMoveTheTableAllowsAndNoOther) {
  std::set<std::pair<S, S>> taken;
  for (const Trail& trail :
       {MapsAFile(), BuildsAndWrites(), BuildsInMemory(), FailsAndIsRequestedAgain(),
        FailsWhilePersisting(), CancelledWhileQueued(), CancelledAt(kOpen), CancelledAt(kBuild),
        CancelledAt(kWrite), EvictedAndMappedAgain()}) {
    for (size_t i = 1; i < trail.size(); ++i) taken.insert({trail[i - 1], trail[i]});
  }
  for (const auto& [from, to] : taken) {
    EXPECT_TRUE(LegalTransition(from, to))
        << "taken but not allowed: " << GraphStateName(from) << " -> " << GraphStateName(to);
  }
  for (int from = 0; from < kGraphStateCount; ++from) {
    for (int to = 0; to < kGraphStateCount; ++to) {
      // Loading never fails: a file that cannot be mapped is rebuilt.
      if (S(from) == S::kLoading && S(to) == S::kFailed) continue;
      if (LegalTransition(S(from), S(to))) {
        EXPECT_TRUE(taken.count({S(from), S(to)}))
            << "allowed but never taken: " << GraphStateName(S(from)) << " -> "
            << GraphStateName(S(to));
      }
    }
  }
}

// What a call would make an illegal move is refused: the graph stays where
// it is, and nothing is built again.
TEST_F(GraphMovesTest, CallsThatWouldMakeAnIllegalMoveLeaveTheGraphWhereItIs) {
  Fresh(/*persist=*/false);
  const GraphKey failing{"grid", Eps(0.2)}, cancelled{"grid", Eps(0.3)};
  maker_->Hold(kBuild);
  cache_->Request(mesh_, key_.params);
  ASSERT_TRUE(maker_->AwaitReached(kBuild));
  // building -> queued: a request while it builds joins the build.
  EXPECT_EQ(cache_->Request(mesh_, key_.params).state, S::kBuilding);
  // queued -> queued again: a second request joins the first.
  EXPECT_EQ(cache_->Request(mesh_, cancelled.params).state, S::kQueued);
  const uint64_t version = cache_->Get(cancelled)->version;
  EXPECT_EQ(cache_->Request(mesh_, cancelled.params).state, S::kQueued);
  EXPECT_EQ(cache_->Get(cancelled)->version, version);
  ASSERT_EQ(cache_->Cancel(cancelled)->state, S::kCancelled);
  maker_->Release(kBuild);
  ASSERT_EQ(Settle(key_), S::kReady);
  EXPECT_EQ(maker_->calls(kBuild), 1);

  // ready -> cancelled, ready -> queued.
  EXPECT_EQ(cache_->Cancel(key_)->state, S::kReady);
  EXPECT_EQ(cache_->Request(mesh_, key_.params).state, S::kReady);
  EXPECT_EQ(Settle(key_), S::kReady);
  EXPECT_EQ(maker_->calls(kBuild), 1);

  // cancelled -> cancelled again, and no use restarts it: only a request.
  EXPECT_EQ(cache_->Cancel(cancelled)->state, S::kCancelled);
  EXPECT_EQ(cache_->Acquire(cancelled).status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(cache_->Get(cancelled)->state, S::kCancelled);

  // failed -> cancelled, and no use restarts it either.
  maker_->FailBuild(true);
  cache_->Request(mesh_, failing.params);
  ASSERT_EQ(Settle(failing), S::kFailed);
  EXPECT_EQ(cache_->Cancel(failing)->state, S::kFailed);
  EXPECT_EQ(cache_->Acquire(failing).status().code(), absl::StatusCode::kFailedPrecondition);
  EXPECT_EQ(cache_->Get(failing)->state, S::kFailed);
  EXPECT_EQ(maker_->calls(kBuild), 2);

  // evicted -> cancelled.
  Fresh(/*persist=*/true, /*memory_limit=*/1);
  cache_->Request(mesh_, key_.params);
  ASSERT_EQ(Settle(key_), S::kReady);
  cache_->Request(mesh_, failing.params);
  ASSERT_EQ(Settle(failing), S::kReady);
  ASSERT_EQ(cache_->Get(key_)->state, S::kEvicted);
  EXPECT_EQ(cache_->Cancel(key_)->state, S::kEvicted);
  EXPECT_EQ(cache_->Get(key_)->state, S::kEvicted);
}

}  // namespace
}  // namespace geodesic::server
