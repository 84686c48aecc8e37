#include "server/base/echo.h"

#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"

namespace geodesic::server {
namespace {

// The first `n` bytes of `text`, less a UTF-8 character cut in two.
std::string_view Head(std::string_view text, size_t n) {
  if (n >= text.size()) return text;
  // A continuation byte (10xxxxxx) at `n` means a character starts before it.
  while (n > 0 && (static_cast<unsigned char>(text[n]) & 0xC0) == 0x80) --n;
  return text.substr(0, n);
}

}  // namespace

std::string Cut(std::string_view text) {
  if (text.size() <= kMaxEcho) return std::string(text);
  return absl::StrFormat("%s... (%u bytes)", Head(text, kMaxEcho), text.size());
}

std::string Echo(std::string_view input) {
  // Debian's Abseil has a string_view of its own.
  const absl::string_view in(input.data(), input.size());
  if (in.size() <= kMaxEcho) return absl::CHexEscape(in);
  return absl::StrFormat("%s... (%u bytes)", absl::CHexEscape(in.substr(0, kMaxEcho)), in.size());
}

}  // namespace geodesic::server
