#include "server/http/http_server.h"

#include <openssl/ssl.h>

#include <atomic>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/ssl.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <cctype>
#include <condition_variable>
#include <cstdlib>
#include <deque>
#include <limits>
#include <map>
#include <mutex>
#include <thread>

#include "absl/strings/str_format.h"
#include "core/base/status.h"
#include "server/base/listen_socket.h"
#include "server/http/http_request_text.h"

namespace geodesic::server {
namespace {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
namespace ssl = net::ssl;
using tcp = net::ip::tcp;

const char* RefusalText(HttpRefusal why) {
  switch (why) {
    case HttpRefusal::kBadRequest:
      return "bad request";
    case HttpRefusal::kBodyTooLarge:
      return "request body too large";
    case HttpRefusal::kHeaderTooLarge:
      return "request headers too large";
    case HttpRefusal::kBusy:
      return "server busy, retry later";
    case HttpRefusal::kInternal:
      return "internal error";
  }
  return "error";
}

int RefusalStatus(HttpRefusal why) {
  switch (why) {
    case HttpRefusal::kBadRequest:
      return 400;
    case HttpRefusal::kBodyTooLarge:
      return 413;
    case HttpRefusal::kHeaderTooLarge:
      return 431;
    case HttpRefusal::kBusy:
      return 503;
    case HttpRefusal::kInternal:
      return 500;
  }
  return 500;
}

// Handlers block (in-process gRPC calls can take seconds), so they run here
// rather than on the io threads; a bounded queue turns overload into an
// immediate 503 instead of an ever longer wait.
class WorkerPool {
 public:
  WorkerPool(int workers, int max_queued) : max_queued_(static_cast<size_t>(max_queued)) {
    for (int i = 0; i < workers; ++i) threads_.emplace_back([this] { Run(); });
  }
  ~WorkerPool() { Drain(); }

  bool TryPost(std::function<void()> job) {
    {
      std::lock_guard<std::mutex> lock(mu_);
      if (stopping_ || queue_.size() >= max_queued_) return false;
      queue_.push_back(std::move(job));
    }
    cv_.notify_one();
    return true;
  }

  // Runs what is queued, then joins.
  void Drain() {
    {
      std::lock_guard<std::mutex> lock(mu_);
      stopping_ = true;
    }
    cv_.notify_all();
    for (auto& t : threads_) {
      if (t.joinable()) t.join();
    }
  }

 private:
  void Run() {
    for (;;) {
      std::function<void()> job;
      {
        std::unique_lock<std::mutex> lock(mu_);
        cv_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
        if (queue_.empty()) return;
        job = std::move(queue_.front());
        queue_.pop_front();
      }
      try {
        job();
      } catch (...) {
        // Jobs answer their own errors; this only keeps the worker alive.
      }
    }
  }

  const size_t max_queued_;
  std::mutex mu_;
  std::condition_variable cv_;
  std::deque<std::function<void()>> queue_;
  bool stopping_ = false;
  std::vector<std::thread> threads_;
};

// Open connections, in total and per client address.
class ConnectionLimiter {
 public:
  ConnectionLimiter(int total, int per_address) : total_limit_(total), per_address_(per_address) {}

  bool TryAcquire(const std::string& address) {
    std::lock_guard<std::mutex> lock(mu_);
    if (total_ >= total_limit_) return false;
    int& n = by_address_[address];
    if (n >= per_address_) {
      if (n == 0) by_address_.erase(address);
      return false;
    }
    ++n;
    ++total_;
    return true;
  }

  void Release(const std::string& address) {
    std::lock_guard<std::mutex> lock(mu_);
    --total_;
    auto it = by_address_.find(address);
    if (it != by_address_.end() && --it->second <= 0) by_address_.erase(it);
  }

