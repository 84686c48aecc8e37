// The daemon's log: one line per event on stderr, each with a UTC timestamp
// and a level, as text ("2026-11-24T12:00:00.123Z info graph_ready mesh=spot
// eps=0.001") or as one JSON object per line for log collectors.
//
// Events are named by a short snake_case word and carry key-value fields, so
// that both formats hold the same facts and operators can grep or parse them.
#ifndef GEODESIC_SERVER_LOG_H_
#define GEODESIC_SERVER_LOG_H_

#include <initializer_list>
#include <string>
#include <string_view>

#include "absl/status/statusor.h"
#include "absl/strings/str_cat.h"

namespace geodesic::server {

enum class LogLevel { kDebug, kInfo, kWarning, kError };
enum class LogFormat { kText, kJson };

// "debug", "info", "warning" or "error"; INVALID_ARGUMENT otherwise.
absl::StatusOr<LogLevel> ParseLogLevel(std::string_view name);
// "text" or "json"; INVALID_ARGUMENT otherwise.
absl::StatusOr<LogFormat> ParseLogFormat(std::string_view name);

// Process-wide: set once at start, before threads log.
void SetLogLevel(LogLevel level);
void SetLogFormat(LogFormat format);
bool LogEnabled(LogLevel level);

// A field's value is kept as text; numbers are formatted by the caller's
// AlphaNum conversion, which round-trips doubles.
struct LogField {
  LogField(std::string_view k, const absl::AlphaNum& v) : key(k), value(v.Piece()) {}
  std::string_view key;
  std::string value;
};

// Writes one line atomically (one write call), so concurrent events never
// interleave.
void Log(LogLevel level, std::string_view event, std::initializer_list<LogField> fields = {});

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_LOG_H_
