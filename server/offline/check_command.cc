// geodesicd check: what a graph delivers on its own mesh, against the exact
// engine, from seeded random vertices or given sources.
#include <algorithm>
#include <chrono>
#include <cstdio>

#include "CLI/CLI.hpp"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/dgg/graph_file.h"
#include "core/query/accuracy_check.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {
namespace {

// A vertex id, or null when there is none.
Json VertexJson(VertexId v) { return v == kNone ? Json(nullptr) : Json(v); }

// The first inequality that must hold and does not, in words.
std::string Violation(const SourceCheck& c) {
  const std::string source = FormatSurfacePoint(c.source);
  const FieldComparison& f = c.comparison;
  if (f.below_exact) {
    return absl::StrFormat(
        "source %s: %d vertices have a graph distance below the exact one (first: vertex %u)",
        source, f.below_exact, f.first_below_exact);
  }
  if (f.below_straight) {
    return absl::StrFormat("source %s: %d exact distances are below the straight line", source,
                           f.below_straight);
  }
  if (f.graph_unreached) {
    return absl::StrFormat(
        "source %s: the graph leaves %d vertices unreached that the surface "
        "connects",
        source, f.graph_unreached);
  }
  if (f.exact_unreached) {
    return absl::StrFormat(
        "source %s: the exact engine leaves %d vertices unreached that the "
        "graph reaches",
        source, f.exact_unreached);
  }
  return absl::StrFormat("source %s: its own distance is not 0", source);
}

struct CheckFlags {
  std::string mesh_path, graph_path;
  std::vector<std::string> source_specs;
  int random_sources = 8, threads = 0;
  uint64_t seed = 1;
  double fail_above = 0;
  bool json = false;
  bool repair = false;
};

// Returns --sources' option, to tell whether it was given.
CLI::Option* AddCheckFlags(CLI::App& app, CheckFlags& f) {
  app.add_option("--mesh", f.mesh_path, "mesh file the graph was built for")->required();
  app.add_option("--graph", f.graph_path, "graph file (geodesicd build)")->required();
  auto* random_option =
      app.add_option("--sources", f.random_sources,
                     "random vertex sources (default 8; 0 with --source: only those)")
          ->check(CLI::NonNegativeNumber);
  app.add_option("--seed", f.seed, "seed of the random sources (the same seed, the same vertices)");
  app.add_option("--source", f.source_specs,
                 "also check from this point: v:ID, e:EDGE:T, f:FACE:B0,B1,B2 or xyz:X,Y,Z; "
                 "repeat for several (with --source alone, no random sources are added)");
  app.add_option("--threads", f.threads, "sources checked at once (0: all cores)");
  app.add_option("--fail-above", f.fail_above,
                 "exit 1 when the largest error exceeds this many eps (e.g. 1 or 1.5)")
      ->check(CLI::PositiveNumber);
  app.add_flag("--json", f.json, "print a JSON object");
  AddRepairFlag(app, &f.repair);
  return random_option;
}

// The seeded random vertices, then the given sources.
absl::StatusOr<std::vector<SurfacePoint>> CheckSources(const Mesh& mesh, const CheckFlags& f) {
  std::vector<SurfacePoint> sources;
  for (VertexId v : RandomSurfaceVertices(mesh, f.random_sources, f.seed)) {
    sources.push_back(SurfacePoint::Vertex(v));
  }
  PointResolver resolver(mesh);
  for (const std::string& spec : f.source_specs) {
    ASSIGN_OR_RETURN(const PointResolver::Resolved p, resolver.Resolve(spec));
    sources.push_back(p.point);
  }
  if (sources.empty()) {
    return absl::InvalidArgumentError(
        "no sources: the mesh has no faces, or --sources 0 was given without --source");
  }
  return sources;
}

// The sources' errors together, with each source's JSON row.
struct CheckSummary {
  uint64_t compared = 0;
  double max_error = 0, mean_error = 0, min_error = 0;
  const SourceCheck* worst = nullptr;    // the largest error's source
  const SourceCheck* unsound = nullptr;  // the first with an inequality broken
  Json rows = Json::array();
};

CheckSummary Summarize(const std::vector<SourceCheck>& checks, double eps) {
  CheckSummary s;
  double total = 0;
  for (const SourceCheck& c : checks) {
    const FieldComparison& f = c.comparison;
    if (f.compared && (s.compared == 0 || f.min_error < s.min_error)) s.min_error = f.min_error;
    s.compared += f.compared;
    total += f.mean_error * f.compared;
    if (f.compared && (!s.worst || f.max_error > s.max_error)) {
      s.worst = &c;
      s.max_error = f.max_error;
    }
    if (!s.unsound && !f.sound()) s.unsound = &c;
    s.rows.push_back({{"source", FormatSurfacePoint(c.source)},
                      {"compared", f.compared},
                      {"max_error_eps", f.max_error / eps},
                      {"worst_vertex", VertexJson(f.worst_vertex)},
                      {"mean_error_eps", f.mean_error / eps},
                      {"min_error", f.min_error},
                      {"below_exact", f.below_exact},
                      {"first_below_exact", VertexJson(f.first_below_exact)},
                      {"graph_unreached", f.graph_unreached},
                      {"exact_unreached", f.exact_unreached},
                      {"below_straight", f.below_straight},
                      {"source_nonzero", f.source_nonzero},
                      {"exact_seconds", c.exact_seconds},
                      {"graph_seconds", c.graph_seconds}});
  }
  s.mean_error = s.compared ? total / s.compared : 0;
  return s;
}

void PrintCheckJson(const CheckFlags& f, const Mesh& mesh, double eps, const CheckSummary& s,
                    bool within, double seconds) {
  PrintJson(
      {{"mesh", f.mesh_path},
       {"graph", f.graph_path},
       {"epsilon", eps},
       {"vertices", mesh.num_vertices()},
       {"seed", f.seed},
       {"compared", s.compared},
       {"max_error_eps", s.max_error / eps},
       {"mean_error_eps", s.mean_error / eps},
       {"worst_source", s.worst ? Json(FormatSurfacePoint(s.worst->source)) : Json(nullptr)},
       {"worst_vertex", s.worst ? VertexJson(s.worst->comparison.worst_vertex) : Json(nullptr)},
       {"min_error", s.min_error},
       {"sound", s.unsound == nullptr},
       {"fail_above_eps", f.fail_above > 0 ? Json(f.fail_above) : Json(nullptr)},
       {"within_limit", within},
       {"seconds", seconds},
       {"sources", s.rows}});
}

void PrintCheckTable(const std::vector<SourceCheck>& checks, double eps, const CheckSummary& s,
                     double seconds) {
  std::printf("%-24s %10s %12s %12s %8s\n", "source", "vertices", "max (eps)", "mean (eps)",
              "worst");
  for (const SourceCheck& c : checks) {
    const FieldComparison& f = c.comparison;
    std::printf("%-24s %10llu %12.4f %12.4f %8s%s\n", FormatSurfacePoint(c.source).c_str(),
                static_cast<unsigned long long>(f.compared), f.max_error / eps, f.mean_error / eps,
                f.worst_vertex == kNone ? "-" : absl::StrCat(f.worst_vertex).c_str(),
                f.sound() ? "" : "  UNSOUND");
  }
  std::printf(
      "graph eps %g: max %.4f eps, mean %.4f eps over %llu vertex distances from %zu "
      "sources (%.1f s)\n",
      eps, s.max_error / eps, s.mean_error / eps, static_cast<unsigned long long>(s.compared),
      checks.size(), seconds);
}

}  // namespace

