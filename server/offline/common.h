// Shared plumbing of the offline subcommands: loading, point parsing, output.
#ifndef GEODESIC_SERVER_OFFLINE_COMMON_H_
#define GEODESIC_SERVER_OFFLINE_COMMON_H_

#include <cstdint>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "CLI/CLI.hpp"
#include "absl/status/statusor.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh.h"
#include "core/mesh/region.h"
#include "core/mesh/surface_locator.h"
#include "core/mesh/surface_point.h"
#include "nlohmann/json.hpp"

namespace geodesic::offline {

// For commands that answer one query and exit: memory one phase frees
// (loading the mesh, say) stays with the process for the next phase to
// reuse, rather than going back to the kernel and coming again as fresh
// pages, each faulted in at its first touch. On virtual machines such faults
// cost microseconds a page, about a third of a field's solve in a new
// process (bench/notes.md, "Page faults"). Call first.
void KeepFreedMemory();
// Page faults this process took so far that needed no disk read: first
// touches of fresh memory, mostly.
int64_t MinorPageFaults();

// Prints "geodesicd <command>: <status message>" to stderr; returns 1.
int Fail(const char* command, const absl::Status& status);

// With `repair_non_manifold`, non-manifold vertices are split into one copy
// per fan (appended after the file's vertices) instead of refused.
absl::StatusOr<std::shared_ptr<const Mesh>> LoadMeshOrError(const std::string& path,
                                                            bool repair_non_manifold = false);

// --region-vertices / --region-faces, and --parent-ids where results can be
// written in the parent's ids.
struct RegionFlags {
  std::string vertices_path, faces_path;
  bool parent_ids = false;
  bool given() const { return !vertices_path.empty() || !faces_path.empty(); }
};
void AddRegionFlags(CLI::App& app, RegionFlags* flags, bool parent_ids);

// Vertex or face ids, from a text file (one id a line; blank lines and
// lines starting with # skipped) or a .npy (a 1-d array of integer ids, or
// of bools: the ids of the true entries). A leading @ is ignored, as in
// point lists. Errors name `flag`, the path and, in text, the line.
absl::StatusOr<std::vector<uint32_t>> ReadIdList(std::string path, const std::string& flag);

// The mesh a command works on: the file's, or the region of it the flags
// name (then the file's mesh is its parent).
struct WorkMesh {
  std::shared_ptr<const Mesh> parent;
  std::shared_ptr<const Region> region;  // null without a region
  const std::shared_ptr<const Mesh>& mesh() const { return region ? region->mesh : parent; }
  // The --json keys of a region: its vertex and face counts, and its parent's.
  void AddJson(nlohmann::ordered_json& out) const;
};
absl::StatusOr<WorkMesh> LoadWorkMesh(const std::string& path, bool repair,
                                      const RegionFlags& region);

// A distance limit: a number above zero (inf allowed), never NaN.
inline const CLI::Validator kPositiveDistance(
    [](std::string& text) -> std::string {
      try {
        const double v = std::stod(text);
        if (v > 0) return "";
      } catch (const std::exception&) {
      }
      return "must be a distance above 0, got '" + text + "'";
    },
    "DISTANCE > 0");

// Adds --repair-non-manifold to a command that loads a mesh.
void AddRepairFlag(CLI::App& app, bool* repair);

// Parses point specs (v:ID, e:EDGE:T, f:FACE:B0,B1,B2, xyz:X,Y,Z) and
// validates them against one mesh. Positions are snapped to the nearest
// surface point, with the search index built on the first xyz: spec only.
class PointResolver {
 public:
  explicit PointResolver(const Mesh& mesh) : mesh_(mesh) {}
  struct Resolved {
    SurfacePoint point;
    // How far an xyz: position was from the surface point it snapped to.
    std::optional<double> snap_distance;
  };
  absl::StatusOr<Resolved> Resolve(const std::string& spec);

 private:
  const Mesh& mesh_;
  std::optional<SurfaceLocator> locator_;
};

// A list of points as matrix-like commands take it: each argument is a
// spec, `all` (every mesh vertex in file order) or `@FILE` (one spec per
// line; blank lines and lines starting with # skipped). Errors name `flag`
// and, for a file, its path and line.
absl::StatusOr<std::vector<SurfacePoint>> ResolvePointList(PointResolver& resolver,
                                                           const Mesh& mesh,
                                                           const std::vector<std::string>& args,
                                                           const std::string& flag);

// The point lists of a matrix on the work mesh. With --parent-ids, specs
// name points of the parent (ids and positions alike), mapped into the
// region, a point outside it an error naming `flag` and the point, and
// `all` is every parent vertex, those outside the region included: their
// slot is kNone. Otherwise as ResolvePointList on the work mesh.
struct WorkPoints {
  std::vector<SurfacePoint> points;  // on the work mesh
  std::vector<uint32_t> slot;        // per point listed: its index in `points`, or kNone
};
// `resolver` is on the parent with --parent-ids, on the work mesh otherwise
// (one for every list, so that positions build one search index).
absl::StatusOr<WorkPoints> ResolveWorkPoints(const WorkMesh& work, bool parent_ids,
                                             PointResolver& resolver,
                                             const std::vector<std::string>& args,
                                             const std::string& flag);
// A point of the parent as the region's (the point itself without a region).
absl::StatusOr<SurfacePoint> IntoWorkMesh(const WorkMesh& work, const SurfacePoint& parent_point,
                                          const std::string& flag);

// One spec, for commands that resolve a single point.
absl::StatusOr<SurfacePoint> ResolvePoint(const Mesh& mesh, const std::string& spec);

// The snap distance as JSON: null for points that were not positions.
nlohmann::ordered_json SnapJson(const PointResolver::Resolved& r);

// Writes a field in the format the path's extension names
// (core/query/result_files.h: .f64, .npy, .csv, .func.gii, or .ply coloured
// on `mesh`).
absl::Status WriteFieldFile(const std::string& path, const std::vector<double>& values,
                            const Mesh& mesh);

// --json output. Keys keep the order they are set in; strings are escaped;
// doubles print with full (round-trip) precision; +inf and NaN, which JSON
// cannot hold, print as null.
using Json = nlohmann::ordered_json;

// Prints `value` and a newline to stdout.
void PrintJson(const Json& value);

}  // namespace geodesic::offline

#endif  // GEODESIC_SERVER_OFFLINE_COMMON_H_
