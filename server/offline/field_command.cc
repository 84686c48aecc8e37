// geodesicd field: a distance field on a DGG.
#include <algorithm>
#include <chrono>
#include <cstdio>

#include "CLI/CLI.hpp"
#include "core/base/status.h"
#include "core/dgg/graph_file.h"
#include "core/query/geodesic_engine.h"
#include "core/query/result_files.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

namespace {

struct FieldFlags {
  std::string mesh_path, graph_path, out_path, labels_path, method = "lc";
  std::vector<std::string> source_specs;
  double max_distance = kInfinity;
  bool json = false, repair = false;
  RegionFlags region;
};

void AddFieldFlags(CLI::App& app, FieldFlags& f) {
  app.add_option("--mesh", f.mesh_path,
                 "mesh file the graph was built for (with a region: its parent)")
      ->required();
  app.add_option("--graph", f.graph_path, "graph file (geodesicd build)")->required();
  app.add_option("--source", f.source_specs,
                 "source point(s) (with --parent-ids, the parent's): v:ID, e:EDGE:T, "
                 "f:FACE:B0,B1,B2 (barycentrics in the file's vertex order of that face) or "
                 "xyz:X,Y,Z; repeat for several sources")
      ->required();
  app.add_option("--out", f.out_path,
                 "write the field, one value per vertex in file order: .f64 (little-endian "
                 "float64, +inf unreached), .npy, .csv, .ply (the mesh coloured by distance), "
                 "or .func.gii (a GIFTI metric: float32, +inf unreached)");
  app.add_option("--labels-out", f.labels_path,
                 "write each vertex's nearest source (geodesic Voronoi regions: the index of its "
                 "--source, 4294967295 unreached) as .npy, .csv or .u32");
  app.add_option("--method", f.method,
                 "lc (default: each vertex relaxes only the fan of the edge it was reached by) or "
                 "dijkstra (every edge); both give the graph's shortest distances")
      ->check(CLI::IsMember({"lc", "dijkstra"}));
  app.add_option("--max-distance", f.max_distance, "only settle vertices within this distance")
      ->check(kPositiveDistance);
  app.add_flag("--json", f.json, "print a JSON object");
  AddRepairFlag(app, &f.repair);
  AddRegionFlags(app, &f.region, true);
}

// A bad output name is refused before minutes of work, not after.
absl::Status CheckOutputs(const FieldFlags& f) {
  if (!f.out_path.empty()) RETURN_IF_ERROR(CheckFieldPath(f.out_path, true));
  if (!f.labels_path.empty()) RETURN_IF_ERROR(CheckLabelPath(f.labels_path));
  return absl::OkStatus();
}

// With --parent-ids, one value per parent vertex: outside the region, as
// where unreached.
absl::Status WriteOutputs(const FieldFlags& f, const FieldResult& field, const WorkMesh& work) {
  const bool parent = f.region.parent_ids && work.region;
  if (!f.out_path.empty()) {
    RETURN_IF_ERROR(
        parent ? WriteFieldFile(f.out_path,
                                ScatterToParent(*work.region, absl::MakeConstSpan(field.distance)),
                                *work.parent)
               : WriteFieldFile(f.out_path, field.distance, *work.mesh()));
  }
  if (!f.labels_path.empty()) {
    RETURN_IF_ERROR(WriteLabels(
        f.labels_path, parent ? ScatterToParent<uint32_t>(*work.region, field.nearest_source, kNone)
                              : field.nearest_source));
  }
  return absl::OkStatus();
}

// The --source points on the work mesh, and their snap distances.
absl::StatusOr<std::vector<SurfacePoint>> ResolveSources(const FieldFlags& f, const WorkMesh& work,
                                                         Json& snaps) {
  std::vector<SurfacePoint> sources;
  PointResolver resolver(f.region.parent_ids ? *work.parent : *work.mesh());
  for (const std::string& spec : f.source_specs) {
    ASSIGN_OR_RETURN(PointResolver::Resolved p, resolver.Resolve(spec));
    if (f.region.parent_ids) {
      ASSIGN_OR_RETURN(p.point, IntoWorkMesh(work, p.point, "--source " + spec));
    }
    sources.push_back(p.point);
    snaps.push_back(SnapJson(p));
  }
  return sources;
}

}  // namespace

int RunField(int argc, char** argv) {
  KeepFreedMemory();
  CLI::App app{"Distance field from one or more sources on a discrete geodesic graph",
               "geodesicd field"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  FieldFlags f;
  AddFieldFlags(app, f);
  CLI11_PARSE(app, argc, argv);
  if (absl::Status s = CheckOutputs(f); !s.ok()) return Fail("field", s);
  auto work = LoadWorkMesh(f.mesh_path, f.repair, f.region);
  if (!work.ok()) return Fail("field", work.status());
  const std::shared_ptr<const Mesh>& mesh = work->mesh();
  auto t0 = std::chrono::steady_clock::now();
  auto graph = GraphFile::Open(f.graph_path, *mesh, GraphFile::Check::kFull);
  const double open_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  if (!graph.ok()) return Fail("field", graph.status());
  Json snap_distances = Json::array();
  auto sources = ResolveSources(f, *work, snap_distances);
  if (!sources.ok()) return Fail("field", sources.status());
  GeodesicEngine engine(mesh, *graph);
  FieldOptions options;
  options.method = f.method == "lc" ? FieldMethod::kLabelCorrecting : FieldMethod::kDijkstra;
  options.max_distance = f.max_distance;
  options.nearest_source = !f.labels_path.empty();
  const int64_t faults_before = MinorPageFaults();
  auto t1 = std::chrono::steady_clock::now();
  auto field = engine.Field(*sources, options);
  const double solve_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  const int64_t solve_faults = MinorPageFaults() - faults_before;
  if (!field.ok()) return Fail("field", field.status());
  if (absl::Status s = WriteOutputs(f, *field, *work); !s.ok()) return Fail("field", s);
  const size_t n = mesh->num_vertices();
  size_t reached = 0;
  for (double d : field->distance) reached += d < kInfinity;
  if (f.json) {
    Json out = {{"vertices", n},
                {"reached", reached},
                {"method", f.method},
                {"solve_seconds", solve_seconds},
                {"ns_per_vertex", 1e9 * solve_seconds / std::max<size_t>(n, 1)},
                {"queue_pops_per_vertex", double(field->queue_pops) / std::max<size_t>(n, 1)},
                {"graph_open_seconds", open_seconds},
                {"solve_page_faults", solve_faults},
                {"epsilon", (*graph)->params().epsilon},
                {"relaxed_per_vertex", double(field->relaxed) / std::max<size_t>(n, 1)},
                {"snap_distances", snap_distances}};
    work->AddJson(out);
    PrintJson(out);
  } else {
    std::printf("field on %s (eps %g, %s): %zu of %zu vertices reached in %.3f ms\n",
                f.graph_path.c_str(), (*graph)->params().epsilon, f.method.c_str(), reached, n,
                1e3 * solve_seconds);
  }
  return 0;
}

}  // namespace geodesic::offline
