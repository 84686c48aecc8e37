#include "server/app/serve_options.h"

#include <malloc.h>

#include <algorithm>
#include <cctype>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <memory>
#include <set>
#include <sstream>
#include <thread>
#include <variant>
#include <vector>

#include "CLI/CLI.hpp"
#include "absl/strings/ascii.h"
#include "absl/strings/match.h"
#include "absl/strings/str_cat.h"
#include "absl/strings/str_split.h"
#include "grpcpp/security/server_credentials.h"
#include "server/base/byte_size.h"
#include "server/base/log.h"

namespace geodesic::server {
namespace {

std::string DefaultGraphDir() {
  if (const char* xdg = std::getenv("XDG_CACHE_HOME"); xdg && *xdg) {
    return std::string(xdg) + "/geodesicd";
  }
  if (const char* home = std::getenv("HOME"); home && *home) {
    return std::string(home) + "/.cache/geodesicd";
  }
  return "/tmp/geodesicd-graphs";
}

// The bundled sample mesh: GEODESIC_DATA_DIR, or data/ next to the source
// tree the binary was built from (build/bin/../../data), or an install path.
std::string FindSampleMesh(const char* argv0) {
  std::vector<std::filesystem::path> candidates;
  if (const char* dir = std::getenv("GEODESIC_DATA_DIR"); dir && *dir) {
    candidates.push_back(std::filesystem::path(dir) / "spot.obj");
  }
  std::error_code ec;
  auto exe = std::filesystem::read_symlink("/proc/self/exe", ec);
  if (ec) exe = argv0;
  candidates.push_back(exe.parent_path() / "../../data/spot.obj");
  candidates.push_back(exe.parent_path() / "../share/geodesicd/spot.obj");
  candidates.push_back("/usr/share/geodesicd/spot.obj");
  for (const auto& c : candidates) {
    if (std::filesystem::exists(c)) return std::filesystem::weakly_canonical(c).string();
  }
  return "";
}

// Certificates, keys and tokens: small files read once at start.
bool ReadSecretFile(const std::string& flag, const std::string& path, std::string* out) {
  std::ifstream in(path, std::ios::binary);
  std::stringstream text;
  if (in) text << in.rdbuf();
  if (!in || text.str().empty()) {
    std::fprintf(stderr, "geodesicd serve: %s %s: cannot read it or it is empty\n", flag.c_str(),
                 path.c_str());
    return false;
  }
  *out = text.str();
  return true;
}

// Plaintext unless a certificate is given; with a client CA, clients must
// present a certificate it signed (mutual TLS).
std::shared_ptr<grpc::ServerCredentials> ServerCredentials(const ServeOptions& o) {
  if (o.tls_cert.empty() && o.tls_key.empty()) {
    if (!o.tls_client_ca.empty()) {
      std::fprintf(stderr, "geodesicd serve: --tls-client-ca needs --tls-cert and --tls-key\n");
      return nullptr;
    }
    return grpc::InsecureServerCredentials();
  }
  grpc::SslServerCredentialsOptions::PemKeyCertPair pair;
  if (!ReadSecretFile("--tls-cert", o.tls_cert, &pair.cert_chain) ||
      !ReadSecretFile("--tls-key", o.tls_key, &pair.private_key)) {
    return nullptr;
  }
  grpc::SslServerCredentialsOptions options;
  options.pem_key_cert_pairs.push_back(std::move(pair));
  if (!o.tls_client_ca.empty()) {
    if (!ReadSecretFile("--tls-client-ca", o.tls_client_ca, &options.pem_root_certs)) {
      return nullptr;
    }
    options.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(options);
}

// What the command line holds before it is checked and converted: byte
// sizes and durations as text and seconds, the options ServeOptions does
// not keep.
struct ServeFlags {
  std::string memory_limit = "0", disk_limit = "0", build_memory_limit = "0", max_graph_bytes = "0";
  std::string max_exact_bytes = "256M";
  std::string config_path;
  std::string log_level = "info", log_format = "text";
  std::string sample;
  int query_threads = 0;
  bool exact_fans = false;
  bool no_build_on_query = false;
  double http_header_seconds = 0, http_body_seconds = 0, http_idle_seconds = 0;
  std::string auth_token_file;
};

double Seconds(std::chrono::milliseconds d) { return std::chrono::duration<double>(d).count(); }

std::chrono::milliseconds Millis(double seconds) {
  return std::chrono::milliseconds(static_cast<int64_t>(std::max(0.001, seconds) * 1000));
}

void AddStorageFlags(CLI::App& app, ServeFlags& f, ServeOptions& o) {
  app.add_option("--listen", o.listen,
                 "address to serve gRPC on (HOST:PORT; port 0: any free port)");
  app.add_option(
      "--port-file", o.port_file,
      "once listening, write the bound ports here as JSON, {\"grpc\": P} and, with "
      "--metrics-listen or --http-listen, \"metrics\": Q or \"http\": H (replaced atomically: the "
      "file appears complete or not at all); for HOST:0 addresses");
  app.add_option("--graph-dir", o.graph_dir,
                 "where graphs, and snapshots of registered meshes, are written and read back");
  app.add_option("--mesh-root", o.mesh_root, "RegisterMesh paths must lie under this directory");
  app.add_option("--memory-limit", f.memory_limit,
                 "bytes of registered meshes, ready graphs and their query scratch to keep, e.g. "
                 "6G or 512M: least recently used graphs no query holds are evicted to stay "
                 "within it; meshes are not. Running queries reserve their answer and scratch "
                 "bytes within it before they start (0: no limit)");
  app.add_option(
      "--disk-limit", f.disk_limit,
      "bytes --graph-dir may hold, e.g. 50G: least recently used graph files and mesh "
      "snapshots no catalog entry names go first, then catalogued ones (rebuilt when "
      "needed); never a file in use, an uploaded mesh's snapshot or a file written in the "
      "last two minutes. A graph file or snapshot that would still pass it is not written: "
      "the graph fails, the upload is refused (0: no limit)");
  app.add_option("--config", f.config_path,
                 "YAML file of meshes to register and graphs to build at start, and of any "
                 "of these flags by name (flags given here win; see docs/daemon.md)")
      ->check(CLI::ExistingFile);
  app.add_option("--catalog-poll-seconds", o.catalog_poll_seconds,
                 "how often to follow the graph directory's catalog (meshes and graphs other "
                 "replicas registered or unloaded), and to apply --disk-limit");
}

void AddBuildFlags(CLI::App& app, ServeFlags& f, ServeOptions& o) {
  app.add_option("--build-threads", o.build_threads, "threads per graph build (0: all cores)");
  app.add_option("--pseudo-vertex-limit", o.pseudo_vertex_limit,
                 "a graph with pseudo vertices is refused, with its estimated cost, when it "
                 "would have more than this many per mesh vertex (0: no limit)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--build-memory-limit", f.build_memory_limit,
                 "candidate edges a build keeps in memory, e.g. 2G; beyond it they go to an "
                 "unlinked file in --graph-dir (the system's temporary directory without one), "
                 "which counts within --disk-limit while it lasts (0: no limit)");
  app.add_option("--build-workers", o.build_workers,
                 "graphs built at once, besides one build estimated to take longer than "
                 "--large-build-seconds, which runs in a lane of its own");
  app.add_option("--large-build-seconds", o.large_build_seconds,
                 "builds estimated to take longer than this (on --build-threads) run one at a "
                 "time in their own lane, so they never hold the workers small graphs need");
  app.add_option("--max-graph-bytes", f.max_graph_bytes,
                 "RequestGraph refuses graphs whose estimated file passes this, e.g. 4G, with "
                 "RESOURCE_EXHAUSTED naming the estimate (0: no limit; a graph already in "
                 "--graph-dir is always mapped)");
  app.add_option(
         "--exact-landmarks", o.exact_landmarks,
         "exact distance fields from this many landmarks a graph computes in the "
         "background once asked for exact answers (4 bytes per vertex each, and 64 per "
         "half-edge for the face frames the graph's queries then read; one exact field's time "
         "each, on a build worker and its --build-threads): each exact pair then sweeps "
         "a narrower region; with --graph-dir they are kept beside the graph's file "
         "and read back after a restart (0: none, exact pairs prune by the straight "
         "line only)")
      ->check(CLI::Range(0, 256));
  app.add_flag("--exact-fans", f.exact_fans,
               "build graphs with fans from exact local distances instead of the default's "
               "short sweeps: about as narrow, longer builds (graphs found in --graph-dir are "
               "used as they are)");
}

void AddQueryFlags(CLI::App& app, ServeFlags& f, ServiceLimits& limits) {
  app.add_option("--query-threads", f.query_threads,
                 "admitted queries running at once, the rest waiting their turn in arrival "
                 "order (0: the cores)");
  app.add_option("--max-inflight", limits.max_inflight,
                 "queries admitted, running or waiting; beyond them a query is answered "
                 "RESOURCE_EXHAUSTED \"server overloaded\" at once, with a retry-after-ms hint");
  app.add_option("--max-streams", limits.max_streams,
                 "streams open at once (GetGeometry, MatrixRows, DistanceField, WatchGraph, "
                 "UploadMesh); beyond them a stream is answered RESOURCE_EXHAUSTED at once "
                 "(health, listing, get and cancel keep their own threads)");
  app.add_option("--idle-seconds", limits.idle_seconds,
                 "a stream waiting this long on its client (an answer not read, an upload not "
                 "sent) is closed, giving back its slot, and so is a unary call whose answer "
                 "its client does not take; gRPC connections with no call this long are "
                 "closed too, and quiet ones probed (0: never)")
      ->check(CLI::Range(0.0, 86400.0));
  app.add_option("--max-inflight-per-client", limits.max_inflight_per_client,
                 "queries one client (its bearer token, else its address) may have admitted at "
                 "once; beyond them its queries are answered RESOURCE_EXHAUSTED while other "
                 "clients' are admitted (0: half of --max-inflight)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-streams-per-client", limits.max_streams_per_client,
                 "streams one client (its bearer token, else its address) may have open at "
                 "once; beyond them its streams are answered RESOURCE_EXHAUSTED while other "
                 "clients' are opened (0: half of --max-streams)")
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-pairs", limits.max_pairs, "pairs per Distance call");
  app.add_option("--max-exact-pairs", limits.max_exact_pairs,
                 "exact pairs per Distance call (each is a window propagation); beyond: "
                 "RESOURCE_EXHAUSTED")
      ->check(CLI::PositiveNumber);
  app.add_option("--max-samples", limits.max_samples,
                 "points per SamplePoints call (each costs a distance field); beyond: "
                 "RESOURCE_EXHAUSTED")
      ->check(CLI::PositiveNumber);
  app.add_option("--max-exact-bytes", f.max_exact_bytes,
                 "memory one exact pair or matrix row may hold, e.g. 256M; past it the call is "
                 "answered RESOURCE_EXHAUSTED (0: no limit)");
  app.add_option("--max-sources", limits.max_sources, "sources per field");
  app.add_option("--max-upload-bytes", limits.max_upload_bytes, "largest mesh upload");
  app.add_option("--default-epsilon", limits.default_epsilon, "epsilon when a request gives none");
  app.add_flag("--no-build-on-query", f.no_build_on_query,
               "a query on a graph nobody requested fails (FAILED_PRECONDITION) instead of "
               "starting its build and waiting for it: for daemons whose graphs are built ahead");
  app.add_flag("--auto-build-any-epsilon", limits.auto_build_any_epsilon,
               "a query on a graph nobody requested starts its build at any epsilon, bound or "
               "pseudo vertices it names; without it, only at --default-epsilon, and other "
               "graphs must be asked for with RequestGraph (FAILED_PRECONDITION otherwise)");
  app.add_option("--max-queued-builds", limits.max_queued_builds,
                 "graphs queued or being made at once; a request for a new one beyond them is "
                 "answered RESOURCE_EXHAUSTED (joining one being made is always answered)")
      ->check(CLI::PositiveNumber);
  app.add_option("--max-queued-builds-per-client", limits.max_queued_builds_per_client,
                 "graphs one client (its bearer token, else its address) may have queued or "
                 "being made at once, by RequestGraph or its queries")
      ->check(CLI::PositiveNumber);
  app.add_option("--min-epsilon", limits.min_epsilon,
                 "the smallest epsilon clients may have a graph built at (smaller ones cost "
                 "steeply more); refused INVALID_ARGUMENT with the graph's estimate. --config "
                 "graphs are not held to it")
      ->check(CLI::Range(1e-6, 0.5));
  app.add_option("--min-max-error", limits.min_max_error,
                 "the smallest bound clients may have a certified graph built for; refused "
                 "INVALID_ARGUMENT with the estimate of its first build. --config graphs are "
                 "not held to it")
      ->check(CLI::Range(kMinMaxError, kMaxMaxError));
  app.add_option("--build-wait-seconds", limits.build_wait_seconds,
                 "longest a query waits for its graph to be built or mapped (within its own "
                 "deadline); then UNAVAILABLE with the build's progress, to retry")
      ->check(CLI::Range(0.0, 86400.0));
}

void AddHttpFlags(CLI::App& app, ServeFlags& f, ServeOptions& o) {
  app.add_option("--http-listen", o.http_listen,
                 "serve the HTTP/JSON API and the web viewer on HOST:PORT (same TLS and token; "
                 "port 0: any free port)");
  HttpLimits& limits = o.http_limits;
  f.http_header_seconds = Seconds(limits.header_timeout);
  f.http_body_seconds = Seconds(limits.body_timeout);
  f.http_idle_seconds = Seconds(limits.idle_timeout);
  app.add_option("--http-header-timeout", f.http_header_seconds,
                 "seconds a client has to send a request's headers (TLS handshake included)")
      ->capture_default_str();
  app.add_option("--http-body-timeout", f.http_body_seconds,
                 "seconds a client has to send a request's body")
      ->capture_default_str();
  app.add_option("--http-idle-timeout", f.http_idle_seconds,
                 "seconds a kept-alive HTTP connection may wait for its next request")
      ->capture_default_str();
  app.add_option("--http-max-connections", limits.max_connections,
                 "open HTTP connections; more are answered 503 and closed")
      ->capture_default_str();
  app.add_option("--http-max-connections-per-ip", limits.max_connections_per_ip,
                 "open HTTP connections per client address")
      ->capture_default_str();
  app.add_option("--http-cors-origin", o.http_cors_origin,
                 "a web origin (https://host[:port], or *) whose pages may call the HTTP API "
                 "from a browser (CORS); empty: only pages this gateway serves");
  app.add_option("--http-workers", limits.workers,
                 "threads answering HTTP requests (sockets are served apart from them)")
      ->capture_default_str();
  app.add_option("--metrics-listen", o.metrics_listen,
                 "serve Prometheus metrics on HOST:PORT (port 0: any free port)");
}

void AddRunFlags(CLI::App& app, ServeFlags& f, ServeOptions& o) {
  app.add_option("--log-level", f.log_level, "debug, info (one line per request), warning or error")
      ->check(CLI::IsMember({"debug", "info", "warning", "error"}));
  app.add_option("--log-format", f.log_format,
                 "text (timestamped key=value lines) or json (one object per line)")
      ->check(CLI::IsMember({"text", "json"}));
  app.add_option("--sample-mesh", f.sample,
                 "mesh registered as 'spot' at start (default: bundled)");
  app.add_flag("--no-sample", o.no_sample, "do not register the bundled sample mesh");
  app.add_option("--drain-seconds", o.drain_seconds, "grace period for running calls at shutdown");
  app.add_option("--tls-cert", o.tls_cert, "PEM certificate chain: serve TLS")
      ->check(CLI::ExistingFile);
  app.add_option("--tls-key", o.tls_key, "PEM private key of --tls-cert")->check(CLI::ExistingFile);
  app.add_option("--tls-client-ca", o.tls_client_ca,
                 "PEM CA: require client certificates signed by it (mutual TLS)")
      ->check(CLI::ExistingFile);
  app.add_option("--auth-token-file", f.auth_token_file,
                 "file of bearer tokens, one a line, each a client of its own: every "
                 "geodesic.v1 call must send one as 'authorization: Bearer <token>' "
                 "(health and reflection stay open)")
      ->check(CLI::ExistingFile);
}

// Logging, admission and the query threads; false after saying what is
// wrong.
bool ResolveLimits(const ServeFlags& f, ServeOptions& o) {
  SetLogLevel(*ParseLogLevel(f.log_level));
  SetLogFormat(*ParseLogFormat(f.log_format));
  ServiceLimits& limits = o.limits;
  limits.log_requests = LogEnabled(LogLevel::kInfo);
  limits.build_on_query = !f.no_build_on_query;
  if (limits.max_inflight < 1 || limits.max_streams < 1 || f.query_threads < 0) {
    std::fprintf(stderr,
                 "geodesicd serve: --max-inflight and --max-streams must be at least 1, "
                 "--query-threads at least 0\n");
    return false;
  }
  limits.query_threads = f.query_threads > 0
                             ? f.query_threads
                             : std::max(1, static_cast<int>(std::thread::hardware_concurrency()));
  // One malloc arena per running query, not one per gRPC thread: memory a
  // query frees in its arena is reused by the next query there instead of
  // staying with an idle thread's arena, where the limit cannot see it.
  mallopt(M_ARENA_MAX, std::max(2, limits.query_threads));
  o.http_limits.header_timeout = Millis(f.http_header_seconds);
  o.http_limits.body_timeout = Millis(f.http_body_seconds);
  o.http_limits.idle_timeout = Millis(f.http_idle_seconds);
  return true;
}

// The byte sizes.
bool ResolveSizes(const ServeFlags& f, ServeOptions& o) {
  const struct {
    const char* flag;
    const std::string& text;
    uint64_t* bytes;
  } sizes[] = {{"--memory-limit", f.memory_limit, &o.memory_limit},
               {"--disk-limit", f.disk_limit, &o.disk_limit},
               {"--build-memory-limit", f.build_memory_limit, &o.build_memory_limit},
               {"--max-graph-bytes", f.max_graph_bytes, &o.max_graph_bytes},
               {"--max-exact-bytes", f.max_exact_bytes, &o.limits.max_exact_bytes}};
  for (const auto& size : sizes) {
    auto bytes = ParseByteSize(size.text, size.flag);
    if (!bytes.ok()) {
      std::fprintf(stderr, "geodesicd serve: %s\n", std::string(bytes.status().message()).c_str());
      return false;
    }
    *size.bytes = *bytes;
  }
  o.limits.exact_fans = f.exact_fans;
  return true;
}

// The listener's credentials and the bearer token.
bool ResolveSecurity(const ServeFlags& f, ServeOptions& o) {
  if (o.tls_cert.empty() != o.tls_key.empty()) {
    std::fprintf(stderr, "geodesicd serve: --tls-cert and --tls-key go together\n");
    return false;
  }
  o.credentials = ServerCredentials(o);
  if (!o.credentials) return false;
  if (f.auth_token_file.empty()) return true;
  std::string text;
  if (!ReadSecretFile("--auth-token-file", f.auth_token_file, &text)) return false;
  // One token a line, each a client of its own (client_key.h).
  for (absl::string_view line : absl::StrSplit(text, '\n')) {
    line = absl::StripAsciiWhitespace(line);
    if (!line.empty() && !absl::StartsWith(line, "#")) o.tokens.emplace_back(line);
  }
  if (o.tokens.empty()) {
    std::fprintf(stderr, "geodesicd serve: --auth-token-file %s holds only whitespace\n",
                 f.auth_token_file.c_str());
    return false;
  }
  return true;
}

// What one parse of a command line leaves: the options, the text beside
// them, and the flags it named ("memory-limit"). Its own allocation: the
// parser holds references into it.
struct Parsed {
  ServeOptions o;
  ServeFlags f;
  std::set<std::string> given;
};

// Parses `args` (the program name left out) into fresh options, or the
// exit code when the command ends here (--help, a refused flag). `source`
// prefixes an error's message; empty: CLI11 prints its own.
std::variant<int, std::unique_ptr<Parsed>> ParseArgs(const std::vector<std::string>& args,
                                                     const std::string& source) {
  auto parsed = std::make_unique<Parsed>();
  ServeOptions& o = parsed->o;
  ServeFlags& f = parsed->f;
  o.listen = "127.0.0.1:50051";
  o.graph_dir = DefaultGraphDir();
  CLI::App app{"Serve geodesic queries over gRPC", "geodesicd serve"};
  app.option_defaults()->always_capture_default();  // --help shows defaults
  AddStorageFlags(app, f, o);
  AddBuildFlags(app, f, o);
  AddQueryFlags(app, f, o.limits);
  AddHttpFlags(app, f, o);
  AddRunFlags(app, f, o);
  // CLI11 reads a vector from its end.
  std::vector<std::string> reversed(args.rbegin(), args.rend());
  try {
    app.parse(reversed);
  } catch (const CLI::ParseError& e) {
    if (source.empty() || e.get_exit_code() == 0) return app.exit(e);
    std::fprintf(stderr, "geodesicd serve: %s: %s\n", source.c_str(), e.what());
    return 2;
  }
  for (const CLI::Option* option : app.get_options()) {
    if (option->count() == 0) continue;
    for (const std::string& name : option->get_lnames()) parsed->given.insert(name);
  }
  return parsed;
}

}  // namespace

std::optional<int> ParseServeOptions(int argc, char** argv, ServeOptions* out) {
  const std::vector<std::string> line(argv + 1, argv + argc);
  auto first = ParseArgs(line, "");
  if (auto* code = std::get_if<int>(&first)) return *code;
  std::unique_ptr<Parsed> parsed = std::move(std::get<std::unique_ptr<Parsed>>(first));
  ServeConfig config;
  if (!parsed->f.config_path.empty()) {
    absl::StatusOr<ServeConfig> loaded = LoadServeConfig(parsed->f.config_path);
    if (!loaded.ok()) {
      std::fprintf(stderr, "geodesicd serve: %s\n", std::string(loaded.status().message()).c_str());
      return 2;
    }
    config = *std::move(loaded);
  }
  // The file's flags under the command line's: each checked alone first, so
  // that an error names its line, then all of them before the command line.
  std::vector<std::string> args;
  for (const DeclaredFlag& flag : config.flags) {
    if (parsed->given.contains(flag.name)) continue;
    std::string arg = absl::StrCat("--", flag.name, "=", flag.value);
    auto alone = ParseArgs({arg}, absl::StrCat(flag.where, ": flags.", flag.name));
    if (auto* code = std::get_if<int>(&alone)) return *code;
    args.push_back(std::move(arg));
  }
  if (!args.empty()) {
    args.insert(args.end(), line.begin(), line.end());
    auto merged = ParseArgs(args, parsed->f.config_path);
    if (auto* code = std::get_if<int>(&merged)) return *code;
    parsed = std::move(std::get<std::unique_ptr<Parsed>>(merged));
  }
  ServeOptions& o = *out;
  o = std::move(parsed->o);
  const ServeFlags& f = parsed->f;
  o.config = std::move(config);
  if (!ResolveLimits(f, o) || !ResolveSizes(f, o) || !ResolveSecurity(f, o)) return 2;
  if (!o.no_sample) {
    const std::string bundled = FindSampleMesh(argv[0]);
    o.sample_path = f.sample.empty() ? bundled : f.sample;
    // With no --mesh-root, clients may register the bundled meshes.
    if (o.mesh_root.empty() && !bundled.empty()) {
      o.mesh_root = std::filesystem::path(bundled).parent_path().string();
    }
  }
  return std::nullopt;
}

}  // namespace geodesic::server
