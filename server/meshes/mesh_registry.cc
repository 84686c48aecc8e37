#include "server/meshes/mesh_registry.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <bit>
#include <cerrno>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <future>
#include <limits>
#include <map>
#include <tuple>

#include "absl/cleanup/cleanup.h"
#include "absl/container/flat_hash_set.h"
#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "core/dgg/dgg_graph.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/mesh_snapshot.h"
#include "server/base/echo.h"
#include "server/base/log.h"

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

// `room(vertices, faces)`: whether a mesh that size may be built, asked
// before the build, which takes several times the soup's memory.
absl::StatusOr<std::shared_ptr<RegisteredMesh>> Finish(
    const std::string& name, const std::string& source, absl::StatusOr<TriangleSoup> soup,
    MeshDiagnostics diagnostics, bool repair,
    const std::function<absl::Status(uint64_t, uint64_t)>& room) {
  if (!soup.ok()) return soup.status();
  RETURN_IF_ERROR(RequireFaces(*soup, source == "upload" ? name : source));
  RETURN_IF_ERROR(room(soup->positions.size(), soup->triangles.size()));
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

// A request listing its ids many times over is refused before any work:
// its region is no more than each id once, and cutting it would take time
// and memory for every repeat.
absl::Status RefuseRepeatedIds(const Mesh& parent, RegionMask mask, uint64_t ids,
                               const std::string& source) {
  const bool by_vertex = mask == RegionMask::kVertices;
  const uint64_t count = by_vertex ? parent.num_vertices() : parent.num_faces();
  if (ids <= MeshRegistry::kMaxIdsPerElement * count) return absl::OkStatus();
  const char* what = by_vertex ? "vertices" : "faces";
  return absl::InvalidArgumentError(absl::StrFormat(
      "%s: %u %s ids for a mesh of %u %s, more than %u times as many: list each id once", source,
      ids, by_vertex ? "vertex" : "face", count, what, MeshRegistry::kMaxIdsPerElement));
}

// A region's maps of `vertices` and `faces` and its `ids`, as
// Region::map_bytes and RegisteredMesh::extra_bytes will count them.
uint64_t RegionExtraBytes(uint64_t vertices, uint64_t faces, uint64_t ids) {
  return (2 * (vertices + faces) + ids) * sizeof(uint32_t);
}

// Bytes of the registered meshes, each mesh once however many names share
// it (the meshes counted are added to `counted`), and what each name holds
// beside its mesh.
uint64_t Resident(const std::map<std::string, std::shared_ptr<const RegisteredMesh>>& meshes,
                  absl::flat_hash_set<const Mesh*>& counted) {
  uint64_t total = 0;
  for (const auto& [name, m] : meshes) {
    if (counted.insert(m->mesh.get()).second) total += m->mesh->memory_bytes();
    total += m->extra_bytes();
  }
  return total;
}

const char* KindOf(mode_t mode) {
  if (S_ISDIR(mode)) return "a directory";
  if (S_ISFIFO(mode)) return "a FIFO";
  if (S_ISSOCK(mode)) return "a socket";
  if (S_ISCHR(mode)) return "a character device";
  if (S_ISBLK(mode)) return "a block device";
  return "not a regular file";
}

bool Beneath(const std::filesystem::path& root, const std::filesystem::path& path) {
  auto [root_end, unused] = std::mismatch(root.begin(), root.end(), path.begin(), path.end());
  return root_end == root.end();
}

// The whole of the regular file at `path`, read from the one descriptor
// that was checked: opened without blocking (a FIFO's open would wait for a
// writer, holding the mesh's name and the daemon's shutdown), refused
// unless it is a regular file, and, with a `root`, refused unless the file
// opened is still under it (a symbolic link swapped in after the path was
// resolved). `display` names the file in messages.
absl::StatusOr<std::string> ReadRegularFile(const std::string& path, const std::string& display,
                                            const std::filesystem::path& root) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC | O_NOCTTY);
  if (fd < 0) {
    const int err = errno;
    if (err == ENOENT || err == ENOTDIR) {
      return absl::NotFoundError(absl::StrFormat("'%s': no such file", display));
    }
    if (err == EACCES || err == EPERM) {
      return absl::PermissionDeniedError(absl::StrFormat("'%s': permission denied", display));
    }
    if (err == ENAMETOOLONG || err == ELOOP) {
      return absl::InvalidArgumentError(absl::StrFormat("'%s': %s", display, std::strerror(err)));
    }
    return absl::InternalError(
        absl::StrFormat("cannot open '%s': %s", display, std::strerror(err)));
  }
  absl::Cleanup close_fd = [fd] { ::close(fd); };
  struct stat st;
  if (::fstat(fd, &st) != 0) {
    return absl::InternalError(
        absl::StrFormat("cannot stat '%s': %s", display, std::strerror(errno)));
  }
  if (!S_ISREG(st.st_mode)) {
    return absl::InvalidArgumentError(
        absl::StrFormat("'%s' is %s, not a mesh file", display, KindOf(st.st_mode)));
  }
  if (!root.empty()) {
    std::error_code ec;
    const auto opened = std::filesystem::read_symlink(absl::StrFormat("/proc/self/fd/%d", fd), ec);
    if (!ec && !Beneath(root, opened)) {
      return absl::PermissionDeniedError(
          absl::StrFormat("'%s' leads outside the mesh root", display));
    }
  }
  std::string bytes;
  bytes.reserve(st.st_size);
  char buffer[1 << 16];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof(buffer));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) {
      return absl::InternalError(
          absl::StrFormat("cannot read '%s': %s", display, std::strerror(errno)));
    }
    if (n == 0) break;
    bytes.append(buffer, n);
  }
  return bytes;
}

}  // namespace

