// A client's own input as an error message repeats it back.
#ifndef GEODESIC_SERVER_BASE_ECHO_H_
#define GEODESIC_SERVER_BASE_ECHO_H_

#include <cstddef>
#include <string>
#include <string_view>

namespace geodesic::server {

// How much of a client's own input an error message repeats back: an answer
// (and its log line) must not grow with what a client sends, and error
// messages travel in trailing metadata, which clients cap.
inline constexpr size_t kMaxEcho = 80;

// `text` itself when it has at most kMaxEcho bytes, else its first kMaxEcho
// (cut back to a whole UTF-8 character) and the full length named. For text
// the caller already quotes or escapes (a JSON value, a name in quotes).
std::string Cut(std::string_view text);

// Cut(input) with control and non-ASCII bytes escaped: raw client bytes.
std::string Echo(std::string_view input);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_BASE_ECHO_H_
