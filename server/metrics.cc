#include "server/metrics.h"

#include <vector>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "server/http_server.h"

namespace geodesic::server {

void Metrics::Record(const std::string& method, const std::string& code, double seconds) {
  absl::MutexLock lock(&mu_);
  ++requests_[{method, code}];
  Histogram& h = latency_[method];
  for (size_t i = 0; i < kBuckets.size(); ++i) {
    if (seconds <= kBuckets[i]) ++h.buckets[i];
  }
  ++h.count;
  h.sum += seconds;
}

void Metrics::AddGauge(const std::string& name, const std::string& help,
                       std::function<double()> read) {
  absl::MutexLock lock(&mu_);
  series_[name] = {help, "gauge", std::move(read)};
}

void Metrics::AddCounter(const std::string& name, const std::string& help,
                         std::function<double()> read) {
  absl::MutexLock lock(&mu_);
  series_[name] = {help, "counter", std::move(read)};
}

std::string Metrics::Render() const {
  absl::MutexLock lock(&mu_);
  std::string out;
  out += "# HELP geodesicd_requests_total Finished RPCs by method and status code.\n";
  out += "# TYPE geodesicd_requests_total counter\n";
  for (const auto& [key, n] : requests_) {
    out += absl::StrFormat("geodesicd_requests_total{method=\"%s\",code=\"%s\"} %u\n", key.first,
                           key.second, n);
  }
  out += "# HELP geodesicd_request_seconds RPC latency.\n";
  out += "# TYPE geodesicd_request_seconds histogram\n";
  for (const auto& [method, h] : latency_) {
    for (size_t i = 0; i < kBuckets.size(); ++i) {
      out += absl::StrFormat("geodesicd_request_seconds_bucket{method=\"%s\",le=\"%g\"} %u\n",
                             method, kBuckets[i], h.buckets[i]);
    }
    out += absl::StrFormat("geodesicd_request_seconds_bucket{method=\"%s\",le=\"+Inf\"} %u\n",
                           method, h.count);
    out += absl::StrFormat("geodesicd_request_seconds_sum{method=\"%s\"} %.9f\n", method, h.sum);
    out += absl::StrFormat("geodesicd_request_seconds_count{method=\"%s\"} %u\n", method, h.count);
  }
  for (const auto& [name, g] : series_) {
    out += absl::StrFormat("# HELP %s %s\n# TYPE %s %s\n%s %.17g\n", name, g.help, name, g.type,
                           name, g.read());
  }
  out += info_;
  return out;
}

void Metrics::AddInfo(const std::string& name, const std::string& help,
                      const std::map<std::string, std::string>& labels) {
  std::vector<std::string> pairs;
  for (const auto& [key, value] : labels) {
    // Label values escape backslash, quote and newline (exposition format).
    std::string escaped;
    for (char c : value) {
      if (c == '\\' || c == '"') escaped += '\\';
      escaped += c == '\n' ? std::string("\\n") : std::string(1, c);
    }
    pairs.push_back(absl::StrFormat("%s=\"%s\"", key, escaped));
  }
  absl::MutexLock lock(&mu_);
  info_ += absl::StrFormat("# HELP %s %s\n# TYPE %s gauge\n%s{%s} 1\n", name, help, name, name,
                           absl::StrJoin(pairs, ","));
}

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
