#include "core/dgg/dgg_part_file.h"

#include <cstring>
#include <fstream>

#include "absl/strings/str_format.h"
#include "core/base/atomic_file.h"
#include "core/base/status.h"
#include "xxhash.h"

namespace geodesic {
namespace {

constexpr char kMagic[8] = {'G', 'E', 'O', 'D', 'P', 'R', 'T', '\0'};
constexpr uint32_t kEndianTag = 0x01020304;

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
  uint64_t payload_checksum;  // XXH3-64 of offsets then edges
  uint64_t header_checksum;   // XXH3-64 of this struct with this field zero
};
static_assert(std::is_trivially_copyable_v<DggHalfEdge> && sizeof(DggHalfEdge) == 16);

uint64_t HeaderChecksum(PartHeader h) {
  h.header_checksum = 0;
  return XXH3_64bits(&h, sizeof(h));
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
  std::memcpy(h.magic, kMagic, sizeof(kMagic));
  h.version = kPartFormatVersion;
  h.endian = kEndianTag;
  h.mesh_fingerprint = part.mesh_fingerprint;
  h.params = StoredDggParams::Of(part.params);
  h.num_vertices = part.num_vertices;
  h.begin = part.begin;
  h.end = part.end;
  h.windows_created = part.windows_created;
  h.num_edges = part.edges.size();
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

// Reads a part's header and offsets, checking everything but the payload
// checksum; `in` is left after the offsets.
absl::StatusOr<DggCandidatePart> ReadIndex(std::ifstream& in, const std::string& path,
                                           PartHeader& h) {
  if (!in) return ErrnoStatus("cannot open", path);
  if (!in.read(reinterpret_cast<char*>(&h), sizeof(h))) {
    return absl::DataLossError(absl::StrFormat("%s is too short for a part file header", path));
  }
  if (std::memcmp(h.magic, kMagic, sizeof(kMagic)) != 0) {
    return absl::DataLossError(absl::StrFormat("%s is not a geodesicd part file", path));
  }
  if (h.version != kPartFormatVersion || h.endian != kEndianTag) {
    return absl::FailedPreconditionError(absl::StrFormat(
        "%s has part format version %u (endian tag %x); this build reads version %u", path,
        h.version, h.endian, kPartFormatVersion));
  }
  if (HeaderChecksum(h) != h.header_checksum) {
    return absl::DataLossError(absl::StrFormat("%s: header checksum mismatch", path));
  }
  in.seekg(0, std::ios::end);
  const uint64_t size = in.tellg();
  if (h.begin > h.end || h.end > h.num_vertices ||
      size != sizeof(h) + (uint64_t{h.end - h.begin} + 1) * sizeof(uint64_t) +
                  h.num_edges * sizeof(DggHalfEdge)) {
    return absl::DataLossError(
        absl::StrFormat("%s: %u bytes do not match vertices %u..%u with %u edges", path, size,
                        h.begin, h.end, h.num_edges));
  }
  DggCandidatePart part;
  part.params = h.params.params();
  part.mesh_fingerprint = h.mesh_fingerprint;
  part.num_vertices = h.num_vertices;
  part.begin = h.begin;
  part.end = h.end;
  part.windows_created = h.windows_created;
  part.offsets.resize(h.end - h.begin + 1);
  in.seekg(sizeof(h));
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
