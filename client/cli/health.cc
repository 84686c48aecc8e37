// geodesic health: the server's gRPC health.
#include <chrono>
#include <cstdio>

#include "client/cli/commands.h"
#include "grpc/health/v1/health.grpc.pb.h"

namespace geodesic::cli {
namespace {

// The standard gRPC health check, which needs no token: for probes such as
// the container's HEALTHCHECK. Exit 0 only when SERVING.
int CmdHealth(const Common& c, const std::string& service) {
  auto stub = grpc::health::v1::Health::NewStub(OpenChannel(c, false));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(c.timeout * 1000)));
  grpc::health::v1::HealthCheckRequest req;
  req.set_service(service);
  grpc::health::v1::HealthCheckResponse resp;
  grpc::Status s = stub->Check(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  const std::string status =
      grpc::health::v1::HealthCheckResponse::ServingStatus_Name(resp.status());
  if (c.json) {
    PrintJson(Json{{"service", service}, {"status", status}});
  } else {
    std::printf("%s\n", status.c_str());
  }
  return resp.status() == grpc::health::v1::HealthCheckResponse::SERVING ? 0 : 1;
}

}  // namespace

Command AddHealth(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand(
      "health", "the server's gRPC health (no token needed); exit 0 only when SERVING");
  auto service = std::make_shared<std::string>();
  sub->add_option("--service", *service,
                  "service to ask about: empty for the server, geodesic.v1.Geodesic, or a "
                  "graph's name as in `status`");
  return {sub, [&c, service] { return CmdHealth(c, *service); }};
}

}  // namespace geodesic::cli
