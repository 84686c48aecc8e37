#include "server/store/catalog.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cmath>
#include <functional>
#include <limits>
#include <optional>
#include <string_view>

#include "absl/cleanup/cleanup.h"
#include "absl/strings/escaping.h"
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

bool SortedDistinct(const std::vector<uint32_t>& ids) {
  return std::adjacent_find(ids.begin(), ids.end(), std::greater_equal<uint32_t>()) == ids.end();
}

// Region ids once each, in increasing order, as the compact forms need
// them; ids that are so already (as registries record them) are only
// checked.
void SortDistinct(std::vector<uint32_t>& ids) {
  if (SortedDistinct(ids)) return;
  std::sort(ids.begin(), ids.end());
  ids.erase(std::unique(ids.begin(), ids.end()), ids.end());
}

// Increasing distinct ids as runs: "0-99,105,200-300".
std::string IdRanges(const std::vector<uint32_t>& ids) {
  std::string out;
  for (size_t i = 0, j; i < ids.size(); i = j) {
    for (j = i + 1; j < ids.size() && ids[j] == ids[j - 1] + 1; ++j) {
    }
    if (!out.empty()) out += ',';
    absl::StrAppendFormat(&out, "%u", ids[i]);
    if (j - i > 1) absl::StrAppendFormat(&out, "-%u", ids[j - 1]);
  }
  return out;
}

// The bytes of a bitmap of ids up to `last`: bit i % 8 of byte i / 8 for
// id i.
uint64_t BitmapBytes(uint32_t last) { return uint64_t{last} / 8 + 1; }
uint64_t Base64Size(uint64_t bytes) { return 4 * ((bytes + 2) / 3); }

std::string IdBitmap(const std::vector<uint32_t>& ids) {
  std::string bits(BitmapBytes(ids.back()), '\0');
  for (uint32_t id : ids) bits[id / 8] = static_cast<char>(bits[id / 8] | (1 << (id % 8)));
  return absl::Base64Escape(bits);
}

json RegionToJson(const CatalogMesh& m) {
  json region = {{"parent", m.parent}, {"mask", m.region_faces ? "faces" : "vertices"}};
  const bool sorted_already = SortedDistinct(m.region_ids);
  std::vector<uint32_t> sorted;
  if (!sorted_already) {
    sorted = m.region_ids;
    SortDistinct(sorted);
  }
  const std::vector<uint32_t>& ids = sorted_already ? m.region_ids : sorted;
  region["count"] = ids.size();
  std::string ranges = IdRanges(ids);
  if (!ids.empty() && Base64Size(BitmapBytes(ids.back())) < ranges.size()) {
    region["bitmap"] = IdBitmap(ids);
  } else {
    region["ranges"] = std::move(ranges);
  }
  return region;
}

uint32_t ParseId(std::string_view text, const std::string& where) {
  uint32_t id = 0;
  if (text.empty() || text.size() > 10 ||
      !std::all_of(text.begin(), text.end(), [](char c) { return c >= '0' && c <= '9'; }) ||
      !absl::SimpleAtoi(absl::string_view(text.data(), text.size()), &id)) {
    throw Malformed{absl::StrFormat("%s: '%s' is not an id", where, text)};
  }
  return id;
}

// Past `count` ids (the entry's own), a damaged list, and no more memory.
void CheckCount(uint64_t ids, uint64_t count, const std::string& where) {
  if (ids > count) {
    throw Malformed{absl::StrFormat("%s holds more than the %u ids of its count", where, count)};
  }
}

std::vector<uint32_t> IdsFromRanges(const std::string& text, uint64_t count,
                                    const std::string& where) {
  std::vector<uint32_t> ids;
  std::string_view rest = text;
  while (!rest.empty()) {
    const size_t comma = rest.find(',');
    const std::string_view run = rest.substr(0, comma);
    rest = comma == std::string_view::npos ? std::string_view() : rest.substr(comma + 1);
    if (comma != std::string_view::npos && rest.empty()) {
      throw Malformed{absl::StrFormat("%s ends with a comma", where)};
    }
    const size_t dash = run.find('-');
    const uint32_t first = ParseId(run.substr(0, dash), where);
    const uint32_t last =
        dash == std::string_view::npos ? first : ParseId(run.substr(dash + 1), where);
    if (last < first || (!ids.empty() && first <= ids.back())) {
      throw Malformed{
          absl::StrFormat("%s: '%s' is not a run after the ones before it", where, run)};
    }
    CheckCount(ids.size() + (uint64_t{last} - first + 1), count, where);
    for (uint64_t id = first; id <= last; ++id) ids.push_back(static_cast<uint32_t>(id));
  }
  return ids;
}

std::vector<uint32_t> IdsFromBitmap(const std::string& text, uint64_t count,
                                    const std::string& where) {
  std::string bits;
  if (!absl::Base64Unescape(text, &bits)) {
    throw Malformed{absl::StrFormat("%s is not base64", where)};
  }
  if (bits.size() > BitmapBytes(std::numeric_limits<uint32_t>::max())) {
    throw Malformed{absl::StrFormat("%s holds ids past 2^32", where)};
  }
  std::vector<uint32_t> ids;
  for (uint64_t byte = 0; byte < bits.size(); ++byte) {
    for (int bit = 0; bit < 8; ++bit) {
      if (!(bits[byte] & (1 << bit))) continue;
      CheckCount(ids.size() + 1, count, where);
      ids.push_back(static_cast<uint32_t>(8 * byte + bit));
    }
  }
  return ids;
}

