#include "server/http_gateway.h"

#include <chrono>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <optional>
#include <sstream>
#include <thread>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/escaping.h"
#include "absl/strings/str_format.h"
#include "core/surface_point.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "grpcpp/grpcpp.h"
#include "httplib.h"
#include "nlohmann/json.hpp"
#include "server/listen_socket.h"

namespace geodesic::server {
namespace {

using json = nlohmann::json;

// The canonical name ("INVALID_ARGUMENT"): gRPC's codes are Abseil's.
std::string CodeName(grpc::StatusCode code) {
  return absl::StatusCodeToString(static_cast<absl::StatusCode>(code));
}

// FAILED_PRECONDITION means "request the graph first": the resource's state
// conflicts with the call (409), not a failed conditional header (412).
int HttpStatus(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::OK:
      return 200;
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::OUT_OF_RANGE:
      return 400;
    case grpc::StatusCode::UNAUTHENTICATED:
      return 401;
    case grpc::StatusCode::PERMISSION_DENIED:
      return 403;
    case grpc::StatusCode::NOT_FOUND:
      return 404;
    case grpc::StatusCode::ALREADY_EXISTS:
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::ABORTED:
      return 409;
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
      return 429;
    case grpc::StatusCode::CANCELLED:
      return 499;
    case grpc::StatusCode::UNIMPLEMENTED:
      return 501;
    case grpc::StatusCode::UNAVAILABLE:
      return 503;
    case grpc::StatusCode::DEADLINE_EXCEEDED:
      return 504;
    default:
      return 500;
  }
}

grpc::Status Invalid(const std::string& message) {
  return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, message);
}

grpc::Status FromAbsl(const absl::Status& s) {
  if (s.ok()) return grpc::Status::OK;
  return grpc::Status(static_cast<grpc::StatusCode>(s.code()), std::string(s.message()));
}

// JSON text of a reply. Error messages quote request paths and values, which
// need not be UTF-8: those bytes become U+FFFD instead of an exception.
std::string Dump(const json& j) { return j.dump(-1, ' ', false, json::error_handler_t::replace); }

// An offending request value as an error message quotes it: at most 80
// characters, so a huge body is not echoed back (or logged) whole.
std::string Quote(const json& j) {
  std::string text = Dump(j);
  if (text.size() > 80) text = text.substr(0, 77) + "...";
  return text;
}

void WriteError(const grpc::Status& s, httplib::Response& res) {
  res.status = HttpStatus(s.error_code());
  if (s.error_code() == grpc::StatusCode::UNAUTHENTICATED) {
    res.set_header("WWW-Authenticate", "Bearer");
  } else if (s.error_code() == grpc::StatusCode::UNAVAILABLE) {
    res.set_header("Retry-After", "1");
  }
  json body = {{"error", {{"code", CodeName(s.error_code())}, {"message", s.error_message()}}}};
  res.set_content(Dump(body), "application/json");
}

// Whether text is UTF-8, as protobuf requires of every string field (the
// JSON library's strict serialiser checks it).
bool IsUtf8(const std::string& text) {
  try {
    (void)json(text).dump();
    return true;
  } catch (const json::type_error&) {
    return false;
  }
}

// +inf (unreachable) has no JSON form: null stands for it.
json JsonDistance(double d) { return std::isfinite(d) ? json(d) : json(nullptr); }

// A call's context: the HTTP bearer token travels as the gRPC metadata the
// service checks, so a wrong or missing token fails exactly as over gRPC.
// `?timeout=SECONDS` becomes the calls' deadline, which long solves poll.
class Call {
 public:
  explicit Call(const httplib::Request& req) {
    const std::string auth = req.get_header_value("Authorization");
    for (char c : auth) {
      if (c < 0x20 || c > 0x7e) {
        status_ = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                               "the Authorization header holds non-printable characters");
        return;
      }
    }
    auth_ = auth;
    for (size_t i = 1; i < req.matches.size(); ++i) {
      if (!IsUtf8(req.matches[i])) {
        status_ = grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                               absl::StrFormat("path segment '%s' is not UTF-8",
                                               absl::CHexEscape(req.matches[i].str())));
        return;
      }
    }
    if (req.has_param("timeout")) {
      const std::string text = req.get_param_value("timeout");
      char* end = nullptr;
      const double seconds = std::strtod(text.c_str(), &end);
      if (text.empty() || end != text.c_str() + text.size() || !(seconds > 0 && seconds < 1e6)) {
        status_ = grpc::Status(
            grpc::StatusCode::INVALID_ARGUMENT,
            absl::StrFormat("query parameter timeout=%s is not a number of seconds in (0, 1e6)",
                            text));
        return;
      }
      deadline_ = std::chrono::system_clock::now() +
                  std::chrono::microseconds(static_cast<int64_t>(seconds * 1e6));
    }
  }
  // A fresh context per RPC (gRPC contexts are single-use); the deadline is
  // the whole HTTP request's.
  std::unique_ptr<grpc::ClientContext> Context() const {
    auto ctx = std::make_unique<grpc::ClientContext>();
    if (!auth_.empty()) ctx->AddMetadata("authorization", auth_);
    if (deadline_) ctx->set_deadline(*deadline_);
    return ctx;
  }
  // The deadline passed: an answer now comes too late for the client, as a
  // gRPC client's call fails once its deadline passes, whatever the server.
  bool expired() const { return deadline_ && std::chrono::system_clock::now() > *deadline_; }
  // Not OK when the request itself is unusable.
  const grpc::Status& status() const { return status_; }

 private:
  std::string auth_;
  std::optional<std::chrono::system_clock::time_point> deadline_;
  grpc::Status status_;
};

