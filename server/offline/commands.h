// The offline subcommands of `geodesicd`: each takes the arguments after its
// name (argv[0] is the subcommand) and returns the process exit code. Their
// flags and --json keys are a contract that scripts rely on.
#ifndef GEODESIC_SERVER_OFFLINE_COMMANDS_H_
#define GEODESIC_SERVER_OFFLINE_COMMANDS_H_

#include <string>

namespace geodesic::offline {

int RunInfo(int argc, char** argv);                    // geodesicd info MESH|GRAPH.dgg [--json]
int RunGraphInfo(const std::string& path, bool json);  // info on a .dgg file
int RunExact(int argc, char** argv);     // geodesicd exact --mesh M --source SPEC --out F.f64
int RunBuild(int argc, char** argv);     // geodesicd build MESH --eps E --out G.dgg [--part I/N]
int RunMerge(int argc, char** argv);     // geodesicd merge MESH PART... --out G.dgg
int RunField(int argc, char** argv);     // geodesicd field --mesh M --graph G --source SPEC
int RunDistance(int argc, char** argv);  // geodesicd distance --mesh M --graph G --from A --to B
int RunMatrix(int argc,
              char** argv);  // geodesicd matrix --mesh M --graph G --sources ... --out D.npy
int RunCheck(int argc, char** argv);  // geodesicd check --mesh M --graph G [--sources N]

}  // namespace geodesic::offline

#endif  // GEODESIC_SERVER_OFFLINE_COMMANDS_H_
