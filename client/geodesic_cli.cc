// geodesic: the command-line client of geodesicd.
#include <openssl/evp.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cctype>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <limits>
#include <memory>
#include <mutex>
#include <sstream>
#include <thread>

#include "CLI/CLI.hpp"
#include "absl/status/status.h"
#include "absl/strings/match.h"
#include "absl/strings/str_format.h"
#include "core/mesh_io.h"
#include "core/result_files.h"
#include "core/surface_point.h"
#include "core/version.h"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "grpc/health/v1/health.grpc.pb.h"
#include "grpcpp/grpcpp.h"
#include "nlohmann/json.hpp"
#include "server/convert.h"

namespace {

using namespace geodesic;
namespace v1 = geodesic::v1;

struct Common {
  std::string server = "127.0.0.1:50051";
  std::string mesh = "spot";
  double epsilon = 0;
  // The graph with pseudo vertices rather than the plain one of --eps: a
  // separate graph, for graph requests and queries alike.
  bool pseudo_vertices = false;
  bool json = false;
  double timeout = 600;
  // Security: TLS when a CA is given; a client certificate for mutual TLS;
  // a bearer token (from --token-file or $GEODESIC_TOKEN).
  std::string tls_ca, tls_cert, tls_key, token_file;
  std::string token;
  grpc::SslCredentialsOptions tls;
};

bool ReadWholeFile(const std::string& flag, const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  if (in) text << in.rdbuf();
  if (!in || text.str().empty()) {
    std::fprintf(stderr, "geodesic: %s %s: cannot read it or it is empty\n", flag.c_str(),
                 path.c_str());
    return false;
  }
  *out = text.str();
  return true;
}

// Reads the certificate and token files named by the flags.
bool LoadSecurity(Common& c) {
  if (!c.tls_ca.empty() && !ReadWholeFile("--tls-ca", c.tls_ca, &c.tls.pem_root_certs)) {
    return false;
  }
  if (c.tls_cert.empty() != c.tls_key.empty() || (!c.tls_cert.empty() && c.tls_ca.empty())) {
    std::fprintf(stderr, "geodesic: --tls-cert and --tls-key go together, with --tls-ca\n");
    return false;
  }
  if (!c.tls_cert.empty() && (!ReadWholeFile("--tls-cert", c.tls_cert, &c.tls.pem_cert_chain) ||
                              !ReadWholeFile("--tls-key", c.tls_key, &c.tls.pem_private_key))) {
    return false;
  }
  if (!c.token_file.empty()) {
    if (!ReadWholeFile("--token-file", c.token_file, &c.token)) return false;
  } else if (const char* env = std::getenv("GEODESIC_TOKEN")) {
    c.token = env;
  }
  while (!c.token.empty() && std::isspace(static_cast<unsigned char>(c.token.back()))) {
    c.token.pop_back();
  }
  return true;
}

// `connected`: wait (up to 5 s, and at most the call timeout) until the
// connection is up, so that a call timed after it measures the call, not the
// handshake. A server that is down fails the call after that, not after a
// whole --timeout.
std::shared_ptr<grpc::Channel> OpenChannel(const Common& c, bool connected) {
  grpc::ChannelArguments args;
  args.SetMaxReceiveMessageSize(256 << 20);
  auto credentials =
      c.tls_ca.empty() ? grpc::InsecureChannelCredentials() : grpc::SslCredentials(c.tls);
  auto channel = grpc::CreateCustomChannel(c.server, credentials, args);
  if (connected) {
    // A failure shows up, with its reason, in the call that follows.
    (void)channel->WaitForConnected(
        std::chrono::system_clock::now() +
        std::chrono::milliseconds(static_cast<int64_t>(std::min(c.timeout, 5.0) * 1000)));
  }
  return channel;
}

std::unique_ptr<v1::Geodesic::Stub> Connect(const Common& c, bool connected = false) {
  return v1::Geodesic::NewStub(OpenChannel(c, connected));
}

// Every call carries the mesh name so that a proxy can route by it.
void Prepare(grpc::ClientContext* ctx, const Common& c) {
  ctx->AddMetadata("x-geodesic-mesh", c.mesh);
  if (!c.token.empty()) ctx->AddMetadata("authorization", "Bearer " + c.token);
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<int64_t>(c.timeout * 1000)));
}

// A number in [low, high] (NaN is not), as a CLI11 check.
CLI::Validator NumberIn(double low, double high, const std::string& what) {
  return CLI::Validator(
      [=](std::string& text) -> std::string {
        try {
          const double v = std::stod(text);
          if (v >= low && v <= high) return "";
        } catch (const std::exception&) {
        }
        return what + ", got '" + text + "'";
      },
      what);
}

int Fail(const grpc::Status& s) {
  const std::string code = server::CodeName(s.error_code());
  std::fprintf(stderr, "geodesic: %s: %s\n", code.c_str(), s.error_message().c_str());
  return s.error_code() == grpc::StatusCode::UNAVAILABLE ? 3 : 1;
}

