// Byte sizes as operators write them: "6G", "512M", "1.5GiB", "123".
#ifndef GEODESIC_SERVER_BYTE_SIZE_H_
#define GEODESIC_SERVER_BYTE_SIZE_H_

#include <cstdint>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"

namespace geodesic::server {

// A number (decimals allowed) and an optional suffix K, M, G or T, alone or
// followed by B or iB, any case. The suffixes are binary (K = 1024), as
// memory and disk budgets are read against binary-sized machines.
// INVALID_ARGUMENT naming `flag` and the text otherwise.
absl::StatusOr<uint64_t> ParseByteSize(std::string_view text, std::string_view flag);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_BYTE_SIZE_H_
