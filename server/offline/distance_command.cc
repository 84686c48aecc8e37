// geodesicd distance: point-to-point distances (and paths) on a DGG.
#include <chrono>
#include <cstdio>
#include <optional>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/dgg/graph_file.h"
#include "core/query/exact_landmarks_file.h"
#include "core/query/geodesic_engine.h"
#include "core/query/result_files.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {
namespace {

Json PathJson(const GeodesicPath& path) {
  Json points = Json::array();
  for (const PathPoint& p : path.points) {
    points.push_back(
        {{"point", FormatSurfacePoint(p.point)}, {"xyz", {p.xyz.x, p.xyz.y, p.xyz.z}}});
  }
  return points;
}

struct DistanceFlags {
  std::string mesh_path, graph_path, from, to, pairs_path, path_out;
  bool json = false, want_path = false, no_astar = false, exact = false, repair = false;
  std::optional<int> landmarks;
  int exact_landmarks = 0;
  bool save_exact_landmarks = false;
};

// The exact landmarks --exact-landmarks asks for: read from beside the
// graph file when they are there for this mesh and count (a daemon, or an
// earlier --save-exact-landmarks, kept them), else computed, and with
// --save-exact-landmarks kept there. The time goes to stderr.
absl::Status PrepareExactLandmarks(const DistanceFlags& f, const Mesh& mesh,
                                   const GeodesicEngine& engine) {
  const auto t0 = std::chrono::steady_clock::now();
  auto seconds = [&] {
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  };
  const std::string path = ExactLandmarksPathOf(f.graph_path);
  auto read = ReadExactLandmarks(path, mesh, f.exact_landmarks);
  if (read.ok()) {
    RETURN_IF_ERROR(engine.AdoptExactLandmarks(*std::move(read)));
    std::fprintf(stderr, "exact landmarks: %d fields read from %s in %.2f s\n", f.exact_landmarks,
                 path.c_str(), seconds());
    return absl::OkStatus();
  }
  if (!absl::IsNotFound(read.status())) {
    std::fprintf(stderr, "exact landmarks: not read (%s); computing them\n",
                 std::string(read.status().message()).c_str());
  }
  RETURN_IF_ERROR(engine.PrepareExactLandmarks(f.exact_landmarks));
  std::fprintf(stderr, "exact landmarks: %d fields in %.2f s\n", f.exact_landmarks, seconds());
  if (!f.save_exact_landmarks) return absl::OkStatus();
  RETURN_IF_ERROR(WriteExactLandmarks(*engine.exact_landmarks(), mesh, path));
  std::fprintf(stderr, "exact landmarks: kept in %s\n", path.c_str());
  return absl::OkStatus();
}

void AddDistanceFlags(CLI::App& app, DistanceFlags& f) {
  app.add_option("--mesh", f.mesh_path, "mesh file the graph was built for")->required();
  app.add_option("--graph", f.graph_path, "graph file (geodesicd build)")->required();
  app.add_option("--from", f.from,
                 "first point: v:ID, e:EDGE:T, f:FACE:B0,B1,B2 (barycentrics in the file's vertex "
                 "order of that face) or xyz:X,Y,Z");
  app.add_option("--to", f.to, "second point, same forms");
  app.add_option("--pairs", f.pairs_path, "file with one pair of points per line");
  app.add_flag("--path", f.want_path, "also recover the geodesic path");
  app.add_option("--path-out", f.path_out,
                 "write the path (implies --path; --from/--to only) as a polyline: .csv (x,y,z), "
                 ".ply (vertices and edges) or .obj (v and l lines)");
  app.add_flag("--no-astar", f.no_astar, "plain bidirectional Dijkstra instead of A*");
  app.add_flag("--exact", f.exact,
               "the exact polyhedral distance (and with --path the exact geodesic): a window "
               "propagation bounded by the graph's answer");
  app.add_option("--landmarks", f.landmarks,
                 "landmarks whose graph distances tighten the A* bounds, computed once before "
                 "the queries (0: straight-line bounds only; default: 16 to 64 by the graph's "
                 "density)")
      ->check(CLI::Range(0, 64));
  app.add_option("--exact-landmarks", f.exact_landmarks,
                 "with --exact: exact distance fields from this many landmarks, computed once "
                 "before the queries (one exact field each), whose bounds leave each pair's "
                 "propagation a narrower region; worth it for many pairs (0: straight-line "
                 "bounds only). Read from beside the graph file (GRAPH.exact-landmarks, as "
                 "geodesicd serve and --save-exact-landmarks keep them) when that file holds "
                 "this many for this mesh")
      ->check(CLI::Range(0, 256));
  app.add_flag("--save-exact-landmarks", f.save_exact_landmarks,
               "with --exact-landmarks: keep the landmarks computed beside the graph file "
               "(GRAPH.exact-landmarks), for later runs to read")
      ->needs("--exact-landmarks");
  app.add_flag("--json", f.json, "print JSON");
  AddRepairFlag(app, &f.repair);
}

// --pairs' file, or --from and --to (with --path-out, which then implies
// --path).
absl::StatusOr<std::vector<SpecPair>> PairsToAnswer(DistanceFlags& f) {
  std::vector<SpecPair> pairs;
  if (!f.pairs_path.empty()) {
    ASSIGN_OR_RETURN(pairs, ReadSpecPairs(f.pairs_path));
  } else if (!f.from.empty() && !f.to.empty()) {
    if (!f.path_out.empty()) {
      RETURN_IF_ERROR(CheckPolylinePath(f.path_out));
      f.want_path = true;
    }
    pairs.push_back({f.from, f.to});
  } else {
    return absl::InvalidArgumentError("give --from and --to, or --pairs FILE");
  }
  if (!f.path_out.empty() && !f.pairs_path.empty()) {
    return absl::InvalidArgumentError("--path-out writes one path: use --from and --to");
  }
  return pairs;
}

absl::Status WritePath(const std::string& path_out, const PairResult& r) {
  if (!r.path) {
    return absl::FailedPreconditionError(
        "no path to write: the points are in different components");
  }
  std::vector<Vec3> polyline;
  for (const PathPoint& p : r.path->points) polyline.push_back(p.xyz);
  return WritePolyline(path_out, polyline);
}

Json PairJson(const SpecPair& pair, const PairResult& r, double seconds,
              const PointResolver::Resolved& a, const PointResolver::Resolved& b) {
  Json result = {{"from", pair.first},
                 {"to", pair.second},
                 {"distance", r.distance},
                 {"reachable", r.distance < kInfinity},
                 {"seconds", seconds},
                 {"settled", r.settled},
                 {"queued", r.queued},
                 {"relaxed", r.relaxed},
                 {"exact", r.exact},
                 {"from_snap_distance", SnapJson(a)},
                 {"to_snap_distance", SnapJson(b)}};
  if (r.exact) result["windows"] = r.windows;
  if (r.path) {
    result["path"] = PathJson(*r.path);
    result["path_length"] = r.path->length;  // the polyline's own length
  }
  return result;
}

std::string PairText(const SpecPair& pair, const PairResult& r, double seconds) {
  std::string d =
      r.distance < kInfinity ? absl::StrFormat("%.12g", r.distance) : std::string("unreachable");
  std::string out =
      absl::StrFormat("%s -> %s: %s%s (%.3f ms, %u nodes settled)\n", pair.first, pair.second, d,
                      r.exact ? " exact" : "", 1e3 * seconds, r.settled);
  if (r.path) {
    for (const PathPoint& p : r.path->points) {
      out += absl::StrFormat("  %s  %.9g %.9g %.9g\n", FormatSurfacePoint(p.point), p.xyz.x,
                             p.xyz.y, p.xyz.z);
    }
  }
  return out;
}

}  // namespace

