// geodesic field: a distance field, written to a file.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <limits>

#include "absl/status/status.h"
#include "absl/strings/match.h"
#include "client/cli/commands.h"
#include "core/mesh/mesh_io.h"
#include "core/query/result_files.h"

namespace geodesic::cli {
namespace {

// The geometry a coloured .ply field needs: the local copy of the mesh.
absl::StatusOr<TriangleSoup> GeometryFor(const std::string& out, const std::string& mesh_file) {
  if (!absl::EndsWithIgnoreCase(out, ".ply")) return TriangleSoup{};
  if (mesh_file.empty()) {
    return absl::InvalidArgumentError(out + ": .ply output needs --mesh-file (the mesh geometry)");
  }
  return ReadTriangleSoup(mesh_file);
}

int CmdField(const Common& c, const std::vector<std::string>& sources, const std::string& out,
             const std::string& labels_out, double radius, const std::string& method, bool f32,
             const std::string& mesh_file) {
  // Refused before the query, not after it.
  absl::StatusOr<TriangleSoup> geometry = TriangleSoup{};
  if (!out.empty()) {
    geometry = GeometryFor(out, mesh_file);
    if (!geometry.ok()) return FailText(std::string(geometry.status().message()));
    absl::Status s = CheckFieldPath(out, true);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  if (!labels_out.empty()) {
    absl::Status s = CheckLabelPath(labels_out);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  auto stub = Connect(c, /*connected=*/true);
  v1::DistanceFieldRequest req;
  *req.mutable_graph() = Selector(c);
  req.set_max_distance(radius);
  req.set_method(method);
  req.set_float32(f32);
  req.set_nearest_source(!labels_out.empty());
  std::vector<v1::SurfacePoint> points;
  int rc = 0;
  if (!ResolvePoints(stub.get(), c, sources, &points, &rc)) return rc;
  for (auto& p : points) *req.add_sources() = p;
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  const auto start = std::chrono::steady_clock::now();
  auto reader = stub->DistanceField(&ctx, req);
  std::vector<double> values;
  std::vector<uint32_t> labels;
  v1::DistanceFieldChunk chunk;
  while (reader->Read(&chunk)) {
    values.resize(chunk.total());
    if (!labels_out.empty()) labels.resize(chunk.total());
    for (int i = 0; i < chunk.nearest_source_size(); ++i) {
      labels[chunk.offset() + i] = chunk.nearest_source(i);
    }
    for (int i = 0; i < chunk.values_size(); ++i) values[chunk.offset() + i] = chunk.values(i);
    for (int i = 0; i < chunk.values_f32_size(); ++i)
      values[chunk.offset() + i] = chunk.values_f32(i);
  }
  grpc::Status s = reader->Finish();
  if (!s.ok()) return Fail(s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!out.empty()) {
    absl::Status w = WriteField(out, values, &*geometry);
    if (!w.ok()) return FailText(std::string(w.message()));
  }
  if (!labels_out.empty()) {
    absl::Status w = WriteLabels(labels_out, labels);
    if (!w.ok()) return FailText(std::string(w.message()));
  }
  size_t reached = 0;
  double far = 0;
  for (double v : values) {
    if (std::isfinite(v)) ++reached, far = std::max(far, v);
  }
  if (c.json) {
    PrintJson({{"vertices", values.size()},
               {"reached", reached},
               {"max_distance", far},
               {"seconds", seconds}});
  } else {
    std::printf("field on %s: %zu of %zu vertices reached, farthest %.9g, %.2f ms%s%s\n",
                c.mesh.c_str(), reached, values.size(), far, 1e3 * seconds,
                out.empty() ? "" : ", written to ", out.c_str());
  }
  return 0;
}

}  // namespace

Command AddField(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("field", "distance field");
  struct Args {
    std::vector<std::string> sources;
    std::string out, labels_out, method = "lc", mesh_file;
    double radius = 0;
    bool f32 = false;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("--source", a->sources, "source point(s)")->required();
  sub->add_option("--out", a->out,
                  "write the field as .f64 (float64 per vertex), .npy, .csv, .ply (colours; "
                  "needs --mesh-file), or .func.gii (GIFTI metric, float32)");
  sub->add_option("--labels-out", a->labels_out,
                  "write each vertex's nearest source (geodesic Voronoi regions) as .npy, .csv "
                  "or .u32");
  sub->add_option("--mesh-file", a->mesh_file, "local copy of the mesh, for .ply output");
  sub->add_option("--radius", a->radius, "only vertices within this distance (0: no limit)")
      ->check(NumberIn(0, std::numeric_limits<double>::infinity(), "a distance, 0 or more"));
  sub->add_option("--method", a->method,
                  "lc (default: each vertex relaxes only the fan of the edge it was reached by) "
                  "or dijkstra (every edge); both give the graph's shortest distances");
  sub->add_flag("--float32", a->f32, "transfer float32 values");
  return {sub,
          [&c, a] {
            return CmdField(c, a->sources, a->out, a->labels_out, a->radius, a->method, a->f32,
                            a->mesh_file);
          },
          true};
}

}  // namespace geodesic::cli
