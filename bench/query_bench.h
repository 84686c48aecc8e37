// A bounded load on a running geodesicd: concurrent clients issue random
// point-to-point queries until a count or a duration is reached, then the
// throughput and latency percentiles are printed. Run as `geodesic bench`
// or as the query_bench tool. With --local the same load runs on an engine
// in this process and also reports the searches' work counters.
#ifndef GEODESIC_BENCH_QUERY_BENCH_H_
#define GEODESIC_BENCH_QUERY_BENCH_H_

#include <string>

#include "client/cli/common.h"

namespace geodesic::bench {

struct BenchOptions {
  int concurrency = 4;  // parallel clients, each on the one channel
  double duration = 10;
  int count = 1000;
  bool with_path = false;
  bool face_points = false;  // points inside faces, not vertices
  // A mesh file to query in this process instead of a daemon: the load then
  // also reports the searches' work (core/query/search_work.h), which a
  // daemon's answers do not carry.
  std::string local_mesh;
  std::string local_graph;  // with local_mesh: its graph file, instead of a build
};
// --local's epsilon when --eps is not given.
inline constexpr double kLocalEpsilon = 1e-3;

void AddBenchFlags(CLI::App& app, BenchOptions& options);
// The exit code: 0 when every query was answered, 1 otherwise.
int RunBench(const cli::Common& c, const BenchOptions& options);

}  // namespace geodesic::bench

#endif  // GEODESIC_BENCH_QUERY_BENCH_H_