// The deepest nesting of arrays and objects in JSON text (brackets inside
// strings do not count). Reading and copying a value recurses once per
// level, so a body of 100,000 nested brackets would overflow the stack.
size_t NestingDepth(std::string_view text) {
  size_t depth = 0, deepest = 0;
  bool in_string = false, escaped = false;
  for (char c : text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
    } else if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      deepest = std::max(deepest, ++depth);
    } else if ((c == ']' || c == '}') && depth > 0) {
      --depth;
    }
  }
  return deepest;
}

constexpr size_t kMaxNesting = 64;

grpc::Status ParseBody(const httplib::Request& req, json* body) {
  if (req.body.empty()) {
    *body = json::object();
    return grpc::Status::OK;
  }
  if (NestingDepth(req.body) > kMaxNesting) {
    return Invalid(absl::StrFormat("request body nests arrays and objects deeper than %u levels",
                                   kMaxNesting));
  }
  *body = json::parse(req.body, nullptr, /*allow_exceptions=*/false);
  if (body->is_discarded()) return Invalid("request body is not valid JSON");
  if (!body->is_object()) return Invalid("request body must be a JSON object");
  return grpc::Status::OK;
}

// Epsilon from the body's "eps" (or "epsilon"); absent means the server's
// default, which the service applies to 0.
grpc::Status BodyEpsilon(const json& body, double* eps) {
  *eps = 0;
  for (const char* key : {"eps", "epsilon"}) {
    auto it = body.find(key);
    if (it == body.end() || it->is_null()) continue;
    if (!it->is_number()) return Invalid(absl::StrFormat("\"%s\" must be a number", key));
    const double value = it->get<double>();
    if (*eps != 0 && value != *eps) {
      return Invalid(absl::StrFormat("\"eps\" (%g) and \"epsilon\" (%g) disagree", *eps, value));
    }
    *eps = value;
  }
  return grpc::Status::OK;
}

grpc::Status QueryEpsilon(const httplib::Request& req, double* eps) {
  *eps = 0;
  if (!req.has_param("eps")) return grpc::Status::OK;
  const std::string text = req.get_param_value("eps");
  char* end = nullptr;
  *eps = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size()) {
    return Invalid(absl::StrFormat("query parameter eps=%s is not a number", text));
  }
  return grpc::Status::OK;
}

grpc::Status BoolField(const json& body, const char* key, bool* out) {
  *out = false;
  auto it = body.find(key);
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (!it->is_boolean()) return Invalid(absl::StrFormat("\"%s\" must be true or false", key));
  *out = it->get<bool>();
  return grpc::Status::OK;
}

// Which graph a query asks: "eps" (0: the server's default) and
// "pseudo_vertices" (the graph with pseudo vertices, a separate graph).
struct GraphChoice {
  double epsilon = 0;
  bool pseudo_vertices = false;
};

grpc::Status BodyGraph(const json& body, GraphChoice* out) {
  if (grpc::Status s = BodyEpsilon(body, &out->epsilon); !s.ok()) return s;
  return BoolField(body, "pseudo_vertices", &out->pseudo_vertices);
}

// A request for `mesh` on the graph the body chooses.
template <typename Request>
grpc::Status ForGraphOf(const std::string& mesh, const json& body, Request* req) {
  GraphChoice graph;
  if (grpc::Status s = BodyGraph(body, &graph); !s.ok()) return s;
  req->set_mesh(mesh);
  req->set_epsilon(graph.epsilon);
  req->set_pseudo_vertices(graph.pseudo_vertices);
  return grpc::Status::OK;
}

