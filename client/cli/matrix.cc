// geodesic matrix: sources x targets distances.
#include <cstdio>

#include "client/cli/commands.h"

namespace geodesic::cli {
namespace {

int CmdMatrix(const Common& c, const std::vector<std::string>& sources,
              const std::vector<std::string>& targets, bool exact) {
  auto stub = Connect(c);
  std::vector<v1::SurfacePoint> s_points, t_points;
  int rc = 0;
  if (!ResolvePoints(stub.get(), c, sources, &s_points, &rc)) return rc;
  if (!ResolvePoints(stub.get(), c, targets, &t_points, &rc)) return rc;
  v1::MatrixRequest req;
  *req.mutable_graph() = Selector(c);
  req.set_exact(exact);
  for (auto& p : s_points) *req.add_sources() = p;
  for (auto& p : t_points) *req.add_targets() = p;
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::MatrixResponse resp;
  grpc::Status s = stub->Matrix(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    Json rows = Json::array();
    for (uint32_t i = 0; i < resp.rows(); ++i) {
      Json row = Json::array();
      for (uint32_t j = 0; j < resp.cols(); ++j) row.push_back(resp.distances(i * resp.cols() + j));
      rows.push_back(std::move(row));
    }
    PrintJson({{"rows", resp.rows()},
               {"cols", resp.cols()},
               {"exact", exact},
               {"distances", std::move(rows)}});
    return 0;
  }
  for (uint32_t i = 0; i < resp.rows(); ++i) {
    for (uint32_t j = 0; j < resp.cols(); ++j) {
      std::printf("%s%14.9g", j ? " " : "", resp.distances(i * resp.cols() + j));
    }
    std::printf("\n");
  }
  return 0;
}

}  // namespace

Command AddMatrix(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("matrix", "sources x targets distances");
  struct Args {
    std::vector<std::string> sources, targets;
    bool exact = false;
  };
  auto a = std::make_shared<Args>();
  sub->add_option("--source", a->sources, "source points")->required();
  sub->add_option("--target", a->targets, "target points")->required();
  sub->add_flag("--exact", a->exact, "exact polyhedral distances");
  return {sub, [&c, a] { return CmdMatrix(c, a->sources, a->targets, a->exact); }, true};
}

}  // namespace geodesic::cli