int FailText(const std::string& message) {
  std::fprintf(stderr, "geodesic: %s\n", message.c_str());
  return 2;
}

// Resolves point specs, snapping xyz positions through the server.
// `snap_distances`, if given, gets for each spec how far its xyz: position
// was from the surface point it snapped to (null for other specs).
bool ResolvePoints(v1::Geodesic::Stub* stub, const Common& c, const std::vector<std::string>& specs,
                   std::vector<v1::SurfacePoint>* out, int* rc,
                   std::vector<nlohmann::ordered_json>* snap_distances = nullptr) {
  if (snap_distances) snap_distances->assign(specs.size(), nullptr);
  server::PointSpecs points;
  for (const std::string& spec : specs) {
    if (absl::Status s = points.Add(spec); !s.ok()) {
      *rc = FailText(std::string(s.message()));
      return false;
    }
  }
  if (points.has_positions()) {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    v1::SnapResponse resp;
    grpc::Status s = stub->Snap(&ctx, points.SnapRequest(c.mesh), &resp);
    if (s.ok()) s = server::ToGrpc(points.Snapped(resp));
    if (!s.ok()) {
      *rc = Fail(s);
      return false;
    }
    const std::vector<size_t>& snapped = points.snapped();
    for (size_t k = 0; snap_distances && k < snapped.size() && k < size_t(resp.distances_size());
         ++k) {
      (*snap_distances)[snapped[k]] = resp.distances(k);
    }
  }
  *out = std::move(points.points());
  return true;
}

// --json output. Keys keep the order they are set in; strings are escaped;
// doubles print with full (round-trip) precision; +inf and NaN, which JSON
// cannot hold, print as null.
using Json = nlohmann::ordered_json;

void PrintJson(const Json& value) { std::printf("%s\n", value.dump().c_str()); }

