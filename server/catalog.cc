#include "server/catalog.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <fstream>
#include <sstream>

#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "nlohmann/json.hpp"

namespace geodesic::server {
namespace {

using nlohmann::json;
constexpr char kFormatName[] = "geodesicd-catalog";

// 64-bit keys as hex strings: JSON numbers are doubles to most readers.
std::string Hex(uint64_t v) { return absl::StrFormat("%016x", v); }

json ParamsToJson(const DggParams& p) {
  return json{{"epsilon", p.epsilon},
              {"pseudo_vertices", p.pseudo_vertices},
              {"prune_redundant", p.prune_redundant},
              {"exact_fans", p.exact_fans},
              {"candidate_rule", p.candidate_rule}};
}

// A malformed entry, named by where it is ("meshes[2].fingerprint"). Thrown
// and caught inside CatalogFromJson only.
struct Malformed {
  std::string what;
};

template <typename T>
T Get(const json& object, const char* key, const std::string& where) {
  const std::string name = where.empty() ? key : where + "." + key;
  if (!object.is_object() || !object.contains(key)) throw Malformed{name + " is missing"};
  const json& value = object.at(key);
  try {
    return value.get<T>();
  } catch (const json::exception&) {
    throw Malformed{absl::StrFormat("%s has the wrong type (%s)", name, value.type_name())};
  }
}

uint64_t GetHex(const json& object, const char* key, const std::string& where) {
  const std::string text = Get<std::string>(object, key, where);
  uint64_t v = 0;
  if (text.size() != 16 || !absl::SimpleHexAtoi(text, &v)) {
    throw Malformed{absl::StrFormat("%s.%s: '%s' is not 16 hex digits", where, key, text)};
  }
  return v;
}

DggParams ParamsFromJson(const json& j, const std::string& where) {
  DggParams p;
  p.epsilon = Get<double>(j, "epsilon", where);
  p.pseudo_vertices = Get<bool>(j, "pseudo_vertices", where);
  p.prune_redundant = Get<bool>(j, "prune_redundant", where);
  p.exact_fans = Get<bool>(j, "exact_fans", where);
  p.candidate_rule = Get<uint32_t>(j, "candidate_rule", where);
  return p;
}

const json& GetArray(const json& j, const char* key) {
  if (!j.contains(key) || !j.at(key).is_array())
    throw Malformed{std::string(key) + " is not a list"};
  return j.at(key);
}

// Holds an exclusive open-file-description lock for its lifetime.
class FileLock {
 public:
  static absl::StatusOr<FileLock> Acquire(const std::string& path) {
    const int fd = ::open(path.c_str(), O_RDWR | O_CREAT | O_CLOEXEC, 0644);
    if (fd < 0) return ErrnoStatus("cannot open lock file", path);
    struct flock lock = {};
    lock.l_type = F_WRLCK;
    lock.l_whence = SEEK_SET;
    while (::fcntl(fd, F_OFD_SETLKW, &lock) != 0) {
      if (errno == EINTR) continue;
      absl::Status s = ErrnoStatus("cannot lock", path);
      ::close(fd);
      return s;
    }
    return FileLock(fd);
  }
  FileLock(FileLock&& other) noexcept : fd_(std::exchange(other.fd_, -1)) {}
  FileLock& operator=(FileLock&&) = delete;
  ~FileLock() {
    if (fd_ >= 0) ::close(fd_);  // closing the description releases the lock
  }

