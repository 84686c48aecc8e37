// The HTTP gateway's front: the route table and how a request finds its
// route and answer, the viewer's static files, CORS, and start-up. The
// handlers are by resource (routes_meshes.cc, routes_queries.cc), the JSON
// readers and answers beside them (json_requests.h, json_answers.h), and
// what is decided before the body in gateway_admission.cc.
#include "server/gateway/http_gateway.h"

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>
#include <optional>
#include <sstream>
#include <variant>
#include <vector>

#include "absl/strings/ascii.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_format.h"
#include "server/gateway/gateway_impl.h"
#include "server/gateway/json_requests.h"

namespace geodesic::server {
// The gateway's helpers (gateway_call.h), unqualified as the handlers were
// written; this file is compiled alone, never in a unity batch.
using namespace gateway;  // NOLINT(build/namespaces)
namespace {

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

}  // namespace

// A query's body keys: its own, then those that choose the graph.
std::vector<std::string> HttpGateway::Impl::WithGraph(std::vector<std::string> keys) {
  for (const char* key : {"eps", "epsilon", "pseudo_vertices", "max_error"}) keys.push_back(key);
  return keys;
}

const std::vector<HttpGateway::Impl::Route>& HttpGateway::Impl::Routes() {
  // clang-format off
  static const std::vector<Route> routes = {
      {"GET",    "/v1/openapi.json",       &Impl::OpenApi},
      {"GET",    "/v1/meshes",             &Impl::ListMeshes},
      {"GET",    "/v1/graphs",             &Impl::ListGraphs},
      {"POST",   "/v1/meshes",             &Impl::RegisterMesh, kRegisterMeshKeys, /*reads_own_body=*/true},
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
HttpResponse HttpGateway::Impl::Answer(const Route& route, const HttpRequest& req,
                                       const std::vector<std::string>& args) {
  if (const Page* page = std::get_if<Page>(&route.handler)) return (this->*(*page))();
  const Handler handler = std::get<Handler>(route.handler);
  Call call(req, args);
  json body = json::object(), out;
  grpc::Status s = call.status();
  if (s.ok() && !route.body_keys.empty() && !route.reads_own_body) {
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

bool HttpGateway::Impl::Matches(std::string_view pattern, std::string_view path,
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
const HttpGateway::Impl::Route* HttpGateway::Impl::FindRoute(const HttpRequest& req,
                                                             std::vector<std::string>* args,
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

HttpResponse HttpGateway::Impl::OpenApi() const {
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

HttpResponse HttpGateway::Impl::NotFound(const HttpRequest& req) const {
  return ErrorResponse(
      grpc::Status(grpc::StatusCode::NOT_FOUND,
                   web_root.empty() && !req.path.starts_with("/v1/")
                       ? "the viewer's files were not found (set GEODESIC_WEB_DIR)"
                       : absl::StrFormat("no such resource: %s %s", req.method, req.path)));
}

HttpResponse HttpGateway::Impl::NotAllowed(const HttpRequest& req, const std::string& allow) {
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
std::optional<HttpResponse> HttpGateway::Impl::StaticFile(const HttpRequest& req) const {
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

std::string HttpGateway::Impl::MimeType(const std::string& extension) {
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
HttpResponse HttpGateway::Impl::Handle(const HttpRequest& req) {
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
HttpResponse HttpGateway::Impl::WithCors(const HttpRequest& req, HttpResponse res) const {
  if (options.cors_origin.empty() || !req.path.starts_with("/v1/")) return res;
  res.headers.emplace_back("Access-Control-Allow-Origin", options.cors_origin);
  if (options.cors_origin != "*") res.headers.emplace_back("Vary", "Origin");
  return res;
}

// A CORS preflight: which methods and headers a page on the allowed origin
// may use on this path.
std::optional<HttpResponse> HttpGateway::Impl::Preflight(const HttpRequest& head) const {
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

std::vector<GatewayRoute> HttpGateway::Routes() {
  std::vector<GatewayRoute> out;
  for (const Impl::Route& route : Impl::Routes()) {
    out.push_back({route.method, route.pattern, route.body_keys});
  }
  return out;
}

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
                                                                grpc::Server* grpc_server) {
  auto impl = std::make_unique<Impl>();
  impl->options = options;
  impl->identity = ClientIdentity(options.bearer_tokens);
  impl->web_root = options.web_root.empty() ? FindWebRoot() : options.web_root;
  std::error_code ec;
  impl->has_three = std::filesystem::exists(options.three_root, ec);
  grpc::ChannelArguments args;
  // Fields and matrices of large meshes exceed gRPC's 4 MiB default: the
  // channel carries what the service itself sends and receives.
  args.SetMaxReceiveMessageSize(static_cast<int>(options.service.max_message_bytes));
  args.SetMaxSendMessageSize(static_cast<int>(MaxRequestBytes(options.service)));
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
