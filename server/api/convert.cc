#include "server/api/convert.h"

#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"
#include "core/base/status.h"

namespace geodesic::server {

v1::GraphSelector MakeSelector(const std::string& mesh, double epsilon, bool pseudo_vertices) {
  v1::GraphSelector out;
  out.set_mesh(mesh);
  out.set_epsilon(epsilon);
  out.set_pseudo_vertices(pseudo_vertices);
  return out;
}

v1::GraphSelector ToProto(const GraphKey& key) {
  v1::GraphSelector out = MakeSelector(key.mesh, key.params.epsilon, key.params.pseudo_vertices);
  out.set_max_error(key.max_error);
  return out;
}

void ToProto(const GraphCertificate& c, v1::GraphCertificate* out) {
  out->set_max_error_bound(c.max_error_bound);
  out->set_epsilon(c.epsilon);
  out->set_measured_max_error(c.measured_max_error);
  out->set_measured_mean_error(c.measured_mean_error);
  out->set_sources(c.sources);
  out->set_seed(c.seed);
  out->set_sound(c.sound);
  out->set_builds(c.builds);
}

void FillEcho(const GraphKey& key, const std::string& method, v1::QueryEcho* echo) {
  *echo->mutable_graph() = ToProto(key);
  echo->set_mesh(key.mesh);
  echo->set_epsilon(key.params.epsilon);
  echo->set_pseudo_vertices(key.params.pseudo_vertices);
  echo->set_method(method);
}

std::optional<SurfacePoint> PointOf(const v1::SurfacePoint& p) {
  switch (p.point_case()) {
    case v1::SurfacePoint::kVertex:
      return SurfacePoint::Vertex(p.vertex());
    case v1::SurfacePoint::kEdge:
      return SurfacePoint::Edge(p.edge().edge(), p.edge().t());
    case v1::SurfacePoint::kFace:
      return SurfacePoint::Face(p.face().face(), p.face().b0(), p.face().b1(), p.face().b2());
    default:
      return std::nullopt;
  }
}

absl::StatusOr<SurfacePoint> FromProto(const v1::SurfacePoint& p, const Mesh& mesh,
                                       const std::string& what) {
  const std::optional<SurfacePoint> out = PointOf(p);
  if (!out) return absl::InvalidArgumentError(absl::StrFormat("%s: no point given", what));
  absl::Status s = ValidateSurfacePoint(mesh, *out);
  if (!s.ok()) return absl::Status(s.code(), absl::StrFormat("%s: %s", what, s.message()));
  return *out;
}

std::string FormatPoint(const v1::SurfacePoint& p) {
  const std::optional<SurfacePoint> point = PointOf(p);
  return point ? FormatSurfacePoint(*point) : "?";
}

absl::Status PointSpecs::Add(std::string_view text) {
  ASSIGN_OR_RETURN(const SurfacePointSpec spec, ParseSurfacePointSpec(text));
  if (!spec.is_position) {
    points_.push_back(ToProto(spec.point));
    return absl::OkStatus();
  }
  v1::Vec3& position = positions_.emplace_back();
  position.set_x(spec.position.x);
  position.set_y(spec.position.y);
  position.set_z(spec.position.z);
  snapped_.push_back(points_.size());
  points_.emplace_back();
  return absl::OkStatus();
}

void PointSpecs::AddVertex(uint32_t vertex) { points_.emplace_back().set_vertex(vertex); }

v1::SnapRequest PointSpecs::SnapRequest(const std::string& mesh) const {
  v1::SnapRequest req;
  req.set_mesh(mesh);
  for (const v1::Vec3& p : positions_) *req.add_positions() = p;
  return req;
}

absl::Status PointSpecs::Snapped(const v1::SnapResponse& answer) {
  if (answer.points_size() != static_cast<int>(snapped_.size())) {
    return absl::InternalError("Snap returned a wrong number of points");
  }
  for (size_t k = 0; k < snapped_.size(); ++k) points_[snapped_[k]] = answer.points(k);
  return absl::OkStatus();
}

v1::SurfacePoint ToProto(const SurfacePoint& p) {
  v1::SurfacePoint out;
  switch (p.kind) {
    case SurfacePoint::Kind::kVertex:
      out.set_vertex(p.id);
      break;
    case SurfacePoint::Kind::kEdge:
      out.mutable_edge()->set_edge(p.id);
      out.mutable_edge()->set_t(p.t);
      break;
    case SurfacePoint::Kind::kFace:
      out.mutable_face()->set_face(p.id);
      out.mutable_face()->set_b0(p.bary[0]);
      out.mutable_face()->set_b1(p.bary[1]);
      out.mutable_face()->set_b2(p.bary[2]);
      break;
  }
  return out;
}

void ToProto(const GraphStatus& s, v1::Graph* out) {
  out->set_mesh(s.mesh);
  out->set_epsilon(s.epsilon);
  // Persisting is a building graph being written: clients see "building"
  // with phase "writing", as before the state had a name of its own.
  static const v1::GraphState kStates[kGraphStateCount] = {
      v1::GRAPH_STATE_QUEUED,    v1::GRAPH_STATE_LOADING, v1::GRAPH_STATE_BUILDING,
      v1::GRAPH_STATE_BUILDING,  v1::GRAPH_STATE_READY,   v1::GRAPH_STATE_FAILED,
      v1::GRAPH_STATE_CANCELLED, v1::GRAPH_STATE_EVICTED};
  out->set_state(kStates[static_cast<int>(s.state)]);
  out->set_phase(s.phase);
  out->set_progress(s.progress);
  out->set_error(s.error);
  out->set_bytes(s.bytes);
  out->set_landmark_bytes(s.landmark_bytes);
  out->set_mapped(s.mapped);
  out->set_from_file(s.from_file);
  out->set_nodes(s.nodes);
  out->set_edges(s.edges);
  out->set_build_seconds(s.build_seconds);
  out->set_last_used_unix_ms(s.last_used_unix_ms);
  out->set_pseudo_vertices(s.params.pseudo_vertices);
  out->set_prune_redundant(s.params.prune_redundant);
  out->set_exact_fans(s.params.exact_fans);
  out->set_candidate_rule(s.params.candidate_rule);
  out->set_estimated_bytes(s.estimated_bytes);
  out->set_estimated_seconds(s.estimated_seconds);
  out->set_max_error(s.max_error);
  if (s.certificate) ToProto(*s.certificate, out->mutable_certificate());
}

void ToProto(const MeshDiagnostics& d, v1::MeshDiagnostics* out) {
  out->set_path(d.path);
  out->set_format(d.format);
  out->set_vertices(d.vertices);
  out->set_faces(d.faces);
  out->set_edges(d.edges);
  out->set_polygons_triangulated(d.polygons_triangulated);
  out->set_components(d.components);
  out->set_boundary_loops(d.boundary_loops);
  out->set_genus(d.genus);
  out->set_isolated_vertices(d.isolated_vertices);
  out->set_duplicate_vertices(d.duplicate_vertices);
  out->set_zero_area_faces(d.zero_area_faces);
  out->set_near_degenerate_faces(d.near_degenerate_faces);
  out->set_non_manifold_edges(d.non_manifold_edges);
  out->set_non_manifold_vertices(d.non_manifold_vertices);
  out->set_faces_refused(d.faces_refused);
  out->set_bbox_diagonal(d.bbox_diagonal);
  out->set_mean_edge_length(d.mean_edge_length);
  out->set_min_edge_length(d.min_edge_length);
  out->set_anisotropy_mean(d.anisotropy_mean);
  out->set_anisotropy_p95(d.anisotropy_p95);
  out->set_anisotropy_max(d.anisotropy_max);
  out->set_saddle_vertices(d.saddle_vertices);
  out->set_boundary_vertices(d.boundary_vertices);
  out->set_manifold(d.manifold);
  out->set_load_seconds(d.load_seconds);
  out->set_mesh_error(d.mesh_error);
  out->set_json(d.ToJson());
}

MeshDiagnostics FromProto(const v1::MeshDiagnostics& m) {
  MeshDiagnostics d;
  d.path = m.path();
  d.format = m.format();
  d.vertices = m.vertices();
  d.faces = m.faces();
  d.edges = m.edges();
  d.polygons_triangulated = m.polygons_triangulated();
  d.components = m.components();
  d.boundary_loops = m.boundary_loops();
  d.genus = m.genus();
  d.isolated_vertices = m.isolated_vertices();
  d.duplicate_vertices = m.duplicate_vertices();
  d.zero_area_faces = m.zero_area_faces();
  d.near_degenerate_faces = m.near_degenerate_faces();
  d.non_manifold_edges = m.non_manifold_edges();
  d.non_manifold_vertices = m.non_manifold_vertices();
  d.faces_refused = m.faces_refused();
  d.bbox_diagonal = m.bbox_diagonal();
  d.mean_edge_length = m.mean_edge_length();
  d.min_edge_length = m.min_edge_length();
  d.anisotropy_mean = m.anisotropy_mean();
  d.anisotropy_p95 = m.anisotropy_p95();
  d.anisotropy_max = m.anisotropy_max();
  d.saddle_vertices = m.saddle_vertices();
  d.boundary_vertices = m.boundary_vertices();
  d.manifold = m.manifold();
  d.load_seconds = m.load_seconds();
  d.mesh_error = m.mesh_error();
  return d;
}

std::string DiagnosticsJsonText(const v1::MeshDiagnostics& d) {
  // Every server that fills the typed fields names the format.
  if (d.format().empty() && !d.json().empty()) return d.json();
  return FromProto(d).ToJson();
}

grpc::Status ToGrpc(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

std::string CodeName(grpc::StatusCode code) {
  return absl::StatusCodeToString(static_cast<absl::StatusCode>(code));
}

const char* StateName(v1::GraphState s) {
  switch (s) {
    case v1::GRAPH_STATE_QUEUED:
      return "queued";
    case v1::GRAPH_STATE_BUILDING:
      return "building";
    case v1::GRAPH_STATE_LOADING:
      return "loading";
    case v1::GRAPH_STATE_READY:
      return "ready";
    case v1::GRAPH_STATE_FAILED:
      return "failed";
    case v1::GRAPH_STATE_CANCELLED:
      return "cancelled";
    case v1::GRAPH_STATE_EVICTED:
      return "evicted";
    default:
      return "unknown";
  }
}

}  // namespace geodesic::server
