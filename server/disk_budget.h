// Keeps a graph directory under a byte budget (geodesicd serve --disk-limit).
//
// Graph files (*.dgg) and mesh snapshots (*.mesh) can be made again, so
// when the directory holds more than the budget the least recently used of
// them are removed: first those no catalog entry refers to, then catalogued
// ones, which a restart would rebuild. A file in use (a graph mapped by the
// cache, the snapshot of a registered mesh, any file being written) is never
// removed, even if that leaves the directory over budget; the report says
// so. "Recently used" is a file's modification time, which the daemon sets
// with MarkFileUsed whenever it maps or restores a file: access times are
// not kept on many mounts (noatime, relatime).
#ifndef GEODESIC_SERVER_DISK_BUDGET_H_
#define GEODESIC_SERVER_DISK_BUDGET_H_

#include <chrono>
#include <cstdint>
#include <functional>
#include <set>
#include <string>
#include <vector>

#include "absl/status/statusor.h"
#include "server/catalog.h"

namespace geodesic::server {

enum class FileRole {
  kInUse,      // never removed
  kCataloged,  // removed only after every spare file
  kSpare,      // removed first
};

struct DiskReport {
  uint64_t bytes_before = 0;  // every regular file in the directory
  uint64_t bytes_after = 0;
  std::vector<std::string> removed;  // file names, in the order removed
  bool over_limit = false;           // still over: what is left is in use
};

// `role` is asked about each *.dgg and *.mesh file by name. Other files
// (the catalog, temporary files) count towards the total but are never
// removed. A limit of 0 means no limit (nothing is removed).
absl::StatusOr<DiskReport> EnforceDiskLimit(
    const std::string& dir, uint64_t limit,
    const std::function<FileRole(const std::string&)>& role);

// The graph directory's files a catalog names.
struct CatalogFiles {
  std::set<std::string> catalogued;  // made again by a restart if removed...
  std::set<std::string> uploads;     // ...except uploaded meshes' snapshots: the only copy
};
CatalogFiles FilesOf(const CatalogState& state);

// The daemon's rule for file `name` in `dir`, given the catalog read before
// the sweep: in use if `in_use` says so, if it is an upload's snapshot, or
// if it was written less than `grace` ago (or its time cannot be read),
// since a registration or a replica's file may not be in that catalog yet;
// then catalogued, then spare.
FileRole GraphDirFileRole(const std::string& dir, const std::string& name,
                          const CatalogFiles& files, bool in_use, std::chrono::seconds grace);

// The total size of the directory's regular files.
absl::StatusOr<uint64_t> DirectoryBytes(const std::string& dir);

// Records that `path` was used now (its modification time), for the LRU
// order above. Best effort: a file that vanished is not an error.
void MarkFileUsed(const std::string& path);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_DISK_BUDGET_H_
