// geodesicd info: diagnostics of a mesh file, or a description of a graph file.
#include <cstdio>

#include "CLI/CLI.hpp"
#include "core/mesh/mesh_io.h"
#include "server/offline/commands.h"
#include "server/offline/common.h"

namespace geodesic::offline {

int RunInfo(int argc, char** argv) {
  CLI::App app{"Diagnostics of a mesh file (" + MeshFormatList() +
                   ": x.surf.gii), or describe and validate a graph file (.dgg)",
               "geodesicd info"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  std::string path;
  bool json = false, repair = false;
  app.add_option("path", path, "mesh or graph file")->required();
  app.add_flag("--json", json, "print a JSON object");
  app.add_flag("--repair-non-manifold", repair,
               "split non-manifold vertices before checking usability");
  CLI11_PARSE(app, argc, argv);
  if (path.size() > 4 && path.compare(path.size() - 4, 4, ".dgg") == 0) {
    return RunGraphInfo(path, json);
  }
  MeshDiagnostics diagnostics;
  LoadOptions options;
  options.repair_non_manifold = repair;
  auto mesh = LoadMesh(path, options, &diagnostics);
  if (!mesh.ok() && diagnostics.vertices == 0 && diagnostics.faces == 0) {
    return Fail("info", mesh.status());  // the file itself could not be read
  }
  if (!mesh.ok() && diagnostics.mesh_error.empty()) {
    diagnostics.mesh_error = std::string(mesh.status().message());
  }
  if (json) {
    Json report = Json::parse(diagnostics.ToJson());
    // What the mesh holds once loaded: sizes --memory-limit before any build.
    // null for a mesh that cannot be used: the key is part of the contract.
    report["mesh_bytes"] = mesh.ok() ? Json(mesh->memory_bytes()) : Json(nullptr);
    PrintJson(report);
  } else {
    std::fputs(diagnostics.ToText().c_str(), stdout);
  }
  // Scripts check the exit code: a mesh no query can use is a failure
  // (the report above says why).
  return mesh.ok() ? 0 : 3;
}

}  // namespace geodesic::offline