// The same from the query string: ?eps=E&pseudo_vertices=true.
grpc::Status QueryGraph(const httplib::Request& req, GraphChoice* out) {
  if (grpc::Status s = QueryEpsilon(req, &out->epsilon); !s.ok()) return s;
  out->pseudo_vertices = false;
  if (!req.has_param("pseudo_vertices")) return grpc::Status::OK;
  const std::string text = req.get_param_value("pseudo_vertices");
  if (text == "true" || text == "1") {
    out->pseudo_vertices = true;
  } else if (text != "false" && text != "0") {
    return Invalid(
        absl::StrFormat("query parameter pseudo_vertices=%s: expected true or false", text));
  }
  return grpc::Status::OK;
}

// What every query's answer says about the graph that gave it.
void AddEcho(const v1::QueryEcho& echo, json* out) {
  (*out)["eps"] = echo.epsilon();
  (*out)["method"] = echo.method();
  (*out)["pseudo_vertices"] = echo.pseudo_vertices();
}

grpc::Status ArrayField(const json& body, const char* key, const json** out) {
  auto it = body.find(key);
  if (it == body.end() || !it->is_array()) {
    return Invalid(absl::StrFormat("\"%s\" must be an array", key));
  }
  *out = &*it;
  return grpc::Status::OK;
}

std::string FormatProtoPoint(const v1::SurfacePoint& p) {
  switch (p.point_case()) {
    case v1::SurfacePoint::kVertex:
      return FormatSurfacePoint(SurfacePoint::Vertex(p.vertex()));
    case v1::SurfacePoint::kEdge:
      return FormatSurfacePoint(SurfacePoint::Edge(p.edge().edge(), p.edge().t()));
    case v1::SurfacePoint::kFace:
      return FormatSurfacePoint(
          SurfacePoint::Face(p.face().face(), p.face().b0(), p.face().b1(), p.face().b2()));
    default:
      return "";
  }
}

json GraphJson(const v1::Graph& g) {
  std::string state = v1::GraphState_Name(g.state());
  constexpr std::string_view kPrefix = "GRAPH_STATE_";
  if (state.starts_with(kPrefix)) state = state.substr(kPrefix.size());
  return {{"mesh", g.mesh()},
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
          {"last_used_unix_ms", g.last_used_unix_ms()},
          {"pseudo_vertices", g.pseudo_vertices()}};
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
  json diagnostics = json::parse(d.json(), nullptr, false);
  if (!diagnostics.is_discarded()) out["diagnostics"] = std::move(diagnostics);
  return out;
}

}  // namespace

struct HttpGateway::Impl {
  std::unique_ptr<httplib::Server> http;
  std::unique_ptr<v1::Geodesic::Stub> stub;
  const MeshRegistry* meshes = nullptr;
  HttpGatewayOptions options;
  int port = 0;
  bool tls = false;
  std::thread thread;

  // SPEC strings (or vertex ids) to points; "xyz:" positions are snapped
  // through the Snap RPC, all of a request's in one call.
  grpc::Status Resolve(const Call& call, const std::string& mesh, const std::vector<json>& specs,
                       const std::string& what, std::vector<v1::SurfacePoint>* out) {
    out->assign(specs.size(), v1::SurfacePoint());
    v1::SnapRequest snap;
    snap.set_mesh(mesh);
    std::vector<size_t> snapped;
    for (size_t i = 0; i < specs.size(); ++i) {
      const json& s = specs[i];
      if (s.is_number_unsigned()) {
        if (s.get<uint64_t>() > UINT32_MAX) {
          return grpc::Status(
              grpc::StatusCode::OUT_OF_RANGE,
              absl::StrFormat("%s %u: vertex id %s is out of range", what, i, Quote(s)));
        }
        (*out)[i].set_vertex(s.get<uint32_t>());
        continue;
      }
      if (!s.is_string()) {
        return Invalid(
            absl::StrFormat("%s %u: expected a point spec string such as \"v:12\", "
                            "got %s",
                            what, i, Quote(s)));
      }
      auto spec = ParseSurfacePointSpec(s.get<std::string>());
      if (!spec.ok()) {
        return Invalid(absl::StrFormat("%s %u: %s", what, i, spec.status().message()));
      }
      if (spec->is_position) {
        auto* p = snap.add_positions();
        p->set_x(spec->position.x);
        p->set_y(spec->position.y);
        p->set_z(spec->position.z);
        snapped.push_back(i);
        continue;
      }
      const SurfacePoint& p = spec->point;
      switch (p.kind) {
        case SurfacePoint::Kind::kVertex:
          (*out)[i].set_vertex(p.id);
          break;
        case SurfacePoint::Kind::kEdge:
          (*out)[i].mutable_edge()->set_edge(p.id);
          (*out)[i].mutable_edge()->set_t(p.t);
          break;
        case SurfacePoint::Kind::kFace:
          (*out)[i].mutable_face()->set_face(p.id);
          (*out)[i].mutable_face()->set_b0(p.bary[0]);
          (*out)[i].mutable_face()->set_b1(p.bary[1]);
          (*out)[i].mutable_face()->set_b2(p.bary[2]);
          break;
      }
    }
    if (snapped.empty()) return grpc::Status::OK;
    v1::SnapResponse points;
    grpc::Status s = stub->Snap(call.Context().get(), snap, &points);
    if (!s.ok()) return s;
    if (points.points_size() != static_cast<int>(snapped.size())) {
      return grpc::Status(grpc::StatusCode::INTERNAL, "Snap returned a wrong number of points");
    }
    for (size_t k = 0; k < snapped.size(); ++k) (*out)[snapped[k]] = points.points(k);
    return grpc::Status::OK;
  }

