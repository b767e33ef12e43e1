// The only server translation unit that includes Beast.
#include <utility>  // before Asio: Boost 1.74's awaitable.hpp misses it under GCC 12

#include "server/http/http_server.hpp"

#include <boost/asio/dispatch.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/post.hpp>
#include <boost/asio/signal_set.hpp>
#include <boost/asio/steady_timer.hpp>
#include <boost/asio/strand.hpp>
#include <boost/asio/thread_pool.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <fmt/format.h>

#include <atomic>
#include <limits>
#include <chrono>
#include <optional>
#include <sstream>
#include <thread>
#include <vector>

#include "server/http/event_stream.hpp"
#include "server/http/http_framing.hpp"
#include "server/http/connection_counters.hpp"
#include "server/http/http_handler.hpp"
#include "server/http/problem.hpp"

namespace tally {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;

namespace {

std::chrono::steady_clock::duration secs(double s) {
  return std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(s));
}

using BeastRequest = http::request<http::string_body>;

// Method, target and headers (names in lower case), without the body.
template <class Fields>
HttpRequest to_http_head(const http::request_header<Fields>& req) {
  HttpRequest r;
  r.method = std::string(req.method_string());
  r.target = std::string(req.target());
  for (const auto& f : req) {
    std::string name(f.name_string());
    for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
    r.headers.emplace_back(std::move(name), std::string(f.value()));
  }
  return r;
}

HttpRequest to_http_request(BeastRequest& req) {
  HttpRequest r = to_http_head(req.base());
  r.body = std::move(req.body());
  return r;
}

// A streamed body (BodySink) is read in parts of this size.
constexpr size_t kBodyPartBytes = 256 << 10;

// The problem response for a request the parser rejected, or nullopt when the
// error means the peer went away (no answer possible).
std::optional<HttpResponse> parse_error_response(beast::error_code ec, const HttpServerConfig& config) {
  if (ec == http::error::body_limit) {
    return problem_response(413, fmt::format("the request body exceeds {} bytes", config.max_body_bytes));
  }
  if (ec == http::error::header_limit) {
    return problem_response(431, fmt::format("the request header exceeds {} bytes", config.max_header_bytes));
  }
  if (ec != http::error::end_of_stream && ec != http::error::partial_message &&
      ec.category() == beast::error_code(http::error::bad_target).category()) {
    return problem_response(400, fmt::format("malformed HTTP request: {}", ec.message()));
  }
  return std::nullopt;
}

// Framing the parser accepted but we must not (RFC 9112 §3.2 Host, §6.3 Transfer-Encoding).
std::optional<HttpResponse> framing_response(const HttpRequest& r, unsigned version) {
  std::string te;
  size_t hosts = 0;
  for (const auto& [k, v] : r.headers) {
    if (k == "transfer-encoding") te += (te.empty() ? "" : ", ") + v;
    if (k == "host") ++hosts;
  }
  if (auto p = host_problem(hosts, version)) return problem_response(p->status, p->detail);
  if (auto p = transfer_encoding_problem(te)) return problem_response(p->status, p->detail);
  return std::nullopt;
}

void configure_parser(http::request_parser<http::string_body>& p, const HttpServerConfig& config) {
  p.body_limit(config.max_body_bytes);
  p.header_limit(static_cast<uint32_t>(config.max_header_bytes));
}

struct Shared {
  HttpServerConfig config;
  HttpHandler& handler;
  ConnectionCounters& counters;
  net::thread_pool& blocking;
  net::thread_pool& slow;
  std::atomic<size_t> connections{0};
  std::atomic<size_t> slow_requests{0};  // running or waiting on the slow lane
};

template <class Stream>
struct StreamTraits {
  static constexpr bool tls = false;
  static Stream make(tcp::socket&& s, net::ssl::context*) { return Stream(std::move(s)); }
};
template <>
struct StreamTraits<beast::ssl_stream<beast::tcp_stream>> {
  static constexpr bool tls = true;
  static beast::ssl_stream<beast::tcp_stream> make(tcp::socket&& s, net::ssl::context* ctx) {
    return beast::ssl_stream<beast::tcp_stream>(std::move(s), *ctx);
  }
};

// One connection, plain (beast::tcp_stream) or TLS (beast::ssl_stream over it).
template <class Stream>
class Session : public std::enable_shared_from_this<Session<Stream>> {
  using std::enable_shared_from_this<Session<Stream>>::shared_from_this;

