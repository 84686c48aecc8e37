// A request's text as the listener reads it: header names compared without
// case, the target split into a path and query parameters, percent-decoded.
#ifndef GEODESIC_SERVER_HTTP_HTTP_REQUEST_TEXT_H_
#define GEODESIC_SERVER_HTTP_HTTP_REQUEST_TEXT_H_

#include <string>
#include <string_view>

#include "server/http/http_server.h"

namespace geodesic::server {

// Debian's Abseil has its own string_view, so header names are compared here.
bool EqualsIgnoreCase(std::string_view a, std::string_view b);
// %XX sequences become bytes (malformed ones stay as they are); in a query
// '+' is a space too.
std::string PercentDecode(std::string_view text, bool plus_is_space);
// `target`'s path and query parameters into `req`.
void SplitTarget(std::string_view target, HttpRequest* req);

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_HTTP_HTTP_REQUEST_TEXT_H_