  grpc::Status Specs(const Call& call, const std::string& mesh, const json& body, const char* key,
                     const std::string& what, std::vector<v1::SurfacePoint>* out) {
    const json* array;
    if (grpc::Status s = ArrayField(body, key, &array); !s.ok()) return s;
    return Resolve(call, mesh, std::vector<json>(array->begin(), array->end()), what, out);
  }

  grpc::Status ListMeshes(const Call& call, json* out) {
    v1::ListMeshesResponse resp;
    grpc::Status s = stub->ListMeshes(call.Context().get(), {}, &resp);
    if (!s.ok()) return s;
    json meshes = json::array();
    for (const auto& m : resp.meshes()) meshes.push_back(MeshJson(m));
    *out = {{"meshes", std::move(meshes)}};
    return s;
  }

  grpc::Status GetMesh(const Call& call, const std::string& name, json* out) {
    v1::GetMeshRequest req;
    req.set_name(name);
    v1::Mesh resp;
    grpc::Status s = stub->GetMesh(call.Context().get(), req, &resp);
    if (s.ok()) *out = MeshJson(resp);
    return s;
  }

  // Geometry has no RPC: GetMesh authorises the call and names a missing
  // mesh, then the registry's arrays are sent as they are, in file order,
  // so that a face id and its barycentrics mean the same on both sides.
  grpc::Status Geometry(const Call& call, const std::string& name, json* out) {
    json info;
    if (grpc::Status s = GetMesh(call, name, &info); !s.ok()) return s;
    auto m = meshes->Get(name);
    if (!m.ok()) return FromAbsl(m.status());
    const Mesh& mesh = *(*m)->mesh;
    std::vector<double> positions;
    positions.reserve(3 * mesh.num_vertices());
    for (const Vec3& p : mesh.positions()) {
      positions.push_back(p.x);
      positions.push_back(p.y);
      positions.push_back(p.z);
    }
    *out = {{"name", name},
            {"fingerprint", info["fingerprint"]},
            {"positions", std::move(positions)},
            {"faces", mesh.corners()}};
    return grpc::Status::OK;
  }

  grpc::Status RequestGraph(const Call& call, const std::string& mesh, const json& body,
                            json* out) {
    v1::RequestGraphRequest req;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    v1::Graph g;
    grpc::Status s = stub->RequestGraph(call.Context().get(), req, &g);
    if (s.ok()) *out = GraphJson(g);
    return s;
  }

  grpc::Status GetGraph(const Call& call, const std::string& mesh, const httplib::Request& http,
                        bool cancel, json* out) {
    GraphChoice graph;
    if (grpc::Status s = QueryGraph(http, &graph); !s.ok()) return s;
    v1::Graph g;
    grpc::Status s;
    if (cancel) {
      v1::CancelGraphRequest req;
      req.set_mesh(mesh);
      req.set_epsilon(graph.epsilon);
      req.set_pseudo_vertices(graph.pseudo_vertices);
      s = stub->CancelGraph(call.Context().get(), req, &g);
    } else {
      v1::GetGraphRequest req;
      req.set_mesh(mesh);
      req.set_epsilon(graph.epsilon);
      req.set_pseudo_vertices(graph.pseudo_vertices);
      s = stub->GetGraph(call.Context().get(), req, &g);
    }
    if (s.ok()) *out = GraphJson(g);
    return s;
  }

  grpc::Status ListGraphs(const Call& call, json* out) {
    v1::ListGraphsResponse resp;
    grpc::Status s = stub->ListGraphs(call.Context().get(), {}, &resp);
    if (!s.ok()) return s;
    json graphs = json::array();
    for (const auto& g : resp.graphs()) graphs.push_back(GraphJson(g));
    *out = {{"graphs", std::move(graphs)}};
    return s;
  }

