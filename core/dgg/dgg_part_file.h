// Part files of a distributed build (geodesicd build --part, geodesicd merge):
// the candidate edges of one vertex range, with the mesh fingerprint and
// parameters they were built for, checksummed and written atomically.
#ifndef GEODESIC_CORE_DGG_DGG_PART_FILE_H_
#define GEODESIC_CORE_DGG_DGG_PART_FILE_H_

#include <string>

#include "absl/status/statusor.h"
#include "core/dgg/dgg_build.h"

namespace geodesic {

// 3: the common file header (core/base/file_header.h), which adds the
// file's size; 2: the whole build record (DggParams), so a merge can refuse
// parts built with other pruning, fans or candidate rule; version 1 held
// only epsilon and pseudo vertices. The magic and the places of the version
// and endian tag never change, so a part of any version is told apart from
// a damaged one.
inline constexpr uint32_t kPartFormatVersion = 3;

absl::Status WriteDggPart(const DggCandidatePart& part, const std::string& path);

// DATA_LOSS when the file is truncated or corrupt, FAILED_PRECONDITION for
// another format version or endianness (naming both versions); messages
// name the path.
absl::StatusOr<DggCandidatePart> ReadDggPart(const std::string& path);

// The part without its edges (offsets, parameters, range), for a merge to
// check parts against each other before loading any; ReadDggPart verifies
// the edges' checksum when they are loaded.
absl::StatusOr<DggCandidatePart> ReadDggPartIndex(const std::string& path);

}  // namespace geodesic

#endif  // GEODESIC_CORE_DGG_DGG_PART_FILE_H_