 private:
  explicit FileLock(int fd) : fd_(fd) {}
  int fd_;
};

}  // namespace

const CatalogMesh* CatalogState::FindMesh(const std::string& name) const {
  for (const CatalogMesh& m : meshes) {
    if (m.name == name) return &m;
  }
  return nullptr;
}

void CatalogState::PutMesh(CatalogMesh mesh) {
  auto it = std::find_if(meshes.begin(), meshes.end(),
                         [&](const CatalogMesh& m) { return m.name == mesh.name; });
  if (it != meshes.end()) {
    *it = std::move(mesh);
    return;
  }
  meshes.push_back(std::move(mesh));
  std::sort(meshes.begin(), meshes.end(),
            [](const CatalogMesh& a, const CatalogMesh& b) { return a.name < b.name; });
}

bool CatalogState::RemoveMesh(const std::string& name) {
  std::erase_if(graphs, [&](const CatalogGraph& g) { return g.mesh == name; });
  return std::erase_if(meshes, [&](const CatalogMesh& m) { return m.name == name; }) > 0;
}

bool CatalogState::HasGraph(const std::string& mesh, const DggParams& params,
                            double max_error) const {
  return std::find(graphs.begin(), graphs.end(), CatalogGraph{mesh, params, max_error}) !=
         graphs.end();
}

void CatalogState::PutGraph(CatalogGraph graph) {
  if (HasGraph(graph.mesh, graph.params, graph.max_error)) return;
  graphs.push_back(std::move(graph));
  std::sort(graphs.begin(), graphs.end());
}

bool CatalogState::RemoveGraph(const std::string& mesh, const DggParams& params, double max_error) {
  return std::erase(graphs, CatalogGraph{mesh, params, max_error}) > 0;
}

std::string CatalogToJson(const CatalogState& state) {
  json meshes = json::array(), graphs = json::array();
  uint32_t version = Catalog::kOldestFormatVersion;
  for (const CatalogMesh& m : state.meshes) {
    json entry = {{"name", m.name},
                  {"source", m.source},
                  {"format", m.format},
                  {"source_hash", Hex(m.source_hash)},
                  {"fingerprint", Hex(m.fingerprint)},
                  {"repair_non_manifold", m.repair_non_manifold}};
    if (!m.parent.empty()) {
      entry["region"] = {{"parent", m.parent},
                         {"mask", m.region_faces ? "faces" : "vertices"},
                         {"ids", m.region_ids}};
      version = Catalog::kFormatVersion;
    }
    meshes.push_back(std::move(entry));
  }
  for (const CatalogGraph& g : state.graphs) {
    json entry = ParamsToJson(g.params);
    entry["mesh"] = g.mesh;
    // Only for a certified graph: a catalog without one stays version 1.
    if (g.max_error > 0) {
      entry["max_error"] = g.max_error;
      version = std::max(version, Catalog::kCertifiedFormatVersion);
    }
    graphs.push_back(std::move(entry));
  }
  const json j = {{"format", kFormatName},
                  {"version", version},
                  {"generation", state.generation},
                  {"meshes", std::move(meshes)},
                  {"graphs", std::move(graphs)}};
  return j.dump(2) + "\n";
}

absl::StatusOr<CatalogState> CatalogFromJson(const std::string& text, const std::string& path) {
  const json j = json::parse(text, nullptr, /*allow_exceptions=*/false);
  if (j.is_discarded() || !j.is_object()) {
    return absl::DataLossError(absl::StrFormat("%s: not a JSON object", path));
  }
  if (!j.contains("format") || j["format"] != kFormatName) {
    return absl::DataLossError(absl::StrFormat("%s: not a geodesicd catalog", path));
  }
  CatalogState state;
  try {
    const uint32_t version = Get<uint32_t>(j, "version", "");
    if (version < Catalog::kOldestFormatVersion || version > Catalog::kFormatVersion) {
      return absl::FailedPreconditionError(
          absl::StrFormat("%s has catalog format version %u; this build reads versions %u to %u",
                          path, version, Catalog::kOldestFormatVersion, Catalog::kFormatVersion));
    }
    state.generation = Get<uint64_t>(j, "generation", "");
    const json& meshes = GetArray(j, "meshes");
    for (size_t i = 0; i < meshes.size(); ++i) {
      const json& m = meshes[i];
      const std::string where = absl::StrFormat("meshes[%u]", i);
      CatalogMesh& mesh = state.meshes.emplace_back(
          CatalogMesh{Get<std::string>(m, "name", where), Get<std::string>(m, "source", where),
                      Get<std::string>(m, "format", where), GetHex(m, "source_hash", where),
                      GetHex(m, "fingerprint", where), Get<bool>(m, "repair_non_manifold", where)});
      if (m.contains("region")) {
        const json& region = m.at("region");
        const std::string at = where + ".region";
        mesh.parent = Get<std::string>(region, "parent", at);
        const std::string mask = Get<std::string>(region, "mask", at);
        if (mask != "vertices" && mask != "faces") {
          throw Malformed{absl::StrFormat("%s.mask: '%s' is not vertices or faces", at, mask)};
        }
        mesh.region_faces = mask == "faces";
        mesh.region_ids = Get<std::vector<uint32_t>>(region, "ids", at);
      }
    }
    const json& graphs = GetArray(j, "graphs");
    for (size_t i = 0; i < graphs.size(); ++i) {
      const std::string where = absl::StrFormat("graphs[%u]", i);
      CatalogGraph g{Get<std::string>(graphs[i], "mesh", where), ParamsFromJson(graphs[i], where)};
      if (graphs[i].contains("max_error")) {
        g.max_error = Get<double>(graphs[i], "max_error", where);
        if (!(g.max_error > 0) || !std::isfinite(g.max_error)) {
          throw Malformed{
              absl::StrFormat("%s.max_error: %g is not a positive bound", where, g.max_error)};
        }
      }
      state.graphs.push_back(std::move(g));
    }
  } catch (const Malformed& e) {
    return absl::DataLossError(absl::StrFormat("%s: %s", path, e.what));
  }
  return state;
}

Catalog::Catalog(std::string dir, Writer writer)
    : dir_(std::move(dir)),
      path_(dir_ + "/catalog.json"),
      lock_path_(dir_ + "/catalog.lock"),
      writer_(std::move(writer)) {
  if (!writer_) {
    writer_ = [](const std::string& path, const std::string& text) -> absl::Status {
      ASSIGN_OR_RETURN(AtomicFileWriter out, AtomicFileWriter::Create(path));
      RETURN_IF_ERROR(out.Append(text.data(), text.size()));
      return std::move(out).Commit();
    };
  }
}

absl::Status Catalog::EnsureReserve() const {
  const std::string path = reserve_path();
  struct stat st;
  if (::stat(path.c_str(), &st) == 0 && uint64_t(st.st_size) >= kReserveBytes) {
    return absl::OkStatus();
  }
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) return ErrnoStatus("cannot create", path);
  // Allocated blocks, not a sparse file: deleting it must free real space.
  const int e = ::posix_fallocate(fd, 0, static_cast<off_t>(kReserveBytes));
  ::close(fd);
  if (e != 0) {
    ::unlink(path.c_str());
    errno = e;
    return ErrnoStatus("cannot allocate the catalog's reserve", path);
  }
  return absl::OkStatus();
}