  grpc::Status Distance(const Call& call, const std::string& mesh, const json& body, json* out) {
    v1::DistanceRequest req;
    bool with_path;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    if (grpc::Status s = BoolField(body, "path", &with_path); !s.ok()) return s;
    req.set_with_path(with_path);
    const json* pairs;
    if (grpc::Status s = ArrayField(body, "pairs", &pairs); !s.ok()) return s;
    std::vector<json> ends;
    for (size_t i = 0; i < pairs->size(); ++i) {
      const json& pair = (*pairs)[i];
      if (!pair.is_array() || pair.size() != 2) {
        return Invalid(
            absl::StrFormat("pair %u: expected [\"SPEC\", \"SPEC\"], got %s", i, Quote(pair)));
      }
      ends.push_back(pair[0]);
      ends.push_back(pair[1]);
    }
    std::vector<v1::SurfacePoint> points;
    if (grpc::Status s = Resolve(call, mesh, ends, "pair end", &points); !s.ok()) return s;
    for (size_t i = 0; i < points.size(); i += 2) {
      auto* pair = req.add_pairs();
      *pair->mutable_from() = points[i];
      *pair->mutable_to() = points[i + 1];
    }
    v1::DistanceResponse resp;
    grpc::Status s = stub->Distance(call.Context().get(), req, &resp);
    if (!s.ok()) return s;
    json distances = json::array(), paths = json::array();
    for (const auto& r : resp.results()) {
      distances.push_back(r.reachable() ? JsonDistance(r.distance()) : json(nullptr));
      if (!with_path) continue;
      json path = json::array();
      for (const auto& p : r.path().points()) {
        path.push_back({p.xyz().x(), p.xyz().y(), p.xyz().z()});
      }
      paths.push_back(std::move(path));
    }
    *out = {{"distances", std::move(distances)}};
    AddEcho(resp.echo(), out);
    if (with_path) (*out)["paths"] = std::move(paths);
    return s;
  }

  grpc::Status Field(const Call& call, const std::string& mesh, const json& body, json* out) {
    v1::DistanceFieldRequest req;
    bool nearest;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    if (grpc::Status s = BoolField(body, "nearest_source", &nearest); !s.ok()) return s;
    req.set_nearest_source(nearest);
    if (auto it = body.find("max_distance"); it != body.end() && !it->is_null()) {
      if (!it->is_number()) return Invalid("\"max_distance\" must be a number");
      req.set_max_distance(it->get<double>());
    }
    if (auto it = body.find("method"); it != body.end() && !it->is_null()) {
      if (!it->is_string()) return Invalid("\"method\" must be \"lc\" or \"dijkstra\"");
      req.set_method(it->get<std::string>());
    }
    if (auto it = body.find("targets"); it != body.end() && !it->is_null()) {
      if (!it->is_array()) return Invalid("\"targets\" must be an array of vertex ids");
      for (size_t i = 0; i < it->size(); ++i) {
        const json& t = (*it)[i];
        if (!t.is_number_unsigned() || t.get<uint64_t>() > UINT32_MAX) {
          return Invalid(absl::StrFormat("target %u: %s is not a vertex id", i, Quote(t)));
        }
        req.add_targets(t.get<uint32_t>());
      }
    }
    std::vector<v1::SurfacePoint> sources;
    if (grpc::Status s = Specs(call, mesh, body, "sources", "source", &sources); !s.ok()) return s;
    for (auto& p : sources) *req.add_sources() = std::move(p);
    auto ctx = call.Context();
    auto reader = stub->DistanceField(ctx.get(), req);
    std::vector<double> values;
    std::vector<uint32_t> nearest_source;
    v1::QueryEcho echo;
    v1::DistanceFieldChunk chunk;
    while (reader->Read(&chunk)) {
      if (chunk.has_echo()) echo = chunk.echo();
      if (values.size() < chunk.total()) values.resize(chunk.total());
      if (nearest && nearest_source.size() < chunk.total()) nearest_source.resize(chunk.total());
      if (chunk.offset() + chunk.values_size() > values.size()) {
        return grpc::Status(grpc::StatusCode::INTERNAL, "field chunk beyond the field's total");
      }
      for (int i = 0; i < chunk.values_size(); ++i) values[chunk.offset() + i] = chunk.values(i);
      for (int i = 0; i < chunk.nearest_source_size() && nearest; ++i) {
        nearest_source[chunk.offset() + i] = chunk.nearest_source(i);
      }
    }
    grpc::Status s = reader->Finish();
    if (!s.ok()) return s;
    json distances = json::array();
    for (double d : values) distances.push_back(JsonDistance(d));
    *out = {{"distances", std::move(distances)}};
    AddEcho(echo, out);
    if (nearest) (*out)["nearest_source"] = nearest_source;
    return s;
  }

