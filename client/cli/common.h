// What every command of the `geodesic` client shares: the global flags,
// the connection, failures and their exit codes, point specs, --json output.
#ifndef GEODESIC_CLIENT_CLI_COMMON_H_
#define GEODESIC_CLIENT_CLI_COMMON_H_

#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "CLI/CLI.hpp"
#include "geodesic/v1/geodesic.grpc.pb.h"
#include "grpcpp/grpcpp.h"
#include "nlohmann/json.hpp"
#include "server/api/json_views.h"

namespace geodesic::cli {

struct Common {
  std::string server = "127.0.0.1:50051";
  std::string mesh = "spot";
  double epsilon = 0;
  // The graph with pseudo vertices rather than the plain one of --eps: a
  // separate graph, for graph requests and queries alike.
  bool pseudo_vertices = false;
  // A certified graph (--max-error): the server chooses its epsilon, and
  // --eps is ignored. 0: not certified.
  double max_error = 0;
  bool json = false;
  double timeout = 600;
  // Security: TLS when a CA is given; a client certificate for mutual TLS;
  // a bearer token (from --token-file or $GEODESIC_TOKEN).
  std::string tls_ca, tls_cert, tls_key, token_file;
  std::string token;
  grpc::SslCredentialsOptions tls;
};

// The flags every command takes, on `app` (--server, --mesh, --eps, --json,
// --timeout, TLS and token). Returns --mesh's option, to tell whether it was
// given.
CLI::Option* AddCommonFlags(CLI::App& app, Common& c);
inline constexpr const char* kPseudoHelp =
    "the graph with pseudo vertices (anisotropic meshes), a separate graph from the plain one "
    "of --eps";
// Reads the certificate and token files named by the flags; false after
// saying what is wrong.
bool LoadSecurity(Common& c);

// `connected`: wait (up to 5 s, and at most the call timeout) until the
// connection is up, so that a call timed after it measures the call, not the
// handshake. A server that is down fails the call after that, not after a
// whole --timeout.
std::shared_ptr<grpc::Channel> OpenChannel(const Common& c, bool connected);
std::unique_ptr<v1::Geodesic::Stub> Connect(const Common& c, bool connected = false);
// Every call carries the mesh name so that a proxy can route by it.
void Prepare(grpc::ClientContext* ctx, const Common& c);
// The graph the flags name (--mesh, --eps, --pseudo-vertices, --max-error), as every
// request that names a graph carries it in its `graph`.
v1::GraphSelector Selector(const Common& c);

// A number in [low, high] (NaN is not), as a CLI11 check.
CLI::Validator NumberIn(double low, double high, const std::string& what);

// Say why on stderr; the exit code: 3 when the server is unavailable, 1 for
// other failed calls, 2 for what is wrong on this side.
int Fail(const grpc::Status& s);
int FailText(const std::string& message);

// Resolves point specs, snapping xyz positions through the server.
// `snap_distances`, if given, gets for each spec how far its xyz: position
// was from the surface point it snapped to (null for other specs).
bool ResolvePoints(v1::Geodesic::Stub* stub, const Common& c, const std::vector<std::string>& specs,
                   std::vector<v1::SurfacePoint>* out, int* rc,
                   std::vector<nlohmann::ordered_json>* snap_distances = nullptr);

// --json output. Keys keep the order they are set in; strings are escaped;
// doubles print with full (round-trip) precision; +inf and NaN, which JSON
// cannot hold, print as null.
using Json = nlohmann::ordered_json;
void PrintJson(const Json& value);
// "certified: max error ... from N sources ..." for a graph with a
// certificate; empty otherwise.
std::string CertificateText(const v1::Graph& g);

// A subcommand and what runs it once the command line is parsed. Graph
// commands also take --pseudo-vertices after their name.
struct Command {
  CLI::App* app;
  std::function<int()> run;
  bool graph = false;
};

}  // namespace geodesic::cli

#endif  // GEODESIC_CLIENT_CLI_COMMON_H_
