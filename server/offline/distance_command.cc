// geodesicd distance: point-to-point distances (and paths) on a DGG.
#include <chrono>
#include <cstdio>
#include <optional>

#include "CLI/CLI.hpp"
#include "absl/strings/str_format.h"
#include "core/graph_file.h"
#include "core/queries.h"
#include "core/result_files.h"
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

}  // namespace

int RunDistance(int argc, char** argv) {
  CLI::App app{"Geodesic distance (and path) between surface points on a discrete geodesic graph",
               "geodesicd distance"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  std::string mesh_path, graph_path, from, to, pairs_path, path_out;
  bool json = false, want_path = false, no_astar = false;
  std::optional<int> landmarks;
  app.add_option("--mesh", mesh_path, "mesh file the graph was built for")->required();
  app.add_option("--graph", graph_path, "graph file (geodesicd build)")->required();
  app.add_option("--from", from,
                 "first point: v:ID, e:EDGE:T, f:FACE:B0,B1,B2 (barycentrics in the file's vertex "
                 "order of that face) or xyz:X,Y,Z");
  app.add_option("--to", to, "second point, same forms");
  app.add_option("--pairs", pairs_path, "file with one pair of points per line");
  app.add_flag("--path", want_path, "also recover the geodesic path");
  app.add_option("--path-out", path_out,
                 "write the path (implies --path; --from/--to only) as a polyline: .csv (x,y,z), "
                 ".ply (vertices and edges) or .obj (v and l lines)");
  app.add_flag("--no-astar", no_astar, "plain bidirectional Dijkstra instead of A*");
  app.add_option("--landmarks", landmarks,
                 "landmarks whose graph distances tighten the A* bounds, computed once before "
                 "the queries (0: straight-line bounds only; default: 16 to 64 by the graph's "
                 "density)")
      ->check(CLI::Range(0, 64));
  app.add_flag("--json", json, "print JSON");
  bool repair = false;
  AddRepairFlag(app, &repair);
  CLI11_PARSE(app, argc, argv);
  std::vector<std::pair<std::string, std::string>> pairs;
  if (!pairs_path.empty()) {
    auto read = ReadSpecPairs(pairs_path);
    if (!read.ok()) return Fail("distance", read.status());
    pairs = *std::move(read);
  } else if (!from.empty() && !to.empty()) {
    if (!path_out.empty()) {
      if (absl::Status s = CheckPolylinePath(path_out); !s.ok()) return Fail("distance", s);
      want_path = true;
    }
    pairs.push_back({from, to});
  } else {
    return Fail("distance", absl::InvalidArgumentError("give --from and --to, or --pairs FILE"));
  }
  if (!path_out.empty() && !pairs_path.empty()) {
    return Fail("distance",
                absl::InvalidArgumentError("--path-out writes one path: use --from and --to"));
  }
  auto mesh = LoadMeshOrError(mesh_path, repair);
  if (!mesh.ok()) return Fail("distance", mesh.status());
  auto graph = GraphFile::Open(graph_path, **mesh, GraphFile::Check::kFull);
  if (!graph.ok()) return Fail("distance", graph.status());
  GeodesicEngine engine(*mesh, *graph);
  if (landmarks.value_or(1) > 0 && !no_astar) {
    absl::Status prepared =
        engine.PrepareLandmarks(landmarks.value_or(engine.DefaultLandmarkCount()));
    if (!prepared.ok()) return Fail("distance", prepared);
  }
  PairOptions options;
  options.want_path = want_path;
  options.use_astar = !no_astar;
  std::string out;
  Json results = Json::array();
  PointResolver resolver(**mesh);
  for (size_t i = 0; i < pairs.size(); ++i) {
    auto a = resolver.Resolve(pairs[i].first);
    if (!a.ok()) return Fail("distance", a.status());
    auto b = resolver.Resolve(pairs[i].second);
    if (!b.ok()) return Fail("distance", b.status());
    auto t0 = std::chrono::steady_clock::now();
    auto r = engine.Distance(a->point, b->point, options);
    const double seconds =
        std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    if (!r.ok()) return Fail("distance", r.status());
    if (!path_out.empty() && !r->path) {
      return Fail("distance", absl::FailedPreconditionError(
                                  "no path to write: the points are in different components"));
    }
    if (!path_out.empty()) {
      std::vector<Vec3> polyline;
      for (const PathPoint& p : r->path->points) polyline.push_back(p.xyz);
      if (absl::Status s = WritePolyline(path_out, polyline); !s.ok()) return Fail("distance", s);
    }
    if (json) {
      Json result = {{"from", pairs[i].first},
                     {"to", pairs[i].second},
                     {"distance", r->distance},
                     {"reachable", r->distance < kInfinity},
                     {"seconds", seconds},
                     {"settled", r->settled},
                     {"queued", r->queued},
                     {"relaxed", r->relaxed},
                     {"from_snap_distance", SnapJson(*a)},
                     {"to_snap_distance", SnapJson(*b)}};
      if (r->path) {
        result["path"] = PathJson(*r->path);
        result["path_length"] = r->path->length;  // the polyline's own length
      }
      // One pair: an object; --pairs: an array of them.
      if (pairs_path.empty()) {
        PrintJson(result);
      } else {
        results.push_back(std::move(result));
      }
    } else {
      std::string d = r->distance < kInfinity ? absl::StrFormat("%.12g", r->distance)
                                              : std::string("unreachable");
      out += absl::StrFormat("%s -> %s: %s (%.3f ms, %u nodes settled)\n", pairs[i].first,
                             pairs[i].second, d, 1e3 * seconds, r->settled);
      if (r->path) {
        for (const PathPoint& p : r->path->points) {
          out += absl::StrFormat("  %s  %.9g %.9g %.9g\n", FormatSurfacePoint(p.point), p.xyz.x,
                                 p.xyz.y, p.xyz.z);
        }
      }
    }
  }
  if (json && !pairs_path.empty()) PrintJson(results);
  std::fputs(out.c_str(), stdout);
  return 0;
}

}  // namespace geodesic::offline