 private:
  const int total_limit_, per_address_;
  std::mutex mu_;
  int total_ = 0;
  std::map<std::string, int> by_address_;
};

// What shutdown asks of a connection, on its strand.
class SessionControl {
 public:
  virtual ~SessionControl() = default;
  // Closes the connection unless it is answering a request; one that is
  // closes once its answer is written (`now`: closes it whatever it does).
  virtual void Stop(bool now) = 0;
};

// The open connections and how many are answering a request (from the
// request's dispatch to the end of its answer's write), for shutdown.
class SessionRegistry {
 public:
  uint64_t Add(std::weak_ptr<SessionControl> session) {
    std::lock_guard<std::mutex> lock(mu_);
    sessions_.emplace(next_id_, std::move(session));
    return next_id_++;
  }
  void Remove(uint64_t id) {
    std::lock_guard<std::mutex> lock(mu_);
    sessions_.erase(id);
  }
  void Busy(int delta) {
    std::lock_guard<std::mutex> lock(mu_);
    busy_ += delta;
    if (busy_ == 0) idle_.notify_all();
  }
  // Until no connection is answering, or the deadline.
  void WaitIdle(std::chrono::steady_clock::time_point deadline) {
    std::unique_lock<std::mutex> lock(mu_);
    idle_.wait_until(lock, deadline, [this] { return busy_ == 0; });
  }
  void StopAll(bool now) {
    std::vector<std::shared_ptr<SessionControl>> live;
    {
      std::lock_guard<std::mutex> lock(mu_);
      for (auto& [id, weak] : sessions_) {
        if (auto session = weak.lock()) live.push_back(std::move(session));
      }
    }
    // Outside the lock: a session released here unregisters itself.
    for (auto& session : live) session->Stop(now);
  }

 private:
  std::mutex mu_;
  std::condition_variable idle_;
  std::map<uint64_t, std::weak_ptr<SessionControl>> sessions_;
  uint64_t next_id_ = 0;
  int busy_ = 0;
};

// What connections share with the server; they hold it, so it lives as long
// as the last of them, whatever the order of destruction at shutdown.
struct Shared {
  explicit Shared(HttpServerOptions o)
      : options(std::move(o)),
        pool(std::max(1, options.limits.workers), std::max(0, options.limits.max_queued)),
        limiter(options.limits.max_connections, options.limits.max_connections_per_ip) {}

  HttpResponse Refuse(HttpRefusal why, const HttpRequest& head, size_t body_limit) const {
    HttpResponse res;
    if (options.refuse) {
      try {
        res = options.refuse(why, head, body_limit);
      } catch (...) {
        res = HttpResponse();
      }
    }
    if (res.status == 200 || res.status == 0) {
      res.status = RefusalStatus(why);
      res.content_type = "text/plain";
      res.body = RefusalText(why);
    }
    if (why == HttpRefusal::kBusy) {
      bool has_retry = false;
      for (const auto& [k, v] : res.headers) has_retry |= EqualsIgnoreCase(k, "Retry-After");
      if (!has_retry) {
        res.headers.emplace_back("Retry-After", std::to_string(options.limits.retry_after_seconds));
      }
    }
    return res;
  }

  HttpServerOptions options;
  std::optional<ssl::context> tls;
  WorkerPool pool;
  ConnectionLimiter limiter;
  SessionRegistry sessions;
  // Shutdown began: no connection reads another request.
  std::atomic<bool> stopping{false};
};

// One client connection, plain or TLS. Every operation runs on the
// connection's strand; the timer of the lowest layer (beast::tcp_stream)
// holds each phase's deadline.
template <typename Stream>
class Session : public SessionControl, public std::enable_shared_from_this<Session<Stream>> {
 public:
  Session(std::shared_ptr<Shared> shared, Stream stream, std::string address)
      : shared_(std::move(shared)), stream_(std::move(stream)), address_(std::move(address)) {}
  ~Session() override {
    if (busy_) shared_->sessions.Busy(-1);
    shared_->sessions.Remove(id_);
    shared_->limiter.Release(address_);
  }

  void Stop(bool now) override {
    net::post(stream_.get_executor(), [self = this->shared_from_this(), now] {
      self->Guard([&] {
        if (now || !self->busy_) self->Close();
      });
    });
  }

  void Start() {
    id_ = shared_->sessions.Add(this->weak_from_this());
    if (shared_->stopping) return Close();
    // One deadline for the handshake and the first request's headers.
    Tcp().expires_after(shared_->options.limits.header_timeout);
    if constexpr (kTls) {
      stream_.async_handshake(ssl::stream_base::server,
                              [self = this->shared_from_this()](beast::error_code ec) {
                                self->Guard([&] {
                                  if (ec) return self->Close();
                                  self->ReadHeader();
                                });
                              });
    } else {
      ReadHeader();
    }
  }

 private:
  static constexpr bool kTls = !std::is_same_v<Stream, beast::tcp_stream>;

  beast::tcp_stream& Tcp() { return beast::get_lowest_layer(stream_); }

