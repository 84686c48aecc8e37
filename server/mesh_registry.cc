#include "server/mesh_registry.h"

#include <filesystem>
#include <future>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/dgg_graph.h"
#include "core/status.h"

namespace geodesic::server {
namespace {

absl::StatusOr<std::shared_ptr<RegisteredMesh>> Finish(const std::string& name,
                                                       const std::string& source,
                                                       absl::StatusOr<TriangleSoup> soup,
                                                       MeshDiagnostics diagnostics) {
  if (!soup.ok()) return soup.status();
  // The diagnostics and the mesh need only the soup, and each takes about
  // half of a large mesh's registration: one runs beside the other (the
  // mesh gets its own copy of the soup).
  auto diagnosed = std::async(std::launch::async, [&] { ComputeDiagnostics(*soup, &diagnostics); });
  auto mesh = Mesh::Build(*soup, source);
  diagnosed.wait();
  if (!mesh.ok()) return mesh.status();
  auto m = std::make_shared<RegisteredMesh>();
  m->mesh = std::make_shared<const Mesh>(std::move(mesh).value());
  m->fingerprint = MeshFingerprint(*m->mesh);
  m->locator = std::make_shared<const LazySurfaceLocator>(m->mesh);
  m->name = name;
  m->source = source;
  m->diagnostics = std::move(diagnostics);
  return m;
}

}  // namespace

absl::StatusOr<SurfacePoint> LazySurfaceLocator::Snap(const Vec3& position) const {
  absl::call_once(built_, [&] { locator_ = SurfaceLocator::Build(*mesh_); });
  if (!locator_.ok()) return locator_.status();
  return locator_->Snap(position);
}

absl::Status MeshRegistry::ValidateName(const std::string& name) {
  if (name.empty() || name.size() > 64) {
    return absl::InvalidArgumentError("a mesh name has 1 to 64 characters");
  }
  for (char c : name) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.')) {
      return absl::InvalidArgumentError(
          absl::StrFormat("mesh name '%s' has a character outside [A-Za-z0-9_.-]", name));
    }
  }
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterPath(
    const std::string& name, const std::string& relative_path) {
  RETURN_IF_ERROR(ValidateName(name));
  if (mesh_root_.empty()) {
    return absl::PermissionDeniedError("the server has no --mesh-root: register by upload");
  }
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path root = fs::canonical(mesh_root_, ec);
  if (ec) return absl::InternalError(absl::StrFormat("mesh root %s: %s", mesh_root_, ec.message()));
  const fs::path requested(relative_path);
  if (relative_path.empty() || requested.is_absolute()) {
    return absl::PermissionDeniedError(
        absl::StrFormat("'%s': give a path relative to the mesh root", relative_path));
  }
  // Resolve symbolic links, then require the result to stay under the root.
  const fs::path resolved = fs::weakly_canonical(root / requested, ec);
  auto [root_end, unused] =
      std::mismatch(root.begin(), root.end(), resolved.begin(), resolved.end());
  if (ec || root_end != root.end()) {
    return absl::PermissionDeniedError(
        absl::StrFormat("'%s' leads outside the mesh root", relative_path));
  }
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoup(resolved.string(), &diagnostics);
  ASSIGN_OR_RETURN(auto m, Finish(name, relative_path, std::move(soup), std::move(diagnostics)));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterTrustedPath(
    const std::string& name, const std::string& path) {
  RETURN_IF_ERROR(ValidateName(name));
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoup(path, &diagnostics);
  ASSIGN_OR_RETURN(auto m, Finish(name, path, std::move(soup), std::move(diagnostics)));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterBytes(
    const std::string& name, const std::string& format, const std::string& bytes) {
  RETURN_IF_ERROR(ValidateName(name));
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoupFromMemory(bytes, format, name, &diagnostics);
  ASSIGN_OR_RETURN(auto m, Finish(name, "upload", std::move(soup), std::move(diagnostics)));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::Insert(
    std::shared_ptr<RegisteredMesh> m) {
  absl::MutexLock lock(&mu_);
  auto it = meshes_.find(m->name);
  if (it != meshes_.end()) {
    if (it->second->fingerprint == m->fingerprint) return it->second;
    return absl::AlreadyExistsError(
        absl::StrFormat("mesh '%s' is registered with other content; unload it first", m->name));
  }
  std::shared_ptr<const RegisteredMesh> stored = std::move(m);
  meshes_.emplace(stored->name, stored);
  return stored;
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::Get(
    const std::string& name) const {
  absl::MutexLock lock(&mu_);
  auto it = meshes_.find(name);
  if (it == meshes_.end()) {
    return absl::NotFoundError(absl::StrFormat("no mesh named '%s'; register it first", name));
  }
  return it->second;
}

std::vector<std::shared_ptr<const RegisteredMesh>> MeshRegistry::List() const {
  absl::MutexLock lock(&mu_);
  std::vector<std::shared_ptr<const RegisteredMesh>> out;
  for (const auto& [name, m] : meshes_) out.push_back(m);
  return out;
}

absl::Status MeshRegistry::Remove(const std::string& name) {
  absl::MutexLock lock(&mu_);
  if (meshes_.erase(name) == 0) {
    return absl::NotFoundError(absl::StrFormat("no mesh named '%s'", name));
  }
  return absl::OkStatus();
}

}  // namespace geodesic::server
