#include "core/mesh/mesh_snapshot.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cerrno>
#include <cstring>
#include <future>
#include <utility>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/file_header.h"
#include "core/base/status.h"
#include "xxhash.h"

namespace geodesic {
namespace {

constexpr char kSnapshotMagic[8] = {'G', 'E', 'O', 'D', 'M', 'S', 'H', '\0'};
constexpr size_t kHeaderBytes = 4096;
constexpr size_t kAlignment = kSectionAlignment;
constexpr int kArrayCount = 11;

// Calls f(array) for every array of a mesh, in file order.
template <typename Arrays, typename F>
void ForEachArray(Arrays& a, F f) {
  f(a.positions), f(a.corners), f(a.twin), f(a.edge), f(a.edge_halfedge), f(a.length),
      f(a.corner_angle), f(a.polar_angle), f(a.vertex_halfedge), f(a.total_angle), f(a.flags);
}

// The diagnostics a file determines, as plain data.
struct StoredDiagnostics {
  uint64_t vertices, faces, edges, polygons_triangulated, components, boundary_loops;
  int64_t genus;
  uint64_t isolated_vertices, duplicate_vertices, zero_area_faces, near_degenerate_faces,
      non_manifold_edges, non_manifold_vertices, faces_refused, saddle_vertices, boundary_vertices;
  double bbox_diagonal, mean_edge_length, min_edge_length, anisotropy_mean, anisotropy_p95,
      anisotropy_max;
  uint32_t manifold;
  char format[12];
};

// Both directions between MeshDiagnostics and StoredDiagnostics.
template <typename To, typename From>
void CopyFacts(To& to, const From& from) {
  to.vertices = from.vertices, to.faces = from.faces, to.edges = from.edges;
  to.polygons_triangulated = from.polygons_triangulated, to.components = from.components;
  to.boundary_loops = from.boundary_loops, to.genus = from.genus;
  to.isolated_vertices = from.isolated_vertices, to.duplicate_vertices = from.duplicate_vertices;
  to.zero_area_faces = from.zero_area_faces;
  to.near_degenerate_faces = from.near_degenerate_faces;
  to.non_manifold_edges = from.non_manifold_edges;
  to.non_manifold_vertices = from.non_manifold_vertices, to.faces_refused = from.faces_refused;
  to.saddle_vertices = from.saddle_vertices, to.boundary_vertices = from.boundary_vertices;
  to.bbox_diagonal = from.bbox_diagonal, to.mean_edge_length = from.mean_edge_length;
  to.min_edge_length = from.min_edge_length, to.anisotropy_mean = from.anisotropy_mean;
  to.anisotropy_p95 = from.anisotropy_p95, to.anisotropy_max = from.anisotropy_max;
  to.manifold = from.manifold;
}

struct ArrayEntry {
  uint64_t offset;
  uint64_t bytes;
  uint64_t checksum;  // XXH3-64 of the array's bytes
};

struct Header {
  char magic[8];
  uint32_t version;
  uint32_t endian;
  uint64_t source_hash;
  uint64_t mesh_fingerprint;
  uint64_t num_vertices, num_halfedges, num_edges;
  uint64_t file_bytes;
  StoredDiagnostics diagnostics;
  ArrayEntry arrays[kArrayCount];
  uint64_t header_checksum;  // XXH3-64 of this struct with this field zero
};
static_assert(sizeof(Header) <= kHeaderBytes);
static_assert(std::is_trivially_copyable_v<Vec3> && sizeof(Vec3) == 24);

// Reads exactly `bytes` at `offset`, or says why not.
absl::Status ReadAt(int fd, void* data, size_t bytes, uint64_t offset, const std::string& path) {
  char* p = static_cast<char*>(data);
  while (bytes > 0) {
    const ssize_t n = ::pread(fd, p, bytes, static_cast<off_t>(offset));
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) return ErrnoStatus("cannot read", path);
    if (n == 0) return absl::DataLossError(absl::StrFormat("%s is truncated", path));
    p += n, bytes -= n, offset += n;
  }
  return absl::OkStatus();
}

class Fd {
 public:
  explicit Fd(int fd) : fd_(fd) {}
  Fd(const Fd&) = delete;
  ~Fd() {
    if (fd_ >= 0) ::close(fd_);
  }
  int get() const { return fd_; }

 private:
  int fd_;
};

uint64_t FormatSeed(std::string_view format) { return XXH3_64bits(format.data(), format.size()); }

}  // namespace

uint64_t SourceHash(std::string_view bytes, std::string_view format) {
  return XXH3_64bits_withSeed(bytes.data(), bytes.size(), FormatSeed(format));
}

absl::StatusOr<uint64_t> SourceHashOfFile(const std::string& path) {
  Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) return ErrnoStatus("cannot open", path);
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset_withSeed(state, FormatSeed(MeshFormatOfPath(path)));
  std::vector<char> buffer(size_t{1} << 20);
  absl::Status status;
  for (;;) {
    const ssize_t n = ::read(fd.get(), buffer.data(), buffer.size());
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) status = ErrnoStatus("cannot read", path);
    if (n <= 0) break;
    XXH3_64bits_update(state, buffer.data(), n);
  }
  const uint64_t hash = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  if (!status.ok()) return status;
  return hash;
}

std::string MeshSnapshotName(uint64_t source_hash) {
  return absl::StrFormat("%016x.mesh", source_hash);
}

