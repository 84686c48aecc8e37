// Shared plumbing of the offline subcommands: loading, point parsing, output.
#ifndef GEODESIC_SERVER_OFFLINE_COMMON_H_
#define GEODESIC_SERVER_OFFLINE_COMMON_H_

#include <memory>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "core/dgg_graph.h"
#include "core/mesh.h"
#include "core/surface_point.h"
#include "nlohmann/json.hpp"

namespace geodesic::offline {

// Prints "geodesicd <command>: <status message>" to stderr; returns 1.
int Fail(const char* command, const absl::Status& status);

absl::StatusOr<std::shared_ptr<const Mesh>> LoadMeshOrError(const std::string& path);

// Parses a point spec (v:ID, e:EDGE:T, f:FACE:B0,B1,B2, xyz:X,Y,Z), snapping
// positions to the surface, and validates it against the mesh.
absl::StatusOr<SurfacePoint> ResolvePoint(const Mesh& mesh, const std::string& spec);

// Writes one little-endian float64 per value.
absl::Status WriteF64(const std::string& path, const std::vector<double>& values);

// --json output. Keys keep the order they are set in; strings are escaped;
// doubles print with full (round-trip) precision; +inf and NaN, which JSON
// cannot hold, print as null.
using Json = nlohmann::ordered_json;

// Prints `value` and a newline to stdout.
void PrintJson(const Json& value);

}  // namespace geodesic::offline

#endif  // GEODESIC_SERVER_OFFLINE_COMMON_H_
