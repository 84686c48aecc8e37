// The daemon's plaintext listener for Prometheus scrapes and probes.
#ifndef GEODESIC_SERVER_HTTP_METRICS_LISTENER_H_
#define GEODESIC_SERVER_HTTP_METRICS_LISTENER_H_

#include <functional>
#include <memory>
#include <string>

#include "server/base/metrics.h"

namespace geodesic::server {

// Serves GET /metrics, /healthz (200 while the process answers) and /readyz
// (200 once `ready` says so, 503 before) on host:port (port 0: any free
// port) on threads of its own until destroyed, on the gateway's hardened
// server (http_server.h) but always in plaintext: bind it to loopback or a
// private network. A port already taken is refused, with the reason.
class MetricsHttpServer {
 public:
  static std::unique_ptr<MetricsHttpServer> Start(const std::string& address,
                                                  const Metrics* metrics,
                                                  std::function<bool()> ready, std::string* error);
  ~MetricsHttpServer();
  int port() const;

 private:
  struct Impl;
  std::unique_ptr<Impl> impl_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_HTTP_METRICS_LISTENER_H_
