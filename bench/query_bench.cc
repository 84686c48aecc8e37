#include "bench/query_bench.h"

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cstdio>
#include <mutex>
#include <thread>
#include <vector>

#include "core/dgg/graph_file.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/geodesic_engine.h"
#include "core/query/search_work.h"

namespace geodesic::bench {
namespace {

using cli::Common;
using Clock = std::chrono::steady_clock;

struct MeshSize {
  uint32_t vertices = 0, faces = 0;
};

// Random vertices, or points inside faces with random barycentrics, from a
// seed of the worker's own (xorshift): the same points for a daemon's load
// and a local one.
class RandomPoints {
 public:
  RandomPoints(int worker, MeshSize mesh, bool face_points)
      : state_(0x9e3779b97f4a7c15ull * (worker + 1)), mesh_(mesh), face_points_(face_points) {}

  void Pick(v1::SurfacePoint* p) {
    const SurfacePoint drawn = PickLocal();
    if (drawn.kind == SurfacePoint::Kind::kVertex) {
      p->set_vertex(drawn.id);
      return;
    }
    auto* f = p->mutable_face();
    f->set_face(drawn.id);
    f->set_b0(drawn.bary[0]);
    f->set_b1(drawn.bary[1]);
    f->set_b2(drawn.bary[2]);
  }

  SurfacePoint PickLocal() {
    if (!face_points_) return SurfacePoint::Vertex(static_cast<uint32_t>(Next() % mesh_.vertices));
    const double u = (Next() >> 11) * 0x1p-53, v = (Next() >> 11) * 0x1p-53;
    const double b0 = u + v > 1 ? 1 - u : u, b1 = u + v > 1 ? 1 - v : v;
    const auto face = static_cast<uint32_t>(Next() % mesh_.faces);
    return SurfacePoint::Face(face, b0, b1, 1 - b0 - b1);
  }

 private:
  uint64_t Next() {
    state_ ^= state_ << 13, state_ ^= state_ >> 7, state_ ^= state_ << 17;
    return state_;
  }

