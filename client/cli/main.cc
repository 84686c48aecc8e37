// geodesic: the command-line client of geodesicd.
#include <vector>

#include "absl/strings/str_format.h"
#include "client/cli/commands.h"
#include "core/base/version.h"

int main(int argc, char** argv) {
  using namespace geodesic::cli;
  CLI::App app{
      "geodesic: client of the geodesicd server.\n\n"
      "Surface points: v:ID (vertex), e:EDGE:T (edge point), f:FACE:B0,B1,B2 (face point; the\n"
      "barycentric coordinates weight the face's vertices in the order the mesh file lists them\n"
      "for that face) or xyz:X,Y,Z (snapped to the surface). Ids are the file's order.",
      "geodesic"};
  app.set_version_flag("--version", absl::StrFormat("geodesic %s (%s build)", geodesic::kVersion,
                                                    geodesic::kBuildType));
  // Every option's help shows its default.
  app.option_defaults()->always_capture_default();
  Common c;
  const CLI::Option* mesh_option = AddCommonFlags(app, c);
  app.require_subcommand(1);
  const std::vector<Command> commands = {
      AddMeshes(app, c), AddHealth(app, c),   AddLoad(app, c, mesh_option),
      AddUnload(app, c), AddGraph(app, c),    AddStatus(app, c),
      AddField(app, c),  AddDistance(app, c), AddPath(app, c),
      AddMatrix(app, c), AddSample(app, c),   AddSnap(app, c),
      AddBench(app, c)};
  // Also accepted after the subcommand, where `graph --pseudo-vertices` has
  // always been, and where the offline commands take --json.
  for (const Command& command : commands) {
    if (command.graph) command.app->add_flag("--pseudo-vertices", c.pseudo_vertices, kPseudoHelp);
  }
  for (const Command& command : commands) {
    command.app->add_flag("--json", c.json, "machine-readable output");
  }
  CLI11_PARSE(app, argc, argv);
  if (!LoadSecurity(c)) return 2;
  for (const Command& command : commands) {
    if (command.app->parsed()) return command.run();
  }
  return 2;
}
