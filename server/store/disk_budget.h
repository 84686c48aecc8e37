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

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "server/store/catalog.h"

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

// `role` is asked about each *.dgg and *.mesh file by name; a graph's
// sidecars ("<graph>.certificate.json", "<graph>.exact-landmarks") are
// removed with its graph (and listed after it in `removed`). Other files
// (the catalog, temporary files) count towards the total but are never
// removed; the catalog's reserve file is not counted. A limit of 0 means no limit (nothing is
// removed).
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
// the sweep: in use if `in_use` says so or if it is an upload's snapshot;
// then catalogued, whatever its age; then, for a file the catalog does not
// name, in use if it was written less than `grace` ago (or its time cannot
// be read), since a registration or a replica's file may not be in that
// catalog yet; else spare.
FileRole GraphDirFileRole(const std::string& dir, const std::string& name,
                          const CatalogFiles& files, bool in_use, std::chrono::seconds grace);

// The total size of the directory's regular files, but the catalog's
// reserve file.
absl::StatusOr<uint64_t> DirectoryBytes(const std::string& dir);

// The directory's bytes as this daemon knows them, and the writes it has
// admitted: a write that would take the directory past the limit is refused
// before it starts, once what may be evicted is gone, instead of being
// found over budget afterwards. Counted bytes come from a scan (at start,
// and whenever the caller sweeps the directory) plus the writes admitted
// since; a replica's writes show up at the next scan. The catalog's
// reserve file (Catalog::kReserveFileName) is space kept for the catalog,
// not the directory's contents, and is not counted.
class DiskBudget {
 public:
  // `evict(target)` removes what the daemon's rule lets go until the
  // directory holds at most `target` bytes, and returns the bytes it then
  // holds; empty: nothing may be evicted. A limit of 0 admits everything.
  DiskBudget(std::string dir, uint64_t limit,
             std::function<absl::StatusOr<uint64_t>(uint64_t target)> evict = {});

  // Counts the directory's files now.
  absl::Status Scan();
  // Admits a write of `bytes`, evicting first if need be; RESOURCE_EXHAUSTED
  // naming the bytes, the directory's bytes and the limit otherwise. An
  // admitted write ends with Done().
  absl::Status Reserve(uint64_t bytes);
  // A reserved write finished: `written` bytes of it are on disk now (0 if
  // it failed).
  void Done(uint64_t reserved, uint64_t written);
  // The directory holds `bytes` (a sweep counted them).
  void Set(uint64_t bytes);

  uint64_t limit() const { return limit_; }
  // On disk, plus admitted writes not yet done.
  uint64_t used() const;

 private:
  const std::string dir_;
  const uint64_t limit_;
  const std::function<absl::StatusOr<uint64_t>(uint64_t)> evict_;
  mutable absl::Mutex mu_;
  uint64_t on_disk_ ABSL_GUARDED_BY(mu_) = 0;
  uint64_t pending_ ABSL_GUARDED_BY(mu_) = 0;
};

// Records that `path` was used now (its modification time), for the LRU
// order above. Best effort: a file that vanished is not an error.
void MarkFileUsed(const std::string& path);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_DISK_BUDGET_H_