 public:
  Session(tcp::socket&& socket, net::ssl::context* tls, Shared& shared, bool reject)
      : stream_(StreamTraits<Stream>::make(std::move(socket), tls)),
        shared_(shared),
        reject_(reject),
        heartbeat_(stream_.get_executor()),
        read_timer_(stream_.get_executor()) {
    shared_.connections++;
    shared_.counters.connections++;
  }
  ~Session() {
    if (streaming_) shared_.counters.streams--;
    shared_.counters.connections--;
    shared_.connections--;
  }

  void run() {
    beast::error_code peer_ec;
    const tcp::endpoint peer = lowest().socket().remote_endpoint(peer_ec);
    if (!peer_ec) peer_ = peer.address().to_string();
    net::dispatch(stream_.get_executor(), [self = shared_from_this()] {
      if constexpr (StreamTraits<Stream>::tls) {
        // TLS first (within the read timeout); a client that never finishes it is cut off.
        self->lowest().expires_after(secs(self->shared_.config.read_timeout_s));
        self->stream_.async_handshake(net::ssl::stream_base::server, [self](beast::error_code ec) {
          if (ec) return self->on_error(ec);
          self->start();
        });
      } else {
        self->start();
      }
    });
  }

 private:
  beast::tcp_stream& lowest() { return beast::get_lowest_layer(stream_); }

  void start() {
    if (reject_) {
      shared_.counters.rejected_connections++;
      send(problem_response(503, "too many connections; retry later"), false);
    } else {
      wait_for_request();
    }
  }

  // Idle phase: wait (idle timeout) for the first byte of the next request.
  void wait_for_request() {
    if (buffer_.size() > 0) return read_request();
    lowest().expires_after(secs(shared_.config.idle_timeout_s));
    stream_.async_read_some(buffer_.prepare(4096), [self = shared_from_this()](beast::error_code ec, size_t n) {
      if (ec) return self->on_error(ec);
      self->buffer_.commit(n);
      self->read_request();
    });
  }

  // Read phase: the whole request within the read timeout. The timeout is our own
  // timer (not the stream's, which would close the socket) so the client gets a 408.
  // The header comes first: a route that streams its body (BodySink: uploads) then
  // reads it in parts, every other route as one string within --max-body.
  void read_request() {
    header_parser_.emplace();
    header_parser_->header_limit(static_cast<uint32_t>(shared_.config.max_header_bytes));
    header_parser_->body_limit(std::numeric_limits<uint64_t>::max());  // decided once the route is known
    lowest().expires_never();
    read_timed_out_ = false;
    arm_read_timer();
    http::async_read_header(stream_, buffer_, *header_parser_,
                            [self = shared_from_this()](beast::error_code ec, size_t) { self->on_header(ec); });
  }

  void arm_read_timer() {
    read_timer_.expires_after(secs(shared_.config.read_timeout_s));
    read_timer_.async_wait([self = shared_from_this()](beast::error_code ec) {
      if (ec) return;  // cancelled or re-armed: the request (or its next part) arrived in time
      self->read_timed_out_ = true;
      beast::error_code ignored;
      self->lowest().socket().cancel(ignored);
    });
  }

  // A read that failed or timed out: the response (408, 413, 400 ...) or a close.
  void on_read_failure(beast::error_code ec) {
    read_timer_.cancel();
    sink_.reset();  // an unfinished streamed body is undone
    if (read_timed_out_) {
      shared_.counters.timeouts++;
      return send(problem_response(408, fmt::format("the request was not received within {} s",
                                                    shared_.config.read_timeout_s)),
                  false);
    }
    if (auto res = parse_error_response(ec, shared_.config)) return send(std::move(*res), false);
    return on_error(ec);
  }

  void on_header(beast::error_code ec) {
    if (ec || read_timed_out_) return on_read_failure(ec);
    HttpRequest head = to_http_head(header_parser_->get().base());
    head.peer_address = peer_;
    if (auto res = framing_response(head, header_parser_->get().version())) {
      read_timer_.cancel();
      return send(std::move(*res), false);
    }
    keep_alive_ = header_parser_->get().keep_alive();
    version_ = header_parser_->get().version();
    if (shared_.handler.streams_body(head)) return start_body_stream(std::move(head));
    const auto length = header_parser_->content_length();
    if (length && *length > shared_.config.max_body_bytes) return on_read_failure(http::error::body_limit);
    parser_.emplace(std::move(*header_parser_));
    header_parser_.reset();
    parser_->body_limit(shared_.config.max_body_bytes);
    http::async_read(stream_, buffer_, *parser_,
                     [self = shared_from_this()](beast::error_code ec2, size_t) { self->on_read(ec2); });
  }

