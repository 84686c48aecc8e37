// The meshes a daemon knows, by name: loaded once, immutable, shared.
#ifndef GEODESIC_SERVER_MESH_REGISTRY_H_
#define GEODESIC_SERVER_MESH_REGISTRY_H_

#include <filesystem>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <string>
#include <vector>

#include "absl/base/call_once.h"
#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "absl/types/span.h"
#include "core/mesh/mesh.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/region.h"
#include "core/mesh/surface_locator.h"

namespace geodesic::server {

// Snaps positions to a mesh, building its index on the first snap: the
// kd-tree over every face takes about a quarter of a large mesh's
// registration, and many clients never snap.
class LazySurfaceLocator {
 public:
  explicit LazySurfaceLocator(std::shared_ptr<const Mesh> mesh) : mesh_(std::move(mesh)) {}
  absl::StatusOr<SurfacePoint> Snap(const Vec3& position) const;

 private:
  std::shared_ptr<const Mesh> mesh_;
  mutable absl::once_flag built_;
  mutable absl::StatusOr<SurfaceLocator> locator_;
};

struct RegisteredMesh {
  std::string name;
  std::string source;  // path, or "upload"
  std::string format;  // one of MeshFormats() (core/mesh/mesh_io.h), or "arrays"
  // The key of its snapshot (core/mesh/mesh_snapshot.h): the source bytes' hash.
  uint64_t source_hash = 0;
  uint64_t fingerprint = 0;
  std::shared_ptr<const Mesh> mesh;
  MeshDiagnostics diagnostics;
  std::shared_ptr<const LazySurfaceLocator> locator;
  bool restored = false;  // from a snapshot, not parsed and built
  // Registered with non-manifold vertices split; the copies made (ids past
  // the file's vertices).
  bool repair_non_manifold = false;
  std::vector<VertexCopy> vertex_copies;
  // A region of the registered mesh `parent` (RegisterRegion), cut with
  // these ids (once each, increasing), which a catalog records to cut it
  // again; source "region".
  std::string parent;
  std::shared_ptr<const Region> region;
  RegionMask region_mask = RegionMask::kVertices;
  std::vector<uint32_t> region_ids;

  // What it holds beside its mesh (a region's maps and ids), which the
  // memory limit counts as it counts the mesh.
  uint64_t extra_bytes() const;
};

class MeshRegistry {
 public:
  // `snapshot_dir`: where built meshes are saved, keyed by their file's
  // bytes, and restored from when the same bytes are registered again
  // (core/mesh/mesh_snapshot.h); empty for never.
  //
  // With `durable`, a registration returns only once its snapshot is on disk
  // (fsynced), so that a catalog entry recorded afterwards can always be
  // restored, an upload included; otherwise snapshots are written in the
  // background.
  explicit MeshRegistry(std::string mesh_root, std::string snapshot_dir = {}, bool durable = false)
      : mesh_root_(std::move(mesh_root)),
        snapshot_dir_(std::move(snapshot_dir)),
        durable_(durable) {}
  // Waits for snapshots still being written.
  ~MeshRegistry();

  // Asked before each snapshot is written, with its size (--disk-limit): an
  // error skips the snapshot, and fails a registration that must be durable.
  // Set before the first registration.
  void SetDiskReservation(std::function<absl::Status(uint64_t bytes)> reserve,
                          std::function<void(uint64_t reserved, uint64_t written)> done) {
    reserve_disk_ = std::move(reserve);
    disk_done_ = std::move(done);
  }

  // --memory-limit (0: none): a mesh registered under a new name is refused
  // when the registered meshes with it, and room for a query on the largest
  // of them, would pass it; queries, not registrations, would fail
  // otherwise. Set before the first registration.
  void SetMemoryLimit(uint64_t limit) { memory_limit_ = limit; }

