// A bounded load on a running geodesicd: concurrent clients issue random
// point-to-point queries until a count or a duration is reached, then the
// throughput and latency percentiles are printed. Run as `geodesic bench`
// or as the query_bench tool.
#ifndef GEODESIC_BENCH_QUERY_BENCH_H_
#define GEODESIC_BENCH_QUERY_BENCH_H_

#include "client/cli/common.h"

namespace geodesic::bench {

struct BenchOptions {
  int concurrency = 4;  // parallel clients, each on the one channel
  double duration = 10;
  int count = 1000;
  bool with_path = false;
  bool face_points = false;  // points inside faces, not vertices
};

void AddBenchFlags(CLI::App& app, BenchOptions& options);
// The exit code: 0 when every query was answered, 1 otherwise.
int RunBench(const cli::Common& c, const BenchOptions& options);

}  // namespace geodesic::bench

#endif  // GEODESIC_BENCH_QUERY_BENCH_H_