  // ---- streamed bodies: each part is handed to the sink on the blocking pool (hashing
  // and disk writes stay off the I/O threads); the next part is read once it is taken.
  // The read timeout applies to each part (progress), not to the whole body.
  void start_body_stream(HttpRequest head) {
    const bool expect_continue = iequals(head.header("expect"), "100-continue");
    BodyStream bs = shared_.handler.open_body_stream(std::move(head));
    if (!bs.sink) {
      read_timer_.cancel();
      return send(std::move(bs.response), false);  // the body is not read: the connection ends
    }
    sink_ = std::move(bs.sink);
    body_parser_.emplace(std::move(*header_parser_));
    header_parser_.reset();
    body_parser_->body_limit(std::numeric_limits<uint64_t>::max());  // the sink enforces its own limit
    part_.resize(kBodyPartBytes);
    if (!expect_continue) return read_body_part();
    continue_ = "HTTP/1.1 100 Continue\r\n\r\n";
    lowest().expires_after(secs(shared_.config.write_timeout_s));
    net::async_write(stream_, net::buffer(continue_), [self = shared_from_this()](beast::error_code ec, size_t) {
      self->lowest().expires_never();
      if (ec) return self->on_read_failure(ec);
      self->read_body_part();
    });
  }

  void read_body_part() {
    if (body_parser_->is_done()) return finish_body_stream();
    arm_read_timer();
    body_parser_->get().body().data = part_.data();
    body_parser_->get().body().size = part_.size();
    // read_some: each part goes to the sink as it arrives, so a limit (size, quota) is
    // enforced as soon as the running total passes it, not once a whole part is filled.
    http::async_read_some(stream_, buffer_, *body_parser_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec == http::error::need_buffer) ec = {};
      if (ec || self->read_timed_out_) return self->on_read_failure(ec);
      self->read_timer_.cancel();
      const size_t n = self->part_.size() - self->body_parser_->get().body().size;
      if (n == 0) return self->read_body_part();  // framing only (a chunk header): nothing to hand over
      net::post(self->shared_.blocking, [self, n] {
        std::optional<HttpResponse> early = self->sink_->write(std::string_view(self->part_.data(), n));
        net::post(self->stream_.get_executor(), [self, early = std::move(early)]() mutable {
          if (early) {
            self->sink_.reset();
            return self->send(std::move(*early), false);
          }
          self->read_body_part();
        });
      });
    });
  }

  void finish_body_stream() {
    read_timer_.cancel();
    net::post(shared_.blocking, [self = shared_from_this()] {
      HttpResponse res = self->sink_->finish();
      net::post(self->stream_.get_executor(), [self, res = std::move(res)]() mutable {
        self->sink_.reset();
        self->body_parser_.reset();
        self->send(std::move(res), self->keep_alive_);
      });
    });
  }

  void on_error(beast::error_code ec) {
    if (ec == beast::error::timeout) shared_.counters.timeouts++;
    beast::error_code ignored;
    read_timer_.cancel();
    lowest().socket().shutdown(tcp::socket::shutdown_both, ignored);
    lowest().socket().close(ignored);
  }

  // After an error response that ends the connection: stop sending, then discard
  // what the client still sends for a moment, so closing with unread input (which
  // resets the connection) cannot destroy the response before the client reads it.
  void linger_close() {
    beast::error_code ignored;
    lowest().socket().shutdown(tcp::socket::shutdown_send, ignored);
    lowest().expires_after(std::chrono::seconds(1));  // one second in all, however much arrives
    drain_.resize(4096);
    linger_read();
  }
  void linger_read() {
    lowest().async_read_some(net::buffer(drain_), [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) return self->on_error({});
      self->linger_read();
    });
  }

  void on_read(beast::error_code ec) {
    if (ec || read_timed_out_) return on_read_failure(ec);
    read_timer_.cancel();
    BeastRequest req = parser_->release();
    parser_.reset();
    HttpRequest r = to_http_request(req);
    r.peer_address = peer_;
    const Lane lane = shared_.handler.lane(r);
    if (lane == Lane::slow && shared_.slow_requests.fetch_add(1) >= shared_.config.max_slow_requests) {
      shared_.slow_requests.fetch_sub(1);
      HttpResponse busy = problem_response(
          503, fmt::format("{} validate requests are running or waiting (the most the server takes); retry later",
                           shared_.config.max_slow_requests));
      busy.set_header("Retry-After", "1");
      return send(std::move(busy), keep_alive_);
    }
    if (lane == Lane::slow) {
      // Own pool: a pilot never delays a submit or an image encode on the blocking pool.
      net::post(shared_.slow, [self = shared_from_this(), r = std::move(r)]() mutable {
        HttpResponse res = self->shared_.handler.handle(std::move(r));
        self->shared_.slow_requests.fetch_sub(1);
        net::post(self->stream_.get_executor(),
                  [self, res = std::move(res)]() mutable { self->send(std::move(res), self->keep_alive_); });
      });
    } else if (lane == Lane::blocking) {
      net::post(shared_.blocking, [self = shared_from_this(), r = std::move(r)]() mutable {
        HttpResponse res = self->shared_.handler.handle(std::move(r));
        net::post(self->stream_.get_executor(),
                  [self, res = std::move(res)]() mutable { self->send(std::move(res), self->keep_alive_); });
      });
    } else {
      send(shared_.handler.handle(std::move(r)), keep_alive_);
    }
  }

  void send(HttpResponse res, bool keep_alive) {
    if (res.stream) return start_stream(std::move(res));
    auto msg = std::make_shared<http::response<http::string_body>>(static_cast<http::status>(res.status), version_);
    msg->set(http::field::server, "tally-server");
    for (auto& [k, v] : res.headers) msg->set(k, v);
    msg->body() = std::move(res.body);
    msg->keep_alive(keep_alive);
    msg->prepare_payload();
    lowest().expires_after(secs(shared_.config.write_timeout_s));
    http::async_write(stream_, *msg, [self = shared_from_this(), msg](beast::error_code ec, size_t) {
      if (ec) return self->on_error(ec);
      if (msg->need_eof()) return self->linger_close();
      self->wait_for_request();
    });
  }

  // ---- event streams: header, then one chunk per batch of events, then the last chunk.
  void start_stream(HttpResponse res) {
    events_ = std::move(res.stream);
    streaming_ = true;
    shared_.counters.streams++;
    stream_res_.emplace(static_cast<http::status>(res.status), version_);
    stream_res_->set(http::field::server, "tally-server");
    for (auto& [k, v] : res.headers) stream_res_->set(k, v);
    stream_res_->keep_alive(false);  // the stream ends the connection
    stream_res_->chunked(true);
    serializer_.emplace(*stream_res_);
    lowest().expires_after(secs(shared_.config.write_timeout_s));
    http::async_write_header(stream_, *serializer_, [self = shared_from_this()](beast::error_code ec, size_t) {
      if (ec) return self->on_error(ec);
      self->pump();
    });
  }

  void pump() {
    std::string out;
    const bool more = events_->poll(out);
    if (!out.empty()) {
      chunk_ = std::move(out);
      lowest().expires_after(secs(shared_.config.write_timeout_s));
      net::async_write(stream_, http::make_chunk(net::buffer(chunk_)),
                       [self = shared_from_this(), more](beast::error_code ec, size_t) {
                         if (ec) return self->on_error(ec);
                         if (more) {
                           self->pump();
                         } else {
                           self->finish_stream();
                         }
                       });
      return;
    }
    if (!more) return finish_stream();
    park();
  }

  void park() {
    lowest().expires_never();
    std::weak_ptr<Session> weak = this->weak_from_this();
    parked_ = true;
    auto exec = stream_.get_executor();
    if (!waiting_) {
      waiting_ = true;
      events_->on_ready([weak, exec] {
        net::post(exec, [weak] {
          if (auto self = weak.lock()) {
            self->waiting_ = false;
            self->wake();
          }
        });
      });
    }
    // The timer's handler keeps the session alive while it is parked.
    heartbeat_.expires_after(secs(shared_.config.heartbeat_s));
    heartbeat_.async_wait([self = shared_from_this()](beast::error_code ec) {
      if (ec || !self->parked_) return;
      self->parked_ = false;
      const std::string hb = self->events_->heartbeat();
      if (hb.empty()) return self->pump();
      self->chunk_ = hb;
      self->lowest().expires_after(secs(self->shared_.config.write_timeout_s));
      net::async_write(self->stream_, http::make_chunk(net::buffer(self->chunk_)),
                       [self](beast::error_code ec2, size_t) {
                         if (ec2) return self->on_error(ec2);
                         self->pump();
                       });
    });
  }

  void wake() {
    if (!parked_) return;  // a heartbeat write is in flight; pump() follows it
    parked_ = false;
    heartbeat_.cancel();
    pump();
  }

  void finish_stream() {
    lowest().expires_after(secs(shared_.config.write_timeout_s));
    net::async_write(stream_, http::make_chunk_last(), [self = shared_from_this()](beast::error_code, size_t) {
      self->on_error({});
    });
  }

  Stream stream_;
  Shared& shared_;
  bool reject_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::empty_body>> header_parser_;
  std::optional<http::request_parser<http::string_body>> parser_;
  std::optional<http::request_parser<http::buffer_body>> body_parser_;
  std::unique_ptr<BodySink> sink_;
  std::vector<char> part_;
  std::string continue_;
  bool keep_alive_ = false;
  unsigned version_ = 11;
  std::string peer_;  // the client's address (HttpRequest::peer_address)
  // streaming
  std::shared_ptr<EventStream> events_;
  std::optional<http::response<http::empty_body>> stream_res_;
  std::optional<http::response_serializer<http::empty_body>> serializer_;
  std::string chunk_;
  net::steady_timer heartbeat_;
  net::steady_timer read_timer_;
  bool read_timed_out_ = false;
  std::string drain_;
  bool streaming_ = false;
  bool parked_ = false;
  bool waiting_ = false;
};

}  // namespace

