// The gateway's answers as JSON (json_answers.h).
#include "server/gateway/json_answers.h"

#include <algorithm>
#include <charconv>
#include <cmath>

#include "absl/strings/ascii.h"
#include "server/api/json_views.h"

namespace geodesic::server::gateway {
namespace {

// A double as the JSON library writes it: the shortest text that reads back
// the same, with ".0" on an integer so that it stays a float to readers.
void AppendDouble(double value, std::string* out) {
  char text[32];
  const auto end = std::to_chars(text, text + sizeof text, value).ptr;
  out->append(text, end);
  if (std::find_if(text, end, [](char c) { return c == '.' || c == 'e' || c == 'n'; }) == end) {
    out->append(".0");
  }
}

}  // namespace

json JsonDistance(double d) { return std::isfinite(d) ? json(d) : json(nullptr); }

void AddEcho(const v1::QueryEcho& echo, json* out) {
  const v1::GraphSelector graph = SelectorOf(echo);
  (*out)["eps"] = graph.epsilon();
  (*out)["method"] = echo.method();
  (*out)["pseudo_vertices"] = graph.pseudo_vertices();
  if (graph.max_error() > 0) (*out)["max_error"] = graph.max_error();
}

// The shared views (api/json_views.h), with what HTTP v1 clients were
// promised before them: the state in capitals and epsilon also as "eps".
json GraphJson(const v1::Graph& g) {
  json out = server::GraphJson<json>(g);
  out["state"] = absl::AsciiStrToUpper(StateName(g.state()));
  out["eps"] = g.epsilon();
  return out;
}

json MeshJson(const v1::Mesh& m) { return server::MeshJson<json>(m); }

uint64_t GeometryJson::Bound(const v1::GeometryChunk& first) {
  constexpr uint64_t kFrame = 1024;  // keys, the fingerprint
  return kFrame + 2 * first.name().size() + 3 * first.total_vertices() * 25 +
         3 * first.total_faces() * 11;
}

GeometryJson::GeometryJson(const v1::GeometryChunk& first, uint64_t bound)
    : vertex_values_(3 * first.total_vertices()), face_values_(3 * first.total_faces()) {
  text_.reserve(bound);
  text_ += "{\"name\":" + Dump(json(first.name())) +
           ",\"fingerprint\":" + Dump(json(first.fingerprint())) + ",\"positions\":[";
}

absl::Status GeometryJson::Add(const v1::GeometryChunk& chunk) {
  // The stream's order is the proto's: every vertex, then every face.
  if (uint64_t(chunk.vertices_size()) > vertex_values_) {
    return absl::InternalError("geometry chunk with vertices past the total or after the faces");
  }
  for (double c : chunk.vertices()) {
    if (!first_value_) text_ += ',';
    first_value_ = false;
    AppendDouble(c, &text_);
  }
  vertex_values_ -= chunk.vertices_size();
  if (chunk.faces_size() == 0) return absl::OkStatus();
  if (vertex_values_ > 0 || uint64_t(chunk.faces_size()) > face_values_) {
    return absl::InternalError(
        "geometry chunk with faces before the last vertex or past the total");
  }
  if (!faces_begun_) {
    text_ += "],\"faces\":[";
    faces_begun_ = true;
    first_value_ = true;
  }
  for (uint32_t v : chunk.faces()) {
    if (!first_value_) text_ += ',';
    first_value_ = false;
    text_ += std::to_string(v);
  }
  face_values_ -= chunk.faces_size();
  return absl::OkStatus();
}

absl::StatusOr<std::string> GeometryJson::Finish() && {
  if (vertex_values_ > 0 || face_values_ > 0) {
    return absl::InternalError("geometry stream ended before its totals");
  }
  text_ += faces_begun_ ? "]}" : "],\"faces\":[]}";
  return std::move(text_);
}

}  // namespace geodesic::server::gateway