  // Boost throws in places (allocation, header values); nothing may escape
  // into the io loop, so a connection that throws is closed.
  template <typename F>
  void Guard(F&& f) {
    try {
      f();
    } catch (...) {
      Close();
    }
  }

  // A kept-alive connection may stay silent for the idle timeout; once a
  // byte arrives its headers have the header timeout.
  void AwaitNextRequest() {
    if (shared_->stopping) return Close();
    if (buffer_.size() > 0) {
      Tcp().expires_after(shared_->options.limits.header_timeout);
      return ReadHeader();
    }
    Tcp().expires_after(shared_->options.limits.idle_timeout);
    stream_.async_read_some(
        buffer_.prepare(4096), [self = this->shared_from_this()](beast::error_code ec, size_t n) {
          self->Guard([&] {
            if (ec) return self->Close();
            self->buffer_.commit(n);
            self->Tcp().expires_after(self->shared_->options.limits.header_timeout);
            self->ReadHeader();
          });
        });
  }

  void ReadHeader() {
    parser_.emplace();
    parser_->header_limit(static_cast<uint32_t>(shared_->options.limits.max_header_bytes));
    // The limit is set once the headers are known (the pre-body hook may
    // lower it); Content-Length is compared by hand then. Not boost::none:
    // Beast compares a length with it, and any length is greater than none.
    parser_->body_limit(std::numeric_limits<std::uint64_t>::max());
    http::async_read_header(stream_, buffer_, *parser_,
                            [self = this->shared_from_this()](beast::error_code ec, size_t) {
                              self->Guard([&] { self->OnHeader(ec); });
                            });
  }

  void OnHeader(beast::error_code ec) {
    request_ = HttpRequest();
    request_.remote_address = address_;
    head_ = false;
    if (ec == http::error::header_limit) {
      return Send(shared_->Refuse(HttpRefusal::kHeaderTooLarge, request_, 0), true);
    }
    if (ec == http::error::end_of_stream || ec == beast::error::timeout || ec == net::error::eof ||
        ec == net::error::connection_reset || ec == net::error::operation_aborted ||
        ec == ssl::error::stream_truncated) {
      return Close();
    }
    if (ec) return Send(shared_->Refuse(HttpRefusal::kBadRequest, request_, 0), true);
    const auto& msg = parser_->get();
    request_.method = std::string(msg.method_string());
    request_.target = std::string(msg.target());
    for (const auto& field : msg) {
      request_.headers.emplace_back(std::string(field.name_string()), std::string(field.value()));
    }
    head_ = msg.method() == http::verb::head;
    keep_alive_ = msg.keep_alive();
    version_ = msg.version();
    if (request_.target.empty() || request_.target.front() != '/') {
      return Send(shared_->Refuse(HttpRefusal::kBadRequest, request_, 0), true);
    }
    SplitTarget(request_.target, &request_);

    const bool has_body = !parser_->is_done();
    size_t limit = shared_->options.limits.max_body_bytes;
    if (shared_->options.headers) {
      std::optional<HttpResponse> early;
      try {
        early = shared_->options.headers(request_, &limit);
      } catch (...) {
        early = shared_->Refuse(HttpRefusal::kInternal, request_, limit);
      }
      // Answered before the body: the body is never read, so the
      // connection cannot carry another request.
      if (early) return Send(std::move(*early), has_body || !keep_alive_);
    }
    if (!has_body) return Dispatch();
    limit_ = limit;
    const auto length = parser_->content_length();
    if (length && *length > limit) {
      return Send(shared_->Refuse(HttpRefusal::kBodyTooLarge, request_, limit), true);
    }
    if (shared_->options.reserve_body) {
      std::optional<HttpResponse> refused;
      try {
        refused = shared_->options.reserve_body(
            request_, length ? static_cast<size_t>(*length) : limit, &body_hold_);
      } catch (...) {
        refused = shared_->Refuse(HttpRefusal::kInternal, request_, limit);
      }
      if (refused) return Send(std::move(*refused), true);
    }
    parser_->body_limit(static_cast<uint64_t>(limit));
    Tcp().expires_after(shared_->options.limits.body_timeout);
    if (EqualsIgnoreCase(request_.header("Expect"), "100-continue")) {
      // Clients that ask wait for this before sending a large body.
      static constexpr std::string_view kContinue = "HTTP/1.1 100 Continue\r\n\r\n";
      return net::async_write(stream_, net::buffer(kContinue.data(), kContinue.size()),
                              [self = this->shared_from_this()](beast::error_code ec, size_t) {
                                self->Guard([&] {
                                  if (ec) return self->Close();
                                  self->ReadBody();
                                });
                              });
    }
    ReadBody();
  }