struct HttpServer::Impl {
  Impl(HttpServerConfig cfg, HttpHandler& handler, ConnectionCounters& counters)
      : blocking(2),
        slow(std::max(1u, cfg.slow_threads)),
        shared{std::move(cfg), handler, counters, blocking, slow, {}, {}},
        acceptor(ioc),
        accept_backoff(ioc),
        signals(ioc, SIGINT, SIGTERM),
        hangups(ioc, SIGHUP) {
    if (!shared.config.tls_cert.empty()) {
      tls.emplace(net::ssl::context::tls_server);
      tls->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                       net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 | net::ssl::context::no_tlsv1_1);
      tls->use_certificate_chain_file(shared.config.tls_cert);
      tls->use_private_key_file(shared.config.tls_key, net::ssl::context::pem);
    }
  }

  void wait_hangup() {
    hangups.async_wait([this](beast::error_code ec, int) {
      if (ec) return;
      if (on_hangup) on_hangup();
      wait_hangup();
    });
  }

  // Declaration order matters: the io_context is destroyed before `shared`, so
  // sessions still queued in it when it dies can update the shared counters.

  void accept() {
    acceptor.async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
      if (ec) {
        if (ec == net::error::operation_aborted || !acceptor.is_open()) return;
        // Out of descriptors (EMFILE/ENFILE) or memory: the pending connection stays
        // in the backlog, so accepting again at once would spin. Wait, then retry.
        shared.counters.accept_errors++;
        accept_backoff.expires_after(std::chrono::milliseconds(100));
        accept_backoff.async_wait([this](beast::error_code tec) {
          if (!tec && acceptor.is_open()) accept();
        });
        return;
      }
      const bool reject = shared.connections.load() >= shared.config.max_connections;
      if (tls) {
        std::make_shared<Session<beast::ssl_stream<beast::tcp_stream>>>(std::move(socket), &*tls, shared, reject)->run();
      } else {
        std::make_shared<Session<beast::tcp_stream>>(std::move(socket), nullptr, shared, reject)->run();
      }
      if (acceptor.is_open()) accept();
    });
  }

  net::thread_pool blocking;
  net::thread_pool slow;
  std::optional<net::ssl::context> tls;  // before `shared`'s users: sessions hold a reference
  Shared shared;
  net::io_context ioc;
  tcp::acceptor acceptor;
  net::steady_timer accept_backoff;
  net::signal_set signals;
  net::signal_set hangups;
  std::function<void()> on_hangup;
  std::vector<std::thread> threads;
  uint16_t port = 0;
  std::optional<net::executor_work_guard<net::io_context::executor_type>> work;
};

