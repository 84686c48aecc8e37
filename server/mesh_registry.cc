#include "server/mesh_registry.h"

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <future>
#include <map>
#include <tuple>

#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_format.h"
#include "core/dgg_graph.h"
#include "core/mesh_snapshot.h"
#include "core/status.h"
#include "server/log.h"

namespace geodesic::server {
namespace {

// `fingerprint`: MeshFingerprint(mesh), which a restore has already taken.
std::shared_ptr<RegisteredMesh> Wrap(const std::string& name, const std::string& source, Mesh mesh,
                                     uint64_t fingerprint, MeshDiagnostics diagnostics) {
  auto m = std::make_shared<RegisteredMesh>();
  m->mesh = std::make_shared<const Mesh>(std::move(mesh));
  m->fingerprint = fingerprint;
  m->locator = std::make_shared<const LazySurfaceLocator>(m->mesh);
  m->name = name;
  m->source = source;
  m->diagnostics = std::move(diagnostics);
  return m;
}

absl::StatusOr<std::shared_ptr<RegisteredMesh>> Finish(const std::string& name,
                                                       const std::string& source,
                                                       absl::StatusOr<TriangleSoup> soup,
                                                       MeshDiagnostics diagnostics, bool repair) {
  if (!soup.ok()) return soup.status();
  // The diagnostics (of the file as it is) and the mesh need only the soup,
  // and each takes about half of a large mesh's registration: one runs
  // beside the other (the mesh gets its own copy of the soup).
  auto diagnosed = std::async(std::launch::async, [&] { ComputeDiagnostics(*soup, &diagnostics); });
  TriangleSoup built = *soup;
  std::vector<VertexCopy> copies;
  if (repair) copies = SplitNonManifoldVertices(&built);
  auto mesh = Mesh::Build(std::move(built), source);
  diagnosed.wait();
  if (!mesh.ok()) {
    if (!repair && !diagnostics.manifold) {
      return absl::InvalidArgumentError(
          absl::StrFormat("%s (register with repair_non_manifold to split non-manifold vertices)",
                          mesh.status().message()));
    }
    return mesh.status();
  }
  const uint64_t fingerprint = MeshFingerprint(*mesh);
  auto m = Wrap(name, source, std::move(mesh).value(), fingerprint, std::move(diagnostics));
  m->repair_non_manifold = repair;
  m->vertex_copies = std::move(copies);
  return m;
}

// A repaired mesh is another mesh than the file's: its snapshot has a key
// of its own.
uint64_t SnapshotKey(uint64_t source_hash, bool repair) {
  return repair ? source_hash ^ 0x9e3779b97f4a7c15ULL : source_hash;
}

// The copies a restored repaired mesh holds: vertices past the file's own,
// each at the position of the original it copies.
std::vector<VertexCopy> CopiesOf(const Mesh& mesh, uint64_t file_vertices) {
  std::vector<VertexCopy> copies;
  if (mesh.num_vertices() <= file_vertices) return copies;
  std::map<std::tuple<double, double, double>, VertexId> original;
  for (VertexId v = 0; v < file_vertices; ++v) {
    const Vec3& p = mesh.position(v);
    original.emplace(std::make_tuple(p.x, p.y, p.z), v);
  }
  for (VertexId v = file_vertices; v < mesh.num_vertices(); ++v) {
    const Vec3& p = mesh.position(v);
    auto it = original.find(std::make_tuple(p.x, p.y, p.z));
    if (it != original.end()) copies.push_back({it->second, v});
  }
  return copies;
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
    const std::string& name, const std::string& relative_path, bool repair) {
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
  ASSIGN_OR_RETURN(auto m, LoadFile(name, relative_path, resolved.string(), durable_, repair));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterTrustedPath(
    const std::string& name, const std::string& path, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  // The operator's own meshes (the sample, the config's) are registered at
  // every start, so their snapshots are a speed-up, written in the
  // background, never a condition of serving.
  ASSIGN_OR_RETURN(auto m, LoadFile(name, path, path, /*durable=*/false, repair));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterBytes(
    const std::string& name, const std::string& format, const std::string& bytes, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  const std::string lower = absl::AsciiStrToLower(format);
  const uint64_t key = SnapshotKey(SourceHash(bytes, lower), repair);
  if (auto m = Restore(key, name, "upload", repair)) {
    m->diagnostics.path = name;
    m->format = lower;
    return Insert(std::move(m));
  }
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoupFromMemory(bytes, format, name, &diagnostics);
  ASSIGN_OR_RETURN(auto m, Finish(name, "upload", std::move(soup), std::move(diagnostics), repair));
  m->format = lower;
  m->source_hash = key;
  RETURN_IF_ERROR(Save(m, key, durable_));
  return Insert(std::move(m));
}

MeshRegistry::~MeshRegistry() {
  absl::MutexLock lock(&saves_mu_);
  for (auto& save : saves_) save.wait();
}

absl::StatusOr<std::shared_ptr<RegisteredMesh>> MeshRegistry::LoadFile(const std::string& name,
                                                                       const std::string& source,
                                                                       const std::string& path,
                                                                       bool durable, bool repair) {
  if (snapshot_dir_.empty()) {
    MeshDiagnostics diagnostics;
    auto soup = ReadTriangleSoup(path, &diagnostics);
    return Finish(name, source, std::move(soup), std::move(diagnostics), repair);
  }
  ASSIGN_OR_RETURN(const uint64_t file_key, SourceHashOfFile(path));
  const uint64_t key = SnapshotKey(file_key, repair);
  if (auto m = Restore(key, name, source, repair)) {
    m->diagnostics.path = path;
    m->format = MeshFormatOfPath(path);
    return m;
  }
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoup(path, &diagnostics);
  ASSIGN_OR_RETURN(auto m, Finish(name, source, std::move(soup), std::move(diagnostics), repair));
  m->format = MeshFormatOfPath(path);
  m->source_hash = key;
  // A file rewritten while it was read must not be saved under either
  // version's key.
  auto after = SourceHashOfFile(path);
  if (after.ok() && *after == file_key) RETURN_IF_ERROR(Save(m, key, durable));
  return m;
}

std::shared_ptr<RegisteredMesh> MeshRegistry::Restore(uint64_t key, const std::string& name,
                                                      const std::string& source,
                                                      bool repair) const {
  if (snapshot_dir_.empty()) return nullptr;
  const auto start = std::chrono::steady_clock::now();
  const std::string path = (std::filesystem::path(snapshot_dir_) / MeshSnapshotName(key)).string();
  auto restored = ReadMeshSnapshot(path, key);
  if (!restored.ok()) {
    // A missing snapshot is the common case; a damaged one is rebuilt and
    // replaced, and worth a line in the log.
    if (!absl::IsNotFound(restored.status())) {
      Log(LogLevel::kWarning, "mesh_snapshot_ignored", {{"error", restored.status().ToString()}});
    }
    return nullptr;
  }
  restored->diagnostics.load_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  auto m = Wrap(name, source, std::move(restored->mesh), restored->fingerprint,
                std::move(restored->diagnostics));
  m->restored = true;
  m->source_hash = key;
  m->repair_non_manifold = repair;
  if (repair) m->vertex_copies = CopiesOf(*m->mesh, m->diagnostics.vertices);
  return m;
}

absl::Status MeshRegistry::Save(std::shared_ptr<const RegisteredMesh> m, uint64_t key,
                                bool durable) {
  if (snapshot_dir_.empty()) return absl::OkStatus();
  const std::string path = (std::filesystem::path(snapshot_dir_) / MeshSnapshotName(key)).string();
  // The snapshot holds the mesh's arrays: its size in memory, near enough.
  const uint64_t bytes = m->mesh->memory_bytes();
  if (reserve_disk_) {
    if (absl::Status room = reserve_disk_(bytes); !room.ok()) {
      if (!durable) return absl::OkStatus();  // a speed-up only
      return absl::Status(room.code(), absl::StrFormat("mesh '%s' could not be stored: %s", m->name,
                                                       room.message()));
    }
  }
  auto done = [this, bytes, path](const absl::Status& s) {
    if (!disk_done_) return;
    std::error_code ec;
    const uint64_t written = s.ok() ? std::filesystem::file_size(path, ec) : 0;
    disk_done_(bytes, ec ? bytes : written);
  };
  if (durable) {
    absl::Status s = WriteMeshSnapshot(*m->mesh, m->diagnostics, key, path);
    done(s);
    if (!s.ok()) {
      return absl::Status(s.code(), absl::StrFormat("mesh '%s' could not be stored durably: %s",
                                                    m->name, s.message()));
    }
    return s;
  }
  absl::MutexLock lock(&saves_mu_);
  // Finished saves are dropped so the list stays as long as the saves in
  // flight.
  std::erase_if(saves_, [](const std::future<void>& f) {
    return f.wait_for(std::chrono::seconds(0)) == std::future_status::ready;
  });
  saves_.push_back(std::async(std::launch::async, [m = std::move(m), key, path, done] {
    absl::Status s = WriteMeshSnapshot(*m->mesh, m->diagnostics, key, path);
    done(s);
    if (!s.ok()) {
      Log(LogLevel::kWarning, "mesh_snapshot_failed", {{"mesh", m->name}, {"error", s.ToString()}});
    }
  }));
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterRecorded(
    const std::string& name, const std::string& source, const std::string& format,
    uint64_t source_hash, uint64_t fingerprint, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  std::shared_ptr<RegisteredMesh> m = Restore(source_hash, name, source, repair);
  if (m) {
    m->format = format;
  } else if (source == "upload") {
    return absl::DataLossError(
        absl::StrFormat("mesh '%s' was uploaded, and its snapshot %s is missing or damaged in %s",
                        name, MeshSnapshotName(source_hash), snapshot_dir_));
  } else {
    std::string path = source;
    if (!std::filesystem::path(source).is_absolute()) {
      if (mesh_root_.empty()) {
        return absl::FailedPreconditionError(absl::StrFormat(
            "mesh '%s' came from %s under a mesh root, and this daemon has none", name, source));
      }
      path = (std::filesystem::path(mesh_root_) / source).string();
    }
    ASSIGN_OR_RETURN(m, LoadFile(name, source, path, durable_, repair));
  }
  if (m->fingerprint != fingerprint) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "mesh '%s' from %s has fingerprint %016x, not the %016x recorded: the file changed", name,
        source, m->fingerprint, fingerprint));
  }
  return Insert(std::move(m));
}

std::string MeshRegistry::SnapshotName(const RegisteredMesh& m) {
  return MeshSnapshotName(m.source_hash);
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

uint64_t MeshRegistry::resident_bytes() const {
  absl::MutexLock lock(&mu_);
  absl::flat_hash_set<const Mesh*> counted;
  uint64_t total = 0;
  for (const auto& [name, m] : meshes_) {
    if (counted.insert(m->mesh.get()).second) total += m->mesh->memory_bytes();
  }
  return total;
}

absl::Status MeshRegistry::Remove(const std::string& name) {
  absl::MutexLock lock(&mu_);
  if (meshes_.erase(name) == 0) {
    return absl::NotFoundError(absl::StrFormat("no mesh named '%s'", name));
  }
  return absl::OkStatus();
}

}  // namespace geodesic::server
