// geodesic meshes: the registered meshes.
#include <cstdio>

#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

int CmdMeshes(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::ListMeshesResponse resp;
  grpc::Status s = stub->ListMeshes(&ctx, {}, &resp);
  if (!s.ok()) return Fail(s);
  Json list = Json::array();
  for (int i = 0; i < resp.meshes_size(); ++i) {
    const auto& m = resp.meshes(i);
    if (c.json) {
      list.push_back(server::MeshJson<Json>(m));
    } else {
      std::printf("%-16s %8lu vertices %8lu faces  %s  %s\n", m.name().c_str(),
                  m.diagnostics().vertices(), m.diagnostics().faces(), m.fingerprint().c_str(),
                  m.source().c_str());
    }
  }
  if (c.json) PrintJson(list);
  return 0;
}

}  // namespace

Command AddMeshes(CLI::App& app, Common& c) {
  return {app.add_subcommand("meshes", "list registered meshes"), [&c] { return CmdMeshes(c); }};
}

}  // namespace geodesic::cli
