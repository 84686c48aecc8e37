// The daemon's durable state: the meshes clients registered and the graphs
// they requested, kept in <graph dir>/catalog.json so that a restarted daemon,
// or another replica sharing the directory, restores them without the
// clients registering again.
//
// The file is replaced atomically (temporary file, fsync, rename, fsync of
// the directory), so a crash leaves the old catalog or the new one, never
// half of one. Updates are read-modify-write under an exclusive lock on
// <graph dir>/catalog.lock (an open-file-description lock: it serialises
// threads of one daemon and daemons on one host alike), so concurrent
// replicas never lose each other's changes. Every update bumps a generation
// number, which replicas compare to notice changes made elsewhere.
#ifndef GEODESIC_SERVER_CATALOG_H_
#define GEODESIC_SERVER_CATALOG_H_

#include <sys/stat.h>
#include <sys/types.h>

#include <atomic>
#include <cstdint>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/functional/function_ref.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "core/dgg/dgg_graph.h"

namespace geodesic::server {

struct CatalogMesh {
  std::string name;
  // Where it came from: a path the daemon may read again (under the mesh
  // root, or the operator's own), or "upload".
  std::string source;
  std::string format;        // one of MeshFormats() (core/mesh/mesh_io.h)
  uint64_t source_hash = 0;  // the mesh snapshot's key (core/mesh/mesh_snapshot.h)
  uint64_t fingerprint = 0;  // of the built mesh: graphs are keyed by it
  bool repair_non_manifold = false;
  // A region (source "region"): cut again from the mesh `parent` with these
  // ids of its vertices, or of its faces. Order and repeats do not change a
  // region: a catalog keeps them once each, in increasing order.
  std::string parent{};
  bool region_faces = false;
  std::vector<uint32_t> region_ids{};
};

// A graph requested plain, or certified (max_error > 0): then `params` are
// its key's in the graph cache (server/graphs/graph_cache.h, GraphKey), the
// epsilon CertifiedKeyEpsilon chose, and the bound is part of its identity,
// since a plain graph of that epsilon is another graph.
struct CatalogGraph {
  std::string mesh;
  DggParams params;
  double max_error = 0;  // 0: a plain graph
  friend auto operator<=>(const CatalogGraph&, const CatalogGraph&) = default;
};

struct CatalogState {
  uint64_t generation = 0;  // 0: no catalog written yet
  std::vector<CatalogMesh> meshes;
  std::vector<CatalogGraph> graphs;

  const CatalogMesh* FindMesh(const std::string& name) const;
  // Adds or replaces the mesh of that name.
  void PutMesh(CatalogMesh mesh);
  // Removes the mesh and every graph of it; false if there was none.
  bool RemoveMesh(const std::string& name);
  bool HasGraph(const std::string& mesh, const DggParams& params, double max_error = 0) const;
  void PutGraph(CatalogGraph graph);  // no-op if present
  bool RemoveGraph(const std::string& mesh, const DggParams& params, double max_error = 0);
};

class Catalog {
 public:
  // Version 2 added certified graphs (a graph's "max_error"), version 3
  // regions (a mesh's "region", its ids a JSON list), version 4 a region's
  // ids as runs ("ranges": "0-99,105") or as a bitmap ("bitmap", base64),
  // whichever is shorter: a list took a line per id, hundreds of megabytes
  // for a large mask. A catalog is written with the oldest version that
  // holds what it lists, which builds before it read; a newer one they
  // refuse rather than take a certified graph for a plain one or a region
  // for a file, or find a region's ids missing (and drop what they cannot
  // hold when they write the catalog back). Every version up to this one is
  // read.
  static constexpr uint32_t kFormatVersion = 4;
  static constexpr uint32_t kCompactRegionFormatVersion = 4;
  static constexpr uint32_t kCertifiedFormatVersion = 2;
  static constexpr uint32_t kOldestFormatVersion = 1;
  // A file of real blocks kept beside the catalog: on a full disk, a change
  // that cannot be written deletes it and tries again, so that unloads and
  // cancels, which free space, never fail for want of it.
  static constexpr char kReserveFileName[] = ".geodesicd-reserve";
  static constexpr uint64_t kReserveBytes = uint64_t{4} << 20;

  // Writes `text` as the file `path`, whole or not at all.
  using Writer = std::function<absl::Status(const std::string& path, const std::string& text)>;

  // `writer`: empty for AtomicFileWriter (tests inject failures).
  explicit Catalog(std::string dir, Writer writer = {});

  const std::string& path() const { return path_; }

  // The current state; a missing file is the empty state (generation 0).
  // DATA_LOSS naming the file and the problem when it cannot be parsed,
  // FAILED_PRECONDITION when it has a format version this build does not
  // read.
  //
  // The file is parsed only when it changed since this object last read or
  // wrote it: another inode, size, modification or change time, or another
  // generation in its first bytes (which every Update bumps, so a file
  // replaced within one tick of the clock on a reused inode is still
  // noticed). Followers poll it every few seconds, and it can be large.
  absl::StatusOr<CatalogState> Read() const;
  // The same, shared: the same object as long as the file is unchanged.
  absl::StatusOr<std::shared_ptr<const CatalogState>> ReadShared() const;

  // Applies `change` to the current state under the lock and, if it
  // returns OK, writes the result with the next generation. The state
  // written is returned. An error from `change` writes nothing.
  // With kFreesSpace (a change that lets files go: an unload, a cancel), a
  // write that fails with RESOURCE_EXHAUSTED (a full disk) is tried again
  // once the reserve file is deleted; other changes fail on a full disk.
  enum class Reserve { kKeep, kFreesSpace };
  absl::StatusOr<CatalogState> Update(absl::FunctionRef<absl::Status(CatalogState&)> change,
                                      Reserve reserve = Reserve::kKeep);
  // The same, the state written shared, as ReadShared then gives it.
  absl::StatusOr<std::shared_ptr<const CatalogState>> UpdateShared(
      absl::FunctionRef<absl::Status(CatalogState&)> change, Reserve reserve = Reserve::kKeep);

  // How many times this object parsed the file (for tests: an unchanged
  // catalog is not parsed again).
  uint64_t parses() const { return parses_.load(); }

  // Makes the reserve file if it is missing (at start, and whenever the
  // disk may have room again); RESOURCE_EXHAUSTED while there is none.
  absl::Status EnsureReserve() const;
  std::string reserve_path() const { return dir_ + "/" + kReserveFileName; }

 private:
  // Which file `path_` names, and which version of it.
  struct Stamp {
    dev_t device = 0;
    ino_t inode = 0;
    off_t size = -1;  // -1: no file
    int64_t modified_ns = 0, changed_ns = 0;
    friend bool operator==(const Stamp&, const Stamp&) = default;
  };
  static Stamp StampOf(const struct stat& st);

  std::string dir_, path_, lock_path_;
  Writer writer_;
  mutable std::atomic<uint64_t> parses_{0};
  // The file's state as last parsed or written here, and its stamp then.
  mutable absl::Mutex cache_mu_;
  mutable std::shared_ptr<const CatalogState> cached_ ABSL_GUARDED_BY(cache_mu_);
  mutable Stamp cached_stamp_ ABSL_GUARDED_BY(cache_mu_);
};

// The JSON text of a state, and back; exposed for tests and `info`.
std::string CatalogToJson(const CatalogState& state);
absl::StatusOr<CatalogState> CatalogFromJson(const std::string& text, const std::string& path);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CATALOG_H_