  uint64_t state_;
  MeshSize mesh_;
  bool face_points_;
};

// What the workers share: the stub, the limits, and what they measured.
struct Load {
  const Common& c;
  const BenchOptions& options;
  MeshSize mesh;
  v1::Geodesic::Stub* stub;
  Clock::time_point stop;
  std::atomic<int> issued{0}, failed{0};
  std::mutex mu{};
  std::vector<double> latencies{};  // seconds of each answered query
};

void Worker(Load& load, int worker) {
  RandomPoints points(worker, load.mesh, load.options.face_points);
  std::vector<double> mine;
  while (Clock::now() < load.stop && load.issued.fetch_add(1) < load.options.count) {
    v1::DistanceRequest req;
    *req.mutable_graph() = cli::Selector(load.c);
    req.set_with_path(load.options.with_path);
    auto* p = req.add_pairs();
    points.Pick(p->mutable_from());
    points.Pick(p->mutable_to());
    grpc::ClientContext ctx;
    cli::Prepare(&ctx, load.c);
    v1::DistanceResponse resp;
    const auto t0 = Clock::now();
    grpc::Status s = load.stub->Distance(&ctx, req, &resp);
    const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
    if (s.ok()) {
      mine.push_back(dt);
    } else {
      ++load.failed;
    }
  }
  std::lock_guard<std::mutex> lock(load.mu);
  load.latencies.insert(load.latencies.end(), mine.begin(), mine.end());
}

// `work`: what the searches did, summed over the answered queries, when the
// load ran here (a daemon does not say); reported per query.
void Report(const Common& c, std::vector<double> latencies, int failed, double elapsed,
            int concurrency, const SearchWork* work = nullptr) {
  std::sort(latencies.begin(), latencies.end());
  auto pct = [&](double q) {
    return latencies.empty() ? 0.0 : latencies[static_cast<size_t>(q * (latencies.size() - 1))];
  };
  const double qps = latencies.size() / elapsed;
  auto per_query = [&](uint64_t total) {
    return latencies.empty() ? 0.0 : double(total) / latencies.size();
  };
  if (c.json) {
    nlohmann::ordered_json out = {{"queries", latencies.size()}, {"failed", failed},
                                  {"seconds", elapsed},          {"qps", qps},
                                  {"p50_ms", 1e3 * pct(0.5)},    {"p90_ms", 1e3 * pct(0.9)},
                                  {"p99_ms", 1e3 * pct(0.99)},   {"max_ms", 1e3 * pct(1.0)},
                                  {"concurrency", concurrency}};
    if (work) {
      out["edges_relaxed_per_query"] = per_query(work->relaxed);
      out["labels_improved_per_query"] = per_query(work->improved);
      out["queue_pushes_per_query"] = per_query(work->pushes);
      out["queue_pops_per_query"] = per_query(work->pops);
      out["graph_bytes_per_query"] = per_query(work->graph_bytes);
    }
    cli::PrintJson(out);
    return;
  }
  std::printf(
      "%zu queries (%d failed) in %.2f s: %.1f queries/s; latency p50 %.3f ms, p90 %.3f "
      "ms, p99 %.3f ms, max %.3f ms\n",
      latencies.size(), failed, elapsed, qps, 1e3 * pct(0.5), 1e3 * pct(0.9), 1e3 * pct(0.99),
      1e3 * pct(1.0));
  if (work) {
    std::printf(
        "work per query: %.1f edges relaxed, %.1f labels improved, %.1f queue pushes, %.1f "
        "queue pops, %.0f bytes of graph read\n",
        per_query(work->relaxed), per_query(work->improved), per_query(work->pushes),
        per_query(work->pops), per_query(work->graph_bytes));
  }
}

// The same load on an engine in this process (--local), each answer's
// search work summed: per worker, added up once it stops.
struct LocalLoad {
  const BenchOptions& options;
  const GeodesicEngine& engine;
  MeshSize mesh;
  Clock::time_point stop;
  std::atomic<int> issued{0}, failed{0};
  std::mutex mu{};
  std::vector<double> latencies{};
  SearchWork work{};
};

void LocalWorker(LocalLoad& load, int worker) {
  RandomPoints points(worker, load.mesh, load.options.face_points);
  PairOptions pair;
  pair.want_path = load.options.with_path;
  std::vector<double> mine;
  SearchWork work;
  while (Clock::now() < load.stop && load.issued.fetch_add(1) < load.options.count) {
    const SurfacePoint a = points.PickLocal(), b = points.PickLocal();
    const auto t0 = Clock::now();
    absl::StatusOr<PairResult> r = load.engine.Distance(a, b, pair);
    const double dt = std::chrono::duration<double>(Clock::now() - t0).count();
    if (r.ok()) {
      mine.push_back(dt);
      work += r->work;
    } else {
      ++load.failed;
    }
  }
  std::lock_guard<std::mutex> lock(load.mu);
  load.latencies.insert(load.latencies.end(), mine.begin(), mine.end());
  load.work += work;
}

int FailLocal(const absl::Status& s) {
  std::fprintf(stderr, "query_bench: %s\n", s.ToString().c_str());
  return 1;
}

// The mesh file's DGG at --eps, built here, with the landmarks a daemon
// prepares, so that the queries do the work they do there.
int RunLocalBench(const Common& c, const BenchOptions& options) {
  absl::StatusOr<Mesh> loaded = LoadMesh(options.local_mesh);
  if (!loaded.ok()) return FailLocal(loaded.status());
  auto mesh = std::make_shared<const Mesh>(*std::move(loaded));
  if (options.face_points && mesh->num_faces() == 0) {
    return FailLocal(absl::FailedPreconditionError("the mesh has no faces"));
  }
  absl::StatusOr<std::shared_ptr<const DggGraph>> graph;
  if (!options.local_graph.empty()) {
    graph = GraphFile::Open(options.local_graph, *mesh, GraphFile::Check::kFull);
  } else {
    DggBuildOptions build;
    build.params.epsilon = c.epsilon > 0 ? c.epsilon : kLocalEpsilon;
    graph = BuildDgg(*mesh, build);
  }
  if (!graph.ok()) return FailLocal(graph.status());
  const GeodesicEngine engine(mesh, *graph);
  if (absl::Status s = engine.PrepareLandmarks(engine.DefaultLandmarkCount()); !s.ok()) {
    return FailLocal(s);
  }
  const auto start = Clock::now();
  LocalLoad load{
      options,
      engine,
      {static_cast<uint32_t>(mesh->num_vertices()), static_cast<uint32_t>(mesh->num_faces())},
      start + std::chrono::milliseconds(static_cast<int64_t>(options.duration * 1000))};
  std::vector<std::thread> workers;
  for (int w = 0; w < options.concurrency; ++w) {
    workers.emplace_back(LocalWorker, std::ref(load), w);
  }
  for (auto& t : workers) t.join();
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  Report(c, std::move(load.latencies), load.failed.load(), elapsed, options.concurrency,
         &load.work);
  return load.failed.load() ? 1 : 0;
}

}  // namespace

void AddBenchFlags(CLI::App& app, BenchOptions& o) {
  app.add_option("--concurrency", o.concurrency, "parallel clients");
  app.add_option("--duration", o.duration, "stop after this many seconds");
  app.add_option("--count", o.count, "stop after this many queries");
  app.add_flag("--path", o.with_path, "also request paths");
  app.add_flag("--face-points", o.face_points,
               "random points inside faces (each end then joined to the graph by its own "
               "exact direct geodesics) instead of random vertices");
  app.add_option("--local", o.local_mesh,
                 "query this mesh file's DGG (built at --eps, else 1e-3) in this process instead "
                 "of a daemon, and report each query's search work too (edges relaxed, labels "
                 "improved, queue pushes and pops, bytes of graph read)");
  app.add_option("--local-graph", o.local_graph,
                 "with --local: query this graph file of the mesh (geodesicd build) instead "
                 "of building one, to compare graphs of two builds")
      ->needs("--local");
}

int RunBench(const Common& c, const BenchOptions& options) {
  if (!options.local_mesh.empty()) return RunLocalBench(c, options);
  auto stub = cli::Connect(c);
  MeshSize mesh;
  {
    grpc::ClientContext ctx;
    cli::Prepare(&ctx, c);
    v1::GetMeshRequest req;
    req.set_name(c.mesh);
    v1::Mesh m;
    grpc::Status s = stub->GetMesh(&ctx, req, &m);
    if (!s.ok()) return cli::Fail(s);
    mesh = {static_cast<uint32_t>(m.diagnostics().vertices()),
            static_cast<uint32_t>(m.diagnostics().faces())};
  }
  if (options.face_points && mesh.faces == 0) {
    return cli::Fail(grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "the mesh has no faces"));
  }
  const auto start = Clock::now();
  Load load{c, options, mesh, stub.get(),
            start + std::chrono::milliseconds(static_cast<int64_t>(options.duration * 1000))};
  std::vector<std::thread> workers;
  for (int w = 0; w < options.concurrency; ++w) workers.emplace_back(Worker, std::ref(load), w);
  for (auto& t : workers) t.join();
  const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
  Report(c, std::move(load.latencies), load.failed.load(), elapsed, options.concurrency);
  return load.failed.load() ? 1 : 0;
}

}  // namespace geodesic::bench