absl::StatusOr<SurfacePoint> LazySurfaceLocator::Snap(const Vec3& position) const {
  absl::call_once(built_, [&] { locator_ = SurfaceLocator::Build(*mesh_); });
  if (!locator_.ok()) return locator_.status();
  return locator_->Snap(position);
}

absl::Status MeshRegistry::ValidateName(const std::string& name) {
  if (name.empty() || name.size() > 64) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "a mesh name has 1 to 64 characters, not %u ('%s')", name.size(), Echo(name)));
  }
  for (char c : name) {
    if (!(std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-' || c == '.')) {
      return absl::InvalidArgumentError(
          absl::StrFormat("mesh name '%s' has a character outside [A-Za-z0-9_.-]", Echo(name)));
    }
  }
  // Names become parts of file names and URLs, where these two mean
  // directories.
  if (name == "." || name == "..") {
    return absl::InvalidArgumentError(absl::StrFormat("'%s' is not a mesh name", name));
  }
  // Names are command-line arguments too (the CLI, scripts), where a
  // leading '-' reads as a flag.
  if (name.front() == '-') {
    return absl::InvalidArgumentError(absl::StrFormat(
        "mesh name '%s' starts with '-', which reads as a flag on command lines", Echo(name)));
  }
  return absl::OkStatus();
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterPath(
    const std::string& name, const std::string& relative_path, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  if (mesh_root_.empty()) {
    return absl::PermissionDeniedError("the server has no --mesh-root: register by upload");
  }
  const std::string shown = Echo(relative_path);
  // The system's calls would read the path only up to its first NUL: what
  // was opened would not be what was asked for (or recorded).
  if (relative_path.find('\0') != std::string::npos) {
    return absl::InvalidArgumentError(absl::StrFormat("path '%s' contains a NUL character", shown));
  }
  namespace fs = std::filesystem;
  std::error_code ec;
  const fs::path root = fs::canonical(mesh_root_, ec);
  if (ec) return absl::InternalError(absl::StrFormat("mesh root %s: %s", mesh_root_, ec.message()));
  const fs::path requested(relative_path);
  if (relative_path.empty() || requested.is_absolute()) {
    return absl::PermissionDeniedError(
        absl::StrFormat("'%s': give a path relative to the mesh root", shown));
  }
  // Resolve symbolic links, then require the result to stay under the root.
  const fs::path resolved = fs::weakly_canonical(root / requested, ec);
  if (ec && ec != std::errc::permission_denied) {
    return absl::InvalidArgumentError(absl::StrFormat("'%s': %s", shown, ec.message()));
  }
  if (ec || !Beneath(root, resolved)) {
    return absl::PermissionDeniedError(absl::StrFormat("'%s' leads outside the mesh root", shown));
  }
  ASSIGN_OR_RETURN(auto m,
                   LoadFile(name, relative_path, resolved.string(), shown, root, durable_, repair));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterTrustedPath(
    const std::string& name, const std::string& path, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  // The operator's own meshes (the sample, the config's) are registered at
  // every start, so their snapshots are a speed-up, written in the
  // background, never a condition of serving.
  ASSIGN_OR_RETURN(auto m, LoadFile(name, path, path, path, {}, /*durable=*/false, repair));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterBytes(
    const std::string& name, const std::string& format, const std::string& bytes, bool repair) {
  RETURN_IF_ERROR(ValidateName(name));
  const std::string lower = absl::AsciiStrToLower(format);
  if (!IsMeshFormat(lower)) {
    return absl::InvalidArgumentError(absl::StrFormat("unknown mesh format '%s' (supported: %s)",
                                                      Echo(format), MeshFormatList()));
  }
  const uint64_t key = SnapshotKey(SourceHash(bytes, lower), repair);
  if (auto m = Restore(key, name, "upload", repair)) {
    m->diagnostics.path = name;
    m->format = lower;
    return Insert(std::move(m));
  }
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoupFromMemory(bytes, format, name, &diagnostics, DecodeBudget());
  ASSIGN_OR_RETURN(auto m, Finish(name, "upload", std::move(soup), std::move(diagnostics), repair,
                                  RoomToBuild(name)));
  m->format = lower;
  m->source_hash = key;
  RETURN_IF_ERROR(Save(m, key, durable_));
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterArrays(
    const std::string& name, const std::vector<double>& vertices,
    const std::vector<uint32_t>& faces, bool repair) {
  static_assert(std::endian::native == std::endian::little,
                "the arrays' key is defined over their little-endian bytes");
  RETURN_IF_ERROR(ValidateName(name));
  if (vertices.size() % 3 != 0 || faces.size() % 3 != 0) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: %u vertex coordinates and %u face indices; each must be a multiple of 3", name,
        vertices.size(), faces.size()));
  }
  const uint64_t nv = vertices.size() / 3;
  if (nv == 0) return absl::InvalidArgumentError(absl::StrFormat("%s has no vertices", name));
  if (nv > std::numeric_limits<VertexId>::max()) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s has %u vertices, more than vertex ids can number", name, nv));
  }
  std::string canonical(reinterpret_cast<const char*>(vertices.data()),
                        vertices.size() * sizeof(double));
  canonical.append(reinterpret_cast<const char*>(faces.data()), faces.size() * sizeof(uint32_t));
  const uint64_t key = SnapshotKey(SourceHash(canonical, "arrays"), repair);
  std::string().swap(canonical);
  if (auto m = Restore(key, name, "upload", repair)) {
    m->diagnostics.path = name;
    m->format = "arrays";
    return Insert(std::move(m));
  }
  // Checked here as the file readers check theirs: the diagnostics run
  // beside Mesh::Build and index positions by the faces' ids.
  TriangleSoup soup;
  soup.positions.reserve(nv);
  for (uint64_t v = 0; v < nv; ++v) {
    const Vec3 p{vertices[3 * v], vertices[3 * v + 1], vertices[3 * v + 2]};
    if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z)) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "%s: vertex %u has a non-finite coordinate (%g, %g, %g)", name, v, p.x, p.y, p.z));
    }
    soup.positions.push_back(p);
  }
  soup.triangles.reserve(faces.size() / 3);
  for (size_t f = 0; f < faces.size() / 3; ++f) {
    const std::array<VertexId, 3> t{faces[3 * f], faces[3 * f + 1], faces[3 * f + 2]};
    for (VertexId v : t) {
      if (v >= nv) {
        return absl::OutOfRangeError(absl::StrFormat(
            "%s: face %u names vertex %u, but there are %u vertices", name, f, v, nv));
      }
    }
    soup.triangles.push_back(t);
  }
  MeshDiagnostics diagnostics;
  diagnostics.path = name;
  diagnostics.format = "arrays";
  ASSIGN_OR_RETURN(auto m, Finish(name, "upload", std::move(soup), std::move(diagnostics), repair,
                                  RoomToBuild(name)));
  m->format = "arrays";
  m->source_hash = key;
  RETURN_IF_ERROR(Save(m, key, durable_));
  return Insert(std::move(m));
}