int RunDistance(int argc, char** argv) {
  KeepFreedMemory();
  CLI::App app{"Geodesic distance (and path) between surface points on a discrete geodesic graph",
               "geodesicd distance"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  DistanceFlags f;
  AddDistanceFlags(app, f);
  CLI11_PARSE(app, argc, argv);
  auto pairs = PairsToAnswer(f);
  if (!pairs.ok()) return Fail("distance", pairs.status());
  auto mesh = LoadMeshOrError(f.mesh_path, f.repair);
  if (!mesh.ok()) return Fail("distance", mesh.status());
  auto graph = GraphFile::Open(f.graph_path, **mesh, GraphFile::Check::kFull);
  if (!graph.ok()) return Fail("distance", graph.status());
  GeodesicEngine engine(*mesh, *graph);
  if (f.landmarks.value_or(1) > 0 && !f.no_astar) {
    absl::Status prepared =
        engine.PrepareLandmarks(f.landmarks.value_or(engine.DefaultLandmarkCount()));
    if (!prepared.ok()) return Fail("distance", prepared);
  }
  if (f.exact && f.exact_landmarks > 0) {
    absl::Status prepared = PrepareExactLandmarks(f, **mesh, engine);
    if (!prepared.ok()) return Fail("distance", prepared);
  }
  PairOptions options;
  options.want_path = f.want_path;
  options.use_astar = !f.no_astar;
  options.exact = f.exact;
  std::string out;
  Json results = Json::array();
  PointResolver resolver(**mesh);
  for (const SpecPair& pair : *pairs) {
    auto a = resolver.Resolve(pair.first);
    if (!a.ok()) return Fail("distance", a.status());
    auto b = resolver.Resolve(pair.second);
    if (!b.ok()) return Fail("distance", b.status());
    auto t0 = std::chrono::steady_clock::now();
    auto r = engine.Distance(a->point, b->point, options);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!r.ok()) return Fail("distance", r.status());
    if (!f.path_out.empty()) {
      if (absl::Status s = WritePath(f.path_out, *r); !s.ok()) return Fail("distance", s);
    }
    if (!f.json) {
      out += PairText(pair, *r, seconds);
    } else if (f.pairs_path.empty()) {
      PrintJson(PairJson(pair, *r, seconds, *a, *b));  // one pair: an object
    } else {
      results.push_back(PairJson(pair, *r, seconds, *a, *b));  // --pairs: an array of them
    }
  }
  if (f.json && !f.pairs_path.empty()) PrintJson(results);
  std::fputs(out.c_str(), stdout);
  return 0;
}

}  // namespace geodesic::offline
