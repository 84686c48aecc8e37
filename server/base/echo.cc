#include "server/base/echo.h"

#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"

namespace geodesic::server {

std::string Echo(std::string_view input) {
  // Debian's Abseil has a string_view of its own.
  const absl::string_view in(input.data(), input.size());
  if (in.size() <= kMaxEcho) return absl::CHexEscape(in);
  return absl::StrFormat("%s... (%u bytes)", absl::CHexEscape(in.substr(0, kMaxEcho)), in.size());
}

}  // namespace geodesic::server
