// Microbenchmarks of the hot loops, on the bundled sample mesh (or the mesh
// in $GEODESIC_BENCH_MESH) at the epsilon in $GEODESIC_BENCH_EPS (1e-2), with
// its graph built at start or mapped from $GEODESIC_BENCH_GRAPH:
//   build/bin/micro_benchmarks [--benchmark_filter=...]
// The end-to-end figures of BENCHMARKS.md come from bench/run_benchmarks.py.
#include <benchmark/benchmark.h>

#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <optional>
#include <random>

#include "core/base/radix_heap.h"
#include "core/dgg/graph_file.h"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/augmented_graph.h"
#include "core/query/build_dgg.h"
#include "core/query/field_lanes.h"
#include "core/query/geodesic_engine.h"
#include "core/query/graph_search.h"
#include "tests/core/radix_heap_workload.h"

namespace geodesic {
namespace {

struct Fixture {
  std::shared_ptr<const Mesh> mesh;
  std::shared_ptr<const DggGraph> graph;
  std::unique_ptr<GeodesicEngine> engine;
  std::string graph_path;
  double epsilon = 1e-2;
};

// The value, or the error on stderr and exit: a benchmark without its
// fixture has nothing to measure.
template <typename T>
T OrExit(absl::StatusOr<T> value) {
  if (!value.ok()) {
    std::fprintf(stderr, "%s\n", std::string(value.status().message()).c_str());
    std::exit(1);
  }
  return *std::move(value);
}

// Loaded once: every benchmark shares the mesh, its graph and its file.
const Fixture& Shared() {
  static const Fixture* fixture = [] {
    auto* f = new Fixture;
    const char* path = std::getenv("GEODESIC_BENCH_MESH");
    const char* eps = std::getenv("GEODESIC_BENCH_EPS");
    if (eps) f->epsilon = std::atof(eps);
    f->mesh = std::make_shared<const Mesh>(
        OrExit(LoadMesh(path ? path : GEODESIC_SOURCE_DIR "/data/spot.obj")));
    if (const char* graph = std::getenv("GEODESIC_BENCH_GRAPH")) {
      f->graph = OrExit(GraphFile::Open(graph, *f->mesh, GraphFile::Check::kFull));
      f->epsilon = f->graph->params().epsilon;
    } else {
      DggBuildOptions options;
      options.params.epsilon = f->epsilon;
      f->graph = OrExit(BuildDgg(*f->mesh, options));
    }
    f->engine = std::make_unique<GeodesicEngine>(f->mesh, f->graph);
    f->graph_path = (std::filesystem::temp_directory_path() /
                     ("micro_benchmarks." + std::to_string(getpid()) + ".dgg"))
                        .string();
    if (!GraphFile::Write(*f->graph, f->graph_path).ok()) std::exit(1);
    std::atexit([] { std::filesystem::remove(Shared().graph_path); });
    return f;
  }();
  return *fixture;
}

// Sources spread over the mesh, the same in every run.
VertexId SourceAt(int64_t i, const Mesh& mesh) {
  return static_cast<VertexId>((i * 7919) % mesh.num_vertices());
}

SurfacePoint RandomFacePoint(std::mt19937& rng, const Mesh& mesh) {
  std::uniform_real_distribution<double> u(0, 1);
  double a = u(rng), b = u(rng);
  if (a + b > 1) a = 1 - a, b = 1 - b;
  const FaceId f = std::uniform_int_distribution<FaceId>(0, mesh.num_faces() - 1)(rng);
  return SurfacePoint::Face(f, 1 - a - b, a, b);
}

// Direct-only propagation from one vertex (the candidate phase's unit of
// work). Arg 1: our corner early stop; arg 0: plain Algorithm 1 (Theorem 2's
// d_max only). The windows/source counter is the comparison the issue asks.
void BM_DirectPropagation(benchmark::State& state) {
  const Fixture& f = Shared();
  ExactGeodesic engine(*f.mesh);
  DirectOptions options;
  options.epsilon = f.epsilon;
  options.stop_at_corners = state.range(0) != 0;
  uint64_t windows = 0, hits = 0, sources = 0;
  for (auto _ : state) {
    auto h = engine.DirectGeodesics(SurfacePoint::Vertex(SourceAt(sources++, *f.mesh)), options);
    windows += engine.stats().windows_created;
    hits += h->size();
  }
  state.counters["windows/source"] = double(windows) / sources;
  state.counters["candidates/source"] = double(hits) / sources;
}
BENCHMARK(BM_DirectPropagation)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// Full exact field (the accuracy oracle), reading face frames as every
// caller of whole fields does.
void BM_ExactField(benchmark::State& state) {
  const Fixture& f = Shared();
  const FaceFrames frames(*f.mesh);
  ExactGeodesic engine(*f.mesh, &frames);
  int64_t i = 0;
  for (auto _ : state) {
    benchmark::DoNotOptimize(engine.Distances(SurfacePoint::Vertex(SourceAt(i++, *f.mesh))));
  }
  state.counters["windows/vertex"] =
      double(engine.stats().windows_created) / f.mesh->num_vertices();
}
BENCHMARK(BM_ExactField)->Unit(benchmark::kMillisecond);

// Everything after the candidates: symmetrization, pruning, fans.
void BM_PruneAndFans(benchmark::State& state) {
  const Fixture& f = Shared();
  DggBuildOptions options;
  options.params.epsilon = f.epsilon;
  options.threads = 1;
  auto part = *BuildDggCandidatePart(*f.mesh, options, 0, 1);
  for (auto _ : state) {
    state.PauseTiming();
    std::vector<DggCandidatePart> parts = {part};
    state.ResumeTiming();
    benchmark::DoNotOptimize(MergeDggParts(*f.mesh, std::move(parts), options));
  }
}
BENCHMARK(BM_PruneAndFans)->Unit(benchmark::kMillisecond);

void BM_Field(benchmark::State& state) {
  const Fixture& f = Shared();
  FieldOptions options;
  options.method = state.range(0) ? FieldMethod::kDijkstra : FieldMethod::kLabelCorrecting;
  int64_t i = 0;
  for (auto _ : state) {
    const SurfacePoint source = SurfacePoint::Vertex(SourceAt(i++, *f.mesh));
    benchmark::DoNotOptimize(f.engine->Field({&source, 1}, options));
  }
  state.SetLabel(state.range(0) ? "dijkstra" : "label-correcting");
  state.counters["ns/vertex"] =
      benchmark::Counter(double(f.mesh->num_vertices()) * state.iterations(),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_Field)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// One sweep of kFieldLanes vertex sources next to each other in node order,
// as a matrix groups them (its unit of work), by the kernel of
// query_internal::LaneKernel's value (first arg; one the machine cannot run
// is skipped), from the graph's edges (second arg 0) or a compact copy (1),
// as `geodesicd matrix` reads them.
void BM_LaneSweep(benchmark::State& state) {
  using query_internal::LaneKernel;
  const auto kernel = static_cast<LaneKernel>(state.range(0));
  const char* names[] = {"best", "avx512", "avx2", "portable"};
  state.SetLabel(names[state.range(0)]);
  if (!query_internal::LaneKernelRuns(kernel)) {
    state.SkipWithError("this machine does not run this kernel");
    return;
  }
  const Fixture& f = Shared();
  const BucketShape shape = BucketShapeOf(*f.graph);
  const LaneFanLayout layout = LaneFanLayoutFor(*f.graph);
  std::optional<query_internal::CompactLaneEdges> compact;
  if (state.range(1) != 0) compact = query_internal::CompactLaneEdges::Of(*f.graph);
  const query_internal::CompactLaneEdges* compact_edges = compact ? &*compact : nullptr;
  QueryScratch sc;
  int64_t i = 0;
  uint64_t pops = 0, relaxed = 0;
  for (auto _ : state) {
    std::vector<query_internal::Endpoint> sources;
    const uint32_t first = SourceAt(i++, *f.mesh) % (f.mesh->num_vertices() - kFieldLanes);
    for (uint32_t k = 0; k < kFieldLanes; ++k) {
      const SurfacePoint p = SurfacePoint::Vertex(f.graph->vertex_of_node(first + k));
      sources.push_back(OrExit(query_internal::JoinToGraph(*f.mesh, *f.graph, sc, p, false)));
    }
    auto stats = query_internal::SolveFieldLanes(*f.graph, shape, layout, compact_edges, sc,
                                                 sources, kInfinity, nullptr, kernel);
    if (!stats.ok()) std::exit(1);
    pops += stats->queue_pops;
    relaxed += stats->relaxed;
  }
  state.counters["pops/sweep"] = double(pops) / state.iterations();
  state.counters["relaxed/sweep"] = double(relaxed) / state.iterations();
  state.counters["ns/vertex/source"] =
      benchmark::Counter(double(f.mesh->num_vertices()) * kFieldLanes * state.iterations(),
                         benchmark::Counter::kIsRate | benchmark::Counter::kInvert);
}
BENCHMARK(BM_LaneSweep)->ArgsProduct({{0, 1, 2, 3}, {0, 1}})->Unit(benchmark::kMillisecond);

// Point-to-point between random face points. Arg: 1 bidirectional A*,
// 0 bidirectional Dijkstra; counter: nodes settled per query.
void BM_PointToPoint(benchmark::State& state) {
  const Fixture& f = Shared();
  std::mt19937 rng(7);
  PairOptions options;
  options.use_astar = state.range(0) != 0;
  uint64_t settled = 0;
  for (auto _ : state) {
    auto r =
        f.engine->Distance(RandomFacePoint(rng, *f.mesh), RandomFacePoint(rng, *f.mesh), options);
    settled += r->settled;
  }
  state.SetLabel(options.use_astar ? "A*" : "dijkstra");
  state.counters["settled"] = double(settled) / state.iterations();
}
BENCHMARK(BM_PointToPoint)->Arg(1)->Arg(0)->Unit(benchmark::kMicrosecond);

// Point-to-point with the path traced on the surface.
void BM_PathTrace(benchmark::State& state) {
  const Fixture& f = Shared();
  std::mt19937 rng(11);
  PairOptions options;
  options.want_path = true;
  for (auto _ : state) {
    benchmark::DoNotOptimize(
        f.engine->Distance(RandomFacePoint(rng, *f.mesh), RandomFacePoint(rng, *f.mesh), options));
  }
}
BENCHMARK(BM_PathTrace)->Unit(benchmark::kMicrosecond);

// Mapping a graph file: header checks only, or every checksum and index.
void BM_GraphOpen(benchmark::State& state) {
  const Fixture& f = Shared();
  const auto check = state.range(0) ? GraphFile::Check::kFull : GraphFile::Check::kHeader;
  for (auto _ : state) {
    benchmark::DoNotOptimize(GraphFile::Open(f.graph_path, *f.mesh, check));
  }
  state.SetLabel(state.range(0) ? "full" : "header");
}
BENCHMARK(BM_GraphOpen)->Arg(0)->Arg(1)->Unit(benchmark::kMicrosecond);

// The radix heap when every push lands inside its sorted run: 64 keys in
// one bucket, then each pop pushes two keys just above the popped one. Arg:
// pops. Time per pop stays flat as the pops grow only if the run is bounded.
void BM_RadixHeapPushesIntoTheRun(benchmark::State& state) {
  auto pushed = [](double) {};
  for (auto _ : state) {
    RadixHeap<uint32_t> heap;
    testing::FillOneBucket(heap, pushed);
    testing::PushIntoTheRun(
        heap, state.range(0), [](int64_t, double) { return true; }, pushed);
    benchmark::DoNotOptimize(heap.size());
  }
  state.SetItemsProcessed(state.iterations() * state.range(0));
}
BENCHMARK(BM_RadixHeapPushesIntoTheRun)->Arg(2000)->Arg(20000)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace geodesic

BENCHMARK_MAIN();