MeshRegistry::~MeshRegistry() {
  absl::MutexLock lock(&saves_mu_);
  for (auto& save : saves_) save.wait();
}

absl::StatusOr<std::shared_ptr<RegisteredMesh>> MeshRegistry::LoadFile(
    const std::string& name, const std::string& source, const std::string& path,
    const std::string& display, const std::filesystem::path& root, bool durable, bool repair) {
  const auto start = std::chrono::steady_clock::now();
  // One read of the file serves both its snapshot key and its parse, so
  // a file rewritten meanwhile cannot be saved under the other version's
  // key.
  ASSIGN_OR_RETURN(std::string bytes, ReadRegularFile(path, display, root));
  const std::string format = MeshFormatOfPath(path);
  if (!IsMeshFormat(format)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "'%s': unknown mesh format (the extension names one of %s; x.surf.gii is gii)", display,
        MeshFormatList()));
  }
  const uint64_t key = SnapshotKey(SourceHash(bytes, format), repair);
  if (auto m = Restore(key, name, source, repair)) {
    m->diagnostics.path = path;
    m->format = format;
    return m;
  }
  MeshDiagnostics diagnostics;
  auto soup = ReadTriangleSoupFromMemory(bytes, format, display, &diagnostics, DecodeBudget());
  std::string().swap(bytes);
  diagnostics.load_seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  ASSIGN_OR_RETURN(auto m, Finish(name, display, std::move(soup), std::move(diagnostics), repair,
                                  RoomToBuild(name)));
  m->source = source;
  m->diagnostics.path = path;
  m->format = format;
  m->source_hash = key;
  RETURN_IF_ERROR(Save(m, key, durable));
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
  // A registration Insert will refuse saves nothing: a refused upload
  // leaves no file behind.
  RETURN_IF_ERROR(NameTakenByOther(*m));
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
    ASSIGN_OR_RETURN(m, LoadFile(name, source, path, path, {}, durable_, repair));
  }
  if (m->fingerprint != fingerprint) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "mesh '%s' from %s has fingerprint %016x, not the %016x recorded: the file changed", name,
        source, m->fingerprint, fingerprint));
  }
  return Insert(std::move(m));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::RegisterRegion(
    const std::string& name, const std::string& parent, RegionMask mask,
    absl::Span<const uint32_t> ids, uint64_t fingerprint) {
  RETURN_IF_ERROR(ValidateName(name));
  ASSIGN_OR_RETURN(std::shared_ptr<const RegisteredMesh> p, Get(parent));
  // A region of a region would need its grandparent to be restored first,
  // and says nothing a region of the grandparent does not.
  if (!p->parent.empty()) {
    return absl::FailedPreconditionError(
        absl::StrFormat("mesh '%s' is itself a region of '%s': cut the region from '%s'", parent,
                        p->parent, p->parent));
  }
  const std::string source = absl::StrFormat("region '%s' of '%s'", name, parent);
  RETURN_IF_ERROR(RefuseRepeatedIds(*p->mesh, mask, ids.size(), source));
  ASSIGN_OR_RETURN(std::vector<uint32_t> distinct, DistinctRegionIds(*p->mesh, mask, ids, source));
  ASSIGN_OR_RETURN(Region region, ExtractRegion(*p->mesh, mask, distinct, source,
                                                RoomForRegion(name, distinct.size())));
  auto m = std::make_shared<RegisteredMesh>();
  m->name = name;
  m->source = "region";
  m->format = "region";
  m->mesh = region.mesh;
  m->fingerprint = MeshFingerprint(*m->mesh);
  if (fingerprint != 0 && m->fingerprint != fingerprint) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "region '%s' of '%s' has fingerprint %016x, not the %016x recorded: its parent changed",
        name, parent, m->fingerprint, fingerprint));
  }
  TriangleSoup soup{m->mesh->positions(), {}};
  for (FaceId f = 0; f < m->mesh->num_faces(); ++f) {
    soup.triangles.push_back(
        {m->mesh->face_vertex(f, 0), m->mesh->face_vertex(f, 1), m->mesh->face_vertex(f, 2)});
  }
  ComputeDiagnostics(soup, &m->diagnostics);
  m->diagnostics.path = absl::StrFormat("region of %s", parent);
  m->diagnostics.format = "region";
  m->locator = std::make_shared<const LazySurfaceLocator>(m->mesh);
  m->parent = parent;
  m->region = std::make_shared<const Region>(std::move(region));
  m->region_mask = mask;
  m->region_ids = std::move(distinct);
  return Insert(std::move(m));
}