  void ReadBody() {
    http::async_read(stream_, buffer_, *parser_,
                     [self = this->shared_from_this()](beast::error_code ec, size_t) {
                       self->Guard([&] { self->OnBody(ec); });
                     });
  }

  void OnBody(beast::error_code ec) {
    if (ec == http::error::body_limit) {
      return Send(shared_->Refuse(HttpRefusal::kBodyTooLarge, request_, limit_), true);
    }
    if (ec == beast::error::timeout || ec == http::error::partial_message ||
        ec == net::error::eof || ec == net::error::connection_reset ||
        ec == net::error::operation_aborted || ec == ssl::error::stream_truncated) {
      return Close();
    }
    if (ec) return Send(shared_->Refuse(HttpRefusal::kBadRequest, request_, 0), true);
    request_.body = std::move(parser_->get().body());
    Dispatch();
  }

  void Dispatch() {
    parser_.reset();
    Tcp().expires_never();
    SetBusy(true);
    auto request = std::make_shared<HttpRequest>(std::move(request_));
    auto self = this->shared_from_this();
    const bool queued = shared_->pool.TryPost([self, request] {
      HttpResponse res;
      try {
        res = self->shared_->options.handler(*request);
      } catch (...) {
        res = self->shared_->Refuse(HttpRefusal::kInternal, *request, 0);
      }
      net::post(self->stream_.get_executor(), [self, res = std::move(res)]() mutable {
        self->Guard([&] { self->Send(std::move(res), !self->keep_alive_); });
      });
    });
    if (!queued) Send(shared_->Refuse(HttpRefusal::kBusy, *request, 0), !keep_alive_);
  }

  void Send(HttpResponse res, bool close) {
    close = close || res.close || shared_->stopping;
    auto out = std::make_shared<http::response<http::string_body>>();
    out->version(version_ == 10 ? 10 : 11);
    out->result(static_cast<unsigned>(res.status));
    if (res.status == 499) out->reason("Client Closed Request");
    if (!res.content_type.empty()) out->set(http::field::content_type, res.content_type);
    for (auto& [name, value] : res.headers) out->insert(name, value);
    out->keep_alive(!close);
    if (head_) {
      out->content_length(res.body.size());
    } else {
      out->body() = std::move(res.body);
      out->prepare_payload();
    }
    Tcp().expires_after(shared_->options.limits.write_timeout);
    http::async_write(stream_, *out,
                      [self = this->shared_from_this(), out, close, hold = std::move(res.hold)](
                          beast::error_code ec, size_t) {
                        self->Guard([&] {
                          self->body_hold_.reset();
                          self->SetBusy(false);
                          if (ec || close) return self->Shutdown();
                          self->AwaitNextRequest();
                        });
                      });
  }

  // Counted from the dispatch to the end of the answer's write, for
  // shutdown to wait on.
  void SetBusy(bool busy) {
    if (busy == busy_) return;
    busy_ = busy;
    shared_->sessions.Busy(busy ? 1 : -1);
  }

  // A polite end: TLS says close_notify (without waiting long for the
  // peer's); TCP sends FIN after the response.
  void Shutdown() {
    if constexpr (kTls) {
      Tcp().expires_after(std::chrono::seconds(1));
      stream_.async_shutdown([self = this->shared_from_this()](beast::error_code) {
        self->Guard([&] { self->Close(); });
      });
    } else {
      Close();
    }
  }

  void Close() {
    beast::error_code ec;
    Tcp().socket().shutdown(tcp::socket::shutdown_both, ec);
    Tcp().socket().close(ec);
  }

  std::shared_ptr<Shared> shared_;
  Stream stream_;
  std::string address_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  HttpRequest request_;
  std::shared_ptr<void> body_hold_;  // reserve_body's, until the answer is written
  uint64_t id_ = 0;
  bool busy_ = false;
  size_t limit_ = 0;
  bool head_ = false, keep_alive_ = false;
  unsigned version_ = 11;
};

}  // namespace

namespace {

struct HostPort {
  std::string host;  // without the brackets of an IPv6 literal
  long port = 0;
};

}  // namespace

struct HttpServer::Impl {
  std::shared_ptr<Shared> shared;
  net::io_context ioc;
  std::optional<tcp::acceptor> acceptor;
  std::optional<net::steady_timer> retry_accept;
  // Keeps the io threads running once the acceptor is closed at shutdown,
  // while answers still come from the workers.
  std::optional<net::executor_work_guard<net::io_context::executor_type>> keep_running;
  std::vector<std::thread> threads;
  int port = 0;

