// Subcommands whose implementation has not landed yet. Each is removed from
// this file when its own <name>_command.cc lands.
#include <cstdio>

#include "server/offline/commands.h"

namespace geodesic::offline {
namespace {
int Pending(const char* name) {
  std::fprintf(stderr, "geodesicd %s: not available in this build yet\n", name);
  return 2;
}
}  // namespace

int RunInfo(int, char**) { return Pending("info"); }
int RunExact(int, char**) { return Pending("exact"); }
int RunBuild(int, char**) { return Pending("build"); }
int RunField(int, char**) { return Pending("field"); }
int RunDistance(int, char**) { return Pending("distance"); }

}  // namespace geodesic::offline
