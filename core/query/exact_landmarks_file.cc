#include "core/query/exact_landmarks_file.h"

#include <cstring>
#include <filesystem>
#include <fstream>
#include <type_traits>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/file_header.h"
#include "core/base/status.h"
#include "xxhash.h"

namespace geodesic {
namespace {

constexpr char kLandmarksMagic[8] = {'G', 'E', 'O', 'D', 'X', 'L', 'M', '\0'};
constexpr uint32_t kFormatVersion = 1;

// The header, then the fields: num_vertices * count float32, vertex-major.
struct LandmarksHeader {
  char magic[8];
  uint32_t version;
  uint32_t endian;
  uint64_t mesh_fingerprint;
  uint32_t num_vertices;
  uint32_t count;
  double slack;
  uint64_t file_bytes;
  uint64_t payload_checksum;  // XXH3-64 of the fields
  uint64_t header_checksum;   // XXH3-64 of this struct with this field zero
};
static_assert(sizeof(LandmarksHeader) == 64, "no padding: every byte is checksummed");
static_assert(std::is_trivially_copyable_v<LandmarksHeader>);

uint64_t FileBytes(uint64_t vertices, uint64_t count) {
  return sizeof(LandmarksHeader) + vertices * count * sizeof(float);
}

}  // namespace

uint64_t ExactLandmarksFileBytes(const ExactLandmarks& landmarks) {
  return FileBytes(landmarks.fields().size() / landmarks.count(), landmarks.count());
}

absl::Status WriteExactLandmarks(const ExactLandmarks& landmarks, const Mesh& mesh,
                                 const std::string& path) {
  const std::span<const float> fields = landmarks.fields();
  LandmarksHeader h{};
  std::memcpy(h.magic, kLandmarksMagic, sizeof(kLandmarksMagic));
  h.version = kFormatVersion;
  h.endian = kEndianTag;
  h.mesh_fingerprint = MeshFingerprint(mesh);
  h.num_vertices = mesh.num_vertices();
  h.count = landmarks.count();
  h.slack = landmarks.slack();
  h.file_bytes = FileBytes(h.num_vertices, h.count);
  if (fields.size() != uint64_t{h.num_vertices} * h.count) {
    return absl::InvalidArgumentError(
        absl::StrFormat("%s: the landmarks hold %u values, not %u vertices times %u landmarks",
                        path, fields.size(), h.num_vertices, h.count));
  }
  h.payload_checksum = XXH3_64bits(fields.data(), fields.size_bytes());
  h.header_checksum = HeaderChecksum(h);
  ASSIGN_OR_RETURN(AtomicFileWriter file, AtomicFileWriter::Create(path));
  RETURN_IF_ERROR(file.Append(&h, sizeof(h)));
  RETURN_IF_ERROR(file.Append(fields.data(), fields.size_bytes()));
  return std::move(file).Commit();
}

absl::StatusOr<std::unique_ptr<const ExactLandmarks>> ReadExactLandmarks(const std::string& path,
                                                                         const Mesh& mesh,
                                                                         int count) {
  std::error_code ec;
  if (!std::filesystem::exists(path, ec) && !ec) {
    return absl::NotFoundError(absl::StrFormat("no file %s", path));
  }
  std::ifstream in(path, std::ios::binary);
  if (!in) return ErrnoStatus("cannot open", path);
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  in.seekg(0);
  LandmarksHeader h{};
  if (size < static_cast<std::streamoff>(sizeof(h)) ||
      !in.read(reinterpret_cast<char*>(&h), sizeof(h))) {
    return absl::DataLossError(
        absl::StrFormat("%s: %d bytes, shorter than an exact landmarks header", path, size));
  }
  RETURN_IF_ERROR(
      CheckHeader(h, kLandmarksMagic, kFormatVersion, size, "exact landmarks file", path));
  const uint64_t fingerprint = MeshFingerprint(mesh);
  if (h.num_vertices != mesh.num_vertices() || h.mesh_fingerprint != fingerprint) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s holds landmarks of another mesh (fingerprint %016x, %u vertices; this mesh %016x, "
        "%u vertices)",
        path, h.mesh_fingerprint, h.num_vertices, fingerprint, mesh.num_vertices()));
  }
  if (h.count != static_cast<uint32_t>(count)) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s holds %u landmarks, not the %d asked for", path, h.count, count));
  }
  if (h.file_bytes != FileBytes(h.num_vertices, h.count) || !(h.slack >= 0)) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes do not hold %u vertices times %u landmarks", path,
                        h.file_bytes, h.num_vertices, h.count));
  }
  std::vector<float> fields(uint64_t{h.num_vertices} * h.count);
  if (!in.read(reinterpret_cast<char*>(fields.data()), fields.size() * sizeof(float))) {
    return absl::DataLossError(absl::StrFormat("%s: read failed", path));
  }
  if (XXH3_64bits(fields.data(), fields.size() * sizeof(float)) != h.payload_checksum) {
    return absl::DataLossError(absl::StrFormat("%s: checksum mismatch in the fields", path));
  }
  return ExactLandmarks::FromFields(mesh, count, std::move(fields), h.slack);
}

}  // namespace geodesic