// Version 4's compact ids, or version 3's list.
std::vector<uint32_t> RegionIdsFromJson(const json& region, const std::string& at) {
  if (!region.contains("ranges") && !region.contains("bitmap")) {
    std::vector<uint32_t> ids = Get<std::vector<uint32_t>>(region, "ids", at);
    SortDistinct(ids);
    return ids;
  }
  const uint64_t count = Get<uint64_t>(region, "count", at);
  std::vector<uint32_t> ids =
      region.contains("ranges")
          ? IdsFromRanges(Get<std::string>(region, "ranges", at), count, at + ".ranges")
          : IdsFromBitmap(Get<std::string>(region, "bitmap", at), count, at + ".bitmap");
  if (count != ids.size()) {
    throw Malformed{
        absl::StrFormat("%s lists %u ids, not the %u of its count", at, ids.size(), count)};
  }
  return ids;
}

// The generation an Update wrote near the file's start (CatalogToJson's
// keys are sorted: "format", then "generation"), if it is there.
std::optional<uint64_t> GenerationAtHead(int fd) {
  char head[256];
  const ssize_t n = ::pread(fd, head, sizeof(head), 0);
  if (n <= 0) return std::nullopt;
  const std::string_view text(head, static_cast<size_t>(n));
  constexpr std::string_view kKey = "\"generation\"";
  size_t at = text.find(kKey);
  if (at == std::string_view::npos) return std::nullopt;
  at = text.find_first_not_of(" \t\r\n:", at + kKey.size());
  const size_t end = text.find_first_not_of("0123456789", at);
  uint64_t generation = 0;
  if (at == std::string_view::npos || end == std::string_view::npos || end == at ||
      !absl::SimpleAtoi(absl::string_view(text.data() + at, end - at), &generation)) {
    return std::nullopt;
  }
  return generation;
}

absl::StatusOr<std::string> ReadAll(int fd, const std::string& path) {
  std::string text;
  char buffer[1 << 16];
  for (;;) {
    const ssize_t n = ::read(fd, buffer, sizeof(buffer));
    if (n == 0) return text;
    if (n < 0) {
      if (errno == EINTR) continue;
      return ErrnoStatus("cannot read", path);
    }
    text.append(buffer, static_cast<size_t>(n));
  }
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
      entry["region"] = RegionToJson(m);
      version = Catalog::kCompactRegionFormatVersion;
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
        mesh.region_ids = RegionIdsFromJson(region, at);
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

Catalog::Stamp Catalog::StampOf(const struct stat& st) {
  auto ns = [](const struct timespec& t) { return int64_t{t.tv_sec} * 1'000'000'000 + t.tv_nsec; };
  return Stamp{st.st_dev, st.st_ino, st.st_size, ns(st.st_mtim), ns(st.st_ctim)};
}

absl::StatusOr<CatalogState> Catalog::Read() const {
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state, ReadShared());
  return *state;
}

absl::StatusOr<std::shared_ptr<const CatalogState>> Catalog::ReadShared() const {
  absl::MutexLock lock(&cache_mu_);
  const int fd = ::open(path_.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd < 0) {
    if (errno != ENOENT) return ErrnoStatus("cannot read", path_);
    if (!cached_ || cached_stamp_ != Stamp{}) {
      cached_ = std::make_shared<const CatalogState>();
      cached_stamp_ = Stamp{};
    }
    return cached_;
  }
  absl::Cleanup close_fd = [fd] { ::close(fd); };
  struct stat st;
  if (::fstat(fd, &st) != 0) return ErrnoStatus("cannot read", path_);
  const Stamp stamp = StampOf(st);
  if (cached_ && stamp == cached_stamp_) {
    // A file not written by Update (by hand, say) may not have it there;
    // its stamp alone then tells.
    const std::optional<uint64_t> generation = GenerationAtHead(fd);
    if (!generation || *generation == cached_->generation) return cached_;
  }
  ASSIGN_OR_RETURN(std::string text, ReadAll(fd, path_));
  ++parses_;
  ASSIGN_OR_RETURN(CatalogState state, CatalogFromJson(text, path_));
  cached_ = std::make_shared<const CatalogState>(std::move(state));
  cached_stamp_ = stamp;
  return cached_;
}

absl::StatusOr<CatalogState> Catalog::Update(absl::FunctionRef<absl::Status(CatalogState&)> change,
                                             Reserve reserve) {
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> state, UpdateShared(change, reserve));
  return *state;
}

absl::StatusOr<std::shared_ptr<const CatalogState>> Catalog::UpdateShared(
    absl::FunctionRef<absl::Status(CatalogState&)> change, Reserve reserve) {
  ASSIGN_OR_RETURN(FileLock lock, FileLock::Acquire(lock_path_));
  ASSIGN_OR_RETURN(std::shared_ptr<const CatalogState> current, ReadShared());
  CatalogState state = *current;
  current.reset();
  RETURN_IF_ERROR(change(state));
  ++state.generation;
  // As a reader will find them in the file.
  for (CatalogMesh& m : state.meshes) SortDistinct(m.region_ids);
  const std::string text = CatalogToJson(state);
  absl::Status written = writer_(path_, text);
  if (absl::IsResourceExhausted(written) && reserve == Reserve::kFreesSpace &&
      ::unlink(reserve_path().c_str()) == 0) {
    written = writer_(path_, text);
    // Made again when the disk has room; the follower retries meanwhile.
    EnsureReserve().IgnoreError();
  }
  RETURN_IF_ERROR(written);
  auto shared = std::make_shared<const CatalogState>(std::move(state));
  // Still the file written: every writer holds the lock.
  absl::MutexLock cache_lock(&cache_mu_);
  struct stat st;
  if (::stat(path_.c_str(), &st) == 0) {
    cached_ = shared;
    cached_stamp_ = StampOf(st);
  } else {
    cached_.reset();
  }
  return shared;
}

}  // namespace geodesic::server