std::string MeshRegistry::SnapshotName(const RegisteredMesh& m) {
  return MeshSnapshotName(m.source_hash);
}

absl::Status MeshRegistry::NameTakenByOther(const RegisteredMesh& m) const {
  absl::MutexLock lock(&mu_);
  auto it = meshes_.find(m.name);
  if (it == meshes_.end() || it->second->fingerprint == m.fingerprint) return absl::OkStatus();
  return absl::AlreadyExistsError(
      absl::StrFormat("mesh '%s' is registered with other content; unload it first", m.name));
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
  RETURN_IF_ERROR(FitsMemoryLimit(*m));
  std::shared_ptr<const RegisteredMesh> stored = std::move(m);
  meshes_.emplace(stored->name, stored);
  return stored;
}

uint64_t RegisteredMesh::extra_bytes() const {
  return (region ? region->map_bytes() : 0) + region_ids.capacity() * sizeof(uint32_t);
}

absl::Status MeshRegistry::FitsMemoryLimit(const RegisteredMesh& m) const {
  return RoomFor(m.name, m.mesh->memory_bytes(), m.mesh.get(), "", m.extra_bytes());
}

RegionRoom MeshRegistry::RoomForRegion(const std::string& name, uint64_t ids) const {
  return [this, name, ids](uint64_t vertices, uint64_t faces) {
    absl::MutexLock lock(&mu_);
    // As RoomToBuild: the same region again is kept without a second copy.
    if (memory_limit_ == 0 || meshes_.contains(name)) return absl::OkStatus();
    return RoomFor(name, Mesh::EstimateMemoryBytes(vertices, faces), nullptr,
                   absl::StrFormat(", estimated from its %u vertices and %u faces before it is "
                                   "built",
                                   vertices, faces),
                   RegionExtraBytes(vertices, faces, ids));
  };
}

