// geodesicd build: construct the discrete geodesic graph of a mesh.
#include <sys/resource.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <functional>
#include <optional>
#include <string_view>
#include <vector>

#include "CLI/CLI.hpp"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "absl/strings/str_split.h"
#include "core/base/status.h"
#include "core/dgg/dgg_part_file.h"
#include "core/dgg/graph_file.h"
#include "core/mesh/mesh_io.h"
#include "core/query/build_dgg.h"
#include "core/query/certified_graph.h"
#include "server/base/byte_size.h"
#include "server/offline/certificate_file.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {
namespace {

uint64_t PeakMemoryBytes() {
  struct rusage usage;
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<uint64_t>(usage.ru_maxrss) * 1024;
}

// A progress bar on stderr when it is a terminal.
std::function<bool(std::string_view, double)> ProgressBar(bool enabled) {
  if (!enabled || !isatty(STDERR_FILENO)) return nullptr;
  return [](std::string_view phase, double fraction) {
    const int width = 40, filled = static_cast<int>(fraction * width);
    std::fprintf(stderr, "\r%-10.*s [%s%s] %5.1f%%", static_cast<int>(phase.size()), phase.data(),
                 std::string(filled, '#').c_str(), std::string(width - filled, ' ').c_str(),
                 100 * fraction);
    return true;
  };
}

// The certificate's line of `build --max-error`'s report.
void PrintCertificate(const GraphCertificate& c) {
  std::printf(
      "certified max error %g: measured max %.6g, mean %.6g over every vertex from %u random "
      "vertex sources (seed %llu), sound; eps %g after %u build%s\n",
      c.max_error_bound, c.measured_max_error, c.measured_mean_error, c.sources,
      static_cast<unsigned long long>(c.seed), c.epsilon, c.builds, c.builds == 1 ? "" : "s");
}

// Where the graph goes: --out, or its name under --graph-dir (made if need be).
std::string GraphPath(const std::string& out_path, const std::string& graph_dir,
                      uint64_t mesh_fingerprint, const DggParams& params) {
  if (!out_path.empty()) return out_path;
  std::error_code ignored;  // a failure shows up as the write's error
  std::filesystem::create_directories(graph_dir, ignored);
  return graph_dir + "/" + GraphFileName(mesh_fingerprint, params);
}

// The graph file a build or merge keeps its edges in as it makes them, so
// that they never take its memory (GraphFileDraft); none with pseudo
// vertices, whose node count the build decides.
absl::StatusOr<std::optional<GraphFileDraft>> DraftFor(const Mesh& mesh, const DggParams& params,
                                                       const std::string& out_path,
                                                       const std::string& graph_dir,
                                                       DggBuildOptions& options) {
  if (params.pseudo_vertices) return std::nullopt;
  ASSIGN_OR_RETURN(
      GraphFileDraft draft,
      GraphFileDraft::Create(GraphPath(out_path, graph_dir, MeshFingerprint(mesh), params),
                             mesh.num_vertices()));
  draft.AttachTo(options);
  return std::optional<GraphFileDraft>(std::move(draft));
}

// Writes the graph, and its certificate beside it (or removes a stale one),
// and prints what `build` and `merge` report.

int WriteAndReport(const char* command, const WorkMesh& work, const DggGraph& graph,
                   const DggBuildStats& stats, std::string out_path, const std::string& graph_dir,
                   int threads, bool json, const GraphCertificate* certificate = nullptr,
                   std::optional<GraphFileDraft> draft = std::nullopt) {
  out_path = GraphPath(out_path, graph_dir, graph.mesh_fingerprint(), graph.params());
  absl::Status written =
      draft ? std::move(*draft).Finish(graph) : GraphFile::Write(graph, out_path);
  if (written.ok()) {
    written =
        certificate ? WriteCertificate(out_path, graph, *certificate) : RemoveCertificate(out_path);
  }
  if (!written.ok()) return Fail(command, written);
  const Mesh& mesh = *work.mesh();
  const uint64_t file_bytes = std::filesystem::file_size(out_path);
  const size_t n = mesh.num_vertices();
  const double epsilon = graph.params().epsilon;
  if (json) {
    Json report = {{"vertices", n},
                   {"nodes", graph.num_nodes()},
                   {"pseudo_vertices", stats.pseudo_vertices},
                   {"pseudo_shots", stats.pseudo_shots},
                   {"pseudo_propagations", stats.pseudo_propagations},
                   {"edges", stats.edges},
                   {"candidate_edges", stats.candidate_edges},
                   {"average_degree", stats.average_degree},
                   {"max_degree", stats.max_degree},
                   {"found_edges", stats.found_edges},
                   {"found_degree", double(stats.found_edges) / std::max<size_t>(n, 1)},
                   {"epsilon", epsilon},
                   {"prune_redundant", graph.params().prune_redundant},
                   {"exact_fans", graph.params().exact_fans},
                   {"candidate_rule", graph.params().candidate_rule},
                   {"graph_file", out_path},
                   {"threads", threads},
                   {"build_seconds", stats.total_seconds},
                   {"candidate_seconds", stats.candidate_seconds},
                   {"pruning_seconds", stats.pruning_seconds},
                   {"pseudo_seconds", stats.pseudo_seconds},
                   {"fan_seconds", stats.fan_seconds},
                   {"windows_per_source", double(stats.windows_created) / std::max<size_t>(n, 1)},
                   {"average_fan", stats.average_fan},
                   {"peak_memory_bytes", PeakMemoryBytes()},
                   {"mesh_bytes", mesh.memory_bytes()},
                   {"spilled_bytes", stats.spilled_bytes},
                   {"file_bytes", file_bytes}};
    if (certificate) report["certificate"] = CertificateJson(*certificate);
    work.AddJson(report);
    PrintJson(report);
  } else {
    std::printf(
        "built %s: %zu vertices, %u pseudo vertices, %llu edges (average degree %.1f, max %u) "
        "at eps %g in %.2f s (candidates %.2f s, pruning %.2f s, pseudo %.2f s, fans %.2f s); "
        "%llu bytes\n",
        out_path.c_str(), n, stats.pseudo_vertices, static_cast<unsigned long long>(stats.edges),
        stats.average_degree, stats.max_degree, epsilon, stats.total_seconds,
        stats.candidate_seconds, stats.pruning_seconds, stats.pseudo_seconds, stats.fan_seconds,
        static_cast<unsigned long long>(file_bytes));
    if (certificate) PrintCertificate(*certificate);
  }
  return 0;
}

// `--part I/N`: the candidate edges of the I-th of N vertex ranges.
int BuildPart(const Mesh& mesh, const DggBuildOptions& options, const std::string& spec,
              const std::string& out_path, bool json) {
  uint32_t index = 0, count = 0;
  std::vector<std::string> fields = absl::StrSplit(spec, '/');
  if (fields.size() != 2 || !absl::SimpleAtoi(fields[0], &index) ||
      !absl::SimpleAtoi(fields[1], &count)) {
    return Fail("build", absl::InvalidArgumentError(absl::StrFormat(
                             "--part %s: expected I/N with 0 <= I < N, e.g. 0/3", spec)));
  }
  const auto start = std::chrono::steady_clock::now();
  auto part = BuildDggCandidatePart(mesh, options, index, count);
  if (options.progress) std::fprintf(stderr, "\n");
  if (!part.ok()) return Fail("build", part.status());
  if (absl::Status s = WriteDggPart(*part, out_path); !s.ok()) return Fail("build", s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  const uint32_t sources = part->end - part->begin;
  if (json) {
    PrintJson(
        {{"part", index},
         {"parts", count},
         {"begin", part->begin},
         {"end", part->end},
         {"epsilon", part->params.epsilon},
         {"prune_redundant", part->params.prune_redundant},
         {"exact_fans", part->params.exact_fans},
         {"candidate_rule", part->params.candidate_rule},
         {"candidate_half_edges", part->edges.size()},
         {"windows_per_source", double(part->windows_created) / std::max<uint32_t>(sources, 1)},
         {"build_seconds", seconds},
         {"file_bytes", std::filesystem::file_size(out_path)}});
  } else {
    std::printf("built part %u/%u of %s: vertices %u..%u, %zu candidate half-edges in %.2f s\n",
                index, count, out_path.c_str(), part->begin, part->end, part->edges.size(),
                seconds);
  }
  return 0;
}

}  // namespace

namespace {

struct BuildFlags {
  std::string mesh_path, out_path, part, graph_dir, memory_limit;
  double epsilon = 1e-3, pseudo_limit = 1, max_error = 0;
  uint32_t sources = CertifyOptions().sources;
  uint64_t seed = CertifyOptions().seed;
  int threads = 0;
  bool json = false, pseudo = false, quiet = false, prune = false, exact_fans = false,
       plain = false, repair = false;
  RegionFlags region;
};

void AddBuildFlags(CLI::App& app, BuildFlags& f) {
  app.add_option("mesh", f.mesh_path,
                 "mesh file (" + MeshFormatList() +
                     ": x.surf.gii); with a region, the graph is the region's, for this file and "
                     "the same region flags only")
      ->required();
  auto* eps =
      app.add_option("--eps", f.epsilon, "accuracy: relative error of graph distances, in (0, 1)");
  auto* max_error =
      app.add_option("--max-error", f.max_error,
                     "instead of --eps: a certified graph, whose largest relative error must stay "
                     "within this bound. The build eps is chosen from it with a margin; the graph "
                     "is checked against exact distances from --sources seeded random vertices "
                     "(at every vertex), rebuilt tighter when it misses, and published with its "
                     "certificate beside it (<graph>.certificate.json)")
          ->excludes(eps);
  app.add_option("--sources", f.sources,
                 "with --max-error: random vertex sources of the check (each costs one exact "
                 "solve)")
      ->check(CLI::PositiveNumber)
      ->needs(max_error);
  app.add_option("--seed", f.seed,
                 "with --max-error: seed of the first check's sources (a rebuild's check takes "
                 "the next seed)")
      ->needs(max_error);
  auto* out = app.add_option("--out", f.out_path,
                             "graph file (or part file with --part) to write, atomically");
  app.add_option("--graph-dir", f.graph_dir,
                 "instead of --out: write the graph under the name geodesicd serve looks for "
                 "in its --graph-dir")
      ->excludes(out);
  app.add_option("--threads", f.threads, "build threads (0: all cores)");
  app.add_flag("--pseudo-vertices", f.pseudo,
               "add pseudo vertices where edge directions leave gaps (section 4.3; for "
               "anisotropic meshes)");
  app.add_option("--pseudo-vertex-limit", f.pseudo_limit,
                 "with --pseudo-vertices: refuse the build, with its estimated cost, when it "
                 "would add more pseudo vertices than this many per mesh vertex (0: no limit)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  app.add_option("--part", f.part,
                 "I/N: only the candidate edges of the I-th (0-based) of N vertex ranges, for "
                 "'geodesicd merge'");
  app.add_flag("--exact-fans", f.exact_fans,
               "fans from each vertex's exact local distances instead of the default's short "
               "sweeps: about as narrow, for a longer build (same distances); parts record it "
               "for the merge");
  app.add_flag("--prune", f.prune,
               "also prune redundant edges (Algorithm 1, phase 2), giving it a tenth of eps: "
               "slower, and rarely smaller (see bench/notes.md); parts record it for the merge");
  app.add_flag("--plain-candidates", f.plain,
               "benchmarking: plain Algorithm 1 candidates (Theorem 2 only, no corner early "
               "stop)");
  app.add_flag("--json", f.json, "print a JSON object");
  app.add_flag("--quiet", f.quiet, "no progress bar");
  app.add_option("--build-memory-limit", f.memory_limit,
                 "candidate edges kept in memory (e.g. 4G); beyond it they go to an unlinked "
                 "file beside the output and are read back once. The graph itself is held once, "
                 "in place (default: no limit)");
  AddRepairFlag(app, &f.repair);
  AddRegionFlags(app, &f.region, false);
}

// `--max-error X`: build, check and rebuild until certified, then write the
// graph and its certificate.
int BuildCertified(const WorkMesh& work, const DggBuildOptions& build, const BuildFlags& f) {
  CertifyOptions options;
  options.build = build;
  options.build.progress = nullptr;
  options.sources = f.sources;
  options.seed = f.seed;
  if (build.progress) {
    options.progress = [bar = build.progress](uint32_t n, std::string_view phase, double fraction) {
      return bar(absl::StrFormat("build %u: %s", n, std::string(phase)), fraction);
    };
  }
  auto certified = BuildCertifiedGraph(work.mesh(), f.max_error, options);
  if (build.progress) std::fprintf(stderr, "\n");
  if (!certified.ok()) return Fail("build", certified.status());
  return WriteAndReport("build", work, *certified->graph, certified->stats, f.out_path, f.graph_dir,
                        f.threads, f.json, &certified->certificate);
}

}  // namespace

int RunBuild(int argc, char** argv) {
  CLI::App app{"Build the discrete geodesic graph (DGG) of a mesh", "geodesicd build"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  BuildFlags f;
  AddBuildFlags(app, f);
  CLI11_PARSE(app, argc, argv);
  uint64_t candidate_memory_limit = 0;
  if (!f.memory_limit.empty()) {
    auto parsed = server::ParseByteSize(f.memory_limit, "--build-memory-limit");
    if (!parsed.ok()) return Fail("build", parsed.status());
    candidate_memory_limit = *parsed;
  }
  if (f.out_path.empty() && (f.graph_dir.empty() || !f.part.empty())) {
    return Fail("build", absl::InvalidArgumentError(
                             "--out is required (or --graph-dir, for a whole graph)"));
  }
  auto work = LoadWorkMesh(f.mesh_path, f.repair, f.region);
  if (!work.ok()) return Fail("build", work.status());
  const Mesh& mesh = *work->mesh();
  DggBuildOptions options;
  options.params.epsilon = f.epsilon;
  options.params.pseudo_vertices = f.pseudo;
  options.pseudo_vertex_limit = f.pseudo_limit;
  options.threads = f.threads;
  options.stop_at_corners = !f.plain;
  options.params.prune_redundant = f.prune;
  options.params.exact_fans = f.exact_fans;
  options.progress = ProgressBar(!f.json && !f.quiet);
  options.candidate_memory_limit = candidate_memory_limit;
  options.spill_dir =
      f.out_path.empty() ? f.graph_dir : std::filesystem::path(f.out_path).parent_path().string();
  if (!f.part.empty()) {
    if (app.count("--max-error")) {
      return Fail("build", absl::InvalidArgumentError(
                               "--max-error certifies a whole graph: it cannot build a --part"));
    }
    return BuildPart(mesh, options, f.part, f.out_path, f.json);
  }
  if (app.count("--max-error")) return BuildCertified(*work, options, f);
  const bool bar = static_cast<bool>(options.progress);
  auto draft = DraftFor(mesh, options.params, f.out_path, f.graph_dir, options);
  if (!draft.ok()) return Fail("build", draft.status());
  DggBuildStats stats;
  auto graph = BuildDgg(mesh, options, &stats);
  if (bar) std::fprintf(stderr, "\n");
  if (!graph.ok()) return Fail("build", graph.status());
  return WriteAndReport("build", *work, **graph, stats, f.out_path, f.graph_dir, f.threads, f.json,
                        nullptr, std::move(*draft));
}

int RunMerge(int argc, char** argv) {
  CLI::App app{"Join the part files of a distributed build into the final graph",
               "geodesicd merge"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  std::string mesh_path, out_path;
  std::vector<std::string> part_paths;
  int threads = 0;
  bool json = false, quiet = false;
  app.add_option("mesh", mesh_path, "mesh file the parts were built for")->required();
  app.add_option("parts", part_paths, "part files (geodesicd build --part I/N), any order")
      ->required();
  std::string graph_dir;
  auto* out = app.add_option("--out", out_path, "graph file to write (atomically)");
  app.add_option("--graph-dir", graph_dir,
                 "instead of --out: write the graph under the name geodesicd serve looks for "
                 "in its --graph-dir")
      ->excludes(out);
  app.add_option("--threads", threads, "threads (0: all cores)");
  double pseudo_limit = 1;
  app.add_option("--pseudo-vertex-limit", pseudo_limit,
                 "for parts built with --pseudo-vertices: as for 'geodesicd build'")
      ->check(CLI::NonNegativeNumber);
  app.add_flag("--json", json, "print a JSON object (the keys of 'geodesicd build --json')");
  app.add_flag("--quiet", quiet, "no progress bar");
  bool prune = false, exact_fans = false;
  app.add_flag("--prune", prune,
               "expect parts built with --prune (the parts' own record decides; a part that "
               "contradicts a flag given is refused)");
  app.add_flag("--exact-fans", exact_fans, "expect parts built with --exact-fans (as --prune)");
  bool repair = false;
  AddRepairFlag(app, &repair);
  RegionFlags region;
  AddRegionFlags(app, &region, false);
  CLI11_PARSE(app, argc, argv);
  if (out_path.empty() && graph_dir.empty()) {
    return Fail("merge", absl::InvalidArgumentError("--out or --graph-dir is required"));
  }
  auto work = LoadWorkMesh(mesh_path, repair, region);
  if (!work.ok()) return Fail("merge", work.status());
  const Mesh& mesh = *work->mesh();
  std::vector<DggPartSource> parts;
  for (const std::string& path : part_paths) {
    auto index = ReadDggPartIndex(path);
    if (!index.ok()) return Fail("merge", index.status());
    parts.push_back({path, *std::move(index), [path] { return ReadDggPart(path); }});
  }
  // The parts carry the whole build record and the graph takes it; the
  // flags, where given, only say what the caller expects of them.
  for (const DggPartSource& part : parts) {
    const DggParams& p = part.index.params;
    if ((app.count("--prune") && p.prune_redundant != prune) ||
        (app.count("--exact-fans") && p.exact_fans != exact_fans)) {
      return Fail("merge", absl::FailedPreconditionError(absl::StrFormat(
                               "%s was built with %s, which the flags given contradict", part.name,
                               DescribeParams(p))));
    }
  }
  DggBuildOptions options;
  options.threads = threads;
  options.pseudo_vertex_limit = pseudo_limit;
  options.progress = ProgressBar(!json && !quiet);
  const bool bar = static_cast<bool>(options.progress);
  // The parts carry the graph's build record (checked alike by the merge).
  auto draft = parts.empty()
                   ? absl::StatusOr<std::optional<GraphFileDraft>>(std::nullopt)
                   : DraftFor(mesh, parts.front().index.params, out_path, graph_dir, options);
  if (!draft.ok()) return Fail("merge", draft.status());
  DggBuildStats stats;
  auto graph = MergeDggParts(mesh, std::move(parts), options, &stats);
  if (bar) std::fprintf(stderr, "\n");
  if (!graph.ok()) return Fail("merge", graph.status());
  return WriteAndReport("merge", *work, **graph, stats, out_path, graph_dir, threads, json, nullptr,
                        std::move(*draft));
}

}  // namespace geodesic::offline
