// Reading meshes (OBJ, OFF, PLY ascii/binary, STL, GIFTI surfaces) into a TriangleSoup with
// the file's own vertex and face order, diagnostics of what was read, and the
// conversion to a Mesh.
#ifndef GEODESIC_CORE_MESH_MESH_IO_H_
#define GEODESIC_CORE_MESH_MESH_IO_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/types/span.h"
#include "core/mesh/corner_fans.h"
#include "core/mesh/mesh.h"
#include "core/mesh/mesh_diagnostics.h"

namespace geodesic {

struct LoadOptions {
  // Split non-manifold vertices into one copy per fan (copies get new ids
  // after the file's vertices) instead of rejecting the mesh.
  bool repair_non_manifold = false;
};

// The format a path names by its extension, lower case ("ply" for a.PLY,
// "gii" for a.surf.gii).
std::string MeshFormatOfPath(const std::string& path);

// The formats the readers below take, as MeshFormatOfPath names them: obj,
// off, ply, stl and gii. The one list every command, RPC and help text
// names, so that a new reader is offered everywhere at once.
absl::Span<const std::string_view> MeshFormats();
// Whether `format` (lower case) is one of MeshFormats().
bool IsMeshFormat(std::string_view format);
// MeshFormats() for messages and help text: "obj, off, ply, stl, gii".
std::string MeshFormatList();

// Reads the file as it is. NOT_FOUND / PERMISSION_DENIED for a missing or
// unreadable file; INVALID_ARGUMENT for an unknown format, an empty or
// truncated file, NaN/Inf coordinates or out-of-range indices, naming the
// file, the problem and the first offending element.
absl::StatusOr<TriangleSoup> ReadTriangleSoup(const std::string& path,
                                              MeshDiagnostics* diagnostics = nullptr);

// The same from bytes in memory (uploads); `format` is one of MeshFormats(),
// and `name` is used in messages. A GIFTI surface is read from the bytes
// themselves, RESOURCE_EXHAUSTED if its arrays declare more than
// `max_decoded_bytes` (0: no budget; see ReadGiftiSurfaceFromMemory); the
// other formats go through a temporary file, which OpenMesh's readers need.
absl::StatusOr<TriangleSoup> ReadTriangleSoupFromMemory(std::string_view bytes,
                                                        std::string_view format,
                                                        std::string_view name,
                                                        MeshDiagnostics* diagnostics = nullptr,
                                                        uint64_t max_decoded_bytes = 0);

// Removes the temporary files of ReadTriangleSoupFromMemory that a process
// killed mid-read left behind: geodesic-mesh-<pid>-* in the temporary
// directory whose process is gone, and files of the older pid-less naming
// (geodesic-mesh-XXXXXX.<format>) more than an hour old. For a daemon's
// start; errors (another user's file, a race with its removal) are ignored.
void RemoveStaleTemporaryMeshFiles();

// INVALID_ARGUMENT naming `name` when the soup has no triangle: a point
// cloud parses, but no distance on it is defined, and such a file is as
// often a torn copy of a mesh.
absl::Status RequireFaces(const TriangleSoup& soup, std::string_view name);

// ReadTriangleSoup + ComputeDiagnostics + RequireFaces + Mesh::Build (with
// optional repair). A refusal after reading leaves the diagnostics filled,
// with mesh_error saying why.
absl::StatusOr<Mesh> LoadMesh(const std::string& path, const LoadOptions& options = {},
                              MeshDiagnostics* diagnostics = nullptr);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_MESH_IO_H_
