// geodesicd exact: exact distances from one source by window propagation.
#include <chrono>
#include <cstdio>

#include "CLI/CLI.hpp"
#include "core/exact_geodesic.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunExact(int argc, char** argv) {
  CLI::App app{"Exact geodesic distances from one source to every vertex (window propagation)",
               "geodesicd exact"};
  std::string mesh_path, source_spec, out_path;
  double max_distance = std::numeric_limits<double>::infinity();
  bool json = false;
  app.add_option("--mesh", mesh_path, "mesh file (obj, off, ply, stl)")->required();
  app.add_option("--source", source_spec,
                 "source point: v:ID, e:EDGE:T, f:FACE:B0,B1,B2 (barycentrics in the file's "
                 "vertex order of that face) or xyz:X,Y,Z")
      ->required();
  app.add_option("--out", out_path, "write one little-endian float64 per vertex (+inf: unreached)");
  app.add_option("--max-distance", max_distance, "stop the wavefront at this distance");
  app.add_flag("--json", json, "print a JSON object");
  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& e) {
    return app.exit(e);
  }
  auto t0 = std::chrono::steady_clock::now();
  auto mesh = LoadMeshOrError(mesh_path);
  if (!mesh.ok()) return Fail("exact", mesh.status());
  const double load_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
  auto source = ResolvePoint(**mesh, source_spec);
  if (!source.ok()) return Fail("exact", source.status());
  ExactGeodesic engine(**mesh);
  ExactOptions options;
  options.max_distance = max_distance;
  auto t1 = std::chrono::steady_clock::now();
  auto field = engine.Distances(*source, options);
  const double solve_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - t1).count();
  if (!field.ok()) return Fail("exact", field.status());
  if (!out_path.empty()) {
    absl::Status s = WriteF64(out_path, *field);
    if (!s.ok()) return Fail("exact", s);
  }
  size_t reached = 0;
  for (double d : *field) reached += d < std::numeric_limits<double>::infinity();
  const size_t n = (*mesh)->num_vertices();
  const ExactStats& st = engine.stats();
  if (json) {
    std::printf(
        "{\"vertices\": %zu, \"reached\": %zu, \"solve_seconds\": %.6f, \"load_seconds\": %.6f, "
        "\"windows_created\": %llu, \"windows_per_vertex\": %.3f, \"windows_propagated\": %llu, "
        "\"vertices_per_second\": %.1f, "
        "\"pseudo_sources\": %llu, \"peak_queue\": %llu}\n",
        n, reached, solve_seconds, load_seconds,
        static_cast<unsigned long long>(st.windows_created), double(st.windows_created) / n,
        static_cast<unsigned long long>(st.windows_propagated), n / std::max(solve_seconds, 1e-9),
        static_cast<unsigned long long>(st.pseudo_sources),
        static_cast<unsigned long long>(st.peak_queue));
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
