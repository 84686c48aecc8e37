#include "server/metrics.h"

#include <cerrno>
#include <cstring>

#include "absl/strings/str_format.h"
#include "httplib.h"
#include "server/listen_socket.h"

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
  return out;
}

struct MetricsHttpServer::Impl {
  httplib::Server http;
  std::thread thread;
  int port = 0;
};

std::unique_ptr<MetricsHttpServer> MetricsHttpServer::Start(const std::string& address,
                                                            const Metrics* metrics,
                                                            std::function<bool()> ready,
                                                            std::string* error) {
  auto colon = address.rfind(':');
  if (colon == std::string::npos) {
    *error = "metrics address must be HOST:PORT";
    return nullptr;
  }
  const std::string host = address.substr(0, colon);
  const int port = std::atoi(address.c_str() + colon + 1);
  auto server = std::unique_ptr<MetricsHttpServer>(new MetricsHttpServer);
  server->impl_ = std::make_unique<Impl>();
  httplib::Server& http = server->impl_->http;
  http.set_socket_options(ExclusiveListenSocket);
  http.Get("/metrics", [metrics](const httplib::Request&, httplib::Response& res) {
    res.set_content(metrics->Render(), "text/plain; version=0.0.4");
  });
  // Liveness: the process answers. Readiness: it has restored what its
  // catalog holds and can answer for it.
  http.Get("/healthz", [](const httplib::Request&, httplib::Response& res) {
    res.set_content("ok\n", "text/plain");
  });
  http.Get("/readyz", [ready](const httplib::Request&, httplib::Response& res) {
    const bool is_ready = !ready || ready();
    res.status = is_ready ? 200 : 503;
    res.set_content(is_ready ? "ready\n" : "restoring\n", "text/plain");
  });
  errno = 0;
  int bound = port == 0 ? http.bind_to_any_port(host) : (http.bind_to_port(host, port) ? port : -1);
  if (bound <= 0) {
    *error =
        "cannot listen on " + address + (errno ? std::string(": ") + std::strerror(errno) : "");
    return nullptr;
  }
  server->impl_->port = bound;
  Impl* impl = server->impl_.get();
  impl->thread = std::thread([impl] { impl->http.listen_after_bind(); });
  return server;
}

int MetricsHttpServer::port() const { return impl_->port; }

MetricsHttpServer::~MetricsHttpServer() {
  if (impl_) {
    impl_->http.stop();
    if (impl_->thread.joinable()) impl_->thread.join();
  }
}

}  // namespace geodesic::server
