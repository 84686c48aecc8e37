// One JSON view of each message a person or a script reads as JSON: the
// CLI's --json and the HTTP gateway's answers print meshes and graphs
// through these, so that a field added to the proto is added here once
// (tests/server/json_views_test.cc fails until every field has its key).
//
// Templates over the JSON type: the CLI prints nlohmann's ordered_json (keys
// in this order), the gateway its plain json (keys sorted).
#ifndef GEODESIC_SERVER_API_JSON_VIEWS_H_
#define GEODESIC_SERVER_API_JSON_VIEWS_H_

#include "geodesic/v1/geodesic.pb.h"
#include "server/api/convert.h"

namespace geodesic::server {

// Every field of the Graph, by its proto name, with the state as StateName (convert.h)
// and the certificate as CertificateJson (null while there is none).
template <typename Json>
Json GraphJson(const v1::Graph& g) {
  return Json{
      {"mesh", g.mesh()},
      {"epsilon", g.epsilon()},
      {"state", StateName(g.state())},
      {"phase", g.phase()},
      {"progress", g.progress()},
      {"error", g.error()},
      {"bytes", g.bytes()},
      {"mapped", g.mapped()},
      {"from_file", g.from_file()},
      {"nodes", g.nodes()},
      {"edges", g.edges()},
      {"build_seconds", g.build_seconds()},
      {"estimated_bytes", g.estimated_bytes()},
      {"estimated_seconds", g.estimated_seconds()},
      {"landmark_bytes", g.landmark_bytes()},
      {"last_used_unix_ms", g.last_used_unix_ms()},
      {"pseudo_vertices", g.pseudo_vertices()},
      {"prune_redundant", g.prune_redundant()},
      {"exact_fans", g.exact_fans()},
      {"candidate_rule", g.candidate_rule()},
      {"max_error", g.max_error()},
      {"certificate", g.has_certificate() ? CertificateJson<Json>(g.certificate()) : Json()}};
}

// Every field of the Mesh, by its proto name, with the diagnostics as
// `geodesicd info --json` writes them (null if the server's are not JSON),
// and the counts a listing shows (vertices, faces, ...) beside them. The
// parent's keys only for a region: a whole mesh has none.
template <typename Json>
Json MeshJson(const v1::Mesh& m) {
  const v1::MeshDiagnostics& d = m.diagnostics();
  Json copies = Json::array();
  for (const v1::VertexCopy& copy : m.vertex_copies()) {
    copies.push_back(Json{{"original", copy.original()}, {"copy", copy.copy()}});
  }
  Json diagnostics = Json::parse(DiagnosticsJsonText(d), nullptr, /*allow_exceptions=*/false);
  if (diagnostics.is_discarded()) diagnostics = nullptr;
  Json out{{"name", m.name()},
           {"fingerprint", m.fingerprint()},
           {"source", m.source()},
           {"restored", m.restored()},
           {"vertices", d.vertices()},
           {"faces", d.faces()},
           {"edges", d.edges()},
           {"components", d.components()},
           {"boundary_loops", d.boundary_loops()},
           {"genus", d.genus()},
           {"bbox_diagonal", d.bbox_diagonal()},
           {"repair_non_manifold", m.repair_non_manifold()},
           {"vertex_copies", std::move(copies)},
           {"diagnostics", std::move(diagnostics)}};
  if (!m.parent().empty()) {
    out["parent"] = m.parent();
    out["parent_vertices"] = m.parent_vertices();
    out["parent_faces"] = m.parent_faces();
  }
  return out;
}

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_API_JSON_VIEWS_H_