// The daemon sends mesh diagnostics as a JSON text; embedded as JSON, or as
// null (with a warning) if it does not parse.
Json DiagnosticsJson(const v1::MeshDiagnostics& d) {
  Json parsed = Json::parse(d.json(), nullptr, /*allow_exceptions=*/false);
  if (parsed.is_discarded()) {
    std::fprintf(stderr, "geodesic: the server's mesh diagnostics are not valid JSON\n");
    return nullptr;
  }
  return parsed;
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

Json GraphJson(const v1::Graph& g) {
  return {{"mesh", g.mesh()},
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
          {"pseudo_vertices", g.pseudo_vertices()}};
}

int CmdMeshes(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::ListMeshesResponse resp;
  grpc::Status s = stub->ListMeshes(&ctx, {}, &resp);
  if (!s.ok()) return Fail(s);
  Json list = Json::array();
  for (int i = 0; i < resp.meshes_size(); ++i) {
    const auto& m = resp.meshes(i);
    if (c.json) {
      list.push_back({{"name", m.name()},
                      {"fingerprint", m.fingerprint()},
                      {"source", m.source()},
                      {"restored", m.restored()},
                      {"diagnostics", DiagnosticsJson(m.diagnostics())}});
    } else {
      std::printf("%-16s %8lu vertices %8lu faces  %s  %s\n", m.name().c_str(),
                  m.diagnostics().vertices(), m.diagnostics().faces(), m.fingerprint().c_str(),
                  m.source().c_str());
    }
  }
  if (c.json) PrintJson(list);
  return 0;
}

// The standard gRPC health check, which needs no token: for probes such as
// the container's HEALTHCHECK. Exit 0 only when SERVING.
int CmdHealth(const Common& c, const std::string& service) {
  auto stub = grpc::health::v1::Health::NewStub(OpenChannel(c, false));
  grpc::ClientContext ctx;
  ctx.set_deadline(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(c.timeout * 1000)));
  grpc::health::v1::HealthCheckRequest req;
  req.set_service(service);
  grpc::health::v1::HealthCheckResponse resp;
  grpc::Status s = stub->Check(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  const std::string status =
      grpc::health::v1::HealthCheckResponse::ServingStatus_Name(resp.status());
  if (c.json) {
    PrintJson(Json{{"service", service}, {"status", status}});
  } else {
    std::printf("%s\n", status.c_str());
  }
  return resp.status() == grpc::health::v1::HealthCheckResponse::SERVING ? 0 : 1;
}

int CmdUnload(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::UnloadMeshRequest req;
  req.set_name(c.mesh);
  v1::UnloadMeshResponse resp;
  grpc::Status s = stub->UnloadMesh(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson({{"name", c.mesh}, {"unloaded", true}});
  } else {
    std::printf("unloaded %s\n", c.mesh.c_str());
  }
  return 0;
}

// The size and lower-case hex SHA-256 of a file, which an upload declares
// before its bytes.
bool SizeAndSha256(const std::string& path, uint64_t* size, std::string* sha256) {
  std::ifstream in(path, std::ios::binary);
  std::unique_ptr<EVP_MD_CTX, decltype(&EVP_MD_CTX_free)> ctx(EVP_MD_CTX_new(), EVP_MD_CTX_free);
  if (!in || !ctx || EVP_DigestInit_ex(ctx.get(), EVP_sha256(), nullptr) != 1) return false;
  std::vector<char> buffer(1 << 20);
  *size = 0;
  while (in) {
    in.read(buffer.data(), buffer.size());
    if (EVP_DigestUpdate(ctx.get(), buffer.data(), in.gcount()) != 1) return false;
    *size += in.gcount();
  }
  if (!in.eof()) return false;
  unsigned char digest[EVP_MAX_MD_SIZE];
  unsigned int length = 0;
  if (EVP_DigestFinal_ex(ctx.get(), digest, &length) != 1) return false;
  sha256->clear();
  for (unsigned int i = 0; i < length; ++i) absl::StrAppendFormat(sha256, "%02x", digest[i]);
  return true;
}

int CmdLoad(const Common& c, const std::string& path, const std::string& upload, bool repair) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::Mesh resp;
  grpc::Status s;
  if (!upload.empty()) {
    std::ifstream in(upload, std::ios::binary);
    if (!in) return FailText("cannot read " + upload);
    // The format is the file's extension: say so here rather than send the
    // whole path as a format.
    const std::string ext = std::filesystem::path(upload).extension().string();
    if (ext.size() < 2) {
      return FailText(upload + " has no extension naming its format (.obj, .off, .ply or .stl)");
    }
    // The server registers the upload only if exactly these bytes arrive:
    // a file changed while it is sent is refused, not half registered.
    uint64_t total = 0;
    std::string sha256;
    if (!SizeAndSha256(upload, &total, &sha256)) return FailText("cannot read " + upload);
    if (total == 0) return FailText(upload + " is empty");
    auto writer = stub->UploadMesh(&ctx, &resp);
    std::vector<char> buffer(1 << 20);
    bool first = true;
    while (in || first) {
      in.read(buffer.data(), buffer.size());
      v1::UploadMeshRequest chunk;
      if (first) {
        chunk.set_name(c.mesh);
        chunk.set_format(ext.substr(1));
        chunk.set_repair_non_manifold(repair);
        chunk.set_total_bytes(total);
        chunk.set_sha256(sha256);
        first = false;
      }
      chunk.set_data(buffer.data(), in.gcount());
      if (!writer->Write(chunk)) break;
    }
    writer->WritesDone();
    s = writer->Finish();
  } else {
    v1::RegisterMeshRequest req;
    req.set_name(c.mesh);
    req.set_path(path);
    req.set_repair_non_manifold(repair);
    s = stub->RegisterMesh(&ctx, req, &resp);
  }
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson({{"name", resp.name()},
               {"fingerprint", resp.fingerprint()},
               {"restored", resp.restored()},
               {"repair_non_manifold", resp.repair_non_manifold()},
               {"vertex_copies",
                [&] {
                  Json copies = Json::array();
                  for (const auto& copy : resp.vertex_copies()) {
                    copies.push_back({{"original", copy.original()}, {"copy", copy.copy()}});
                  }
                  return copies;
                }()},
               {"diagnostics", DiagnosticsJson(resp.diagnostics())}});
  } else {
    std::printf("registered %s: %lu vertices, %lu faces, fingerprint %s%s\n", resp.name().c_str(),
                resp.diagnostics().vertices(), resp.diagnostics().faces(),
                resp.fingerprint().c_str(), resp.restored() ? " (restored from its snapshot)" : "");
  }
  return 0;
}

int CmdGraph(const Common& c, bool wait, bool cancel) {
  auto stub = Connect(c);
  v1::Graph g;
  {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    grpc::Status s;
    if (cancel) {
      v1::CancelGraphRequest req;
      req.set_mesh(c.mesh);
      req.set_epsilon(c.epsilon);
      req.set_pseudo_vertices(c.pseudo_vertices);
      s = stub->CancelGraph(&ctx, req, &g);
    } else {
      v1::RequestGraphRequest req;
      req.set_mesh(c.mesh);
      req.set_epsilon(c.epsilon);
      req.set_pseudo_vertices(c.pseudo_vertices);
      s = stub->RequestGraph(&ctx, req, &g);
    }
    if (!s.ok()) return Fail(s);
  }
  if (wait && !cancel) {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    // --timeout bounds each call, not a build: a large mesh's takes minutes.
    // The stream ends when the graph is ready, failed or cancelled.
    ctx.set_deadline(std::chrono::system_clock::time_point::max());
    v1::GetGraphRequest req;
    req.set_mesh(c.mesh);
    req.set_epsilon(g.epsilon());
    req.set_pseudo_vertices(g.pseudo_vertices());
    auto reader = stub->WatchGraph(&ctx, req);
    const bool bar = !c.json && isatty(STDERR_FILENO);
    while (reader->Read(&g)) {
      if (bar) {
        const int width = 40, filled = static_cast<int>(g.progress() * width);
        std::fprintf(stderr, "\r%-10s [%s%s] %5.1f%%", g.phase().c_str(),
                     std::string(filled, '#').c_str(), std::string(width - filled, ' ').c_str(),
                     100 * g.progress());
      }
    }
    if (bar) std::fprintf(stderr, "\n");
    grpc::Status s = reader->Finish();
    if (!s.ok()) return Fail(s);
  }
  if (c.json) {
    PrintJson(GraphJson(g));
  } else {
    std::printf("graph %s at eps %g%s: %s%s%s (%lu nodes, %lu edges, %lu bytes%s)\n",
                g.mesh().c_str(), g.epsilon(), g.pseudo_vertices() ? " with pseudo vertices" : "",
                StateName(g.state()), g.error().empty() ? "" : ": ", g.error().c_str(), g.nodes(),
                g.edges(), g.bytes(), g.from_file() ? ", mapped from the graph directory" : "");
  }
  return g.state() == v1::GRAPH_STATE_FAILED ? 1 : 0;
}

