// The gateway's answers as JSON (json_answers.h).
#include "server/gateway/json_answers.h"

#include <algorithm>
#include <charconv>
#include <cmath>

#include "server/api/convert.h"

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

json GraphJson(const v1::Graph& g) {
  std::string state = v1::GraphState_Name(g.state());
  constexpr std::string_view kPrefix = "GRAPH_STATE_";
  if (state.starts_with(kPrefix)) state = state.substr(kPrefix.size());
  json out = {
      {"mesh", g.mesh()},
      {"eps", g.epsilon()},
      {"state", state},
      {"phase", g.phase()},
      {"progress", g.progress()},
      {"error", g.error()},
      {"bytes", g.bytes()},
      {"landmark_bytes", g.landmark_bytes()},
      {"mapped", g.mapped()},
      {"from_file", g.from_file()},
      {"nodes", g.nodes()},
      {"edges", g.edges()},
      {"build_seconds", g.build_seconds()},
      {"estimated_bytes", g.estimated_bytes()},
      {"estimated_seconds", g.estimated_seconds()},
      {"last_used_unix_ms", g.last_used_unix_ms()},
      {"pseudo_vertices", g.pseudo_vertices()},
      {"max_error", g.max_error()},
      // null for a plain graph, and while a certified one is made.
      {"certificate", g.has_certificate() ? CertificateJson<json>(g.certificate()) : json()}};
  return out;
}

json MeshJson(const v1::Mesh& m) {
  const auto& d = m.diagnostics();
  json out = {{"name", m.name()},
              {"vertices", d.vertices()},
              {"faces", d.faces()},
              {"edges", d.edges()},
              {"components", d.components()},
              {"boundary_loops", d.boundary_loops()},
              {"genus", d.genus()},
              {"bbox_diagonal", d.bbox_diagonal()},
              {"fingerprint", m.fingerprint()},
              {"source", m.source()},
              {"restored", m.restored()}};
  if (!m.parent().empty()) {
    out["parent"] = m.parent();
    out["parent_vertices"] = m.parent_vertices();
    out["parent_faces"] = m.parent_faces();
  }
  json diagnostics = json::parse(DiagnosticsJsonText(d), nullptr, false);
  if (!diagnostics.is_discarded()) out["diagnostics"] = std::move(diagnostics);
  return out;
}

uint64_t GeometryJsonBound(const Mesh& mesh) {
  constexpr uint64_t kFrame = 1024;  // keys, the name, the fingerprint
  return kFrame + 3 * uint64_t{mesh.num_vertices()} * 25 + 3 * uint64_t{mesh.num_faces()} * 11;
}

std::string GeometryJson(const std::string& name, const json& fingerprint, const Mesh& mesh,
                         uint64_t bound) {
  std::string out;
  out.reserve(bound);
  out += "{\"name\":" + Dump(json(name)) + ",\"fingerprint\":" + Dump(fingerprint) +
         ",\"positions\":[";
  const char* comma = "";
  for (const Vec3& p : mesh.positions()) {
    for (double c : {p.x, p.y, p.z}) {
      out += comma;
      AppendDouble(c, &out);
      comma = ",";
    }
  }
  out += "],\"faces\":[";
  comma = "";
  for (VertexId v : mesh.corners()) {
    out += comma;
    out += std::to_string(v);
    comma = ",";
  }
  out += "]}";
  return out;
}

}  // namespace geodesic::server::gateway
