#include "server/store/catalog_sync.h"

#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "server/base/log.h"

namespace geodesic::server {

absl::Status CatalogSync::Reconcile() {
  // Read under the lock: a state read before a Record* that then applied a
  // newer one would undo that change here (cancel the graph just requested).
  absl::MutexLock lock(&mu_);
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state, catalog_->ReadShared());
  if (state == applied_ && failures_.empty()) return absl::OkStatus();
  if (state->generation < generation_) return absl::OkStatus();  // older than what we applied
  return ApplySharedLocked(std::move(state));
}

absl::Status CatalogSync::ReconcileIfChanged() {
  absl::MutexLock lock(&mu_);
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state, catalog_->ReadShared());
  if (state->generation <= generation_) return absl::OkStatus();
  return ApplySharedLocked(std::move(state));
}

absl::Status CatalogSync::ApplySharedLocked(std::shared_ptr<const CatalogState> state) {
  applied_ = state;
  return ApplyLocked(*state);
}

bool CatalogSync::OrphanedLocked(const CatalogState& state, const CatalogMesh& m) const {
  return !m.parent.empty() && !state.FindMesh(m.parent) && !startup_.contains(m.parent);
}

void CatalogSync::RemoveOrphansLocked(const std::vector<CatalogMesh>& orphans) {
  std::vector<const CatalogMesh*> removed;
  auto updated = catalog_->UpdateShared(
      [&](CatalogState& s) -> absl::Status {
        removed.clear();
        for (const CatalogMesh& orphan : orphans) {
          // Registered again meanwhile, or its parent: not an orphan now.
          const CatalogMesh* now = s.FindMesh(orphan.name);
          if (!now || now->fingerprint != orphan.fingerprint || !OrphanedLocked(s, *now)) continue;
          s.RemoveMesh(orphan.name);
          removed.push_back(&orphan);
        }
        // Nothing to write.
        if (removed.empty()) return absl::CancelledError();
        return absl::OkStatus();
      },
      Catalog::Reserve::kFreesSpace);
  if (!updated.ok()) {
    if (absl::IsCancelled(updated.status())) return;
    for (const CatalogMesh& orphan : orphans) {
      Log(LogLevel::kWarning, "catalog_region_orphaned",
          {{"mesh", orphan.name},
           {"parent", orphan.parent},
           {"removed", "false"},
           {"error", updated.status().ToString()}});
    }
    return;
  }
  // Applied at the next Reconcile, with whatever else changed meanwhile.
  for (const CatalogMesh* orphan : removed) {
    Log(LogLevel::kWarning, "catalog_region_orphaned",
        {{"mesh", orphan->name},
         {"parent", orphan->parent},
         {"removed", "true"},
         {"reason",
          "its parent is not in the catalog and not registered at start here; the "
          "region is removed from the catalog"}});
    listed_.erase(orphan->name);
  }
}

absl::Status CatalogSync::ApplyLocked(const CatalogState& state) {
  generation_ = state.generation;
  listed_.clear();
  for (const CatalogMesh& m : state.meshes) listed_.insert(m.name);
  // Gone from the catalog, or replaced by another mesh of the same name.
  for (auto it = meshes_.begin(); it != meshes_.end();) {
    const CatalogMesh* listed = state.FindMesh(it->first);
    if (listed && listed->fingerprint == it->second) {
      ++it;
      continue;
    }
    Log(LogLevel::kInfo, "catalog_mesh_dropped", {{"mesh", it->first}});
    hooks_.drop_mesh(it->first);
    std::erase_if(graphs_, [&](const CatalogGraph& g) { return g.mesh == it->first; });
    it = meshes_.erase(it);
  }
  // A failure to restore what the catalog no longer lists is no news.
  std::erase_if(failures_, [&](const auto& f) { return !state.FindMesh(f.first); });
  // Regions after the meshes they are cut from.
  std::vector<const CatalogMesh*> order;
  for (const CatalogMesh& m : state.meshes) {
    if (m.parent.empty()) order.push_back(&m);
  }
  for (const CatalogMesh& m : state.meshes) {
    if (!m.parent.empty()) order.push_back(&m);
  }
  std::vector<CatalogMesh> orphans;
  for (const CatalogMesh* listed : order) {
    const CatalogMesh& m = *listed;
    if (meshes_.contains(m.name)) continue;
    if (OrphanedLocked(state, m)) {
      failures_.erase(m.name);
      orphans.push_back(m);
      continue;
    }
    absl::Status s = hooks_.restore_mesh(m);
    if (!s.ok()) {
      auto [failure, added] = failures_.try_emplace(m.name, s.ToString());
      if (added || failure->second != s.ToString()) {
        failure->second = s.ToString();
        Log(LogLevel::kError, "catalog_mesh_restore_failed",
            {{"mesh", m.name}, {"error", s.ToString()}});
      }
      continue;
    }
    failures_.erase(m.name);
    meshes_[m.name] = m.fingerprint;
    Log(LogLevel::kInfo, "catalog_mesh_restored", {{"mesh", m.name}, {"source", m.source}});
  }
  for (auto it = graphs_.begin(); it != graphs_.end();) {
    if (state.HasGraph(it->mesh, it->params, it->max_error)) {
      ++it;
      continue;
    }
    hooks_.cancel_graph(it->mesh, it->params, it->max_error);
    it = graphs_.erase(it);
  }
  for (const CatalogGraph& g : state.graphs) {
    // Its mesh failed to restore, or is a start-up mesh this daemon lacks.
    if (!meshes_.contains(g.mesh) && !startup_.contains(g.mesh)) continue;
    if (graphs_.insert(g).second) hooks_.request_graph(g.mesh, g.params, g.max_error);
  }
  if (!orphans.empty()) RemoveOrphansLocked(orphans);
  return absl::OkStatus();
}

