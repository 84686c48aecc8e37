// query_bench: `geodesic bench` as a tool of its own, with the client's
// connection flags (--server, --mesh, --eps, TLS, token, --json).
#include "bench/query_bench.h"

int main(int argc, char** argv) {
  using namespace geodesic;
  CLI::App app{"A bounded load of random point-to-point queries on a running geodesicd.",
               "query_bench"};
  app.option_defaults()->always_capture_default();
  cli::Common c;
  cli::AddCommonFlags(app, c);
  bench::BenchOptions options;
  bench::AddBenchFlags(app, options);
  CLI11_PARSE(app, argc, argv);
  if (!cli::LoadSecurity(c)) return 2;
  return bench::RunBench(c, options);
}
