// The handlers of /v1/meshes and /v1/graphs: list, get, register (a file
// under --mesh-root, arrays or a file's bytes), regions, unload, geometry,
// and each mesh's graphs. Apart from the queries (routes_queries.cc) and the
// route table (http_gateway.cc) so that each stays readable on its own.
#include <string>
#include <vector>

#include "absl/strings/str_format.h"
#include "core/mesh/mesh_io.h"
#include "server/api/convert.h"
#include "server/gateway/gateway_impl.h"
#include "server/gateway/json_answers.h"
#include "server/gateway/json_requests.h"
#include "server/meshes/upload.h"

namespace geodesic::server {
// The gateway's helpers (gateway_call.h), unqualified as the handlers were
// written; this file is compiled alone, never in a unity batch.
using namespace gateway;  // NOLINT(build/namespaces)

grpc::Status HttpGateway::Impl::ListMeshes(const Call& call, const ApiRequest&, json* out) {
  v1::ListMeshesResponse resp;
  grpc::Status s = stub->ListMeshes(call.Context(), {}, &resp);
  if (!s.ok()) return s;
  json meshes = json::array();
  for (const auto& m : resp.meshes()) meshes.push_back(MeshJson(m));
  *out = {{"meshes", std::move(meshes)}};
  return s;
}

grpc::Status HttpGateway::Impl::GetMesh(const Call& call, const ApiRequest& r, json* out) {
  v1::GetMeshRequest req;
  req.set_name(r.mesh);
  v1::Mesh resp;
  grpc::Status s = stub->GetMesh(call.Context(), req, &resp);
  if (s.ok()) *out = MeshJson(resp);
  return s;
}

// POST /v1/meshes registers a mesh, as the gRPC calls do: JSON naming a
// file under --mesh-root ({"name", "path"}) or holding the mesh as arrays
// ({"name", "vertices": [[x, y, z], ...], "faces": [[i, j, k], ...]}), or
// the file's own bytes with ?name=NAME&format=obj|off|ply|stl|gii (any
// content type but JSON). Arrays and bytes go through UploadMesh, whose
// declared size and SHA-256 the gateway computes.
grpc::Status HttpGateway::Impl::RegisterMesh(const Call& call, const ApiRequest& r, json* out) {
  const HttpRequest& http = r.http;
  v1::Mesh mesh;
  grpc::Status s;
  if (!http.header("Content-Type").starts_with("application/json")) {
    if (!http.has_param("name") || !http.has_param("format")) {
      return Invalid(absl::StrFormat(
          "a mesh file as the body needs ?name=NAME&format=FORMAT, one of %s (or send JSON "
          "with \"path\", or \"vertices\" and \"faces\", and Content-Type: "
          "application/json)",
          MeshFormatList()));
    }
    v1::UploadMeshRequest first;
    first.set_name(http.param("name"));
    first.set_format(http.param("format"));
    first.set_total_bytes(http.body.size());
    first.set_sha256(Sha256Hex(http.body));
    s = Upload(call, std::move(first), http.body, {}, {}, &mesh);
  } else {
    json body;
    if (s = ParseBody(http, &body); !s.ok()) return s;
    if (s = OnlyKeys(body, kRegisterMeshKeys); !s.ok()) return s;
    auto name = body.find("name");
    if (name == body.end() || !name->is_string()) return Invalid("\"name\" must be a string");
    if (body.contains("path")) {
      // {"name", "path", "repair_non_manifold"} is RegisterMeshRequest in
      // protobuf's JSON mapping (see http_gateway.h).
      v1::RegisterMeshRequest req;
      if (s = MessageOf(body, &req); !s.ok()) return s;
      s = stub->RegisterMesh(call.Context(), req, &mesh);
    } else {
      bool repair = false;
      if (s = BoolField(body, "repair_non_manifold", &repair); !s.ok()) return s;
      v1::UploadMeshRequest first;
      first.set_name(name->get<std::string>());
      first.set_repair_non_manifold(repair);
      std::vector<double> vertices;
      std::vector<uint32_t> faces;
      if (s = Rows(body, "vertices", &vertices); !s.ok()) return s;
      if (s = Rows(body, "faces", &faces); !s.ok()) return s;
      first.set_total_bytes(vertices.size() * sizeof(double) + faces.size() * sizeof(uint32_t));
      first.set_sha256(Sha256HexOfArrays(vertices, faces));
      s = Upload(call, std::move(first), {}, vertices, faces, &mesh);
    }
  }
  if (s.ok()) *out = MeshJson(mesh);
  return s;
}

// In messages of kUploadMessageBytes, as any client sends an upload: the
// service takes no request larger than MaxRequestBytes.
grpc::Status HttpGateway::Impl::Upload(const Call& call, v1::UploadMeshRequest header,
                                       std::string_view data, const std::vector<double>& vertices,
                                       const std::vector<uint32_t>& faces, v1::Mesh* mesh) {
  auto ctx = call.Context();
  auto writer = stub->UploadMesh(ctx, mesh);
  // A failed write ends the upload; Finish says why.
  SplitUpload(std::move(header), data, vertices, faces,
              [&](const v1::UploadMeshRequest& m) { return writer->Write(m); });
  writer->WritesDone();
  return writer->Finish();
}

// POST /v1/meshes/PARENT/regions: {"name", "vertex_ids" or "face_ids"}
// is RegisterRegionRequest in protobuf's JSON mapping, its parent the path's.
grpc::Status HttpGateway::Impl::RegisterRegion(const Call& call, const ApiRequest& r, json* out) {
  v1::RegisterRegionRequest req;
  if (grpc::Status s = MessageOf(r.body, &req); !s.ok()) return s;
  req.set_parent(r.mesh);
  v1::Mesh mesh;
  grpc::Status s = stub->RegisterRegion(call.Context(), req, &mesh);
  if (s.ok()) *out = MeshJson(mesh);
  return s;
}

grpc::Status HttpGateway::Impl::UnloadMesh(const Call& call, const ApiRequest& r, json* out) {
  const std::string& name = r.mesh;
  v1::UnloadMeshRequest req;
  req.set_name(name);
  v1::UnloadMeshResponse resp;
  grpc::Status s = stub->UnloadMesh(call.Context(), req, &resp);
  if (s.ok()) *out = {{"name", name}, {"unloaded", true}};
  return s;
}

// The geometry as any gRPC client gets it, from GetGeometry: its first
// chunk names the sizes, the whole text is reserved within --memory-limit
// before any of it is written, and held until it is sent.
grpc::Status HttpGateway::Impl::Geometry(const Call& call, const ApiRequest& r, json*) {
  v1::GetMeshRequest req;
  req.set_name(r.mesh);
  grpc::ClientContext* ctx = call.Context();
  auto reader = stub->GetGeometry(ctx, req);
  v1::GeometryChunk chunk;
  if (!reader->Read(&chunk)) {
    grpc::Status s = reader->Finish();
    return s.ok() ? grpc::Status(grpc::StatusCode::INTERNAL, "GetGeometry sent no chunk") : s;
  }
  const uint64_t bytes = GeometryJson::Bound(chunk);
  if (grpc::Status s = ReserveAnswer(
          r, bytes, absl::StrFormat("the geometry of mesh '%s' as JSON", chunk.name()));
      !s.ok()) {
    ctx->TryCancel();
    return s;
  }
  GeometryJson text(chunk, bytes);
  absl::Status added;
  do {
    added = text.Add(chunk);
  } while (added.ok() && reader->Read(&chunk));
  if (!added.ok()) {
    ctx->TryCancel();
    return ToGrpc(added);
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return s;
  absl::StatusOr<std::string> body = std::move(text).Finish();
  if (!body.ok()) return ToGrpc(body.status());
  HttpResponse& res = r.raw->emplace();
  res.body = *std::move(body);
  res.content_type = "application/json";
  return grpc::Status::OK;
}

grpc::Status HttpGateway::Impl::RequestGraph(const Call& call, const ApiRequest& r, json* out) {
  v1::RequestGraphRequest req;
  if (grpc::Status s = ForGraphOf(r.mesh, r.body, &req); !s.ok()) return s;
  v1::Graph g;
  grpc::Status s = stub->RequestGraph(call.Context(), req, &g);
  if (s.ok()) *out = GraphJson(g);
  return s;
}

// GET and DELETE name the graph in the query string: ?eps=E&pseudo_vertices=true.
grpc::Status HttpGateway::Impl::GetGraph(const Call& call, const ApiRequest& r, json* out) {
  v1::GetGraphRequest req;
  if (grpc::Status s = ForGraphOfQuery(r.mesh, r.http, &req); !s.ok()) return s;
  v1::Graph g;
  grpc::Status s = stub->GetGraph(call.Context(), req, &g);
  if (s.ok()) *out = GraphJson(g);
  return s;
}

grpc::Status HttpGateway::Impl::CancelGraph(const Call& call, const ApiRequest& r, json* out) {
  v1::CancelGraphRequest req;
  if (grpc::Status s = ForGraphOfQuery(r.mesh, r.http, &req); !s.ok()) return s;
  v1::Graph g;
  grpc::Status s = stub->CancelGraph(call.Context(), req, &g);
  if (s.ok()) *out = GraphJson(g);
  return s;
}

grpc::Status HttpGateway::Impl::ListGraphs(const Call& call, const ApiRequest&, json* out) {
  v1::ListGraphsResponse resp;
  grpc::Status s = stub->ListGraphs(call.Context(), {}, &resp);
  if (!s.ok()) return s;
  json graphs = json::array();
  for (const auto& g : resp.graphs()) graphs.push_back(GraphJson(g));
  *out = {{"graphs", std::move(graphs)}};
  return s;
}

}  // namespace geodesic::server