int RunCheck(int argc, char** argv) {
  CLI::App app{
      "Measure a graph's error on its own mesh against exact geodesic distances, at "
      "every vertex, from seeded random vertices or given sources",
      "geodesicd check"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  CheckFlags f;
  const CLI::Option* random_option = AddCheckFlags(app, f);
  CLI11_PARSE(app, argc, argv);
  if (!f.source_specs.empty() && random_option->count() == 0) f.random_sources = 0;
  auto mesh = LoadMeshOrError(f.mesh_path, f.repair);
  if (!mesh.ok()) return Fail("check", mesh.status());
  auto graph = GraphFile::Open(f.graph_path, **mesh, GraphFile::Check::kFull);
  if (!graph.ok()) return Fail("check", graph.status());
  auto sources = CheckSources(**mesh, f);
  if (!sources.ok()) return Fail("check", sources.status());

  const auto start = std::chrono::steady_clock::now();
  AccuracyCheckOptions options;
  options.threads = f.threads;
  auto checks = CheckAgainstExact(*mesh, *graph, *sources, options);
  if (!checks.ok()) return Fail("check", checks.status());
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  const double eps = (*graph)->params().epsilon;
  const CheckSummary s = Summarize(*checks, eps);
  const bool within = f.fail_above == 0 || s.max_error <= f.fail_above * eps;
  if (f.json) {
    PrintCheckJson(f, **mesh, eps, s, within, seconds);
  } else {
    PrintCheckTable(*checks, eps, s, seconds);
  }
  if (s.unsound) return Fail("check", absl::InternalError(Violation(*s.unsound)));
  if (!within) {
    return Fail("check", absl::OutOfRangeError(absl::StrFormat(
                             "the largest error, %.4f eps (source %s, vertex %u), exceeds "
                             "--fail-above %g",
                             s.max_error / eps, FormatSurfacePoint(s.worst->source),
                             s.worst->comparison.worst_vertex, f.fail_above)));
  }
  return 0;
}

}  // namespace geodesic::offline
