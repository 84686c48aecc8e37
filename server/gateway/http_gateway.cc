#include "server/gateway/http_gateway.h"

#include <algorithm>
#include <charconv>
#include <chrono>
#include <cmath>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <map>
#include <optional>
#include <set>
#include <sstream>
#include <variant>
#include <vector>

#include "absl/status/status.h"
#include "absl/strings/ascii.h"
#include "absl/strings/escaping.h"
#include "absl/strings/match.h"
#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "absl/strings/str_join.h"
#include "core/mesh/mesh_io.h"
#include "core/mesh/surface_point.h"
#include "core/query/matrix_files.h"
#include "core/query/result_files.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "google/protobuf/util/json_util.h"
#include "grpcpp/grpcpp.h"
#include "nlohmann/json.hpp"
#include "server/api/convert.h"
#include "server/base/constant_time.h"
#include "server/base/echo.h"
#include "server/http/http_server.h"
#include "server/limits/admission.h"
#include "server/limits/client_key.h"
#include "server/meshes/upload.h"

namespace geodesic::server {
namespace {

using json = nlohmann::json;

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

// `retry_after_ms`: the service's hint (its retry-after-ms trailer), sent
// as Retry-After in whole seconds; without one, UNAVAILABLE says a second.
HttpResponse ErrorResponse(const grpc::Status& s, std::optional<int64_t> retry_after_ms = {}) {
  HttpResponse res;
  res.status = HttpStatus(s.error_code());
  if (s.error_code() == grpc::StatusCode::UNAUTHENTICATED) {
    res.headers.emplace_back("WWW-Authenticate", "Bearer");
  }
  // A client without the right credentials gets its answer and the
  // connection's end: kept alive, its connections would fill the cap.
  res.close = s.error_code() == grpc::StatusCode::UNAUTHENTICATED;
  if (retry_after_ms) {
    res.headers.emplace_back("Retry-After", std::to_string((*retry_after_ms + 999) / 1000));
  } else if (s.error_code() == grpc::StatusCode::UNAVAILABLE) {
    res.headers.emplace_back("Retry-After", "1");
  }
  json body = {{"error", {{"code", CodeName(s.error_code())}, {"message", s.error_message()}}}};
  res.body = Dump(body);
  res.content_type = "application/json";
  return res;
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

// A path's segments between slashes, empty ones included.
std::vector<std::string_view> Split(std::string_view path) {
  std::vector<std::string_view> out;
  for (;;) {
    const size_t slash = path.find('/');
    out.push_back(path.substr(0, slash));
    if (slash == std::string_view::npos) return out;
    path.remove_prefix(slash + 1);
  }
}

// +inf (unreachable) has no JSON form: null stands for it.
json JsonDistance(double d) { return std::isfinite(d) ? json(d) : json(nullptr); }

// A call's context: the HTTP bearer token travels as the gRPC metadata the
// service checks, so a wrong or missing token fails exactly as over gRPC.
// `?timeout=SECONDS` becomes the calls' deadline, which long solves poll.
class Call {
 public:
  // `segments`: the path's parts the route captured (mesh names).
  Call(const HttpRequest& req, const std::vector<std::string>& segments)
      : client_address_(req.remote_address) {
    const std::string auth = req.header("Authorization");
    for (char c : auth) {
      if (c < 0x20 || c > 0x7e) {
        status_ = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                               "the Authorization header holds non-printable characters");
        return;
      }
    }
    auth_ = auth;
    for (const std::string& segment : segments) {
      if (!IsUtf8(segment)) {
        status_ = grpc::Status(
            grpc::StatusCode::INVALID_ARGUMENT,
            absl::StrFormat("path segment '%s' is not UTF-8", absl::CHexEscape(segment)));
        return;
      }
    }
    if (req.has_param("timeout")) {
      const std::string text = req.param("timeout");
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
  // A fresh context per RPC (gRPC contexts are single-use), kept for the
  // HTTP request's life so that the last RPC's trailers can be read; the
  // deadline is the whole HTTP request's.
  grpc::ClientContext* Context() const {
    grpc::ClientContext* ctx =
        contexts_.emplace_back(std::make_unique<grpc::ClientContext>()).get();
    if (!auth_.empty()) ctx->AddMetadata("authorization", auth_);
    // Fair shares go by the HTTP client, not by the gateway's one channel.
    if (!client_address_.empty())
      ctx->AddMetadata(kHttpClientMetadata, HttpClientValue(client_address_));
    if (deadline_) ctx->set_deadline(*deadline_);
    return ctx;
  }
  // The retry hint (milliseconds) of the last RPC's refusal, if it sent one.
  std::optional<int64_t> RetryAfterMs() const {
    if (contexts_.empty()) return std::nullopt;
    const auto& trailers = contexts_.back()->GetServerTrailingMetadata();
    auto it = trailers.find(kRetryAfterMsTrailer);
    int64_t ms;
    if (it == trailers.end() ||
        !absl::SimpleAtoi(absl::string_view(it->second.data(), it->second.size()), &ms) || ms < 0) {
      return std::nullopt;
    }
    return ms;
  }
  // The deadline passed: an answer now comes too late for the client, as a
  // gRPC client's call fails once its deadline passes, whatever the server.
  bool expired() const { return deadline_ && std::chrono::system_clock::now() > *deadline_; }
  // Not OK when the request itself is unusable.
  const grpc::Status& status() const { return status_; }

 private:
  std::string auth_;
  std::string client_address_;
  std::optional<std::chrono::system_clock::time_point> deadline_;
  grpc::Status status_;
  mutable std::vector<std::unique_ptr<grpc::ClientContext>> contexts_;
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

// Reads a JSON text for the first key an object gives twice, building
// nothing. A DOM parse with a callback would do the same, but the library's
// callback parser looks through the enclosing array at each object's end,
// which made an array of many small objects take quadratic time.
class DuplicateKeyFinder : public nlohmann::json_sax<json> {
 public:
  std::optional<std::string> duplicate;

  bool null() override { return true; }
  bool boolean(bool) override { return true; }
  bool number_integer(number_integer_t) override { return true; }
  bool number_unsigned(number_unsigned_t) override { return true; }
  bool number_float(number_float_t, const string_t&) override { return true; }
  bool string(string_t&) override { return true; }
  bool binary(binary_t&) override { return true; }
  bool start_object(std::size_t) override {
    keys_.emplace_back();
    return true;
  }
  bool key(string_t& key) override {
    if (keys_.back().insert(key).second) return true;
    duplicate = key;
    return false;
  }
  bool end_object() override {
    keys_.pop_back();
    return true;
  }
  bool start_array(std::size_t) override { return true; }
  bool end_array() override { return true; }
  bool parse_error(std::size_t, const std::string&, const nlohmann::detail::exception&) override {
    return false;
  }

 private:
  std::vector<std::set<std::string>> keys_;  // of the objects open, innermost last
};

grpc::Status ParseBody(const HttpRequest& req, json* body) {
  if (req.body.empty()) {
    *body = json::object();
    return grpc::Status::OK;
  }
  if (NestingDepth(req.body) > kMaxNesting) {
    return Invalid(absl::StrFormat("request body nests arrays and objects deeper than %u levels",
                                   kMaxNesting));
  }
  // A key given twice would silently take its last value: which one the
  // client meant is unknown, so the body is refused.
  DuplicateKeyFinder finder;
  json::sax_parse(req.body, &finder, json::input_format_t::json, /*strict=*/true,
                  /*ignore_comments=*/false);
  if (finder.duplicate) {
    return Invalid(absl::StrFormat("request body gives the key \"%s\" more than once",
                                   absl::CHexEscape(finder.duplicate->substr(0, 80))));
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

grpc::Status QueryEpsilon(const HttpRequest& req, double* eps) {
  *eps = 0;
  if (!req.has_param("eps")) return grpc::Status::OK;
  const std::string text = req.param("eps");
  char* end = nullptr;
  *eps = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size()) {
    return Invalid(absl::StrFormat("query parameter eps=%s is not a number", text));
  }
  return grpc::Status::OK;
}

// The body's "max_error" (absent or 0: not a certified graph).
grpc::Status BodyMaxError(const json& body, double* max_error) {
  *max_error = 0;
  auto it = body.find("max_error");
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (!it->is_number()) return Invalid("\"max_error\" must be a number");
  *max_error = it->get<double>();
  return grpc::Status::OK;
}

grpc::Status QueryMaxError(const HttpRequest& req, double* max_error) {
  *max_error = 0;
  if (!req.has_param("max_error")) return grpc::Status::OK;
  const std::string text = req.param("max_error");
  char* end = nullptr;
  *max_error = std::strtod(text.c_str(), &end);
  if (text.empty() || end != text.c_str() + text.size()) {
    return Invalid(absl::StrFormat("query parameter max_error=%s is not a number", text));
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

// A request for the graph of `mesh` (the path's) that the body chooses:
// "eps" (or "epsilon"; absent: the server's default), "pseudo_vertices"
// (the graph with pseudo vertices, a separate graph) and "max_error" (a
// certified graph, whose epsilon the server chooses). It goes in the
// request's `graph`, made by the conversion the CLI uses too.
template <typename Request>
grpc::Status ForGraphOf(const std::string& mesh, const json& body, Request* req) {
  double epsilon, max_error;
  bool pseudo_vertices;
  if (grpc::Status s = BodyEpsilon(body, &epsilon); !s.ok()) return s;
  if (grpc::Status s = BoolField(body, "pseudo_vertices", &pseudo_vertices); !s.ok()) return s;
  if (grpc::Status s = BodyMaxError(body, &max_error); !s.ok()) return s;
  *req->mutable_graph() = MakeSelector(mesh, epsilon, pseudo_vertices);
  req->mutable_graph()->set_max_error(max_error);
  return grpc::Status::OK;
}

// The same from the query string: ?eps=E&pseudo_vertices=true&max_error=M.
template <typename Request>
grpc::Status ForGraphOfQuery(const std::string& mesh, const HttpRequest& http, Request* req) {
  double epsilon, max_error;
  if (grpc::Status s = QueryEpsilon(http, &epsilon); !s.ok()) return s;
  if (grpc::Status s = QueryMaxError(http, &max_error); !s.ok()) return s;
  bool pseudo_vertices = false;
  if (http.has_param("pseudo_vertices")) {
    const std::string text = http.param("pseudo_vertices");
    if (text == "true" || text == "1") {
      pseudo_vertices = true;
    } else if (text != "false" && text != "0") {
      return Invalid(
          absl::StrFormat("query parameter pseudo_vertices=%s: expected true or false", text));
    }
  }
  *req->mutable_graph() = MakeSelector(mesh, epsilon, pseudo_vertices);
  req->mutable_graph()->set_max_error(max_error);
  return grpc::Status::OK;
}

// A body whose keys are a request message's fields, under the fields' names
// and with their JSON types, read by protobuf's JSON mapping. Keys the route
// does not take were refused before (OnlyKeys); those of the route's other
// form are left to it.
grpc::Status MessageOf(const json& body, google::protobuf::Message* out) {
  google::protobuf::util::JsonParseOptions options;
  options.ignore_unknown_fields = true;
  const auto s = google::protobuf::util::JsonStringToMessage(Dump(body), out, options);
  if (s.ok()) return grpc::Status::OK;
  return Invalid("request body: " + std::string(s.message().data(), s.message().size()));
}

// What every query's answer says about the graph that gave it.
void AddEcho(const v1::QueryEcho& echo, json* out) {
  const v1::GraphSelector graph = SelectorOf(echo);
  (*out)["eps"] = graph.epsilon();
  (*out)["method"] = echo.method();
  (*out)["pseudo_vertices"] = graph.pseudo_vertices();
  if (graph.max_error() > 0) (*out)["max_error"] = graph.max_error();
}

grpc::Status ArrayField(const json& body, const char* key, const json** out) {
  auto it = body.find(key);
  if (it == body.end() || !it->is_array()) {
    return Invalid(absl::StrFormat("\"%s\" must be an array", key));
  }
  *out = &*it;
  return grpc::Status::OK;
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

// What a route's handler reads: the mesh its path names (empty when it
// names none), the HTTP request, and the JSON body the route takes (an
// empty object for routes that take none).
struct ApiRequest {
  const std::string& mesh;
  const HttpRequest& http;
  const json& body;
  // Set by a handler that answers in another format than JSON (a matrix as
  // .npy bytes): sent as it is instead of the handler's JSON.
  std::optional<HttpResponse>* raw = nullptr;
  // The answer's reservation within --memory-limit (ReserveAnswer), held
  // until the answer is sent.
  std::shared_ptr<void>* hold = nullptr;
};

// What one number of an answer costs while it is made and sent as JSON: its
// value as it came (8 bytes), its node in the JSON tree (16, up to twice that
// as arrays grow) and its text (up to 24 characters and a comma).
constexpr uint64_t kJsonNumberBytes = 8 + 2 * 16 + 25;

// The client asked for a matrix as NumPy bytes rather than JSON.
bool WantsNpy(const HttpRequest& http) {
  return absl::StrContains(absl::AsciiStrToLower(http.header("Accept")), "application/x-npy");
}

// The body's "dtype": "float32" or "float64" (absent: float64).
grpc::Status BodyDtype(const json& body, v1::MatrixDtype* dtype) {
  *dtype = v1::MATRIX_DTYPE_DEFAULT;
  auto it = body.find("dtype");
  if (it == body.end() || it->is_null()) return grpc::Status::OK;
  if (it->is_string() && it->get<std::string>() == "float32") {
    *dtype = v1::MATRIX_DTYPE_FLOAT32;
  } else if (it->is_string() && it->get<std::string>() == "float64") {
    *dtype = v1::MATRIX_DTYPE_FLOAT64;
  } else {
    return Invalid(
        absl::StrFormat("\"dtype\" must be \"float32\" or \"float64\", got %s", Quote(*it)));
  }
  return grpc::Status::OK;
}

// The longest text GeometryJson writes for `mesh`: a shortest round-trip
// double is at most 24 characters, a vertex id 10, each with a comma.
uint64_t GeometryJsonBound(const Mesh& mesh) {
  constexpr uint64_t kFrame = 1024;  // keys, the name, the fingerprint
  return kFrame + 3 * uint64_t{mesh.num_vertices()} * 25 + 3 * uint64_t{mesh.num_faces()} * 11;
}

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

// {"name", "fingerprint", "positions": [x, y, z, ...], "faces": [i, j, k,
// ...]}: the registry's arrays in file order, flat.
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

}  // namespace

struct HttpGateway::Impl {
  std::unique_ptr<v1::Geodesic::Stub> stub;
  const MeshRegistry* meshes = nullptr;
  HttpGatewayOptions options;
  std::string web_root;
  bool has_three = false;
  // Destroyed first: its workers call the members above.
  std::unique_ptr<HttpServer> server;

  // SPEC strings (or vertex ids) to points; "xyz:" positions are snapped
  // through the Snap RPC, all of a request's in one call.
  grpc::Status Resolve(const Call& call, const std::string& mesh, const std::vector<json>& specs,
                       const std::string& what, std::vector<v1::SurfacePoint>* out) {
    PointSpecs points;
    for (size_t i = 0; i < specs.size(); ++i) {
      const json& s = specs[i];
      if (s.is_number_unsigned()) {
        if (s.get<uint64_t>() > UINT32_MAX) {
          return grpc::Status(
              grpc::StatusCode::OUT_OF_RANGE,
              absl::StrFormat("%s %u: vertex id %s is out of range", what, i, Quote(s)));
        }
        points.AddVertex(s.get<uint32_t>());
        continue;
      }
      if (!s.is_string()) {
        return Invalid(
            absl::StrFormat("%s %u: expected a point spec string such as \"v:12\", "
                            "got %s",
                            what, i, Quote(s)));
      }
      if (absl::Status bad = points.Add(s.get<std::string>()); !bad.ok()) {
        return Invalid(absl::StrFormat("%s %u: %s", what, i, bad.message()));
      }
    }
    if (points.has_positions()) {
      v1::SnapResponse snapped;
      grpc::Status s = stub->Snap(call.Context(), points.SnapRequest(mesh), &snapped);
      if (!s.ok()) return s;
      if (absl::Status bad = points.Snapped(snapped); !bad.ok()) return ToGrpc(bad);
    }
    *out = std::move(points.points());
    return grpc::Status::OK;
  }

  grpc::Status Specs(const Call& call, const std::string& mesh, const json& body, const char* key,
                     const std::string& what, std::vector<v1::SurfacePoint>* out) {
    const json* array;
    if (grpc::Status s = ArrayField(body, key, &array); !s.ok()) return s;
    return Resolve(call, mesh, std::vector<json>(array->begin(), array->end()), what, out);
  }

  grpc::Status ListMeshes(const Call& call, const ApiRequest&, json* out) {
    v1::ListMeshesResponse resp;
    grpc::Status s = stub->ListMeshes(call.Context(), {}, &resp);
    if (!s.ok()) return s;
    json meshes = json::array();
    for (const auto& m : resp.meshes()) meshes.push_back(MeshJson(m));
    *out = {{"meshes", std::move(meshes)}};
    return s;
  }

  grpc::Status GetMesh(const Call& call, const ApiRequest& r, json* out) {
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
  grpc::Status RegisterMesh(const Call& call, const ApiRequest& r, json* out) {
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
      if (s = OnlyKeys(body, {"name", "path", "vertices", "faces", "repair_non_manifold"});
          !s.ok()) {
        return s;
      }
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

  // "key": [[a, b, c], ...] as a flat array of T (doubles, or vertex ids).
  template <typename T>
  static grpc::Status Rows(const json& body, const char* key, std::vector<T>* out) {
    auto it = body.find(key);
    if (it == body.end() || !it->is_array()) {
      return Invalid(absl::StrFormat("\"%s\" must be an array of [a, b, c] rows", key));
    }
    out->reserve(3 * it->size());
    for (size_t i = 0; i < it->size(); ++i) {
      const json& row = (*it)[i];
      bool ok = row.is_array() && row.size() == 3;
      for (size_t k = 0; ok && k < 3; ++k) {
        ok = std::is_floating_point_v<T>
                 ? row[k].is_number()
                 : row[k].is_number_unsigned() && row[k].template get<uint64_t>() <= UINT32_MAX;
        if (ok) out->push_back(row[k].template get<T>());
      }
      if (!ok) {
        return Invalid(absl::StrFormat("%s row %u: expected three %s, got %s", key, i,
                                       std::is_floating_point_v<T> ? "numbers" : "vertex ids",
                                       Quote(row)));
      }
    }
    return grpc::Status::OK;
  }

  // In messages of kUploadMessageBytes, as any client sends an upload: the
  // service takes no request larger than MaxRequestBytes.
  grpc::Status Upload(const Call& call, v1::UploadMeshRequest header, std::string_view data,
                      const std::vector<double>& vertices, const std::vector<uint32_t>& faces,
                      v1::Mesh* mesh) {
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
  grpc::Status RegisterRegion(const Call& call, const ApiRequest& r, json* out) {
    v1::RegisterRegionRequest req;
    if (grpc::Status s = MessageOf(r.body, &req); !s.ok()) return s;
    req.set_parent(r.mesh);
    v1::Mesh mesh;
    grpc::Status s = stub->RegisterRegion(call.Context(), req, &mesh);
    if (s.ok()) *out = MeshJson(mesh);
    return s;
  }

  grpc::Status UnloadMesh(const Call& call, const ApiRequest& r, json* out) {
    const std::string& name = r.mesh;
    v1::UnloadMeshRequest req;
    req.set_name(name);
    v1::UnloadMeshResponse resp;
    grpc::Status s = stub->UnloadMesh(call.Context(), req, &resp);
    if (s.ok()) *out = {{"name", name}, {"unloaded", true}};
    return s;
  }

  // Geometry has no RPC: GetMesh authorises the call and names a missing
  // mesh, then the registry's arrays are sent as they are, in file order,
  // so that a face id and its barycentrics mean the same on both sides. The
  // text is written straight into one string of the size reserved for it
  // within --memory-limit, held until it is sent: a tree of JSON values
  // first would take several times the text.
  grpc::Status Geometry(const Call& call, const ApiRequest& r, json*) {
    const std::string& name = r.mesh;
    json info;
    if (grpc::Status s = GetMesh(call, r, &info); !s.ok()) return s;
    auto m = meshes->Get(name);
    if (!m.ok()) return ToGrpc(m.status());
    const Mesh& mesh = *(*m)->mesh;
    const uint64_t bytes = GeometryJsonBound(mesh);
    if (grpc::Status s =
            ReserveAnswer(r, bytes, absl::StrFormat("the geometry of mesh '%s' as JSON", name));
        !s.ok()) {
      return s;
    }
    HttpResponse& res = r.raw->emplace();
    res.body = GeometryJson(name, info["fingerprint"], mesh, bytes);
    res.content_type = "application/json";
    return grpc::Status::OK;
  }

  // `bytes` of --memory-limit for the answer, held until it is sent (see
  // ApiRequest::hold); the limit's refusal otherwise.
  grpc::Status ReserveAnswer(const ApiRequest& r, uint64_t bytes, const std::string& what) {
    if (!options.memory) return grpc::Status::OK;
    auto reserved = options.memory->Reserve(bytes, what);
    if (!reserved.ok()) return ToGrpc(reserved.status());
    *r.hold = *std::move(reserved);
    return grpc::Status::OK;
  }

  grpc::Status RequestGraph(const Call& call, const ApiRequest& r, json* out) {
    v1::RequestGraphRequest req;
    if (grpc::Status s = ForGraphOf(r.mesh, r.body, &req); !s.ok()) return s;
    v1::Graph g;
    grpc::Status s = stub->RequestGraph(call.Context(), req, &g);
    if (s.ok()) *out = GraphJson(g);
    return s;
  }

  // GET and DELETE name the graph in the query string: ?eps=E&pseudo_vertices=true.
  grpc::Status GetGraph(const Call& call, const ApiRequest& r, json* out) {
    v1::GetGraphRequest req;
    if (grpc::Status s = ForGraphOfQuery(r.mesh, r.http, &req); !s.ok()) return s;
    v1::Graph g;
    grpc::Status s = stub->GetGraph(call.Context(), req, &g);
    if (s.ok()) *out = GraphJson(g);
    return s;
  }

  grpc::Status CancelGraph(const Call& call, const ApiRequest& r, json* out) {
    v1::CancelGraphRequest req;
    if (grpc::Status s = ForGraphOfQuery(r.mesh, r.http, &req); !s.ok()) return s;
    v1::Graph g;
    grpc::Status s = stub->CancelGraph(call.Context(), req, &g);
    if (s.ok()) *out = GraphJson(g);
    return s;
  }

  grpc::Status ListGraphs(const Call& call, const ApiRequest&, json* out) {
    v1::ListGraphsResponse resp;
    grpc::Status s = stub->ListGraphs(call.Context(), {}, &resp);
    if (!s.ok()) return s;
    json graphs = json::array();
    for (const auto& g : resp.graphs()) graphs.push_back(GraphJson(g));
    *out = {{"graphs", std::move(graphs)}};
    return s;
  }

  grpc::Status Distance(const Call& call, const ApiRequest& r, json* out) {
    const std::string& mesh = r.mesh;
    const json& body = r.body;
    v1::DistanceRequest req;
    bool with_path;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    if (grpc::Status s = BoolField(body, "path", &with_path); !s.ok()) return s;
    req.set_with_path(with_path);
    bool exact;
    if (grpc::Status s = BoolField(body, "exact", &exact); !s.ok()) return s;
    req.set_exact(exact);
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
    grpc::Status s = stub->Distance(call.Context(), req, &resp);
    if (!s.ok()) return s;
    json distances = json::array(), paths = json::array(), path_lengths = json::array();
    for (const auto& r : resp.results()) {
      distances.push_back(r.reachable() ? JsonDistance(r.distance()) : json(nullptr));
      if (!with_path) continue;
      json path = json::array();
      for (const auto& p : r.path().points()) {
        path.push_back({p.xyz().x(), p.xyz().y(), p.xyz().z()});
      }
      paths.push_back(std::move(path));
      path_lengths.push_back(r.reachable() ? json(r.path().length()) : json(nullptr));
    }
    *out = {{"distances", std::move(distances)}, {"exact", exact}};
    AddEcho(resp.echo(), out);
    if (with_path) {
      (*out)["paths"] = std::move(paths);
      (*out)["path_lengths"] = std::move(path_lengths);  // each polyline's own length
    }
    return s;
  }

  grpc::Status Field(const Call& call, const ApiRequest& r, json* out) {
    const std::string& mesh = r.mesh;
    const json& body = r.body;
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
    auto reader = stub->DistanceField(ctx, req);
    std::vector<double> values;
    std::vector<uint32_t> nearest_source;
    v1::QueryEcho echo;
    v1::DistanceFieldChunk chunk;
    while (reader->Read(&chunk)) {
      if (chunk.has_echo()) echo = chunk.echo();
      if (!*r.hold && chunk.total() > 0) {
        const uint64_t numbers = uint64_t{chunk.total()} * (nearest ? 2 : 1);
        if (grpc::Status s =
                ReserveAnswer(r, numbers * kJsonNumberBytes,
                              absl::StrFormat("a field of %u values as JSON", chunk.total()));
            !s.ok()) {
          ctx->TryCancel();
          return s;
        }
      }
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

  grpc::Status Matrix(const Call& call, const ApiRequest& r, json* out) {
    const std::string& mesh = r.mesh;
    const json& body = r.body;
    v1::MatrixRequest req;
    if (grpc::Status s = ForGraphOf(mesh, body, &req); !s.ok()) return s;
    bool exact;
    if (grpc::Status s = BoolField(body, "exact", &exact); !s.ok()) return s;
    req.set_exact(exact);
    std::vector<v1::SurfacePoint> sources, targets;
    if (grpc::Status s = Specs(call, mesh, body, "sources", "source", &sources); !s.ok()) return s;
    if (grpc::Status s = Specs(call, mesh, body, "targets", "target", &targets); !s.ok()) return s;
    for (auto& p : sources) *req.add_sources() = std::move(p);
    for (auto& p : targets) *req.add_targets() = std::move(p);
    v1::MatrixDtype dtype;
    if (grpc::Status s = BodyDtype(body, &dtype); !s.ok()) return s;
    const bool npy = WantsNpy(r.http);
    // Packed bytes whenever a dtype is named or .npy is wanted: the .npy's
    // data is those bytes as they came.
    if (npy && dtype == v1::MATRIX_DTYPE_DEFAULT) dtype = v1::MATRIX_DTYPE_FLOAT64;
    req.set_dtype(dtype);
    v1::MatrixResponse resp;
    grpc::Status s = stub->Matrix(call.Context(), req, &resp);
    if (!s.ok()) return s;
    const uint64_t entries = static_cast<uint64_t>(resp.rows()) * resp.cols();
    const bool narrow = dtype == v1::MATRIX_DTYPE_FLOAT32;
    // The answer as it came is in memory already; what is made of it is not.
    if (grpc::Status s = ReserveAnswer(
            r, entries * (npy ? (narrow ? sizeof(float) : sizeof(double)) : kJsonNumberBytes),
            absl::StrFormat("a matrix of %u x %u %s", resp.rows(), resp.cols(),
                            npy ? "as .npy" : "as JSON"));
        !s.ok()) {
      return s;
    }
    const uint64_t got = dtype == v1::MATRIX_DTYPE_DEFAULT
                             ? resp.distances_size()
                             : resp.packed().size() / (narrow ? sizeof(float) : sizeof(double));
    if (entries != got || (dtype != v1::MATRIX_DTYPE_DEFAULT && resp.dtype() != dtype)) {
      return grpc::Status(grpc::StatusCode::INTERNAL, "matrix size does not match rows x cols");
    }
    if (npy) {
      HttpResponse& res = r.raw->emplace();
      const MatrixDtype descr = narrow ? MatrixDtype::kFloat32 : MatrixDtype::kFloat64;
      res.body = NpyPreamble(NpyDescr(descr), {resp.rows(), resp.cols()});
      res.body += resp.packed();
      res.content_type = "application/x-npy";
      return s;
    }
    auto entry = [&](uint64_t k) -> double {
      if (dtype == v1::MATRIX_DTYPE_DEFAULT) return resp.distances(static_cast<int>(k));
      if (narrow) {
        float value;
        std::memcpy(&value, resp.packed().data() + k * sizeof value, sizeof value);
        return value;
      }
      double value;
      std::memcpy(&value, resp.packed().data() + k * sizeof value, sizeof value);
      return value;
    };
    json rows = json::array();
    for (uint32_t r = 0; r < resp.rows(); ++r) {
      json row = json::array();
      for (uint32_t c = 0; c < resp.cols(); ++c) {
        row.push_back(JsonDistance(entry(uint64_t(r) * resp.cols() + c)));
      }
      rows.push_back(std::move(row));
    }
    *out = {{"distances", std::move(rows)}, {"exact", exact}};
    if (dtype != v1::MATRIX_DTYPE_DEFAULT) (*out)["dtype"] = narrow ? "float32" : "float64";
    AddEcho(resp.echo(), out);
    return s;
  }

  grpc::Status Sample(const Call& call, const ApiRequest& r, json* out) {
    const std::string& mesh = r.mesh;
    const json& body = r.body;
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
    grpc::Status s = stub->SamplePoints(call.Context(), req, &resp);
    if (!s.ok()) return s;
    *out = {{"vertices", resp.vertices()},
            {"covering_radius", JsonDistance(resp.covering_radius())}};
    AddEcho(resp.echo(), out);
    return s;
  }

  grpc::Status Snap(const Call& call, const ApiRequest& r, json* out) {
    const std::string& mesh = r.mesh;
    const json& body = r.body;
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
    grpc::Status s = stub->Snap(call.Context(), req, &resp);
    if (!s.ok()) return s;
    json points = json::array();
    for (const auto& p : resp.points()) points.push_back(FormatPoint(p));
    json distances = json::array();
    for (double d : resp.distances()) distances.push_back(JsonDistance(d));
    *out = {{"points", std::move(points)}, {"distances", std::move(distances)}};
    return s;
  }

  // The API, one row per path and method: a "{}" segment matches one path
  // segment (a mesh name), handed to the handler. A Handler answers JSON
  // from the gRPC service once the Call's checks (token, timeout) pass; a
  // Page answers by itself, with no token. A POST body is parsed before the
  // handler runs when the row lists the keys it takes: a key not listed is
  // refused rather than ignored, since a typo such as "pseudo_vertex" would
  // otherwise quietly answer from another graph.
  using Handler = grpc::Status (Impl::*)(const Call&, const ApiRequest&, json* out);
  using Page = HttpResponse (Impl::*)() const;
  struct Route {
    const char* method;
    const char* pattern;
    std::variant<Handler, Page> handler;
    std::vector<std::string> body_keys = {};
  };

  // A query's body keys: its own, then those that choose the graph.
  static std::vector<std::string> WithGraph(std::vector<std::string> keys) {
    for (const char* key : {"eps", "epsilon", "pseudo_vertices", "max_error"}) keys.push_back(key);
    return keys;
  }

  static const std::vector<Route>& Routes() {
    // clang-format off
    static const std::vector<Route> routes = {
        {"GET",    "/v1/openapi.json",       &Impl::OpenApi},
        {"GET",    "/v1/meshes",             &Impl::ListMeshes},
        {"GET",    "/v1/graphs",             &Impl::ListGraphs},
        {"POST",   "/v1/meshes",             &Impl::RegisterMesh},  // reads its own body
        {"GET",    "/v1/meshes/{}",          &Impl::GetMesh},
        {"DELETE", "/v1/meshes/{}",          &Impl::UnloadMesh},
        {"GET",    "/v1/meshes/{}/geometry", &Impl::Geometry},
        {"POST",   "/v1/meshes/{}/regions",  &Impl::RegisterRegion, {"name", "vertex_ids", "face_ids"}},
        {"GET",    "/v1/meshes/{}/graph",    &Impl::GetGraph},
        {"DELETE", "/v1/meshes/{}/graph",    &Impl::CancelGraph},
        {"POST",   "/v1/meshes/{}/graph",    &Impl::RequestGraph, WithGraph({})},
        {"POST",   "/v1/meshes/{}/distance", &Impl::Distance,     WithGraph({"pairs", "path", "exact"})},
        {"POST",   "/v1/meshes/{}/field",    &Impl::Field,
         WithGraph({"sources", "targets", "max_distance", "method", "nearest_source"})},
        {"POST",   "/v1/meshes/{}/matrix",   &Impl::Matrix,
         WithGraph({"sources", "targets", "exact", "dtype"})},
        {"POST",   "/v1/meshes/{}/snap",     &Impl::Snap,         {"positions"}},
        {"POST",   "/v1/meshes/{}/sample",   &Impl::Sample,       WithGraph({"count", "seed"})},
    };
    // clang-format on
    return routes;
  }

  // A route's answer. For a Handler: the Call is checked, then the body,
  // then the handler runs; an answer that comes after the request's timeout
  // is an error, as over gRPC.
  HttpResponse Answer(const Route& route, const HttpRequest& req,
                      const std::vector<std::string>& args) {
    if (const Page* page = std::get_if<Page>(&route.handler)) return (this->*(*page))();
    const Handler handler = std::get<Handler>(route.handler);
    Call call(req, args);
    json body = json::object(), out;
    grpc::Status s = call.status();
    if (s.ok() && !route.body_keys.empty()) {
      if (s = ParseBody(req, &body); s.ok()) s = OnlyKeys(body, route.body_keys);
    }
    std::optional<HttpResponse> raw;
    std::shared_ptr<void> hold;
    if (s.ok()) {
      s = (this->*handler)(call, {args.empty() ? "" : args[0], req, body, &raw, &hold}, &out);
    }
    if (s.ok() && call.expired()) {
      s = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the request's timeout passed");
    }
    if (!s.ok()) return ErrorResponse(s, call.RetryAfterMs());
    if (raw) {
      raw->headers.emplace_back("Cache-Control", "no-store");
      raw->hold = std::move(hold);
      return *std::move(raw);
    }
    HttpResponse res;
    res.headers.emplace_back("Cache-Control", "no-store");
    res.body = Dump(out);
    res.content_type = "application/json";
    res.hold = std::move(hold);
    return res;
  }

  static grpc::Status OnlyKeys(const json& body, const std::vector<std::string>& keys) {
    if (!body.is_object()) return grpc::Status::OK;  // the handler names what it expected
    for (const auto& [key, value] : body.items()) {
      if (std::find(keys.begin(), keys.end(), key) != keys.end()) continue;
      return Invalid(absl::StrFormat("unknown key %s in the body; this call takes: %s", Quote(key),
                                     absl::StrJoin(keys, ", ")));
    }
    return grpc::Status::OK;
  }

  static bool Matches(std::string_view pattern, std::string_view path,
                      std::vector<std::string>* args) {
    args->clear();
    const std::vector<std::string_view> want = Split(pattern), got = Split(path);
    if (want.size() != got.size()) return false;
    for (size_t i = 0; i < want.size(); ++i) {
      if (want[i] == "{}" && !got[i].empty()) {
        args->emplace_back(got[i]);
      } else if (want[i] != got[i]) {
        return false;
      }
    }
    return true;
  }

  // The route for the request's path and method; a path the table knows
  // with another method gives the methods it takes in *allow instead.
  static const Route* FindRoute(const HttpRequest& req, std::vector<std::string>* args,
                                std::string* allow) {
    // HEAD is GET without the body, as for any HTTP server.
    const std::string method = req.method == "HEAD" ? "GET" : req.method;
    allow->clear();
    for (const Route& route : Routes()) {
      if (!Matches(route.pattern, req.path, args)) continue;
      if (route.method == method) return &route;
      if (!allow->empty()) *allow += ", ";
      *allow += route.method;
      if (std::string_view(route.method) == "GET") *allow += ", HEAD";
    }
    return nullptr;
  }

  HttpResponse OpenApi() const {
    std::ifstream in(std::filesystem::path(web_root) / "openapi.json");
    std::stringstream text;
    if (web_root.empty() || !(text << in.rdbuf())) {
      return ErrorResponse(grpc::Status(grpc::StatusCode::NOT_FOUND, "openapi.json not installed"));
    }
    HttpResponse res;
    res.body = text.str();
    res.content_type = "application/json";
    return res;
  }

  HttpResponse NotFound(const HttpRequest& req) const {
    return ErrorResponse(
        grpc::Status(grpc::StatusCode::NOT_FOUND,
                     web_root.empty() && !req.path.starts_with("/v1/")
                         ? "the viewer's files were not found (set GEODESIC_WEB_DIR)"
                         : absl::StrFormat("no such resource: %s %s", req.method, req.path)));
  }

  static HttpResponse NotAllowed(const HttpRequest& req, const std::string& allow) {
    HttpResponse res = ErrorResponse(grpc::Status(
        grpc::StatusCode::UNIMPLEMENTED,
        absl::StrFormat("%s is not allowed on %s; allowed: %s", req.method, req.path, allow)));
    res.status = 405;
    res.headers.emplace_back("Allow", allow);
    return res;
  }

  // The viewer under / and three.js under /three. Paths are taken segment by
  // segment, so ".." never climbs out of a root (symbolic links inside one,
  // as Debian's three.js has, are followed).
  std::optional<HttpResponse> StaticFile(const HttpRequest& req) const {
    std::vector<std::pair<std::string_view, std::string>> mounts;
    if (has_three) mounts.emplace_back("/three", options.three_root);
    if (!web_root.empty()) mounts.emplace_back("", web_root);
    for (const auto& [prefix, root] : mounts) {
      if (req.path != prefix && !req.path.starts_with(std::string(prefix) + "/")) continue;
      std::string sub = req.path.substr(prefix.size());
      if (sub.empty()) sub = "/";
      for (std::string_view segment : Split(sub)) {
        if (segment == ".." || segment.find('\0') != std::string_view::npos ||
            segment.find('\\') != std::string_view::npos) {
          return NotFound(req);
        }
      }
      if (sub.back() == '/') sub += "index.html";
      const std::filesystem::path file = root + sub;
      std::error_code ec;
      if (!std::filesystem::is_regular_file(file, ec)) continue;
      std::ifstream in(file, std::ios::binary);
      std::stringstream text;
      if (!(text << in.rdbuf())) continue;
      HttpResponse res;
      res.body = text.str();
      res.content_type = MimeType(file.extension().string());
      return res;
    }
    return std::nullopt;
  }

  static std::string MimeType(const std::string& extension) {
    static const std::map<std::string, std::string> types = {
        {".html", "text/html"},        {".htm", "text/html"},         {".js", "text/javascript"},
        {".mjs", "text/javascript"},   {".json", "application/json"}, {".css", "text/css"},
        {".png", "image/png"},         {".jpg", "image/jpeg"},        {".jpeg", "image/jpeg"},
        {".svg", "image/svg+xml"},     {".ico", "image/x-icon"},      {".txt", "text/plain"},
        {".wasm", "application/wasm"}, {".map", "application/json"},
    };
    auto it = types.find(absl::AsciiStrToLower(extension));
    return it == types.end() ? "application/octet-stream" : it->second;
  }

  // On a worker, with the whole request.
  HttpResponse Handle(const HttpRequest& req) {
    std::vector<std::string> args;
    std::string allow;
    if (const Route* route = FindRoute(req, &args, &allow)) {
      try {
        return Answer(*route, req, args);
      } catch (const json::exception& e) {
        // Type checks precede every JSON read; this is the last guard.
        return ErrorResponse(Invalid(e.what()));
      } catch (const std::exception& e) {
        return ErrorResponse(grpc::Status(grpc::StatusCode::INTERNAL, e.what()));
      }
    }
    if (!allow.empty()) return NotAllowed(req, allow);
    if (req.method == "GET" || req.method == "HEAD") {
      if (auto file = StaticFile(req)) return std::move(*file);
    }
    return NotFound(req);
  }

  // Browsers on another origin may read the API's answers (errors too, so
  // that a page can show them) when --http-cors-origin names that origin.
  HttpResponse WithCors(const HttpRequest& req, HttpResponse res) const {
    if (options.cors_origin.empty() || !req.path.starts_with("/v1/")) return res;
    res.headers.emplace_back("Access-Control-Allow-Origin", options.cors_origin);
    if (options.cors_origin != "*") res.headers.emplace_back("Vary", "Origin");
    return res;
  }

  // A CORS preflight: which methods and headers a page on the allowed origin
  // may use on this path.
  std::optional<HttpResponse> Preflight(const HttpRequest& head) const {
    if (head.method != "OPTIONS" || options.cors_origin.empty() || !head.path.starts_with("/v1/")) {
      return std::nullopt;
    }
    HttpRequest probe = head;
    probe.method = "";  // matches no route: collects every method of the path
    std::vector<std::string> args;
    std::string allow;
    FindRoute(probe, &args, &allow);
    if (allow.empty()) return NotFound(head);
    HttpResponse res;
    res.status = 204;
    res.headers.emplace_back("Access-Control-Allow-Methods", allow);
    res.headers.emplace_back("Access-Control-Allow-Headers", "Authorization, Content-Type");
    res.headers.emplace_back("Access-Control-Max-Age", "600");
    return res;
  }

  // On an io thread, before the body is read: what can be answered from the
  // headers alone is, so that a body nobody will use is never read.
  std::optional<HttpResponse> Admit(const HttpRequest& head, size_t* body_limit) const {
    if (auto preflight = Preflight(head)) return preflight;
    if (head.header("Content-Type").starts_with("application/x-www-form-urlencoded")) {
      *body_limit = std::min(*body_limit, kFormBodyLimit);
    }
    std::vector<std::string> args;
    std::string allow;
    const Route* route = FindRoute(head, &args, &allow);
    if (!route) {
      if (!allow.empty()) return NotAllowed(head, allow);
      const bool maybe_file =
          (head.method == "GET" || head.method == "HEAD") && !head.path.starts_with("/v1/");
      if (maybe_file) return std::nullopt;
      return NotFound(head);
    }
    if (std::holds_alternative<Page>(route->handler) || options.bearer_tokens.empty()) {
      return std::nullopt;
    }
    // Exactly one header: with two, a proxy and this server could each
    // read a different one.
    const size_t count = head.header_count("Authorization");
    if (count > 1) {
      return ErrorResponse(grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                                        "more than one Authorization header: send exactly one, "
                                        "'Authorization: Bearer <token>'"));
    }
    bool known = false;
    for (const std::string& token : options.bearer_tokens) {
      known |= count == 1 && ConstantTimeEquals(head.header("Authorization"), "Bearer " + token);
    }
    if (!known) {
      return ErrorResponse(grpc::Status(
          grpc::StatusCode::UNAUTHENTICATED,
          "missing or wrong bearer token: send the header 'Authorization: Bearer <token>'"));
    }
    return std::nullopt;
  }

  // A body and what is made of it, reserved within --memory-limit before it
  // is read. A JSON body becomes a tree of values, then copies of its
  // points, then the request message on both sides of the in-process
  // channel: a body of short tokens takes tens of times its text, and the
  // reservation covers that worst case. The daemon's peak resident memory
  // over idle for one 8 MiB body, measured: pairs of one-digit "v:ID"
  // strings 51 times its length, of four-digit ones 37, field or matrix
  // sources "v:1" 36, snap positions [0,0,0] 35, a list of {} 36 (the tree
  // alone); fairness_memory_test.py checks the first under --memory-limit.
  // A mesh file's bytes are copied a few times whole.
  static constexpr uint64_t kJsonBodyMemoryFactor = 64;
  static constexpr uint64_t kFileBodyMemoryFactor = 8;

  std::optional<HttpResponse> ReserveBody(const HttpRequest& head, size_t body_bytes,
                                          std::shared_ptr<void>* hold) const {
    if (!options.memory) return std::nullopt;
    const bool is_json = head.header("Content-Type").starts_with("application/json");
    auto reserved = options.memory->Reserve(
        (is_json ? kJsonBodyMemoryFactor : kFileBodyMemoryFactor) * body_bytes,
        absl::StrFormat("a request body of %u bytes, with what is made of it", body_bytes));
    if (reserved.ok()) {
      *hold = *std::move(reserved);
      return std::nullopt;
    }
    HttpResponse res = ErrorResponse(ToGrpc(reserved.status()));
    // Never fits: too large, as an over-long body is; fits later: busy.
    if (absl::IsResourceExhausted(reserved.status())) res.status = 413;
    return res;
  }

  HttpResponse Refuse(HttpRefusal why, const HttpRequest& head, size_t body_limit) const {
    switch (why) {
      case HttpRefusal::kBodyTooLarge: {
        HttpResponse res = ErrorResponse(grpc::Status(
            grpc::StatusCode::RESOURCE_EXHAUSTED,
            head.header("Content-Type").starts_with("application/x-www-form-urlencoded")
                ? absl::StrFormat("a body sent as application/x-www-form-urlencoded (curl -d's "
                                  "default) is limited to %u bytes; send it with Content-Type: "
                                  "application/json",
                                  body_limit)
                : absl::StrFormat("request body over the limit of %u bytes", body_limit)));
        res.status = 413;
        return res;
      }
      case HttpRefusal::kHeaderTooLarge: {
        HttpResponse res =
            ErrorResponse(grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                                       absl::StrFormat("request headers over the limit of %u bytes",
                                                       options.limits.max_header_bytes)));
        res.status = 431;
        return res;
      }
      case HttpRefusal::kBusy:
        return ErrorResponse(grpc::Status(
            grpc::StatusCode::UNAVAILABLE,
            absl::StrFormat("the HTTP gateway is busy: %d requests wait for a worker; retry",
                            options.limits.max_queued)));
      case HttpRefusal::kBadRequest:
        return ErrorResponse(Invalid("malformed HTTP request"));
      case HttpRefusal::kInternal:
        break;
    }
    return ErrorResponse(grpc::Status(grpc::StatusCode::INTERNAL, "internal error"));
  }

  // Bodies sent as forms (curl -d's default content type) are capped as the
  // HTTP library the gateway used to run on capped them, so that a client
  // that forgot its JSON content type hears so rather than nothing.
  static constexpr size_t kFormBodyLimit = 8192;
};

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

HttpGateway::~HttpGateway() = default;

void HttpGateway::StopAccepting() { impl_->server->StopAccepting(); }
void HttpGateway::WaitForAnswers(std::chrono::steady_clock::time_point deadline) {
  impl_->server->WaitForAnswers(deadline);
}
void HttpGateway::Finish(std::chrono::steady_clock::time_point deadline) {
  impl_->server->Finish(deadline);
}

int HttpGateway::port() const { return impl_->server->port(); }
bool HttpGateway::tls() const { return impl_->server->tls(); }

absl::StatusOr<std::unique_ptr<HttpGateway>> HttpGateway::Start(const HttpGatewayOptions& options,
                                                                grpc::Server* grpc_server,
                                                                const MeshRegistry* meshes) {
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->meshes = meshes;
  impl->web_root = options.web_root.empty() ? FindWebRoot() : options.web_root;
  std::error_code ec;
  impl->has_three = std::filesystem::exists(options.three_root, ec);
  grpc::ChannelArguments args;
  // Fields and matrices of large meshes exceed gRPC's 4 MiB default; the
  // service allows 64 MiB each way.
  args.SetMaxReceiveMessageSize(64 << 20);
  args.SetMaxSendMessageSize(64 << 20);
  impl->stub = v1::Geodesic::NewStub(grpc_server->InProcessChannel(args));

  HttpServerOptions server;
  server.listen = options.listen;
  server.tls_cert = options.tls_cert;
  server.tls_key = options.tls_key;
  server.tls_client_ca = options.tls_client_ca;
  server.limits = options.limits;
  server.limits.max_body_bytes = options.max_body_bytes;
  Impl* g = impl.get();
  server.handler = [g](const HttpRequest& req) { return g->WithCors(req, g->Handle(req)); };
  server.headers = [g](const HttpRequest& head, size_t* body_limit) {
    std::optional<HttpResponse> res = g->Admit(head, body_limit);
    if (res) res = g->WithCors(head, std::move(*res));
    return res;
  };
  server.reserve_body = [g](const HttpRequest& head, size_t body_bytes,
                            std::shared_ptr<void>* hold) {
    std::optional<HttpResponse> res = g->ReserveBody(head, body_bytes, hold);
    if (res) res = g->WithCors(head, std::move(*res));
    return res;
  };
  server.refuse = [g](HttpRefusal why, const HttpRequest& head, size_t body_limit) {
    return g->WithCors(head, g->Refuse(why, head, body_limit));
  };
  auto started = HttpServer::Start(std::move(server));
  if (!started.ok()) {
    return absl::Status(started.status().code(),
                        absl::StrCat("--http-listen ", started.status().message()));
  }
  impl->server = std::move(*started);
  return std::unique_ptr<HttpGateway>(new HttpGateway(std::move(impl)));
}

}  // namespace geodesic::server