  // Binds the acceptor (a port another process holds is refused).
  absl::Status Listen(const HostPort& at, const std::string& listen);
  // Starts accepting on the io threads.
  void RunThreads();

  void Accept() {
    acceptor->async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket s) {
      try {
        OnAccept(ec, std::move(s));
      } catch (...) {
      }
    });
  }

  void OnAccept(beast::error_code ec, tcp::socket socket) {
    if (ec == net::error::operation_aborted || !acceptor->is_open()) return;
    if (ec) {
      // Out of descriptors, typically: try again shortly rather than spin.
      retry_accept->expires_after(std::chrono::milliseconds(100));
      retry_accept->async_wait([this](beast::error_code wait_ec) {
        if (!wait_ec) Accept();
      });
      return;
    }
    Accept();
    beast::error_code addr_ec;
    const auto remote = socket.remote_endpoint(addr_ec);
    const std::string address = addr_ec ? std::string() : remote.address().to_string();
    if (!shared->limiter.TryAcquire(address)) {
      if (!shared->tls) {
        // Best effort, never waiting: the socket's buffer is empty.
        const std::string busy = absl::StrFormat(
            "HTTP/1.1 503 Service Unavailable\r\nRetry-After: %d\r\nContent-Length: 0\r\n"
            "Connection: close\r\n\r\n",
            shared->options.limits.retry_after_seconds);
        socket.non_blocking(true, addr_ec);
        socket.write_some(net::buffer(busy), addr_ec);
      }
      socket.shutdown(tcp::socket::shutdown_both, addr_ec);
      socket.close(addr_ec);
      return;
    }
    if (shared->tls) {
      auto session = std::make_shared<Session<beast::ssl_stream<beast::tcp_stream>>>(
          shared, beast::ssl_stream<beast::tcp_stream>(std::move(socket), *shared->tls), address);
      session->Start();
    } else {
      auto session = std::make_shared<Session<beast::tcp_stream>>(
          shared, beast::tcp_stream(std::move(socket)), address);
      session->Start();
    }
  }
};

HttpServer::HttpServer(std::unique_ptr<Impl> impl) : impl_(std::move(impl)) {}

void HttpServer::StopAccepting() {
  if (impl_->shared->stopping.exchange(true)) return;
  net::post(impl_->ioc, [impl = impl_.get()] {
    beast::error_code ec;
    impl->acceptor->close(ec);
    impl->retry_accept->cancel();
  });
  impl_->shared->sessions.StopAll(/*now=*/false);
}

void HttpServer::WaitForAnswers(std::chrono::steady_clock::time_point deadline) {
  impl_->shared->sessions.WaitIdle(deadline);
}

void HttpServer::Finish(std::chrono::steady_clock::time_point deadline) {
  StopAccepting();
  WaitForAnswers(deadline);
  impl_->shared->sessions.StopAll(/*now=*/true);
}

HttpServer::~HttpServer() {
  if (!impl_) return;
  Finish(std::chrono::steady_clock::now());
  impl_->shared->pool.Drain();
  impl_->ioc.stop();
  for (auto& t : impl_->threads) {
    if (t.joinable()) t.join();
  }
}

int HttpServer::port() const { return impl_->port; }
bool HttpServer::tls() const { return impl_->shared->tls.has_value(); }

