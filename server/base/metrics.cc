#include "server/base/metrics.h"

#include <vector>

#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"

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

}  // namespace geodesic::server