HttpServer::HttpServer(HttpServerConfig config, HttpHandler& handler, ConnectionCounters& counters)
    : impl_(std::make_unique<Impl>(std::move(config), handler, counters)) {}

HttpServer::~HttpServer() { stop(0); }

uint16_t HttpServer::start() {
  Impl& s = *impl_;
  const tcp::endpoint ep(net::ip::make_address(s.shared.config.address), s.shared.config.port);
  try {
    s.acceptor.open(ep.protocol());
    s.acceptor.set_option(net::socket_base::reuse_address(true));
    s.acceptor.bind(ep);
    s.acceptor.listen(net::socket_base::max_listen_connections);
  } catch (const boost::system::system_error& e) {
    // "bind: Address already in use" names no address; the operator needs to know which.
    throw std::runtime_error(fmt::format("cannot listen on {}:{}: {}", s.shared.config.address,
                                         s.shared.config.port, e.code().message()));
  }
  s.port = s.acceptor.local_endpoint().port();
  s.accept();
  s.work.emplace(s.ioc.get_executor());
  const unsigned n = std::max(1u, s.shared.config.io_threads);
  for (unsigned i = 0; i < n; ++i) s.threads.emplace_back([&s] { s.ioc.run(); });
  return s.port;
}

uint16_t HttpServer::port() const { return impl_->port; }

