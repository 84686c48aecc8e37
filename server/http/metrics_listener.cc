#include "server/http/metrics_listener.h"

#include "server/http/http_server.h"

namespace geodesic::server {

struct MetricsHttpServer::Impl {
  std::unique_ptr<HttpServer> http;
};

std::unique_ptr<MetricsHttpServer> MetricsHttpServer::Start(const std::string& address,
                                                            const Metrics* metrics,
                                                            std::function<bool()> ready,
                                                            std::string* error) {
  HttpServerOptions options;
  options.listen = address;
  // Scrapers and probes: a few connections, quick answers, the same
  // deadlines as the gateway.
  options.limits.max_body_bytes = 0;
  options.limits.max_connections = 64;
  options.limits.io_threads = 1;
  options.limits.workers = 2;
  options.limits.max_queued = 16;
  options.handler = [metrics, ready](const HttpRequest& req) {
    HttpResponse res;
    res.content_type = "text/plain";
    if (req.method != "GET" && req.method != "HEAD") {
      res.status = 405;
      res.headers.emplace_back("Allow", "GET, HEAD");
      res.body = "method not allowed\n";
    } else if (req.path == "/metrics") {
      res.content_type = "text/plain; version=0.0.4";
      res.body = metrics->Render();
    } else if (req.path == "/healthz") {
      // Liveness: the process answers. Readiness: it has restored what its
      // catalog holds and can answer for it.
      res.body = "ok\n";
    } else if (req.path == "/readyz") {
      const bool is_ready = !ready || ready();
      res.status = is_ready ? 200 : 503;
      res.body = is_ready ? "ready\n" : "restoring\n";
    } else {
      res.status = 404;
      res.body = "not found\n";
    }
    return res;
  };
  auto started = HttpServer::Start(std::move(options));
  if (!started.ok()) {
    *error = std::string(started.status().message());
    return nullptr;
  }
  auto server = std::unique_ptr<MetricsHttpServer>(new MetricsHttpServer);
  server->impl_ = std::make_unique<Impl>();
  server->impl_->http = std::move(*started);
  return server;
}

int MetricsHttpServer::port() const { return impl_->http->port(); }

MetricsHttpServer::~MetricsHttpServer() = default;

}  // namespace geodesic::server