absl::Status CatalogSync::RecordMesh(const CatalogMesh& mesh) {
  absl::MutexLock lock(&mu_);
  ASSIGN_OR_RETURN(
      std::shared_ptr<const CatalogState> state, catalog_->UpdateShared([&](CatalogState& s) {
        const CatalogMesh* existing = s.FindMesh(mesh.name);
        if (existing && existing->fingerprint != mesh.fingerprint) {
          return absl::AlreadyExistsError(
              absl::StrFormat("mesh '%s' is already registered (from %s) with other contents",
                              mesh.name, existing->source));
        }
        // Its parent unloaded on another replica since this one
        // found it: recorded, the region could never be restored.
        if (OrphanedLocked(s, mesh)) {
          return absl::FailedPreconditionError(
              absl::StrFormat("mesh '%s', the parent of region '%s', was unloaded meanwhile (by "
                              "another replica)",
                              mesh.parent, mesh.name));
        }
        s.PutMesh(mesh);
        return absl::OkStatus();
      }));
  // Loaded here already: applying it means only remembering it.
  meshes_[mesh.name] = mesh.fingerprint;
  failures_.erase(mesh.name);
  return ApplySharedLocked(std::move(state));
}

absl::StatusOr<bool> CatalogSync::ForgetMesh(const std::string& name) {
  absl::MutexLock lock(&mu_);
  bool listed = false;
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state,
                   catalog_->UpdateShared(
                       [&](CatalogState& s) -> absl::Status {
                         // Regions registered on other replicas too.
                         for (const CatalogMesh& m : s.meshes) {
                           if (m.parent == name) {
                             return absl::FailedPreconditionError(
                                 absl::StrFormat("mesh '%s' has the region '%s' "
                                                 "registered: unload the region first",
                                                 name, m.name));
                           }
                         }
                         listed = s.RemoveMesh(name);
                         return absl::OkStatus();
                       },
                       Catalog::Reserve::kFreesSpace));
  // The caller unloads the mesh itself.
  meshes_.erase(name);
  std::erase_if(graphs_, [&](const CatalogGraph& g) { return g.mesh == name; });
  RETURN_IF_ERROR(ApplySharedLocked(std::move(state)));
  return listed;
}

void CatalogSync::AddStartupMesh(const std::string& name) {
  absl::MutexLock lock(&mu_);
  startup_.insert(name);
  // Its graphs in the catalog are requested at the next Reconcile, though
  // the file is unchanged.
  applied_.reset();
}

absl::StatusOr<bool> CatalogSync::RecordGraph(const std::string& mesh, const DggParams& params,
                                              double max_error) {
  absl::MutexLock lock(&mu_);
  const bool startup = startup_.contains(mesh) && !meshes_.contains(mesh);
  if (!meshes_.contains(mesh) && !startup) return false;
  ASSIGN_OR_RETURN(
      std::shared_ptr<const CatalogState> state, catalog_->UpdateShared([&](CatalogState& s) {
        if (!startup && !s.FindMesh(mesh)) {
          return absl::NotFoundError(
              absl::StrFormat("mesh '%s' was unloaded meanwhile (by another replica)", mesh));
        }
        s.PutGraph({mesh, params, max_error});
        return absl::OkStatus();
      }));
  // The caller requests the graph itself; remember it as applied.
  graphs_.insert({mesh, params, max_error});
  RETURN_IF_ERROR(ApplySharedLocked(std::move(state)));
  return true;
}

absl::StatusOr<bool> CatalogSync::ForgetGraph(const std::string& mesh, const DggParams& params,
                                              double max_error) {
  absl::MutexLock lock(&mu_);
  bool listed = false;
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state, catalog_->UpdateShared(
                                                                  [&](CatalogState& s) {
                                                                    listed = s.RemoveGraph(
                                                                        mesh, params, max_error);
                                                                    return absl::OkStatus();
                                                                  },
                                                                  Catalog::Reserve::kFreesSpace));
  // The caller cancels the graph itself.
  graphs_.erase({mesh, params, max_error});
  RETURN_IF_ERROR(ApplySharedLocked(std::move(state)));
  return listed;
}

bool CatalogSync::Catalogued(const std::string& mesh) const {
  absl::MutexLock lock(&mu_);
  return listed_.contains(mesh);
}

std::map<std::string, std::string> CatalogSync::failures() const {
  absl::MutexLock lock(&mu_);
  return failures_;
}

std::optional<std::string> CatalogSync::Failure(const std::string& mesh) const {
  absl::MutexLock lock(&mu_);
  auto it = failures_.find(mesh);
  if (it == failures_.end()) return std::nullopt;
  return it->second;
}

uint64_t CatalogSync::generation() const {
  absl::MutexLock lock(&mu_);
  return generation_;
}

}  // namespace geodesic::server
