// Prometheus text metrics for the daemon, served over HTTP.
//
// Written here rather than with prometheus-cpp: dependencies come from
// Debian 12's packages, and Debian 12 packages no prometheus-cpp (nor any
// other C++ Prometheus client). What is written is the text exposition
// format's small core (HELP, TYPE, counters, gauges and one histogram per
// method), checked by MetricsTest against the format's rules; moving to
// prometheus-cpp is a swap of this file once a Debian release carries it.
#ifndef GEODESIC_SERVER_METRICS_H_
#define GEODESIC_SERVER_METRICS_H_

#include <array>
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <thread>

#include "absl/base/thread_annotations.h"
#include "absl/synchronization/mutex.h"

namespace geodesic::server {

class Metrics {
 public:
  // Records one finished request.
  void Record(const std::string& method, const std::string& code, double seconds);
  // Values read when the page is rendered. A gauge is a level that goes up
  // and down (resident bytes, builds running); a counter only ever grows
  // (hits, evictions), and its name ends in "_total", as Prometheus expects
  // of the series rate() and increase() are asked about.
  void AddGauge(const std::string& name, const std::string& help, std::function<double()> read);
  void AddCounter(const std::string& name, const std::string& help, std::function<double()> read);
  // A constant 1 whose labels carry facts (version, build type): the
  // Prometheus "info" idiom, joined onto other series by its labels.
  void AddInfo(const std::string& name, const std::string& help,
               const std::map<std::string, std::string>& labels);
  std::string Render() const;

 private:
  static constexpr std::array<double, 12> kBuckets = {0.0005, 0.001, 0.002, 0.005, 0.01, 0.02,
                                                      0.05,   0.1,   0.2,   0.5,   1,    5};
  struct Histogram {
    std::array<uint64_t, kBuckets.size()> buckets{};
    uint64_t count = 0;
    double sum = 0;
  };
  mutable absl::Mutex mu_;
  std::map<std::pair<std::string, std::string>, uint64_t> requests_ ABSL_GUARDED_BY(mu_);
  std::map<std::string, Histogram> latency_ ABSL_GUARDED_BY(mu_);
  struct Series {
    std::string help;
    const char* type;  // "gauge" or "counter"
    std::function<double()> read;
  };
  std::map<std::string, Series> series_ ABSL_GUARDED_BY(mu_);
  std::string info_ ABSL_GUARDED_BY(mu_);  // rendered once, when added
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_METRICS_H_
