// What the binary files geodesicd writes (graph files, mesh snapshots) have in
// common: a fixed-size header that starts with a magic, a format version and
// an endianness tag, records the file's size, and ends with a checksum of
// itself.
#ifndef GEODESIC_CORE_BASE_FILE_HEADER_H_
#define GEODESIC_CORE_BASE_FILE_HEADER_H_

#include <cstdint>
#include <cstring>
#include <string>
#include <string_view>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "xxhash.h"

namespace geodesic {

inline constexpr uint32_t kEndianTag = 0x01020304;
inline constexpr size_t kSectionAlignment = 64;

// Where the next section starts after one that ends at `offset`.
inline uint64_t AlignToSection(uint64_t offset) {
  return (offset + kSectionAlignment - 1) / kSectionAlignment * kSectionAlignment;
}

// XXH3-64 of the header with its own checksum field zero. `Header` has the
// fields magic, version, endian, file_bytes and header_checksum.
template <typename Header>
uint64_t HeaderChecksum(Header h) {
  h.header_checksum = 0;
  return XXH3_64bits(&h, sizeof(h));
}

// Checks the common fields of a header read from a file of `size` bytes at
// `path`; `kind` names the file type in messages ("graph file"). DATA_LOSS
// for a foreign, damaged or truncated file, FAILED_PRECONDITION for another
// endianness or format version.
template <typename Header>
absl::Status CheckHeader(const Header& h, const char (&magic)[8], uint32_t version, uint64_t size,
                         std::string_view kind, const std::string& path) {
  if (std::memcmp(h.magic, magic, sizeof(magic)) != 0) {
    return absl::DataLossError(absl::StrFormat("%s is not a geodesicd %s", path, kind));
  }
  if (h.endian != kEndianTag) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s was written on a machine of other endianness", path));
  }
  if (h.version != version) {
    return absl::FailedPreconditionError(
        absl::StrFormat("%s has %s format version %u; this build reads version %u", path, kind,
                        h.version, version));
  }
  if (HeaderChecksum(h) != h.header_checksum) {
    return absl::DataLossError(absl::StrFormat("%s: header checksum mismatch", path));
  }
  if (h.file_bytes != size) {
    return absl::DataLossError(
        absl::StrFormat("%s: header says %u bytes but the file has %u", path, h.file_bytes, size));
  }
  return absl::OkStatus();
}

}  // namespace geodesic

#endif  // GEODESIC_CORE_BASE_FILE_HEADER_H_
