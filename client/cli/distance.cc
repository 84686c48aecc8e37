// geodesic distance and geodesic path: point-to-point distances and paths.
#include <chrono>
#include <cstdio>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "client/cli/commands.h"
#include "core/mesh/surface_point.h"
#include "core/query/result_files.h"
#include "server/api/convert.h"

namespace geodesic::cli {
namespace {

// --path's polyline, written to `path_out` (a .csv, .ply or .obj): 0, or the
// exit code of the failure.
int WritePath(const std::string& path_out, const v1::DistanceResponse& resp) {
  std::vector<Vec3> polyline;
  for (const auto& q : resp.results(0).path().points()) {
    polyline.push_back({q.xyz().x(), q.xyz().y(), q.xyz().z()});
  }
  if (polyline.empty()) return FailText("no path to write: the points are unreachable");
  absl::Status w = WritePolyline(path_out, polyline);
  if (!w.ok()) return FailText(std::string(w.message()));
  return 0;
}

Json PathJson(const v1::Path& path) {
  Json out = Json::array();
  for (const auto& q : path.points()) {
    out.push_back({{"point", server::FormatPoint(q.point())},
                   {"xyz", {q.xyz().x(), q.xyz().y(), q.xyz().z()}}});
  }
  return out;
}

// Each pair's distance (and path), then, as text, the call's time and graph.
void PrintResults(const Common& c, const std::vector<std::string>& specs,
                  const std::vector<Json>& snap_distances, const v1::DistanceResponse& resp,
                  bool with_path, double seconds) {
  Json results = Json::array();
  for (int i = 0; i < resp.results_size(); ++i) {
    const auto& r = resp.results(i);
    if (c.json) {
      Json result = {{"from", specs[2 * i]},
                     {"to", specs[2 * i + 1]},
                     {"distance", r.distance()},
                     {"reachable", r.reachable()},
                     {"exact", r.exact()},
                     {"from_snap_distance", snap_distances[2 * i]},
                     {"to_snap_distance", snap_distances[2 * i + 1]}};
      if (with_path) result["path"] = PathJson(r.path());
      results.push_back(std::move(result));
    } else {
      std::printf("%s -> %s: %s\n", specs[2 * i].c_str(), specs[2 * i + 1].c_str(),
                  r.reachable() ? absl::StrFormat("%.12g", r.distance()).c_str() : "unreachable");
      for (const auto& q : r.path().points()) {
        std::printf("  %-48s %.9g %.9g %.9g\n", server::FormatPoint(q.point()).c_str(), q.xyz().x(),
                    q.xyz().y(), q.xyz().z());
      }
    }
  }
  if (c.json) {
    PrintJson(results);
  } else {
    const v1::GraphSelector graph = server::SelectorOf(resp.echo());
    std::printf("(%d pairs in %.2f ms, eps %g%s)\n", resp.results_size(), 1e3 * seconds,
                graph.epsilon(), graph.pseudo_vertices() ? ", pseudo vertices" : "");
  }
}

struct DistanceArgs {
  std::string from, to, pairs_file;
  bool with_path = false;
  bool exact = false;    // the exact distance and geodesic
  std::string path_out;  // --path's polyline (a .csv, .ply or .obj)
};

int CmdDistance(const Common& c, const DistanceArgs& a) {
  if (!a.path_out.empty()) {
    absl::Status s = CheckPolylinePath(a.path_out);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  auto stub = Connect(c);
  std::vector<std::string> specs;
  if (!a.pairs_file.empty()) {
    auto pairs = ReadSpecPairs(a.pairs_file);
    if (!pairs.ok()) return FailText(std::string(pairs.status().message()));
    for (auto& [first, second] : *pairs) specs.push_back(first), specs.push_back(second);
  } else {
    if (a.from.empty() || a.to.empty()) return FailText("give --from and --to, or --pairs FILE");
    specs = {a.from, a.to};
  }
  std::vector<v1::SurfacePoint> points;
  int rc = 0;
  std::vector<Json> snap_distances;
  if (!ResolvePoints(stub.get(), c, specs, &points, &rc, &snap_distances)) return rc;
  v1::DistanceRequest req;
  *req.mutable_graph() = Selector(c);
  req.set_with_path(a.with_path);
  req.set_exact(a.exact);
  for (size_t i = 0; i + 1 < points.size(); i += 2) {
    auto* p = req.add_pairs();
    *p->mutable_from() = points[i];
    *p->mutable_to() = points[i + 1];
  }
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::DistanceResponse resp;
  const auto start = std::chrono::steady_clock::now();
  grpc::Status s = stub->Distance(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!a.path_out.empty() && resp.results_size() == 1) {
    if (int failed = WritePath(a.path_out, resp); failed != 0) return failed;
  }
  PrintResults(c, specs, snap_distances, resp, a.with_path, seconds);
  return 0;
}

}  // namespace

Command AddDistance(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("distance", "point-to-point distance");
  auto a = std::make_shared<DistanceArgs>();
  sub->add_option("--from", a->from, "first point");
  sub->add_option("--to", a->to, "second point");
  sub->add_option("--pairs", a->pairs_file, "file with one pair of points per line");
  sub->add_flag("--path", a->with_path, "also return the geodesic path");
  sub->add_flag("--exact", a->exact,
                "the exact polyhedral distance (and with --path the exact geodesic)");
  return {sub, [&c, a] { return CmdDistance(c, *a); }, true};
}

Command AddPath(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("path", "geodesic path between two points");
  auto a = std::make_shared<DistanceArgs>();
  a->with_path = true;
  sub->add_option("--from", a->from, "first point")->required();
  sub->add_option("--to", a->to, "second point")->required();
  sub->add_option("--out", a->path_out, "write the path as a .csv, .ply or .obj polyline");
  sub->add_flag("--exact", a->exact, "the exact geodesic");
  return {sub, [&c, a] { return CmdDistance(c, *a); }, true};
}

}  // namespace geodesic::cli
