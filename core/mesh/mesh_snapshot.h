// A built mesh and its diagnostics saved to disk, keyed by the bytes of the
// mesh file it came from, so a daemon that registers the same file again
// (after a restart, typically) restores the mesh instead of parsing,
// diagnosing and building it, which on a large scan is far more work than
// reading the arrays back.
//
// Layout (little-endian): a 4 KiB header with magic "GEODMSH\0", format
// version, endianness tag, the hash of the source file's bytes, the mesh
// fingerprint, the diagnostics, and a table of the mesh's arrays (offset,
// bytes, XXH3-64 checksum); then the arrays, each 64-byte aligned. Written
// like graph files: to a temporary name, fsynced and renamed into place.
#ifndef GEODESIC_CORE_MESH_MESH_SNAPSHOT_H_
#define GEODESIC_CORE_MESH_MESH_SNAPSHOT_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "core/mesh/mesh.h"
#include "core/mesh/mesh_io.h"

namespace geodesic {

inline constexpr uint32_t kMeshSnapshotVersion = 1;

// The key of a mesh file: XXH3-64 of its bytes, seeded by its format
// ("obj", "off", "ply", "stl"), since the format decides what they mean.
uint64_t SourceHash(std::string_view bytes, std::string_view format);
// The same for a file, whose format is its extension (MeshFormatOfPath).
// NOT_FOUND / PERMISSION_DENIED naming the path when it cannot be read.
absl::StatusOr<uint64_t> SourceHashOfFile(const std::string& path);

// "<source hash, 16 hex digits>.mesh"
std::string MeshSnapshotName(uint64_t source_hash);

// Saves `mesh` and `diagnostics` (the file's own facts: path, load time and
// mesh_error are not kept) atomically at `path`.
absl::Status WriteMeshSnapshot(const Mesh& mesh, const MeshDiagnostics& diagnostics,
                               uint64_t source_hash, const std::string& path);

struct RestoredMesh {
  Mesh mesh;
  uint64_t fingerprint = 0;  // MeshFingerprint(mesh), checked against the saved one
  MeshDiagnostics diagnostics;
};
// Restores what WriteMeshSnapshot saved, after checking every checksum and
// every index (Mesh::FromArrays). NOT_FOUND when there is no snapshot;
// FAILED_PRECONDITION when it belongs to other bytes or another format
// version; DATA_LOSS when it is truncated or corrupt. Messages name the path.
absl::StatusOr<RestoredMesh> ReadMeshSnapshot(const std::string& path, uint64_t source_hash);

}  // namespace geodesic

#endif  // GEODESIC_CORE_MESH_MESH_SNAPSHOT_H_
