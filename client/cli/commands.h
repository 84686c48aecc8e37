// The commands of the `geodesic` client, one file each: every Add function
// adds its subcommand, with its options, to the app.
#ifndef GEODESIC_CLIENT_CLI_COMMANDS_H_
#define GEODESIC_CLIENT_CLI_COMMANDS_H_

#include "client/cli/common.h"

namespace geodesic::cli {

Command AddMeshes(CLI::App& app, Common& c);
Command AddHealth(CLI::App& app, Common& c);
// `mesh_option`: --mesh, which `load` defaults to the file's stem when it
// was not given.
Command AddLoad(CLI::App& app, Common& c, const CLI::Option* mesh_option);
Command AddUnload(CLI::App& app, Common& c);
Command AddGraph(CLI::App& app, Common& c);
Command AddStatus(CLI::App& app, Common& c);
Command AddField(CLI::App& app, Common& c);
Command AddDistance(CLI::App& app, Common& c);
Command AddPath(CLI::App& app, Common& c);
Command AddMatrix(CLI::App& app, Common& c);
Command AddSample(CLI::App& app, Common& c);
Command AddSnap(CLI::App& app, Common& c);
// A bounded load of random queries (bench/query_bench.h).
Command AddBench(CLI::App& app, Common& c);

}  // namespace geodesic::cli

#endif  // GEODESIC_CLIENT_CLI_COMMANDS_H_