namespace {

absl::StatusOr<HostPort> ParseListen(const std::string& listen) {
  const auto colon = listen.rfind(':');
  char* end = nullptr;
  const long port =
      colon == std::string::npos ? -1 : std::strtol(listen.c_str() + colon + 1, &end, 10);
  if (colon == std::string::npos || end != listen.c_str() + listen.size() || port < 0 ||
      port > 65535) {
    return absl::InvalidArgumentError(absl::StrFormat("%s: expected HOST:PORT", listen));
  }
  std::string host = listen.substr(0, colon);
  if (host.size() >= 2 && host.front() == '[' && host.back() == ']') {
    host = host.substr(1, host.size() - 2);
  }
  return HostPort{std::move(host), port};
}

// The TLS context of the options' files: none without a certificate; with
// a client CA, clients must present a certificate it signed.
absl::StatusOr<std::optional<ssl::context>> TlsContext(const HttpServerOptions& options) {
  std::optional<ssl::context> tls;
  if (options.tls_cert.empty()) return tls;
  tls.emplace(ssl::context::tls_server);
  beast::error_code ec;
  tls->set_options(ssl::context::default_workarounds | ssl::context::no_sslv2 |
                       ssl::context::no_sslv3 | ssl::context::no_tlsv1 | ssl::context::no_tlsv1_1,
                   ec);
  bool ok = !ec;
  tls->use_certificate_chain_file(options.tls_cert, ec);
  ok = ok && !ec;
  tls->use_private_key_file(options.tls_key, ssl::context::pem, ec);
  ok = ok && !ec;
  if (ok && !options.tls_client_ca.empty()) {
    tls->load_verify_file(options.tls_client_ca, ec);
    ok = !ec;
    if (ok) {
      // Names the accepted CAs in the handshake, so clients with
      // several certificates pick the right one.
      if (STACK_OF(X509_NAME)* names = SSL_load_client_CA_file(options.tls_client_ca.c_str())) {
        SSL_CTX_set_client_CA_list(tls->native_handle(), names);
      }
      tls->set_verify_mode(ssl::verify_peer | ssl::verify_fail_if_no_peer_cert, ec);
      ok = !ec;
    }
  }
  if (!ok) {
    return absl::InvalidArgumentError(absl::StrFormat(
        "TLS: cannot load certificate %s or key %s%s", options.tls_cert, options.tls_key,
        options.tls_client_ca.empty() ? "" : " or CA " + options.tls_client_ca));
  }
  return tls;
}

}  // namespace

absl::Status HttpServer::Impl::Listen(const HostPort& at, const std::string& listen) {
  beast::error_code ec;
  tcp::resolver resolver(ioc);
  auto endpoints = resolver.resolve(at.host, std::to_string(at.port),
                                    tcp::resolver::passive | tcp::resolver::numeric_service, ec);
  if (ec || endpoints.empty()) {
    return absl::UnavailableError(
        absl::StrFormat("cannot listen on %s: %s", listen, ec ? ec.message() : "no such address"));
  }
  const tcp::endpoint endpoint = endpoints.begin()->endpoint();
  acceptor.emplace(ioc);
  acceptor->open(endpoint.protocol(), ec);
  if (!ec) ExclusiveListenSocket(acceptor->native_handle());
  if (!ec) acceptor->bind(endpoint, ec);
  if (!ec) acceptor->listen(net::socket_base::max_listen_connections, ec);
  if (ec) {
    return absl::UnavailableError(absl::StrFormat("cannot listen on %s: %s", listen, ec.message()));
  }
  port = acceptor->local_endpoint(ec).port();
  return absl::OkStatus();
}

void HttpServer::Impl::RunThreads() {
  retry_accept.emplace(ioc);
  keep_running.emplace(ioc.get_executor());
  Accept();
  const int io_threads = std::max(1, shared->options.limits.io_threads);
  for (int i = 0; i < io_threads; ++i) {
    threads.emplace_back([this] {
      for (;;) {
        try {
          ioc.run();
          return;
        } catch (...) {
          // A handler threw past its guard: keep serving the others.
        }
      }
    });
  }
}

absl::StatusOr<std::unique_ptr<HttpServer>> HttpServer::Start(HttpServerOptions options) {
  const std::string listen = options.listen;
  ASSIGN_OR_RETURN(const HostPort at, ParseListen(listen));
  if (options.tls_cert.empty() != options.tls_key.empty()) {
    return absl::InvalidArgumentError("TLS needs both a certificate and a key");
  }
  auto impl = std::make_unique<Impl>();
  try {
    ASSIGN_OR_RETURN(std::optional<ssl::context> tls, TlsContext(options));
    impl->shared = std::make_shared<Shared>(std::move(options));
    impl->shared->tls = std::move(tls);
    RETURN_IF_ERROR(impl->Listen(at, listen));
    impl->RunThreads();
  } catch (const std::exception& e) {
    return absl::InternalError(absl::StrFormat("cannot start HTTP on %s: %s", listen, e.what()));
  }
  return std::unique_ptr<HttpServer>(new HttpServer(std::move(impl)));
}

}  // namespace geodesic::server
