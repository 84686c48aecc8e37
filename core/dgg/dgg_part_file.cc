#include "core/dgg/dgg_part_file.h"

#include <cstring>
#include <fstream>

#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/file_header.h"
#include "core/base/status.h"
#include "xxhash.h"

namespace geodesic {
namespace {

// Unchanged since version 1: CheckHeader then names an old part's version.
constexpr char kPartMagic[8] = {'G', 'E', 'O', 'D', 'P', 'R', 'T', '\0'};

// The header, then the offsets (end - begin + 1 uint64) and the edges.
struct PartHeader {
  char magic[8];
  uint32_t version;
  uint32_t endian;
  uint64_t mesh_fingerprint;
  StoredDggParams params;
  uint32_t num_vertices;
  uint32_t begin;
  uint32_t end;
  uint32_t reserved;  // zero: keeps the next field aligned, every byte defined
  uint64_t windows_created;
  uint64_t num_edges;
  uint64_t file_bytes;
  uint64_t payload_checksum;  // XXH3-64 of offsets then edges
  uint64_t header_checksum;   // XXH3-64 of this struct with this field zero
};
static_assert(sizeof(PartHeader) == 104, "no padding: every byte is checksummed");
static_assert(std::is_trivially_copyable_v<DggHalfEdge> && sizeof(DggHalfEdge) == 16);
// What every version's header starts with: magic, version, endian tag.
constexpr size_t kVersionPrefixBytes = 16;

uint64_t PartFileBytes(uint32_t begin, uint32_t end, uint64_t num_edges) {
  return sizeof(PartHeader) + (uint64_t{end - begin} + 1) * sizeof(uint64_t) +
         num_edges * sizeof(DggHalfEdge);
}

uint64_t PayloadChecksum(const DggCandidatePart& part) {
  XXH3_state_t* state = XXH3_createState();
  XXH3_64bits_reset(state);
  XXH3_64bits_update(state, part.offsets.data(), part.offsets.size() * sizeof(uint64_t));
  XXH3_64bits_update(state, part.edges.data(), part.edges.size() * sizeof(DggHalfEdge));
  const uint64_t sum = XXH3_64bits_digest(state);
  XXH3_freeState(state);
  return sum;
}

}  // namespace

absl::Status WriteDggPart(const DggCandidatePart& part, const std::string& path) {
  PartHeader h{};
  std::memcpy(h.magic, kPartMagic, sizeof(kPartMagic));
  h.version = kPartFormatVersion;
  h.endian = kEndianTag;
  h.mesh_fingerprint = part.mesh_fingerprint;
  h.params = StoredDggParams::Of(part.params);
  h.num_vertices = part.num_vertices;
  h.begin = part.begin;
  h.end = part.end;
  h.windows_created = part.windows_created;
  h.num_edges = part.edges.size();
  h.file_bytes = PartFileBytes(part.begin, part.end, h.num_edges);
  h.payload_checksum = PayloadChecksum(part);
  h.header_checksum = HeaderChecksum(h);
  auto file = AtomicFileWriter::Create(path);
  if (!file.ok()) return file.status();
  absl::Status s = file->Append(&h, sizeof(h));
  if (s.ok()) s = file->Append(part.offsets.data(), part.offsets.size() * sizeof(uint64_t));
  if (s.ok()) s = file->Append(part.edges.data(), part.edges.size() * sizeof(DggHalfEdge));
  if (!s.ok()) return s;
  return std::move(*file).Commit();
}

namespace {

// Reads the header of a part file of `size` bytes and checks it: the
// common fields (CheckHeader), then that the file's size is what its range
// and edges take.
absl::StatusOr<PartHeader> ReadHeader(std::ifstream& in, uint64_t size, const std::string& path) {
  PartHeader h{};
  in.read(reinterpret_cast<char*>(&h), sizeof(h));
  if (static_cast<size_t>(in.gcount()) < sizeof(h)) {
    // Too short for this version's header, but perhaps a whole part of
    // another version: that is the better report.
    if (static_cast<size_t>(in.gcount()) >= kVersionPrefixBytes &&
        std::memcmp(h.magic, kPartMagic, sizeof(kPartMagic)) == 0 &&
        (h.version != kPartFormatVersion || h.endian != kEndianTag)) {
      return CheckHeader(h, kPartMagic, kPartFormatVersion, size, "part file", path);
    }
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes is too short for a part file header", path, size));
  }
  RETURN_IF_ERROR(CheckHeader(h, kPartMagic, kPartFormatVersion, size, "part file", path));
  if (h.begin > h.end || h.end > h.num_vertices || h.num_edges > size / sizeof(DggHalfEdge) ||
      size != PartFileBytes(h.begin, h.end, h.num_edges)) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes do not match vertices %u..%u with %u edges", path, size,
                        h.begin, h.end, h.num_edges));
  }
  return h;
}

// Reads a part's header and offsets, checking everything but the payload
// checksum; `in` is left after the offsets.
absl::StatusOr<DggCandidatePart> ReadIndex(std::ifstream& in, const std::string& path,
                                           PartHeader& h) {
  if (!in) return ErrnoStatus("cannot open", path);
  in.seekg(0, std::ios::end);
  const std::streamoff size = in.tellg();
  in.seekg(0);
  if (size < 0 || !in) return absl::DataLossError(absl::StrFormat("%s: read failed", path));
  ASSIGN_OR_RETURN(h, ReadHeader(in, size, path));
  DggCandidatePart part;
  part.params = h.params.params();
  part.mesh_fingerprint = h.mesh_fingerprint;
  part.num_vertices = h.num_vertices;
  part.begin = h.begin;
  part.end = h.end;
  part.windows_created = h.windows_created;
  part.offsets.resize(h.end - h.begin + 1);
  in.read(reinterpret_cast<char*>(part.offsets.data()), part.offsets.size() * sizeof(uint64_t));
  if (!in) return absl::DataLossError(absl::StrFormat("%s: read failed", path));
  if (part.offsets.back() != h.num_edges) {
    return absl::DataLossError(
        absl::StrFormat("%s: the offsets end at %u, not at the %u edges held", path,
                        part.offsets.back(), h.num_edges));
  }
  return part;
}

}  // namespace

absl::StatusOr<DggCandidatePart> ReadDggPartIndex(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  PartHeader h;
  return ReadIndex(in, path, h);
}

absl::StatusOr<DggCandidatePart> ReadDggPart(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  PartHeader h;
  ASSIGN_OR_RETURN(DggCandidatePart part, ReadIndex(in, path, h));
  part.edges.resize(h.num_edges);
  in.read(reinterpret_cast<char*>(part.edges.data()), part.edges.size() * sizeof(DggHalfEdge));
  if (!in) return absl::DataLossError(absl::StrFormat("%s: read failed", path));
  if (PayloadChecksum(part) != h.payload_checksum) {
    return absl::DataLossError(absl::StrFormat("%s: checksum mismatch in the edges", path));
  }
  return part;
}

}  // namespace geodesic