absl::StatusOr<CatalogState> Catalog::Read() const {
  std::ifstream in(path_, std::ios::binary);
  if (!in) {
    if (errno == ENOENT) return CatalogState{};
    return ErrnoStatus("cannot read", path_);
  }
  std::stringstream text;
  text << in.rdbuf();
  if (in.bad()) return ErrnoStatus("cannot read", path_);
  return CatalogFromJson(text.str(), path_);
}

absl::StatusOr<CatalogState> Catalog::Update(absl::FunctionRef<absl::Status(CatalogState&)> change,
                                             Reserve reserve) {
  ASSIGN_OR_RETURN(FileLock lock, FileLock::Acquire(lock_path_));
  ASSIGN_OR_RETURN(CatalogState state, Read());
  RETURN_IF_ERROR(change(state));
  ++state.generation;
  const std::string text = CatalogToJson(state);
  absl::Status written = writer_(path_, text);
  if (absl::IsResourceExhausted(written) && reserve == Reserve::kFreesSpace &&
      ::unlink(reserve_path().c_str()) == 0) {
    written = writer_(path_, text);
    // Made again when the disk has room; the follower retries meanwhile.
    EnsureReserve().IgnoreError();
  }
  RETURN_IF_ERROR(written);
  return state;
}

}  // namespace geodesic::server
