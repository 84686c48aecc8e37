// Comparing secrets (bearer tokens).
#ifndef GEODESIC_SERVER_CONSTANT_TIME_H_
#define GEODESIC_SERVER_CONSTANT_TIME_H_

#include <cstddef>
#include <string_view>

namespace geodesic::server {

// Compares in time independent of where the strings differ, so that response
// times do not leak the token.
inline bool ConstantTimeEquals(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  unsigned char diff = 0;
  for (size_t i = 0; i < a.size(); ++i) diff |= static_cast<unsigned char>(a[i] ^ b[i]);
  return diff == 0;
}

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CONSTANT_TIME_H_
