// geodesic sample: geodesic farthest-point sampling.
#include <cstdio>
#include <vector>

#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

int CmdSample(const Common& c, uint32_t count, uint64_t seed) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::SamplePointsRequest req;
  *req.mutable_graph() = Selector(c);
  req.set_count(count);
  req.set_seed(seed);
  v1::SamplePointsResponse resp;
  grpc::Status s = stub->SamplePoints(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson({{"vertices", std::vector<uint32_t>(resp.vertices().begin(), resp.vertices().end())},
               {"covering_radius", resp.covering_radius()}});
  } else {
    std::printf("%d points, covering radius %.9g:", resp.vertices_size(), resp.covering_radius());
    for (uint32_t v : resp.vertices()) std::printf(" v:%u", v);
    std::printf("\n");
  }
  return 0;
}

}  // namespace

Command AddSample(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand(
      "sample", "geodesic farthest-point sampling: COUNT vertices spread over --mesh");
  struct Args {
    uint32_t count = 0;
    uint64_t seed = 0;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("--count", a->count, "points to choose")->required();
  sub->add_option("--seed", a->seed, "picks the first point (default 0)");
  return {sub, [&c, a] { return CmdSample(c, a->count, a->seed); }, true};
}

}  // namespace geodesic::cli
