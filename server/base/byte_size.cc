#include "server/base/byte_size.h"

#include <cmath>
#include <string>

#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_format.h"

namespace geodesic::server {

absl::StatusOr<uint64_t> ParseByteSize(std::string_view text, std::string_view flag) {
  std::string lower = absl::AsciiStrToLower(std::string(text));
  absl::StripAsciiWhitespace(&lower);
  size_t end = 0;
  while (end < lower.size() && (absl::ascii_isdigit(lower[end]) || lower[end] == '.')) ++end;
  std::string suffix = lower.substr(end);
  for (const char* unit : {"ib", "b"}) {
    if (suffix.size() > std::string(unit).size() && absl::EndsWith(suffix, unit)) {
      suffix.resize(suffix.size() - std::string(unit).size());
      break;
    }
  }
  int shift = -1;
  if (suffix.empty() || suffix == "b") shift = 0;
  if (suffix == "k") shift = 10;
  if (suffix == "m") shift = 20;
  if (suffix == "g") shift = 30;
  if (suffix == "t") shift = 40;
  double number = 0;
  if (end == 0 || shift < 0 || !absl::SimpleAtod(lower.substr(0, end), &number) ||
      !std::isfinite(number)) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "%s: '%s' is not a size (examples: 123, 64K, 512M, 6G, 1.5GiB)", flag, text));
  }
  const double bytes = std::round(number * std::ldexp(1.0, shift));
  if (bytes >= 18446744073709551616.0) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: '%s' is too large", flag, text));
  }
  return static_cast<uint64_t>(bytes);
}

}  // namespace geodesic::server
