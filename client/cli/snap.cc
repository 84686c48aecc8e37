// geodesic snap: the nearest surface points to positions.
#include <cstdio>

#include "client/cli/commands.h"
#include "server/api/convert.h"

namespace geodesic::cli {
namespace {

int CmdSnap(const Common& c, const std::vector<std::string>& positions) {
  auto stub = Connect(c);
  std::vector<v1::SurfacePoint> points;
  std::vector<std::string> specs;
  for (const auto& p : positions) specs.push_back(p.rfind("xyz:", 0) == 0 ? p : "xyz:" + p);
  int rc = 0;
  std::vector<Json> distances;
  if (!ResolvePoints(stub.get(), c, specs, &points, &rc, &distances)) return rc;
  Json snapped = Json::array();
  for (size_t i = 0; i < points.size(); ++i) {
    if (c.json) {
      snapped.push_back({{"position", specs[i]},
                         {"point", server::FormatPoint(points[i])},
                         {"snap_distance", distances[i]}});
    } else {
      std::printf("%s -> %s (%s from the surface)\n", specs[i].c_str(),
                  server::FormatPoint(points[i]).c_str(), distances[i].dump().c_str());
    }
  }
  if (c.json) PrintJson(snapped);
  return 0;
}

}  // namespace

Command AddSnap(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("snap", "nearest surface point to positions X,Y,Z");
  auto positions = std::make_shared<std::vector<std::string>>();
  sub->add_option("positions", *positions, "X,Y,Z ...")->required();
  return {sub, [&c, positions] { return CmdSnap(c, *positions); }};
}

}  // namespace geodesic::cli
