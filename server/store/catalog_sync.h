// Keeps a daemon's meshes and graphs in step with the catalog
// (server/store/catalog.h) that it shares with its restarts and with replicas on
// the same graph directory.
//
// Every change a client makes goes to the catalog first and is applied
// locally second, so a client is told "done" only once the change would
// survive a crash. Reconcile() then brings this daemon to what the catalog
// says: it restores meshes and requests graphs the catalog lists and this
// daemon lacks (after a restart, or when another replica registered them),
// and drops what this daemon applied from the catalog and the catalog no
// longer lists (another replica unloaded it). Meshes this daemon holds that
// never came through the catalog (the bundled sample) are left alone.
//
// A region whose parent the catalog does not list, and which is no start-up
// mesh here (AddStartupMesh), can never be cut again: a restore removes it
// from the catalog, with a warning, rather than fail on it at every poll.
// (Replicas sharing a directory should so declare the same start-up meshes:
// a region of one only another replica declares is such an orphan here.)
//
// What "apply" means is given as hooks, so the rules here are tested
// without a registry or a cache.
#ifndef GEODESIC_SERVER_CATALOG_SYNC_H_
#define GEODESIC_SERVER_CATALOG_SYNC_H_

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <set>
#include <string>
#include <utility>
#include <vector>

#include "absl/base/thread_annotations.h"
#include "absl/status/statusor.h"
#include "absl/synchronization/mutex.h"
#include "server/store/catalog.h"

namespace geodesic::server {

class CatalogSync {
 public:
  struct Hooks {
    // Brings a catalogued mesh into this daemon (from its snapshot, or from
    // its source); the mesh must have the catalogued fingerprint.
    std::function<absl::Status(const CatalogMesh&)> restore_mesh;
    // Removes a mesh and its graphs from this daemon.
    std::function<void(const std::string& name)> drop_mesh;
    // Requests a graph (maps its file, or builds it in the background),
    // certified for `max_error` unless it is 0 (CatalogGraph).
    std::function<void(const std::string& mesh, const DggParams&, double max_error)> request_graph;
    std::function<void(const std::string& mesh, const DggParams&, double max_error)> cancel_graph;
  };

  CatalogSync(Catalog* catalog, Hooks hooks) : catalog_(catalog), hooks_(std::move(hooks)) {}

  // Reads the catalog and applies what differs. Errors are the catalog's
  // (unreadable, damaged); a mesh that fails to restore is reported by
  // failures() and tried again at the next call. A catalog unchanged since
  // it was applied, with no failure to retry, is neither parsed nor applied
  // again (Catalog::Read): the follower calls this every few seconds.
  absl::Status Reconcile();
  // Reconcile, but only if the catalog changed since it was last applied:
  // the cheap path for a query naming what this daemon lacks, so a stream
  // of such queries reads the catalog without loading, again and again,
  // a mesh that failed to restore (Reconcile alone retries those).
  absl::Status ReconcileIfChanged();

  // A client registered `mesh`, already loaded here: records it. If the
  // catalog has a mesh of that name with another fingerprint (registered
  // elsewhere meanwhile), ALREADY_EXISTS and nothing changes.
  absl::Status RecordMesh(const CatalogMesh& mesh);
  // A client unloads a mesh: removes it and its graphs from the catalog;
  // the caller then unloads it here. false if the catalog did not list it
  // (a local-only mesh).
  absl::StatusOr<bool> ForgetMesh(const std::string& name);
  // A mesh every start of this daemon registers itself (the bundled sample,
  // --config's meshes): the catalog does not own it, but records its
  // graphs, so that a graph a client was told is ready is requested again
  // after a restart, as a catalogued mesh's is.
  void AddStartupMesh(const std::string& name);
  // A client requested or cancelled a graph of a catalogued (or start-up)
  // mesh; the caller requests or cancels it here. Graphs of other
  // local-only meshes are not recorded (false).
  // `max_error`: a certified graph's bound, or 0.
  absl::StatusOr<bool> RecordGraph(const std::string& mesh, const DggParams& params,
                                   double max_error = 0);
  absl::StatusOr<bool> ForgetGraph(const std::string& mesh, const DggParams& params,
                                   double max_error = 0);

  // Whether the catalog lists the mesh (as last read).
  bool Catalogued(const std::string& mesh) const;
  // Meshes that could not be restored, with the reason (orphaned regions
  // are not among them: they are removed).
  std::map<std::string, std::string> failures() const;
  // The reason `mesh` could not be restored, if it could not.
  std::optional<std::string> Failure(const std::string& mesh) const;
  uint64_t generation() const;

 private:
  // Applies `state` and remembers it as applied.
  absl::Status ApplySharedLocked(std::shared_ptr<const CatalogState> state)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  absl::Status ApplyLocked(const CatalogState& state) ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // A region that can never be restored here: its parent is not in `state`
  // and is no start-up mesh.
  bool OrphanedLocked(const CatalogState& state, const CatalogMesh& m) const
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);
  // Removes `orphans` from the catalog (those still orphaned there), with a
  // warning each.
  void RemoveOrphansLocked(const std::vector<CatalogMesh>& orphans)
      ABSL_EXCLUSIVE_LOCKS_REQUIRED(mu_);

  Catalog* const catalog_;
  const Hooks hooks_;
  mutable absl::Mutex mu_;
  uint64_t generation_ ABSL_GUARDED_BY(mu_) = 0;
  // The catalog's state last applied (Catalog::ReadShared's object), null
  // when another must be applied even if the file is unchanged.
  std::shared_ptr<const CatalogState> applied_ ABSL_GUARDED_BY(mu_);
  std::set<std::string> listed_ ABSL_GUARDED_BY(mu_);  // meshes in the catalog
  // What this daemon applied from the catalog: mesh name -> fingerprint.
  std::map<std::string, uint64_t> meshes_ ABSL_GUARDED_BY(mu_);
  std::set<CatalogGraph> graphs_ ABSL_GUARDED_BY(mu_);
  std::map<std::string, std::string> failures_ ABSL_GUARDED_BY(mu_);
  std::set<std::string> startup_ ABSL_GUARDED_BY(mu_);  // AddStartupMesh
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CATALOG_SYNC_H_
