// geodesic bench: bench/query_bench.h's load, as a command of the client
// (scripts and the end-to-end test run it so).
#include <memory>

#include "bench/query_bench.h"
#include "client/cli/commands.h"

namespace geodesic::cli {

Command AddBench(CLI::App& app, Common& c) {
  auto* sub = app.add_subcommand("bench", "bounded load of random point-to-point queries");
  auto options = std::make_shared<bench::BenchOptions>();
  bench::AddBenchFlags(*sub, *options);
  return {sub, [&c, options] { return bench::RunBench(c, *options); }, true};
}

}  // namespace geodesic::cli