void HttpServer::on_signal(std::function<void(int)> fn) {
  impl_->signals.async_wait([fn = std::move(fn)](beast::error_code ec, int sig) {
    if (!ec) fn(sig);
  });
}

void HttpServer::on_hangup(std::function<void()> fn) {
  impl_->on_hangup = std::move(fn);
  impl_->wait_hangup();
}

void HttpServer::stop_accepting() {
  net::post(impl_->ioc, [this] {
    beast::error_code ignored;
    impl_->acceptor.close(ignored);
    impl_->accept_backoff.cancel();
  });
}

size_t HttpServer::open_connections() const { return impl_->shared.connections.load(); }

void HttpServer::stop(double grace_seconds) {
  Impl& s = *impl_;
  if (s.threads.empty()) return;
  stop_accepting();
  const auto deadline = std::chrono::steady_clock::now() + secs(grace_seconds);
  while (s.shared.connections.load() > 0 && std::chrono::steady_clock::now() < deadline) {
    std::this_thread::sleep_for(std::chrono::milliseconds(10));
  }
  s.work.reset();
  s.ioc.stop();
  for (auto& t : s.threads) t.join();
  s.threads.clear();
  s.blocking.join();
  s.slow.join();
}

std::string respond_to_bytes(std::string_view raw, const HttpServerConfig& config, HttpHandler& handler) {
  std::string out;
  beast::flat_buffer buffer;
  net::buffer_copy(buffer.prepare(raw.size()), net::buffer(raw.data(), raw.size()));
  buffer.commit(raw.size());
  auto emit = [&out](HttpResponse res, bool keep_alive, unsigned version) {
    http::response<http::string_body> msg(static_cast<http::status>(res.status), version);
    for (auto& [k, v] : res.headers) msg.set(k, v);
    msg.body() = std::move(res.body);
    msg.keep_alive(keep_alive);
    msg.prepare_payload();
    std::ostringstream os;
    os << msg;
    out += os.str();
  };
  while (buffer.size() > 0) {
    http::request_parser<http::string_body> parser;
    configure_parser(parser, config);
    parser.eager(true);
    beast::error_code ec;
    while (!parser.is_done()) {
      const size_t used = parser.put(buffer.data(), ec);
      buffer.consume(used);
      if (ec || used == 0) break;
    }
    if (ec == http::error::need_more || (!ec && !parser.is_done())) {
      // Incomplete at the end of the input: the server would wait, then answer 408.
      emit(problem_response(408, "the request was not received in time"), false, 11);
      break;
    }
    if (ec) {
      if (auto res = parse_error_response(ec, config)) emit(std::move(*res), false, 11);
      break;
    }
    BeastRequest req = parser.release();
    const bool keep_alive = req.keep_alive();
    const unsigned version = req.version();
    HttpRequest r = to_http_request(req);
    if (auto res = framing_response(r, version)) {
      emit(std::move(*res), false, version);
      break;
    }
    HttpResponse res = handler.handle(r);
    if (res.stream) {
      res.stream.reset();  // an event stream ends the connection
      emit(std::move(res), false, version);
      break;
    }
    emit(std::move(res), keep_alive, version);
    if (!keep_alive) break;
  }
  return out;
}

}  // namespace tally
