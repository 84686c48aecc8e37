// A client's own input as an error message repeats it back.
#ifndef GEODESIC_SERVER_BASE_ECHO_H_
#define GEODESIC_SERVER_BASE_ECHO_H_

#include <cstddef>
#include <string>
#include <string_view>

namespace geodesic::server {

// How much of a client's own input an error message repeats back.
inline constexpr size_t kMaxEcho = 80;
// At most kMaxEcho characters of `input` for an error message, with
// control and non-ASCII bytes escaped and, when cut, the full length named:
// an answer (and its log line) must not grow with what a client sends.
std::string Echo(std::string_view input);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_BASE_ECHO_H_
