// geodesicd exact: exact distances from one source by window propagation.
#include <chrono>
#include <cstdio>

#include "CLI/CLI.hpp"
#include "core/exact/exact_geodesic.h"
#include "core/mesh/mesh_io.h"
#include "core/query/result_files.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunExact(int argc, char** argv) {
  KeepFreedMemory();
  CLI::App app{"Exact geodesic distances from one source to every vertex (window propagation)",
               "geodesicd exact"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  std::string mesh_path, source_spec, out_path;
  double max_distance = std::numeric_limits<double>::infinity();
  bool json = false;
  app.add_option("--mesh", mesh_path, "mesh file (" + MeshFormatList() + ": x.surf.gii)")
      ->required();
  app.add_option("--source", source_spec,
                 "source point: v:ID, e:EDGE:T, f:FACE:B0,B1,B2 (barycentrics in the file's "
                 "vertex order of that face) or xyz:X,Y,Z")
      ->required();
  app.add_option("--out", out_path,
                 "write the field, one value per vertex in file order: .f64 (little-endian "
                 "float64, +inf unreached), .npy, .csv, .ply (the mesh coloured by distance), "
                 "or .func.gii (a GIFTI metric: float32, +inf unreached)");
  app.add_option("--max-distance", max_distance, "stop the wavefront at this distance")
      ->check(kPositiveDistance);
  app.add_flag("--json", json, "print a JSON object");
  bool repair = false;
  AddRepairFlag(app, &repair);
  CLI11_PARSE(app, argc, argv);
  if (!out_path.empty()) {
    if (absl::Status s = CheckFieldPath(out_path, true); !s.ok()) return Fail("exact", s);
  }
  auto t0 = std::chrono::steady_clock::now();
  auto mesh = LoadMeshOrError(mesh_path, repair);
  if (!mesh.ok()) return Fail("exact", mesh.status());
  const double load_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  PointResolver resolver(**mesh);
  auto resolved = resolver.Resolve(source_spec);
  if (!resolved.ok()) return Fail("exact", resolved.status());
  const SurfacePoint* source = &resolved->point;
  // A whole field reads each face's frame many times: made once.
  const FaceFrames frames(**mesh);
  ExactGeodesic engine(**mesh, &frames);
  ExactOptions options;
  options.max_distance = max_distance;
  auto t1 = std::chrono::steady_clock::now();
  auto field = engine.Distances(*source, options);
  const double solve_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  if (!field.ok()) return Fail("exact", field.status());
  if (!out_path.empty()) {
    absl::Status s = WriteFieldFile(out_path, *field, **mesh);
    if (!s.ok()) return Fail("exact", s);
  }
  size_t reached = 0;
  for (double d : *field) reached += d < std::numeric_limits<double>::infinity();
  const size_t n = (*mesh)->num_vertices();
  const ExactStats& st = engine.stats();
  if (json) {
    PrintJson({{"vertices", n},
               {"reached", reached},
               {"solve_seconds", solve_seconds},
               {"load_seconds", load_seconds},
               {"windows_created", st.windows_created},
               {"windows_per_vertex", double(st.windows_created) / n},
               {"windows_propagated", st.windows_propagated},
               {"children_computed", st.children_computed},
               {"pseudo_windows_skipped", st.pseudo_windows_skipped},
               {"vertices_per_second", n / std::max(solve_seconds, 1e-9)},
               {"pseudo_sources", st.pseudo_sources},
               {"peak_queue", st.peak_queue},
               {"snap_distance", SnapJson(*resolved)}});
  } else {
    std::printf(
        "exact field from %s on %s: %zu of %zu vertices reached in %.3f s "
        "(%.1f windows per vertex)%s%s\n",
        FormatSurfacePoint(*source).c_str(), mesh_path.c_str(), reached, n, solve_seconds,
        double(st.windows_created) / n, out_path.empty() ? "" : ", written to ", out_path.c_str());
  }
  return 0;
}

}  // namespace geodesic::offline
