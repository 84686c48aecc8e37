// geodesic unload: unregister a mesh.
#include <cstdio>

#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

int CmdUnload(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::UnloadMeshRequest req;
  req.set_name(c.mesh);
  v1::UnloadMeshResponse resp;
  grpc::Status s = stub->UnloadMesh(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson({{"name", c.mesh}, {"unloaded", true}});
  } else {
    std::printf("unloaded %s\n", c.mesh.c_str());
  }
  return 0;
}

}  // namespace

Command AddUnload(CLI::App& app, Common& c) {
  return {app.add_subcommand("unload",
                             "unregister --mesh and drop its graphs (here and, through the "
                             "shared catalog, on every replica)"),
          [&c] { return CmdUnload(c); }};
}

}  // namespace geodesic::cli