int CmdStatus(const Common& c) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::ListGraphsResponse resp;
  grpc::Status s = stub->ListGraphs(&ctx, {}, &resp);
  if (!s.ok()) return Fail(s);
  Json list = Json::array();
  for (int i = 0; i < resp.graphs_size(); ++i) {
    const auto& g = resp.graphs(i);
    if (c.json) {
      list.push_back(GraphJson(g));
    } else {
      std::printf("%-16s eps %-8g %-7s %-10s %5.1f%% %12lu bytes %s%s\n", g.mesh().c_str(),
                  g.epsilon(), g.pseudo_vertices() ? "pseudo" : "", StateName(g.state()),
                  100 * g.progress(), g.bytes(), g.mapped() ? "mapped" : "resident",
                  g.error().empty() ? "" : (" " + g.error()).c_str());
    }
  }
  if (c.json) PrintJson(list);
  return 0;
}

// The geometry a coloured .ply field needs: the local copy of the mesh.
absl::StatusOr<TriangleSoup> GeometryFor(const std::string& out, const std::string& mesh_file) {
  if (!absl::EndsWithIgnoreCase(out, ".ply")) return TriangleSoup{};
  if (mesh_file.empty()) {
    return absl::InvalidArgumentError(out + ": .ply output needs --mesh-file (the mesh geometry)");
  }
  return ReadTriangleSoup(mesh_file);
}

