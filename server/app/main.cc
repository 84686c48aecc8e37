// geodesicd: the geodesic distance daemon and its offline subcommands.
#include <cstdio>
#include <cstring>
#include <string_view>

#include "core/base/version.h"
#include "server/app/serve.h"
#include "server/offline/commands.h"

namespace {

constexpr char kUsage[] =
    "usage: geodesicd <command> [options]\n"
    "\n"
    "commands:\n"
    "  serve                 the gRPC daemon (with no options: the bundled sample mesh on\n"
    "                        127.0.0.1:50051)\n"
    "  info MESH|GRAPH.dgg   diagnostics of a mesh, or describe and validate a graph file\n"
    "  exact                 exact geodesic distances from one source (window propagation)\n"
    "  build MESH            build the discrete geodesic graph of a mesh (or, with\n"
    "                        --part I/N, one part of a distributed build)\n"
    "  merge MESH PART...    join the parts of a distributed build into the graph\n"
    "  field                 distance field on a graph\n"
    "  distance              point-to-point distance (and path) on a graph\n"
    "  matrix                distance matrix between point lists, as .npy or sparse .npz\n"
    "  check                 a graph's error on its own mesh, against exact distances\n"
    "\n"
    "Run 'geodesicd <command> --help' for a command's options, 'geodesicd --version' for\n"
    "the version.\n";

}  // namespace

int main(int argc, char** argv) {
  if (argc < 2 || !std::strcmp(argv[1], "--help") || !std::strcmp(argv[1], "-h")) {
    std::fputs(kUsage, argc < 2 ? stderr : stdout);
    return argc < 2 ? 2 : 0;
  }
  std::string_view command = argv[1];
  if (command == "--version" || command == "version") {
    std::printf("geodesicd %s (%s build)\n", geodesic::kVersion, geodesic::kBuildType);
    return 0;
  }
  using namespace geodesic::offline;
  if (command == "serve") return geodesic::server::RunServe(argc - 1, argv + 1);
  if (command == "info") return RunInfo(argc - 1, argv + 1);
  if (command == "exact") return RunExact(argc - 1, argv + 1);
  if (command == "build") return RunBuild(argc - 1, argv + 1);
  if (command == "merge") return RunMerge(argc - 1, argv + 1);
  if (command == "field") return RunField(argc - 1, argv + 1);
  if (command == "distance") return RunDistance(argc - 1, argv + 1);
  if (command == "matrix") return RunMatrix(argc - 1, argv + 1);
  if (command == "check") return RunCheck(argc - 1, argv + 1);
  std::fprintf(stderr, "geodesicd: unknown command '%s'\n\n%s", argv[1], kUsage);
  return 2;
}