  grpc::Status Matrix(const Call& call, const std::string& mesh, const json& body, json* out) {
    v1::MatrixRequest req;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    std::vector<v1::SurfacePoint> sources, targets;
    if (grpc::Status s = Specs(call, mesh, body, "sources", "source", &sources); !s.ok()) return s;
    if (grpc::Status s = Specs(call, mesh, body, "targets", "target", &targets); !s.ok()) return s;
    for (auto& p : sources) *req.add_sources() = std::move(p);
    for (auto& p : targets) *req.add_targets() = std::move(p);
    v1::MatrixResponse resp;
    grpc::Status s = stub->Matrix(call.Context().get(), req, &resp);
    if (!s.ok()) return s;
    if (static_cast<uint64_t>(resp.rows()) * resp.cols() !=
        static_cast<uint64_t>(resp.distances_size())) {
      return grpc::Status(grpc::StatusCode::INTERNAL, "matrix size does not match rows x cols");
    }
    json rows = json::array();
    for (uint32_t r = 0; r < resp.rows(); ++r) {
      json row = json::array();
      for (uint32_t c = 0; c < resp.cols(); ++c) {
        row.push_back(JsonDistance(resp.distances(r * resp.cols() + c)));
      }
      rows.push_back(std::move(row));
    }
    *out = {{"distances", std::move(rows)}};
    AddEcho(resp.echo(), out);
    return s;
  }

  grpc::Status Sample(const Call& call, const std::string& mesh, const json& body, json* out) {
    v1::SamplePointsRequest req;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    auto count = body.find("count");
    if (count == body.end() || !count->is_number_unsigned() ||
        count->get<uint64_t>() > UINT32_MAX) {
      return Invalid("\"count\" must be a number of points, at least 1");
    }
    req.set_count(count->get<uint32_t>());
    if (auto seed = body.find("seed"); seed != body.end() && !seed->is_null()) {
      if (!seed->is_number_unsigned()) return Invalid("\"seed\" must be a non-negative integer");
      req.set_seed(seed->get<uint64_t>());
    }
    v1::SamplePointsResponse resp;
    grpc::Status s = stub->SamplePoints(call.Context().get(), req, &resp);
    if (!s.ok()) return s;
    *out = {{"vertices", resp.vertices()},
            {"covering_radius", JsonDistance(resp.covering_radius())}};
    AddEcho(resp.echo(), out);
    return s;
  }

  grpc::Status Snap(const Call& call, const std::string& mesh, const json& body, json* out) {
    const json* positions;
    if (grpc::Status s = ArrayField(body, "positions", &positions); !s.ok()) return s;
    v1::SnapRequest req;
    req.set_mesh(mesh);
    for (size_t i = 0; i < positions->size(); ++i) {
      const json& p = (*positions)[i];
      if (!p.is_array() || p.size() != 3 || !p[0].is_number() || !p[1].is_number() ||
          !p[2].is_number()) {
        return Invalid(absl::StrFormat("position %u: expected [x, y, z], got %s", i, Quote(p)));
      }
      auto* q = req.add_positions();
      q->set_x(p[0].get<double>());
      q->set_y(p[1].get<double>());
      q->set_z(p[2].get<double>());
    }
    v1::SnapResponse resp;
    grpc::Status s = stub->Snap(call.Context().get(), req, &resp);
    if (!s.ok()) return s;
    json points = json::array();
    for (const auto& p : resp.points()) points.push_back(FormatProtoPoint(p));
    json distances = json::array();
    for (double d : resp.distances()) distances.push_back(JsonDistance(d));
    *out = {{"points", std::move(points)}, {"distances", std::move(distances)}};
    return s;
  }
};

namespace {

using MeshHandler = std::function<grpc::Status(const Call&, const std::string& mesh,
                                               const httplib::Request&, json* out)>;

void Reply(const httplib::Request& req, httplib::Response& res,
           const std::function<grpc::Status(const Call&, json*)>& handle) {
  Call call(req);
  json out;
  grpc::Status s = call.status().ok() ? handle(call, &out) : call.status();
  if (s.ok() && call.expired()) {
    s = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the request's timeout passed");
  }
  if (!s.ok()) return WriteError(s, res);
  res.set_header("Cache-Control", "no-store");
  res.set_content(Dump(out), "application/json");
}

// Handlers of POST bodies: the body is parsed before the RPC.
std::function<grpc::Status(const Call&, json*)> WithBody(
    const httplib::Request& req,
    const std::function<grpc::Status(const Call&, const json&, json*)>& handle) {
  return [&req, handle](const Call& call, json* out) {
    json body;
    if (grpc::Status s = ParseBody(req, &body); !s.ok()) return s;
    return handle(call, body, out);
  };
}

}  // namespace