std::function<absl::Status(uint64_t, uint64_t)> MeshRegistry::RoomToBuild(
    const std::string& name) const {
  return [this, name](uint64_t vertices, uint64_t faces) {
    absl::MutexLock lock(&mu_);
    // A name registered already may come back with the same content,
    // which Insert then keeps without a second copy: its room is checked
    // once built.
    if (memory_limit_ == 0 || meshes_.contains(name)) return absl::OkStatus();
    return RoomFor(name, Mesh::EstimateMemoryBytes(vertices, faces), nullptr,
                   absl::StrFormat(", estimated from its %u vertices and %u faces before it is "
                                   "built",
                                   vertices, faces));
  };
}

absl::Status MeshRegistry::RoomFor(const std::string& name, uint64_t bytes, const Mesh* mesh,
                                   const std::string& estimate, uint64_t extra) const {
  if (memory_limit_ == 0) return absl::OkStatus();
  // As resident_bytes counts. The room kept for queries is the largest
  // mesh's own bytes again: a field query's scratch and answer on it take
  // about as much as its arrays.
  absl::flat_hash_set<const Mesh*> counted;
  uint64_t total = Resident(meshes_, counted) + extra, largest = bytes;
  for (const auto& [other_name, other] : meshes_) {
    largest = std::max<uint64_t>(largest, other->mesh->memory_bytes());
  }
  if (mesh == nullptr || counted.insert(mesh).second) total += bytes;
  if (total + largest <= memory_limit_) return absl::OkStatus();
  return absl::ResourceExhaustedError(absl::StrFormat(
      "mesh '%s' (%u bytes%s) is refused: the registered meshes would then take %u bytes of the "
      "server's memory limit (--memory-limit, %u bytes), leaving less than the %u bytes a query "
      "on the largest of them needs; unload a mesh or raise the limit",
      Echo(name), bytes + extra, estimate, total, memory_limit_, largest));
}

absl::StatusOr<std::shared_ptr<const RegisteredMesh>> MeshRegistry::Get(
    const std::string& name) const {
  absl::MutexLock lock(&mu_);
  auto it = meshes_.find(name);
  if (it == meshes_.end()) {
    return absl::NotFoundError(
        absl::StrFormat("no mesh named '%s'; register it first", Echo(name)));
  }
  return it->second;
}

std::vector<std::shared_ptr<const RegisteredMesh>> MeshRegistry::List() const {
  absl::MutexLock lock(&mu_);
  std::vector<std::shared_ptr<const RegisteredMesh>> out;
  for (const auto& [name, m] : meshes_) out.push_back(m);
  return out;
}

uint64_t MeshRegistry::DecodeBudget() const {
  if (memory_limit_ == 0) return 0;
  const uint64_t resident = resident_bytes();
  // Never 0, which would mean no budget at all.
  return resident < memory_limit_ ? memory_limit_ - resident : 1;
}

uint64_t MeshRegistry::resident_bytes() const {
  absl::MutexLock lock(&mu_);
  absl::flat_hash_set<const Mesh*> counted;
  return Resident(meshes_, counted);
}

absl::Status MeshRegistry::Remove(const std::string& name) {
  absl::MutexLock lock(&mu_);
  if (meshes_.erase(name) == 0) {
    return absl::NotFoundError(absl::StrFormat("no mesh named '%s'", Echo(name)));
  }
  return absl::OkStatus();
}

}  // namespace geodesic::server
