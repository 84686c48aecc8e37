#include "client/cli/common.h"

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <sstream>

#include "absl/status/status.h"
#include "absl/strings/str_format.h"
#include "server/api/convert.h"

namespace geodesic::cli {

CLI::Option* AddCommonFlags(CLI::App& app, Common& c) {
  if (const char* server = std::getenv("GEODESIC_SERVER"); server && *server) c.server = server;
  app.add_option("--server", c.server, "geodesicd address (default: $GEODESIC_SERVER if set)");
  auto* mesh_option =
      app.add_option("--mesh", c.mesh, "mesh name ('load' defaults to the file's stem)")
          ->capture_default_str();
  app.add_option("--eps", c.epsilon, "graph accuracy (0: the server's default)");
  app.add_flag("--pseudo-vertices", c.pseudo_vertices, kPseudoHelp);
  app.add_option("--max-error", c.max_error,
                 "a certified graph: relative errors measured at most this, in [1e-5, 0.5]; the "
                 "server chooses the epsilon (--eps is ignored), builds, measures and rebuilds "
                 "tighter until the bound holds (0: not certified)");
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
  return mesh_option;
}

v1::GraphSelector Selector(const Common& c) {
  v1::GraphSelector out = server::MakeSelector(c.mesh, c.epsilon, c.pseudo_vertices);
  out.set_max_error(c.max_error);
  return out;
}

namespace {

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

}  // namespace

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

std::unique_ptr<v1::Geodesic::Stub> Connect(const Common& c, bool connected) {
  return v1::Geodesic::NewStub(OpenChannel(c, connected));
}

void Prepare(grpc::ClientContext* ctx, const Common& c) {
  ctx->AddMetadata("x-geodesic-mesh", c.mesh);
  if (!c.token.empty()) ctx->AddMetadata("authorization", "Bearer " + c.token);
  ctx->set_deadline(std::chrono::system_clock::now() +
                    std::chrono::milliseconds(static_cast<int64_t>(c.timeout * 1000)));
}

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

bool ResolvePoints(v1::Geodesic::Stub* stub, const Common& c, const std::vector<std::string>& specs,
                   std::vector<v1::SurfacePoint>* out, int* rc,
                   std::vector<nlohmann::ordered_json>* snap_distances) {
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

void PrintJson(const Json& value) { std::printf("%s\n", value.dump().c_str()); }

std::string CertificateText(const v1::Graph& g) {
  if (!g.has_certificate()) return "";
  const v1::GraphCertificate& c = g.certificate();
  return absl::StrFormat(
      "certified: max error %.3g (mean %.3g) measured from %u sources (seed %u), bound %g, "
      "%s, %u build%s",
      c.measured_max_error(), c.measured_mean_error(), c.sources(), c.seed(), c.max_error_bound(),
      c.sound() ? "sound" : "UNSOUND", c.builds(), c.builds() == 1 ? "" : "s");
}

}  // namespace geodesic::cli
