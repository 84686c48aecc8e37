// A small HTTP/1.1 server meant to face clients that misbehave: every byte a
// client controls is bounded in size and in time, credentials can be checked
// before a body is read, and slow clients cannot hold the threads that answer
// others. Handlers are plain blocking functions run on a worker pool.
#ifndef GEODESIC_SERVER_HTTP_SERVER_H_
#define GEODESIC_SERVER_HTTP_SERVER_H_

#include <chrono>
#include <cstddef>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "absl/status/statusor.h"

namespace geodesic::server {

struct HttpRequest {
  std::string method;  // as sent: "GET", "POST"...
  std::string target;  // as sent: path and query, percent-encoded
  std::string path;    // percent-decoded
  std::vector<std::pair<std::string, std::string>> params;   // query, decoded, in order
  std::vector<std::pair<std::string, std::string>> headers;  // in order, repeats kept
  std::string body;                                          // empty while the pre-body hook runs
  std::string remote_address;

  // Header names compare case-insensitively; the first of repeated ones.
  std::string header(std::string_view name) const;
  size_t header_count(std::string_view name) const;
  bool has_param(std::string_view name) const;
  std::string param(std::string_view name) const;  // the first; empty when absent
};

struct HttpResponse {
  int status = 200;
  std::string content_type;  // none when empty
  std::vector<std::pair<std::string, std::string>> headers;
  std::string body;
  // The connection closes once this is sent: a client refused for its
  // credentials must not keep a connection slot by sending more requests.
  bool close = false;
  // Held until the response is written (a memory reservation for its body).
  std::shared_ptr<void> hold;
};

// Why the server answers by itself, without the handler.
enum class HttpRefusal {
  kBadRequest,      // 400: unparsable request line, headers, chunk framing or path
  kBodyTooLarge,    // 413: over the body limit (announced or while read)
  kHeaderTooLarge,  // 431
  kBusy,            // 503: the worker queue is full
  kInternal,        // 500: the handler threw
};

// Everything a client controls is bounded by one of these.
struct HttpLimits {
  // Bodies, chunked or not, counted while they are read.
  size_t max_body_bytes = size_t{16} << 20;
  size_t max_header_bytes = size_t{16} << 10;
  // From the connection's start (or a kept-alive connection's first byte) to
  // the end of the headers, TLS handshake included: the bound on slowloris.
  std::chrono::milliseconds header_timeout{std::chrono::seconds(10)};
  // From the end of the headers to the end of the body.
  std::chrono::milliseconds body_timeout{std::chrono::seconds(60)};
  // A kept-alive connection with no request coming is closed after this.
  std::chrono::milliseconds idle_timeout{std::chrono::seconds(15)};
  // Writing one response; a client that does not read is dropped.
  std::chrono::milliseconds write_timeout{std::chrono::seconds(60)};
  // Beyond these a new connection is answered 503 (TLS: closed) at once.
  int max_connections = 512;
  int max_connections_per_ip = 64;
  // Sockets are multiplexed on io threads; handlers, which may block for
  // seconds, run on workers; requests wait in a queue of bounded length for a
  // free worker, beyond which they get 503 with Retry-After.
  int io_threads = 2;
  int workers = 8;
  int max_queued = 64;
  int retry_after_seconds = 1;
};

struct HttpServerOptions {
  std::string listen;  // HOST:PORT; port 0 picks a free one
  // TLS when both are set; client certificates signed by the CA are required
  // when it is set too.
  std::string tls_cert, tls_key, tls_client_ca;
  HttpLimits limits;

  // Answers a complete request. Runs on a worker; may block. Exceptions are
  // caught and answered by `refuse` (kInternal).
  std::function<HttpResponse(const HttpRequest&)> handler;
  // Runs on an io thread once the headers are read, before any body byte:
  // a response here is sent instead of reading the body (the connection is
  // then closed if a body was announced). It may lower *body_limit for this
  // request. Must not block.
  std::function<std::optional<HttpResponse>(const HttpRequest& head, size_t* body_limit)> headers;
  // Runs on an io thread before a body is read, with its Content-Length (a
  // chunked body: the body limit): a response here refuses it and closes the
  // connection; otherwise what it leaves in *hold is kept until the
  // request's answer is written (a memory reservation for the body and what
  // is parsed from it). Must not block.
  std::function<std::optional<HttpResponse>(const HttpRequest& head, size_t body_bytes,
                                            std::shared_ptr<void>* hold)>
      reserve_body;
  // The server's own answers; absent: a plain-text body naming the reason.
  // `head` may be empty (a request line that did not parse).
  std::function<HttpResponse(HttpRefusal, const HttpRequest& head, size_t body_limit)> refuse;
};

class HttpServer {
 public:
  // Binds and starts serving; refuses a taken port and unusable TLS files.
  static absl::StatusOr<std::unique_ptr<HttpServer>> Start(HttpServerOptions options);
  // Shutdown's first step: stops accepting, closes connections waiting for
  // a request (kept-alive or half-sent ones), and closes the others once
  // their answer is written. Returns at once.
  void StopAccepting();
  // Waits until every request being answered has had its answer written, or
  // until `deadline`.
  void WaitForAnswers(std::chrono::steady_clock::time_point deadline);
  // WaitForAnswers, then closes every connection. Requests still running
  // then get no answer: their handlers should have been stopped (the gRPC
  // server's shutdown cancels their calls).
  void Finish(std::chrono::steady_clock::time_point deadline);
  // Finish(now) unless it ran, then joins the threads once queued and
  // running handlers return.
  ~HttpServer();

  int port() const;
  bool tls() const;

 private:
  struct Impl;
  explicit HttpServer(std::unique_ptr<Impl> impl);
  std::unique_ptr<Impl> impl_;
};

}  // namespace geodesic::server

#endif  // GEODESIC_SERVER_HTTP_SERVER_H_
