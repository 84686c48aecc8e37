// geodesic graph: request, wait for or cancel the graph of a mesh.
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <string>

#include "absl/strings/str_format.h"
#include "client/cli/commands.h"
#include "server/api/convert.h"

namespace geodesic::cli {
namespace {

int CmdGraph(const Common& c, bool wait, bool cancel) {
  auto stub = Connect(c);
  v1::Graph g;
  {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    grpc::Status s;
    if (cancel) {
      v1::CancelGraphRequest req;
      *req.mutable_graph() = Selector(c);
      s = stub->CancelGraph(&ctx, req, &g);
    } else {
      v1::RequestGraphRequest req;
      *req.mutable_graph() = Selector(c);
      s = stub->RequestGraph(&ctx, req, &g);
    }
    if (!s.ok()) return Fail(s);
  }
  if (wait && !cancel) {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    // --timeout bounds each call, not a build: a large mesh's takes minutes.
    // The stream ends when the graph is ready, failed or cancelled.
    ctx.set_deadline(std::chrono::system_clock::time_point::max());
    v1::GetGraphRequest req;
    // The graph the answer named: its epsilon is the one it is built with.
    *req.mutable_graph() = server::MakeSelector(c.mesh, g.epsilon(), g.pseudo_vertices());
    req.mutable_graph()->set_max_error(g.max_error());
    auto reader = stub->WatchGraph(&ctx, req);
    const bool bar = !c.json && isatty(STDERR_FILENO);
    while (reader->Read(&g)) {
      if (bar) {
        const int width = 40, filled = static_cast<int>(g.progress() * width);
        std::fprintf(stderr, "\r%-10s [%s%s] %5.1f%%", g.phase().c_str(),
                     std::string(filled, '#').c_str(), std::string(width - filled, ' ').c_str(),
                     100 * g.progress());
      }
    }
    if (bar) std::fprintf(stderr, "\n");
    grpc::Status s = reader->Finish();
    if (!s.ok()) return Fail(s);
  }
  if (c.json) {
    PrintJson(server::GraphJson<Json>(g));
  } else {
    const std::string bound =
        g.max_error() > 0 ? absl::StrFormat(" (max error %g)", g.max_error()) : "";
    std::printf("graph %s at eps %g%s%s: %s%s%s (%lu nodes, %lu edges, %lu bytes%s)\n",
                g.mesh().c_str(), g.epsilon(), bound.c_str(),
                g.pseudo_vertices() ? " with pseudo vertices" : "", server::StateName(g.state()),
                g.error().empty() ? "" : ": ", g.error().c_str(), g.nodes(), g.edges(), g.bytes(),
                g.from_file() ? ", mapped from the graph directory" : "");
    if (g.has_certificate()) std::printf("  %s\n", CertificateText(g).c_str());
  }
  return g.state() == v1::GRAPH_STATE_FAILED ? 1 : 0;
}

}  // namespace

Command AddGraph(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand(
      "graph", "request the graph of --mesh at --eps (or certified to --max-error)");
  struct Args {
    bool wait = false, cancel = false;
  };
  auto a = std::make_shared<Args>();
  sub->add_flag("--wait", a->wait, "wait for it, with a progress bar");
  sub->add_flag("--cancel", a->cancel, "cancel its build");
  return {sub, [&c, a] { return CmdGraph(c, a->wait, a->cancel); }, true};
}

}  // namespace geodesic::cli