int CmdField(const Common& c, const std::vector<std::string>& sources, const std::string& out,
             const std::string& labels_out, double radius, const std::string& method, bool f32,
             const std::string& mesh_file) {
  // Refused before the query, not after it.
  absl::StatusOr<TriangleSoup> geometry = TriangleSoup{};
  if (!out.empty()) {
    geometry = GeometryFor(out, mesh_file);
    if (!geometry.ok()) return FailText(std::string(geometry.status().message()));
    absl::Status s = CheckFieldPath(out, true);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  if (!labels_out.empty()) {
    absl::Status s = CheckLabelPath(labels_out);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  auto stub = Connect(c, /*connected=*/true);
  v1::DistanceFieldRequest req;
  req.set_mesh(c.mesh);
  req.set_epsilon(c.epsilon);
  req.set_pseudo_vertices(c.pseudo_vertices);
  req.set_max_distance(radius);
  req.set_method(method);
  req.set_float32(f32);
  req.set_nearest_source(!labels_out.empty());
  std::vector<v1::SurfacePoint> points;
  int rc = 0;
  if (!ResolvePoints(stub.get(), c, sources, &points, &rc)) return rc;
  for (auto& p : points) *req.add_sources() = p;
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  const auto start = std::chrono::steady_clock::now();
  auto reader = stub->DistanceField(&ctx, req);
  std::vector<double> values;
  std::vector<uint32_t> labels;
  v1::DistanceFieldChunk chunk;
  while (reader->Read(&chunk)) {
    values.resize(chunk.total());
    if (!labels_out.empty()) labels.resize(chunk.total());
    for (int i = 0; i < chunk.nearest_source_size(); ++i) {
      labels[chunk.offset() + i] = chunk.nearest_source(i);
    }
    for (int i = 0; i < chunk.values_size(); ++i) values[chunk.offset() + i] = chunk.values(i);
    for (int i = 0; i < chunk.values_f32_size(); ++i)
      values[chunk.offset() + i] = chunk.values_f32(i);
  }
  grpc::Status s = reader->Finish();
  if (!s.ok()) return Fail(s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!out.empty()) {
    absl::Status w = WriteField(out, values, &*geometry);
    if (!w.ok()) return FailText(std::string(w.message()));
  }
  if (!labels_out.empty()) {
    absl::Status w = WriteLabels(labels_out, labels);
    if (!w.ok()) return FailText(std::string(w.message()));
  }
  size_t reached = 0;
  double far = 0;
  for (double v : values) {
    if (std::isfinite(v)) ++reached, far = std::max(far, v);
  }
  if (c.json) {
    PrintJson({{"vertices", values.size()},
               {"reached", reached},
               {"max_distance", far},
               {"seconds", seconds}});
  } else {
    std::printf("field on %s: %zu of %zu vertices reached, farthest %.9g, %.2f ms%s%s\n",
                c.mesh.c_str(), reached, values.size(), far, 1e3 * seconds,
                out.empty() ? "" : ", written to ", out.c_str());
  }
  return 0;
}

int CmdDistance(const Common& c, const std::string& from, const std::string& to,
                const std::string& pairs_file, bool with_path, const std::string& path_out = {}) {
  if (!path_out.empty()) {
    absl::Status s = CheckPolylinePath(path_out);
    if (!s.ok()) return FailText(std::string(s.message()));
  }
  auto stub = Connect(c);
  std::vector<std::string> specs;
  if (!pairs_file.empty()) {
    auto pairs = ReadSpecPairs(pairs_file);
    if (!pairs.ok()) return FailText(std::string(pairs.status().message()));
    for (auto& [a, b] : *pairs) specs.push_back(a), specs.push_back(b);
  } else {
    if (from.empty() || to.empty()) return FailText("give --from and --to, or --pairs FILE");
    specs = {from, to};
  }
  std::vector<v1::SurfacePoint> points;
  int rc = 0;
  std::vector<Json> snap_distances;
  if (!ResolvePoints(stub.get(), c, specs, &points, &rc, &snap_distances)) return rc;
  v1::DistanceRequest req;
  req.set_mesh(c.mesh);
  req.set_epsilon(c.epsilon);
  req.set_pseudo_vertices(c.pseudo_vertices);
  req.set_with_path(with_path);
  for (size_t i = 0; i + 1 < points.size(); i += 2) {
    auto* p = req.add_pairs();
    *p->mutable_from() = points[i];
    *p->mutable_to() = points[i + 1];
  }
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::DistanceResponse resp;
  const auto start = std::chrono::steady_clock::now();
  grpc::Status s = stub->Distance(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  const double seconds =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (!path_out.empty() && resp.results_size() == 1) {
    std::vector<Vec3> polyline;
    for (const auto& q : resp.results(0).path().points()) {
      polyline.push_back({q.xyz().x(), q.xyz().y(), q.xyz().z()});
    }
    if (polyline.empty()) return FailText("no path to write: the points are unreachable");
    absl::Status w = WritePolyline(path_out, polyline);
    if (!w.ok()) return FailText(std::string(w.message()));
  }
  Json results = Json::array();
  for (int i = 0; i < resp.results_size(); ++i) {
    const auto& r = resp.results(i);
    if (c.json) {
      Json result = {{"from", specs[2 * i]},
                     {"to", specs[2 * i + 1]},
                     {"distance", r.distance()},
                     {"reachable", r.reachable()},
                     {"from_snap_distance", snap_distances[2 * i]},
                     {"to_snap_distance", snap_distances[2 * i + 1]}};
      if (with_path) {
        Json path = Json::array();
        for (const auto& q : r.path().points()) {
          path.push_back({{"point", server::FormatPoint(q.point())},
                          {"xyz", {q.xyz().x(), q.xyz().y(), q.xyz().z()}}});
        }
        result["path"] = std::move(path);
      }
      results.push_back(std::move(result));
    } else {
      std::printf("%s -> %s: %s\n", specs[2 * i].c_str(), specs[2 * i + 1].c_str(),
                  r.reachable() ? absl::StrFormat("%.12g", r.distance()).c_str() : "unreachable");
      for (const auto& q : r.path().points()) {
        std::printf("  %-48s %.9g %.9g %.9g\n", server::FormatPoint(q.point()).c_str(), q.xyz().x(),
                    q.xyz().y(), q.xyz().z());
      }
    }
  }
  if (c.json) {
    PrintJson(results);
  } else {
    std::printf("(%d pairs in %.2f ms, eps %g%s)\n", resp.results_size(), 1e3 * seconds,
                resp.echo().epsilon(), resp.echo().pseudo_vertices() ? ", pseudo vertices" : "");
  }
  return 0;
}

int CmdMatrix(const Common& c, const std::vector<std::string>& sources,
              const std::vector<std::string>& targets) {
  auto stub = Connect(c);
  std::vector<v1::SurfacePoint> s_points, t_points;
  int rc = 0;
  if (!ResolvePoints(stub.get(), c, sources, &s_points, &rc)) return rc;
  if (!ResolvePoints(stub.get(), c, targets, &t_points, &rc)) return rc;
  v1::MatrixRequest req;
  req.set_mesh(c.mesh);
  req.set_epsilon(c.epsilon);
  req.set_pseudo_vertices(c.pseudo_vertices);
  for (auto& p : s_points) *req.add_sources() = p;
  for (auto& p : t_points) *req.add_targets() = p;
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::MatrixResponse resp;
  grpc::Status s = stub->Matrix(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    Json rows = Json::array();
    for (uint32_t i = 0; i < resp.rows(); ++i) {
      Json row = Json::array();
      for (uint32_t j = 0; j < resp.cols(); ++j) row.push_back(resp.distances(i * resp.cols() + j));
      rows.push_back(std::move(row));
    }
    PrintJson({{"rows", resp.rows()}, {"cols", resp.cols()}, {"distances", std::move(rows)}});
    return 0;
  }
  for (uint32_t i = 0; i < resp.rows(); ++i) {
    for (uint32_t j = 0; j < resp.cols(); ++j) {
      std::printf("%s%14.9g", j ? " " : "", resp.distances(i * resp.cols() + j));
    }
    std::printf("\n");
  }
  return 0;
}

int CmdSample(const Common& c, uint32_t count, uint64_t seed) {
  auto stub = Connect(c);
  grpc::ClientContext ctx;
  Prepare(&ctx, c);
  v1::SamplePointsRequest req;
  req.set_mesh(c.mesh);
  req.set_epsilon(c.epsilon);
  req.set_pseudo_vertices(c.pseudo_vertices);
  req.set_count(count);
  req.set_seed(seed);
  v1::SamplePointsResponse resp;
  grpc::Status s = stub->SamplePoints(&ctx, req, &resp);
  if (!s.ok()) return Fail(s);
  if (c.json) {
    PrintJson({{"vertices", std::vector<uint32_t>(resp.vertices().begin(), resp.vertices().end())},
               {"covering_radius", resp.covering_radius()}});
  } else {
    std::printf("%d points, covering radius %.9g:", resp.vertices_size(), resp.covering_radius());
    for (uint32_t v : resp.vertices()) std::printf(" v:%u", v);
    std::printf("\n");
  }
  return 0;
}

int CmdSnap(const Common& c, const std::vector<std::string>& positions) {
  auto stub = Connect(c);
  std::vector<v1::SurfacePoint> points;
  std::vector<std::string> specs;
  for (const auto& p : positions) specs.push_back(p.rfind("xyz:", 0) == 0 ? p : "xyz:" + p);
  int rc = 0;
  std::vector<Json> distances;
  if (!ResolvePoints(stub.get(), c, specs, &points, &rc, &distances)) return rc;
  Json snapped = Json::array();
  for (size_t i = 0; i < points.size(); ++i) {
    if (c.json) {
      snapped.push_back({{"position", specs[i]},
                         {"point", server::FormatPoint(points[i])},
                         {"snap_distance", distances[i]}});
    } else {
      std::printf("%s -> %s (%s from the surface)\n", specs[i].c_str(),
                  server::FormatPoint(points[i]).c_str(), distances[i].dump().c_str());
    }
  }
  if (c.json) PrintJson(snapped);
  return 0;
}

// A bounded load: `concurrency` clients issue random point-to-point queries
// between vertices until `count` queries or `duration` seconds are done.
int CmdBench(const Common& c, int concurrency, double duration, int count, uint32_t vertices,
             bool with_path, bool face_points) {
  auto stub = Connect(c);
  uint32_t faces = 0;
  {
    grpc::ClientContext ctx;
    Prepare(&ctx, c);
    v1::GetMeshRequest req;
    req.set_name(c.mesh);
    v1::Mesh m;
    grpc::Status s = stub->GetMesh(&ctx, req, &m);
    if (!s.ok()) return Fail(s);
    if (vertices == 0) vertices = m.diagnostics().vertices();
    faces = m.diagnostics().faces();
  }
  if (face_points && faces == 0) {
    return Fail(grpc::Status(grpc::StatusCode::FAILED_PRECONDITION, "the mesh has no faces"));
  }
  std::mutex mu;
  std::vector<double> latencies;
  std::atomic<int> issued{0}, failed{0};
  const auto start = std::chrono::steady_clock::now();
  const auto stop = start + std::chrono::milliseconds(static_cast<int64_t>(duration * 1000));
  std::vector<std::thread> workers;
  for (int w = 0; w < concurrency; ++w) {
    workers.emplace_back([&, w] {
      uint64_t state = 0x9e3779b97f4a7c15ull * (w + 1);
      auto random = [&] {
        state ^= state << 13, state ^= state >> 7, state ^= state << 17;
        return state;
      };
      // A vertex, or a point inside a face with random barycentrics.
      auto pick = [&](v1::SurfacePoint* p) {
        if (!face_points) {
          p->set_vertex(static_cast<uint32_t>(random() % vertices));
          return;
        }
        const double u = (random() >> 11) * 0x1p-53, v = (random() >> 11) * 0x1p-53;
        const double b0 = u + v > 1 ? 1 - u : u, b1 = u + v > 1 ? 1 - v : v;
        auto* f = p->mutable_face();
        f->set_face(static_cast<uint32_t>(random() % faces));
        f->set_b0(b0);
        f->set_b1(b1);
        f->set_b2(1 - b0 - b1);
      };
      std::vector<double> mine;
      while (std::chrono::steady_clock::now() < stop && issued.fetch_add(1) < count) {
        v1::DistanceRequest req;
        req.set_mesh(c.mesh);
        req.set_epsilon(c.epsilon);
        req.set_pseudo_vertices(c.pseudo_vertices);
        req.set_with_path(with_path);
        auto* p = req.add_pairs();
        pick(p->mutable_from());
        pick(p->mutable_to());
        grpc::ClientContext ctx;
        Prepare(&ctx, c);
        v1::DistanceResponse resp;
        const auto t0 = std::chrono::steady_clock::now();
        grpc::Status s = stub->Distance(&ctx, req, &resp);
        const double dt =
            std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
        if (s.ok()) {
          mine.push_back(dt);
        } else {
          ++failed;
        }
      }
      std::lock_guard<std::mutex> lock(mu);
      latencies.insert(latencies.end(), mine.begin(), mine.end());
    });
  }
  for (auto& t : workers) t.join();
  const double elapsed =
      std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  std::sort(latencies.begin(), latencies.end());
  auto pct = [&](double q) {
    return latencies.empty() ? 0.0 : latencies[static_cast<size_t>(q * (latencies.size() - 1))];
  };
  const double qps = latencies.size() / elapsed;
  if (c.json) {
    PrintJson({{"queries", latencies.size()},
               {"failed", failed.load()},
               {"seconds", elapsed},
               {"qps", qps},
               {"p50_ms", 1e3 * pct(0.5)},
               {"p90_ms", 1e3 * pct(0.9)},
               {"p99_ms", 1e3 * pct(0.99)},
               {"max_ms", 1e3 * pct(1.0)},
               {"concurrency", concurrency}});
  } else {
    std::printf(
        "%zu queries (%d failed) in %.2f s: %.1f queries/s; latency p50 %.3f ms, p90 %.3f "
        "ms, p99 %.3f ms, max %.3f ms\n",
        latencies.size(), failed.load(), elapsed, qps, 1e3 * pct(0.5), 1e3 * pct(0.9),
        1e3 * pct(0.99), 1e3 * pct(1.0));
  }
  return failed.load() ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  CLI::App app{
      "geodesic: client of the geodesicd server.\n\n"
      "Surface points: v:ID (vertex), e:EDGE:T (edge point), f:FACE:B0,B1,B2 (face point; the\n"
      "barycentric coordinates weight the face's vertices in the order the mesh file lists them\n"
      "for that face) or xyz:X,Y,Z (snapped to the surface). Ids are the file's order.",
      "geodesic"};
  app.set_version_flag("--version", absl::StrFormat("geodesic %s (%s build)", geodesic::kVersion,
                                                    geodesic::kBuildType));
  // Every option's help shows its default.
  app.option_defaults()->always_capture_default();
  Common c;
  if (const char* server = std::getenv("GEODESIC_SERVER"); server && *server) c.server = server;
  app.add_option("--server", c.server, "geodesicd address (default: $GEODESIC_SERVER if set)");
  auto* mesh_option =
      app.add_option("--mesh", c.mesh, "mesh name ('load' defaults to the file's stem)")
          ->capture_default_str();
  app.add_option("--eps", c.epsilon, "graph accuracy (0: the server's default)");
  constexpr const char* kPseudoHelp =
      "the graph with pseudo vertices (anisotropic meshes), a separate graph from the plain one "
      "of --eps";
  app.add_flag("--pseudo-vertices", c.pseudo_vertices, kPseudoHelp);
  app.add_flag("--json", c.json, "machine-readable output");
  app.add_option("--timeout", c.timeout, "deadline per call, seconds")
      ->check(NumberIn(1e-3, 1e6, "seconds in [0.001, 1e6]"));
  app.add_option("--tls-ca", c.tls_ca, "PEM CA certificate of the server: connect with TLS")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-cert", c.tls_cert, "PEM client certificate (servers with --tls-client-ca)")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", c.tls_key, "PEM private key of --tls-cert")->check(CLI::ExistingFile);
  app.add_option("--token-file", c.token_file,
                 "file holding the bearer token (default: $GEODESIC_TOKEN)")
      ->check(CLI::ExistingFile);
  app.require_subcommand(1);

  app.add_subcommand("meshes", "list registered meshes");
  auto* health = app.add_subcommand(
      "health", "the server's gRPC health (no token needed); exit 0 only when SERVING");
  std::string health_service;
  health->add_option("--service", health_service,
                     "service to ask about: empty for the server, geodesic.v1.Geodesic, or a "
                     "graph's name as in `status`");
  auto* load =
      app.add_subcommand("load", "register a mesh (server-side path under --mesh-root, or upload)");
  std::string load_path, upload;
  load->add_option("path", load_path, "path relative to the server's --mesh-root");
  load->add_option("--upload", upload, "upload this local file instead");
  bool repair = false;
  load->add_flag("--repair-non-manifold", repair,
                 "split non-manifold vertices into one copy per fan (listed) instead of refusing");
  app.add_subcommand("unload",
                     "unregister --mesh and drop its graphs (here and, through the "
                     "shared catalog, on every replica)");
  auto* graph = app.add_subcommand("graph", "request the graph of --mesh at --eps");
  bool wait = false, cancel = false;
  graph->add_flag("--wait", wait, "wait for it, with a progress bar");
  graph->add_flag("--cancel", cancel, "cancel its build");
  app.add_subcommand("status", "list graphs and their state");
  auto* field = app.add_subcommand("field", "distance field");
  std::vector<std::string> sources;
  std::string out, labels_out, path_out, method = "lc", mesh_file;
  double radius = 0;
  bool f32 = false;
  field->add_option("--source", sources, "source point(s)")->required();
  field->add_option("--out", out,
                    "write the field as .f64 (float64 per vertex), .npy, .csv, or .ply (colours; "
                    "needs --mesh-file)");
  field->add_option("--labels-out", labels_out,
                    "write each vertex's nearest source (geodesic Voronoi regions) as .npy, .csv "
                    "or .u32");
  field->add_option("--mesh-file", mesh_file, "local copy of the mesh, for .ply output");
  field->add_option("--radius", radius, "only vertices within this distance (0: no limit)")
      ->check(NumberIn(0, std::numeric_limits<double>::infinity(), "a distance, 0 or more"));
  field->add_option("--method", method,
                    "lc (default: each vertex relaxes only the fan of the edge it was reached by) "
                    "or dijkstra (every edge); both give the graph's shortest distances");
  field->add_flag("--float32", f32, "transfer float32 values");
  auto* distance = app.add_subcommand("distance", "point-to-point distance");
  std::string from, to, pairs;
  bool with_path = false;
  distance->add_option("--from", from, "first point");
  distance->add_option("--to", to, "second point");
  distance->add_option("--pairs", pairs, "file with one pair of points per line");
  distance->add_flag("--path", with_path, "also return the geodesic path");
  auto* path = app.add_subcommand("path", "geodesic path between two points");
  path->add_option("--from", from, "first point")->required();
  path->add_option("--to", to, "second point")->required();
  path->add_option("--out", path_out, "write the path as a .csv, .ply or .obj polyline");
  auto* matrix = app.add_subcommand("matrix", "sources x targets distances");
  std::vector<std::string> targets;
  matrix->add_option("--source", sources, "source points")->required();
  matrix->add_option("--target", targets, "target points")->required();
  auto* sample = app.add_subcommand(
      "sample", "geodesic farthest-point sampling: COUNT vertices spread over --mesh");
  uint32_t sample_count = 0;
  uint64_t sample_seed = 0;
  sample->add_option("--count", sample_count, "points to choose")->required();
  sample->add_option("--seed", sample_seed, "picks the first point (default 0)");
  auto* snap = app.add_subcommand("snap", "nearest surface point to positions X,Y,Z");
  std::vector<std::string> positions;
  snap->add_option("positions", positions, "X,Y,Z ...")->required();
  auto* bench = app.add_subcommand("bench", "bounded load of random point-to-point queries");
  int concurrency = 4, count = 1000;
  double duration = 10;
  uint32_t bench_vertices = 0;
  bench->add_option("--concurrency", concurrency, "parallel clients");
  bench->add_option("--duration", duration, "stop after this many seconds");
  bench->add_option("--count", count, "stop after this many queries");
  bench->add_flag("--path", with_path, "also request paths");
  bool face_points = false;
  bench->add_flag("--face-points", face_points,
                  "random points inside faces (each end then joined to the graph by its own "
                  "exact direct geodesics) instead of random vertices");
  // Also accepted after the subcommand, where `graph --pseudo-vertices` has
  // always been, and where the offline commands take --json.
  for (CLI::App* sub : {graph, field, distance, path, matrix, sample, bench}) {
    sub->add_flag("--pseudo-vertices", c.pseudo_vertices, kPseudoHelp);
  }
  for (CLI::App* sub : app.get_subcommands({}))
    sub->add_flag("--json", c.json, "machine-readable output");
  CLI11_PARSE(app, argc, argv);
  if (!LoadSecurity(c)) return 2;
  if (app.got_subcommand("meshes")) return CmdMeshes(c);
  if (app.got_subcommand("health")) return CmdHealth(c, health_service);
  if (app.got_subcommand("load")) {
    // 'geodesic load kitten.off' registers 'kitten', not the default mesh.
    if (mesh_option->count() == 0) {
      c.mesh = std::filesystem::path(upload.empty() ? load_path : upload).stem().string();
    }
    return CmdLoad(c, load_path, upload, repair);
  }
  if (app.got_subcommand("unload")) return CmdUnload(c);
  if (app.got_subcommand("graph")) return CmdGraph(c, wait, cancel);
  if (app.got_subcommand("status")) return CmdStatus(c);
  if (app.got_subcommand("field"))
    return CmdField(c, sources, out, labels_out, radius, method, f32, mesh_file);
  if (app.got_subcommand("distance")) return CmdDistance(c, from, to, pairs, with_path);
  if (app.got_subcommand("path")) return CmdDistance(c, from, to, "", true, path_out);
  if (app.got_subcommand("matrix")) return CmdMatrix(c, sources, targets);
  if (app.got_subcommand("snap")) return CmdSnap(c, positions);
  if (app.got_subcommand("sample")) return CmdSample(c, sample_count, sample_seed);
  if (app.got_subcommand("bench"))
    return CmdBench(c, concurrency, duration, count, bench_vertices, with_path, face_points);
  return 2;
}
