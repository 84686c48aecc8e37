// geodesic status: the graphs and their state.
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

int CmdStatus(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::ListGraphsResponse resp;
  grpc::Status s = stub->ListGraphs(&ctx, {}, &resp);
  if (!s.ok()) return Fail(s);
  Json list = Json::array();
  for (int i = 0; i < resp.graphs_size(); ++i) {
    const auto& g = resp.graphs(i);
    if (c.json) {
      list.push_back(server::GraphJson<Json>(g));
    } else {
      std::printf("%-16s eps %-8g %-7s %-10s %5.1f%% %12lu bytes %s%s\n", g.mesh().c_str(),
                  g.epsilon(), g.pseudo_vertices() ? "pseudo" : "", server::StateName(g.state()),
                  100 * g.progress(), g.bytes(), g.mapped() ? "mapped" : "resident",
                  g.error().empty() ? "" : (" " + g.error()).c_str());
      if (g.max_error() > 0) {
        std::printf(
            "%-16s   %s\n", "",
            g.has_certificate()
                ? CertificateText(g).c_str()
                : absl::StrFormat("certified to max error %g: not yet measured", g.max_error())
                      .c_str());
      }
    }
  }
  if (c.json) PrintJson(list);
  return 0;
}

}  // namespace

Command AddStatus(CLI::App& app, Common& c) {
  return {app.add_subcommand("status", "list graphs and their state"),
          [&c] { return CmdStatus(c); }};
}

}  // namespace geodesic::cli