absl::Status WriteMeshSnapshot(const Mesh& mesh, const MeshDiagnostics& diagnostics,
                               uint64_t source_hash, const std::string& path) {
  Header h{};
  std::memcpy(h.magic, kSnapshotMagic, sizeof(kSnapshotMagic));
  h.version = kMeshSnapshotVersion;
  h.endian = kEndianTag;
  h.source_hash = source_hash;
  h.mesh_fingerprint = MeshFingerprint(mesh);
  h.num_vertices = mesh.num_vertices();
  h.num_halfedges = mesh.num_halfedges();
  h.num_edges = mesh.num_edges();
  CopyFacts(h.diagnostics, diagnostics);
  std::strncpy(h.diagnostics.format, diagnostics.format.c_str(), sizeof(h.diagnostics.format) - 1);
  uint64_t offset = kHeaderBytes;
  int i = 0;
  ForEachArray(mesh.arrays(), [&](const auto& v) {
    const uint64_t bytes = v.size() * sizeof(v[0]);
    h.arrays[i++] = {offset, bytes, XXH3_64bits(v.data(), bytes)};
    offset = AlignToSection(offset + bytes);
  });
  h.file_bytes = offset;
  h.header_checksum = HeaderChecksum(h);

  ASSIGN_OR_RETURN(AtomicFileWriter out, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(out.Append(&h, sizeof(h)));
  RETURN_IF_ERROR(out.PadTo(kHeaderBytes));
  absl::Status status;
  ForEachArray(mesh.arrays(), [&](const auto& v) {
    if (!status.ok()) return;
    status = out.Append(v.data(), v.size() * sizeof(v[0]));
    if (status.ok()) status = out.PadTo(kAlignment);
  });
  RETURN_IF_ERROR(status);
  return std::move(out).Commit();
}

absl::StatusOr<RestoredMesh> ReadMeshSnapshot(const std::string& path, uint64_t source_hash) {
  Fd fd(::open(path.c_str(), O_RDONLY | O_CLOEXEC));
  if (fd.get() < 0) return ErrnoStatus("cannot open", path);
  struct stat st;
  if (::fstat(fd.get(), &st) != 0) return ErrnoStatus("cannot stat", path);
  const uint64_t size = st.st_size;
  if (size < kHeaderBytes) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes is too short for a mesh snapshot header", path, size));
  }
  Header h;
  RETURN_IF_ERROR(ReadAt(fd.get(), &h, sizeof(h), 0, path));
  RETURN_IF_ERROR(
      CheckHeader(h, kSnapshotMagic, kMeshSnapshotVersion, size, "mesh snapshot", path));
  if (h.source_hash != source_hash) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s was saved from other file contents", path));
  }
  const uint64_t nv = h.num_vertices, nh = h.num_halfedges, ne = h.num_edges;
  const uint64_t expected[kArrayCount] = {nv, nh, nh, nh, ne, nh, nh, nh, nv, nv, nv};
  RestoredMesh restored;
  Mesh::Arrays arrays;
  // Sizes first, so a damaged header never asks for a huge allocation.
  int i = 0;
  bool sizes_ok = true;
  ForEachArray(arrays, [&](auto& v) {
    const ArrayEntry& e = h.arrays[i];
    sizes_ok = sizes_ok && e.bytes == expected[i++] * sizeof(v[0]) && e.offset % kAlignment == 0 &&
               e.offset <= size && e.bytes <= size - e.offset;
  });
  if (!sizes_ok) {
    return absl::DataLossError(
        absl::StrFormat("%s: an array has the wrong size or lies outside the file", path));
  }
  // The arrays are read and summed on two threads: the work is page faults
  // and copies, which spread well. One is a thread of its own rather than a
  // TBB task, so that TSan sees the synchronisation.
  auto read_array = [&](auto& v, int k) {
    const ArrayEntry& e = h.arrays[k];
    v.resize(e.bytes / sizeof(v[0]));
    RETURN_IF_ERROR(ReadAt(fd.get(), v.data(), e.bytes, e.offset, path));
    if (XXH3_64bits(v.data(), e.bytes) != e.checksum) {
      return absl::DataLossError(absl::StrFormat("%s: array %d checksum mismatch", path, k));
    }
    return absl::OkStatus();
  };
  auto read_every_other = [&](int parity) {
    absl::Status status;
    int k = 0;
    ForEachArray(arrays, [&](auto& v) {
      if (k % 2 == parity && status.ok()) status = read_array(v, k);
      ++k;
    });
    return status;
  };
  auto odd = std::async(std::launch::async, read_every_other, 1);
  const absl::Status even = read_every_other(0);
  RETURN_IF_ERROR(odd.get());
  RETURN_IF_ERROR(even);
  ASSIGN_OR_RETURN(restored.mesh, Mesh::FromArrays(std::move(arrays), path));
  restored.fingerprint = MeshFingerprint(restored.mesh);
  if (restored.fingerprint != h.mesh_fingerprint) {
    return absl::DataLossError(
        absl::StrFormat("%s: the mesh does not match its fingerprint", path));
  }
  CopyFacts(restored.diagnostics, h.diagnostics);
  h.diagnostics.format[sizeof(h.diagnostics.format) - 1] = '\0';
  restored.diagnostics.format = h.diagnostics.format;
  return restored;
}

}  // namespace geodesic