std::string FindWebRoot() {
  std::vector<std::filesystem::path> candidates;
  if (const char* dir = std::getenv("GEODESIC_WEB_DIR"); dir && *dir) candidates.push_back(dir);
  std::error_code ec;
  auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (!ec) {
    // build/bin/geodesicd -> source tree's server/web; installed: ../share.
    candidates.push_back(exe.parent_path() / "../../server/web");
    candidates.push_back(exe.parent_path() / "../share/geodesicd/web");
  }
  candidates.push_back("/usr/share/geodesicd/web");
  for (const auto& c : candidates) {
    if (std::filesystem::exists(c / "index.html")) {
      return std::filesystem::weakly_canonical(c).string();
    }
  }
  return "";
}

HttpGateway::HttpGateway(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

HttpGateway::~HttpGateway() {
  if (impl_ && impl_->http) {
    impl_->http->stop();
    if (impl_->thread.joinable()) impl_->thread.join();
  }
}

int HttpGateway::port() const { return impl_->port; }
bool HttpGateway::tls() const { return impl_->tls; }

absl::StatusOr<std::unique_ptr<HttpGateway>> HttpGateway::Start(const HttpGatewayOptions& options,
                                                                grpc::Server* grpc_server,
                                                                const MeshRegistry* meshes) {
  const auto colon = options.listen.rfind(':');
  char* end = nullptr;
  const long port =
      colon == std::string::npos ? -1 : std::strtol(options.listen.c_str() + colon + 1, &end, 10);
  if (colon == std::string::npos || end != options.listen.c_str() + options.listen.size() ||
      port < 0 || port > 65535) {
    return absl::InvalidArgumentError(
        absl::StrFormat("--http-listen %s: expected HOST:PORT", options.listen));
  }
  std::string host = options.listen.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->meshes = meshes;
  if (options.tls_cert.empty() != options.tls_key.empty()) {
    return absl::InvalidArgumentError("HTTP TLS needs both a certificate and a key");
  }
  if (!options.tls_cert.empty()) {
    auto ssl = std::make_unique<httplib::SSLServer>(
        options.tls_cert.c_str(), options.tls_key.c_str(),
        options.tls_client_ca.empty() ? nullptr : options.tls_client_ca.c_str());
    if (!ssl->is_valid()) {
      return absl::InvalidArgumentError(absl::StrFormat(
          "HTTP TLS: cannot load certificate %s or key %s%s", options.tls_cert, options.tls_key,
          options.tls_client_ca.empty() ? "" : " or CA " + options.tls_client_ca));
    }
    impl->http = std::move(ssl);
    impl->tls = true;
  } else {
    impl->http = std::make_unique<httplib::Server>();
  }
  grpc::ChannelArguments args;
  // Fields and matrices of large meshes exceed gRPC's 4 MiB default; the
  // service allows 64 MiB each way.
  args.SetMaxReceiveMessageSize(64 << 20);
  args.SetMaxSendMessageSize(64 << 20);
  impl->stub = v1::Geodesic::NewStub(grpc_server->InProcessChannel(args));

  httplib::Server& http = *impl->http;
  Impl* g = impl.get();
  http.set_payload_max_length(options.max_body_bytes);
  http.set_file_extension_and_mimetype_mapping("js", "text/javascript");
  http.set_file_extension_and_mimetype_mapping("json", "application/json");
  if (std::filesystem::exists(options.three_root)) {
    http.set_mount_point("/three", options.three_root);
  }
  const std::string web_root = options.web_root.empty() ? FindWebRoot() : options.web_root;
  if (!web_root.empty()) http.set_mount_point("/", web_root);
  http.set_error_handler([max = options.max_body_bytes, web_root](const httplib::Request& req,
                                                                  httplib::Response& res) {
    if (!res.body.empty()) return;
    if (res.status == 413 &&
        req.get_header_value("Content-Type").starts_with("application/x-www-form-urlencoded")) {
      // The HTTP library caps form bodies at 8 KiB whatever our limit is.
      WriteError(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                              "a body sent as application/x-www-form-urlencoded (curl -d's "
                              "default) is limited to 8192 bytes; send it with Content-Type: "
                              "application/json"),
                 res);
      res.status = 413;
    } else if (res.status == 413) {
      WriteError(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                              absl::StrFormat("request body over the limit of %u bytes", max)),
                 res);
      res.status = 413;
    } else if (res.status == 404) {
      WriteError(
          grpc::Status(grpc::StatusCode::NOT_FOUND,
                       web_root.empty() && !req.path.starts_with("/v1/")
                           ? "the viewer's files were not found (set GEODESIC_WEB_DIR)"
                           : absl::StrFormat("no such resource: %s %s", req.method, req.path)),
          res);
    } else {
      const int status = res.status;
      WriteError(grpc::Status(grpc::StatusCode::INVALID_ARGUMENT,
                              absl::StrFormat("HTTP %d on %s %s", status, req.method, req.path)),
                 res);
      res.status = status;
    }
  });
  http.set_exception_handler(
      [](const httplib::Request&, httplib::Response& res, std::exception_ptr ep) {
        // Type checks precede every JSON read; this is the last guard.
        std::string what = "internal error";
        grpc::StatusCode code = grpc::StatusCode::INTERNAL;
        try {
          std::rethrow_exception(ep);
        } catch (const json::exception& e) {
          code = grpc::StatusCode::INVALID_ARGUMENT;
          what = e.what();
        } catch (const std::exception& e) {
          what = e.what();
        } catch (...) {
        }
        WriteError(grpc::Status(code, what), res);
      });

  http.Get("/v1/openapi.json", [web_root](const httplib::Request&, httplib::Response& res) {
    std::ifstream in(std::filesystem::path(web_root) / "openapi.json");
    std::stringstream text;
    if (web_root.empty() || !(text << in.rdbuf())) {
      return WriteError(grpc::Status(grpc::StatusCode::NOT_FOUND, "openapi.json not installed"),
                        res);
    }
    res.set_content(text.str(), "application/json");
  });
  http.Get("/v1/meshes", [g](const httplib::Request& req, httplib::Response& res) {
    Reply(req, res, [g](const Call& call, json* out) { return g->ListMeshes(call, out); });
  });
  http.Get("/v1/graphs", [g](const httplib::Request& req, httplib::Response& res) {
    Reply(req, res, [g](const Call& call, json* out) { return g->ListGraphs(call, out); });
  });
  http.Get(R"(/v1/meshes/([^/]+))", [g](const httplib::Request& req, httplib::Response& res) {
    const std::string mesh = req.matches[1];
    Reply(req, res, [&](const Call& call, json* out) { return g->GetMesh(call, mesh, out); });
  });
  http.Get(
      R"(/v1/meshes/([^/]+)/geometry)", [g](const httplib::Request& req, httplib::Response& res) {
        const std::string mesh = req.matches[1];
        Reply(req, res, [&](const Call& call, json* out) { return g->Geometry(call, mesh, out); });
      });
  http.Get(R"(/v1/meshes/([^/]+)/graph)", [g](const httplib::Request& req, httplib::Response& res) {
    const std::string mesh = req.matches[1];
    Reply(req, res,
          [&](const Call& call, json* out) { return g->GetGraph(call, mesh, req, false, out); });
  });
  http.Delete(
      R"(/v1/meshes/([^/]+)/graph)", [g](const httplib::Request& req, httplib::Response& res) {
        const std::string mesh = req.matches[1];
        Reply(req, res,
              [&](const Call& call, json* out) { return g->GetGraph(call, mesh, req, true, out); });
      });
  using PostHandler = grpc::Status (Impl::*)(const Call&, const std::string&, const json&, json*);
  const std::pair<const char*, PostHandler> posts[] = {
      {R"(/v1/meshes/([^/]+)/graph)", &Impl::RequestGraph},
      {R"(/v1/meshes/([^/]+)/distance)", &Impl::Distance},
      {R"(/v1/meshes/([^/]+)/field)", &Impl::Field},
      {R"(/v1/meshes/([^/]+)/matrix)", &Impl::Matrix},
      {R"(/v1/meshes/([^/]+)/snap)", &Impl::Snap},
      {R"(/v1/meshes/([^/]+)/sample)", &Impl::Sample},
  };
  for (const auto& [pattern, handler] : posts) {
    http.Post(pattern, [g, handler = handler](const httplib::Request& req, httplib::Response& res) {
      const std::string mesh = req.matches[1];
      Reply(req, res, WithBody(req, [&](const Call& call, const json& body, json* out) {
              return (g->*handler)(call, mesh, body, out);
            }));
    });
  }

  http.set_socket_options(ExclusiveListenSocket);
  if (port == 0) {
    impl->port = http.bind_to_any_port(host);
  } else if (http.bind_to_port(host, static_cast<int>(port))) {
    impl->port = static_cast<int>(port);
  }
  if (impl->port <= 0) {
    return absl::UnavailableError(absl::StrFormat("cannot listen on %s", options.listen));
  }
  impl->thread = std::thread([g] { g->http->listen_after_bind(); });
  return std::unique_ptr<HttpGateway>(new HttpGateway(std::move(impl)));
}

}  // namespace geodesic::server
