// Conversions between the API's messages and core types, shared by the
// gRPC service, the HTTP gateway and the command-line client: the graph a
// request names, surface points (messages, spec strings such as
// "f:7:0.2,0.3,0.5"), graph states, mesh diagnostics and status codes.
#ifndef GEODESIC_SERVER_CONVERT_H_
#define GEODESIC_SERVER_CONVERT_H_

#include <cstddef>
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "absl/status/statusor.h"
#include "core/mesh/mesh_diagnostics.h"
#include "core/mesh/surface_point.h"
#include "geodesic/v1/geodesic.pb.h"
#include "grpcpp/support/status.h"
#include "server/graphs/graph_key.h"

namespace geodesic::server {

// The graph a request names (RequestGraph, GetGraph, WatchGraph, CancelGraph
// and every query; also the graph a QueryEcho names): its `graph` when it is
// set, else the fields that `graph` superseded (mesh, epsilon,
// pseudo_vertices), which clients from before it send. This is the one place
// that rule lives: the service reads a request's graph only through it.
template <typename Request>
v1::GraphSelector SelectorOf(const Request& req) {
  if (req.has_graph()) return req.graph();
  v1::GraphSelector out;
  out.set_mesh(req.mesh());
  out.set_epsilon(req.epsilon());
  out.set_pseudo_vertices(req.pseudo_vertices());
  return out;
}

// A selector as clients send it (epsilon 0: the server's --default-epsilon).
v1::GraphSelector MakeSelector(const std::string& mesh, double epsilon, bool pseudo_vertices);
// The graph a key is, its epsilon the one it is built with.
v1::GraphSelector ToProto(const GraphKey& key);
// What a query's answer says about the graph that gave it and the solver
// that ran: `graph` and, for clients from before it, the fields it
// superseded.
void FillEcho(const GraphKey& key, const std::string& method, v1::QueryEcho* echo);

// The API's point as a core point, not checked against a mesh; nothing when
// the message sets no point.
std::optional<SurfacePoint> PointOf(const v1::SurfacePoint& p);
// The same, checked against `mesh`; errors name the point as `what`.
absl::StatusOr<SurfacePoint> FromProto(const v1::SurfacePoint& p, const Mesh& mesh,
                                       const std::string& what);
v1::SurfacePoint ToProto(const SurfacePoint& p);
// The point's spec text (FormatSurfacePoint); "?" when the message sets none.
std::string FormatPoint(const v1::SurfacePoint& p);

// The points of a request from their spec strings (ParseSurfacePointSpec):
// "xyz:" positions are gathered for one Snap call, whose answer then fills
// their places.
class PointSpecs {
 public:
  // INVALID_ARGUMENT saying what is wrong with the text.
  absl::Status Add(std::string_view spec);
  void AddVertex(uint32_t vertex);
  // The Snap call to make on `mesh`, when any spec was a position.
  bool has_positions() const { return !snapped_.empty(); }
  v1::SnapRequest SnapRequest(const std::string& mesh) const;
  // Puts Snap's points in the positions' places (INTERNAL if it answered a
  // wrong number of them).
  absl::Status Snapped(const v1::SnapResponse& answer);

  const std::vector<v1::SurfacePoint>& points() const { return points_; }
  std::vector<v1::SurfacePoint>& points() { return points_; }
  // The place among points() of each position, in Snap's order.
  const std::vector<size_t>& snapped() const { return snapped_; }

 private:
  std::vector<v1::SurfacePoint> points_;
  std::vector<v1::Vec3> positions_;
  std::vector<size_t> snapped_;
};

void ToProto(const GraphStatus& s, v1::Graph* out);
void ToProto(const GraphCertificate& c, v1::GraphCertificate* out);

// Every field of the diagnostics, typed, and the superseded `json` (their
// ToJson) for clients that still read it.
void ToProto(const MeshDiagnostics& d, v1::MeshDiagnostics* out);
// The typed fields back as core's struct.
MeshDiagnostics FromProto(const v1::MeshDiagnostics& d);
// The report as `geodesicd info --json` has it (without mesh_bytes), as
// JSON text: ToJson of the typed fields; the `json` field as sent by a
// server older than the typed fields (one that sets no format).
std::string DiagnosticsJsonText(const v1::MeshDiagnostics& d);

grpc::Status ToGrpc(const absl::Status& s);
// The canonical name of a code ("INVALID_ARGUMENT"): gRPC's codes are
// Abseil's.
std::string CodeName(grpc::StatusCode code);
// "ready", "building", ...: a state as the JSON views (json_views.h) and
// the CLI's text spell it; "unknown" for a value this build does not know.
const char* StateName(v1::GraphState state);

// A certified graph's certificate as a JSON object (nlohmann's json or
// ordered_json), with the keys of `geodesicd build --json`: one mapping for
// the CLI and the HTTP gateway.
template <typename Json>
Json CertificateJson(const v1::GraphCertificate& c) {
  return Json{{"max_error_bound", c.max_error_bound()},
              {"epsilon", c.epsilon()},
              {"measured_max_error", c.measured_max_error()},
              {"measured_mean_error", c.measured_mean_error()},
              {"sources", c.sources()},
              {"seed", c.seed()},
              {"sound", c.sound()},
              {"builds", c.builds()}};
}

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_CONVERT_H_