  // `relative_path` must stay inside the mesh root once symbolic links are
  // resolved (PERMISSION_DENIED otherwise) and name a regular file
  // (INVALID_ARGUMENT naming what it is otherwise: a FIFO is refused, not
  // waited on).
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterPath(
      const std::string& name, const std::string& relative_path, bool repair = false);
  // Registers an absolute path the operator chose (the bundled sample).
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterTrustedPath(const std::string& name,
                                                                            const std::string& path,
                                                                            bool repair = false);
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterBytes(const std::string& name,
                                                                      const std::string& format,
                                                                      const std::string& bytes,
                                                                      bool repair = false);
  // A mesh given as arrays: x, y, z per vertex and three vertex ids per
  // triangle, flattened. Its snapshot key is the source hash of the arrays'
  // little-endian bytes, vertices then faces, with format "arrays".
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterArrays(
      const std::string& name, const std::vector<double>& vertices,
      const std::vector<uint32_t>& faces, bool repair = false);
  // A mesh a catalog recorded (server/store/catalog.h): from its snapshot, or,
  // failing that, from its source file (under the mesh root, or an absolute
  // path the operator gave). FAILED_PRECONDITION if what it finds is not
  // the mesh recorded (another fingerprint); DATA_LOSS if an upload's
  // snapshot is gone.
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterRecorded(
      const std::string& name, const std::string& source, const std::string& format,
      uint64_t source_hash, uint64_t fingerprint, bool repair);
  // A region of the registered mesh `parent` (core/mesh/region.h), kept in
  // memory only: it is cut again from its parent whenever it is needed.
  // NOT_FOUND for an unknown parent, FAILED_PRECONDITION for a parent that
  // is a region itself or, with a non-zero `fingerprint` (a catalog's
  // record), for a region that came out another mesh. The ids are kept
  // (and recorded) once each, in increasing order; INVALID_ARGUMENT, before
  // any work, for more than kMaxIdsPerElement ids per parent vertex (or
  // face), OUT_OF_RANGE for an id past the parent's count,
  // RESOURCE_EXHAUSTED as for meshes (SetMemoryLimit). `ids` are only
  // read: a request's own (repeated field) can be passed as they are.
  static constexpr uint64_t kMaxIdsPerElement = 4;
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> RegisterRegion(
      const std::string& name, const std::string& parent, RegionMask mask,
      absl::Span<const uint32_t> ids, uint64_t fingerprint = 0);
  // The snapshot file name of a mesh ("<source hash>.mesh").
  static std::string SnapshotName(const RegisteredMesh& m);
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> Get(const std::string& name) const;
  std::vector<std::shared_ptr<const RegisteredMesh>> List() const;
  // Bytes of the registered meshes (each mesh once, however many names),
  // and of what they hold beside them (a region's maps and ids).
  uint64_t resident_bytes() const;
  absl::Status Remove(const std::string& name);
  // What a file's decoded arrays may take while it is read (GIFTI's, whose
  // declared sizes a small file can inflate a thousandfold): the memory
  // limit's room beside the registered meshes; 0 without a limit.
  uint64_t DecodeBudget() const;

  static absl::Status ValidateName(const std::string& name);

 private:
  absl::StatusOr<std::shared_ptr<const RegisteredMesh>> Insert(std::shared_ptr<RegisteredMesh> m);
  // RESOURCE_EXHAUSTED, naming the limit, when `m` under a new name does
  // not fit SetMemoryLimit's limit.
  absl::Status FitsMemoryLimit(const RegisteredMesh& m) const ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // The same for `bytes` of mesh `mesh` (null: not built yet) and `extra`
  // bytes beside it (RegisteredMesh::extra_bytes); `estimate` says, in the
  // refusal, how the bytes were had.
  absl::Status RoomFor(const std::string& name, uint64_t bytes, const Mesh* mesh,
                       const std::string& estimate, uint64_t extra = 0) const
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // RoomToBuild for a region cut with `ids` ids, whose maps and ids it
  // counts too.
  RegionRoom RoomForRegion(const std::string& name, uint64_t ids) const;
  // FitsMemoryLimit for a mesh about to be built from its counts, refused
  // before its build rather than after.
  std::function<absl::Status(uint64_t, uint64_t)> RoomToBuild(const std::string& name) const;
  // ALREADY_EXISTS when Insert would refuse `m`.
  absl::Status NameTakenByOther(const RegisteredMesh& m) const;
  // Loads the file at `path`, restoring it from a snapshot when there is one
  // and saving one when there was not. `display` names it in messages; a
  // non-empty `root` is where the file opened must be.
  absl::StatusOr<std::shared_ptr<RegisteredMesh>> LoadFile(
      const std::string& name, const std::string& source, const std::string& path,
      const std::string& display, const std::filesystem::path& root, bool durable, bool repair);
  std::shared_ptr<RegisteredMesh> Restore(uint64_t key, const std::string& name,
                                          const std::string& source, bool repair) const;
  // Writes the snapshot: now if `durable` (failing the registration if it
  // cannot), in the background otherwise.
  absl::Status Save(std::shared_ptr<const RegisteredMesh> m, uint64_t key, bool durable);

  const std::string mesh_root_;
  const std::string snapshot_dir_;
  const bool durable_;
  uint64_t memory_limit_ = 0;
  std::function<absl::Status(uint64_t bytes)> reserve_disk_;
  std::function<void(uint64_t reserved, uint64_t written)> disk_done_;
  absl::Mutex saves_mu_;
  std::vector<std::future<void>> saves_ ABSL_GUARDED_BY(saves_mu_);
  mutable absl::Mutex mu_;
  std::map<std::string, std::shared_ptr<const RegisteredMesh>> meshes_ ABSL_GUARDED_BY(mu_);
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_MESH_REGISTRY_H_
