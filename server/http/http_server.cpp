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
#include <fmt/format.h>

#include <atomic>
#include <chrono>
#include <optional>
#include <thread>
#include <vector>

#include "server/http/event_stream.hpp"
#include "server/api/metrics.hpp"
#include "server/api/problem.hpp"
#include "server/api/request_handler.hpp"

namespace tally {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;

namespace {

std::chrono::steady_clock::duration secs(double s) {
  return std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(s));
}

struct Shared {
  HttpServerConfig config;
  RequestHandler& handler;
  Metrics& metrics;
  net::thread_pool& blocking;
  std::atomic<size_t> connections{0};
};

class Session : public std::enable_shared_from_this<Session> {
 public:
  Session(tcp::socket&& socket, Shared& shared, bool reject)
      : stream_(std::move(socket)), shared_(shared), reject_(reject), heartbeat_(stream_.get_executor()) {
    shared_.connections++;
    shared_.metrics.connections++;
  }
  ~Session() {
    if (streaming_) shared_.metrics.streams--;
    shared_.metrics.connections--;
    shared_.connections--;
  }

  void run() {
    net::dispatch(stream_.get_executor(), [self = shared_from_this()] {
      if (self->reject_) {
        self->shared_.metrics.rejected_connections++;
        self->send(problem_response(503, "too many connections; retry later"), false);
      } else {
        self->wait_for_request();
      }
    });
  }

 private:
  // Idle phase: wait (idle timeout) for the first byte of the next request.
  void wait_for_request() {
    if (buffer_.size() > 0) return read_request();
    stream_.expires_after(secs(shared_.config.idle_timeout_s));
    stream_.async_read_some(buffer_.prepare(4096), [self = shared_from_this()](beast::error_code ec, size_t n) {
      if (ec) return self->on_error(ec);
      self->buffer_.commit(n);
      self->read_request();
    });
  }

  // Read phase: the whole request within the read timeout.
  void read_request() {
    parser_.emplace();
    parser_->body_limit(shared_.config.max_body_bytes);
    parser_->header_limit(static_cast<uint32_t>(shared_.config.max_header_bytes));
    stream_.expires_after(secs(shared_.config.read_timeout_s));
    http::async_read(stream_, buffer_, *parser_,
                     [self = shared_from_this()](beast::error_code ec, size_t) { self->on_read(ec); });
  }

  void on_error(beast::error_code ec) {
    if (ec == beast::error::timeout) shared_.metrics.timeouts++;
    beast::error_code ignored;
    stream_.socket().shutdown(tcp::socket::shutdown_both, ignored);
    stream_.socket().close(ignored);
  }

  void on_read(beast::error_code ec) {
    if (ec == http::error::end_of_stream) return on_error(ec);
    if (ec == http::error::body_limit) {
      return send(problem_response(413, fmt::format("the request body exceeds {} bytes", shared_.config.max_body_bytes)), false);
    }
    if (ec == http::error::header_limit) {
      return send(problem_response(431, fmt::format("the request header exceeds {} bytes", shared_.config.max_header_bytes)),
                  false);
    }
    if (ec == beast::error::timeout) return on_error(ec);
    if (ec) {
      if (ec.category() == beast::error_code(http::error::bad_target).category()) {
        return send(problem_response(400, fmt::format("malformed HTTP request: {}", ec.message())), false);
      }
      return on_error(ec);
    }
    http::request<http::string_body> req = parser_->release();
    parser_.reset();
    keep_alive_ = req.keep_alive();
    version_ = req.version();
    HttpRequest r;
    r.method = std::string(req.method_string());
    r.target = std::string(req.target());
    for (const auto& f : req) {
      std::string name(f.name_string());
      for (char& c : name) c = static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
      r.headers.emplace_back(std::move(name), std::string(f.value()));
    }
    r.body = std::move(req.body());
    stream_.expires_never();
    if (shared_.handler.may_block(r)) {
      net::post(shared_.blocking, [self = shared_from_this(), r = std::move(r)]() mutable {
        HttpResponse res = self->shared_.handler.handle(r);
        net::post(self->stream_.get_executor(),
                  [self, res = std::move(res)]() mutable { self->send(std::move(res), self->keep_alive_); });
      });
    } else {
      send(shared_.handler.handle(r), keep_alive_);
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
    stream_.expires_after(secs(shared_.config.write_timeout_s));
    http::async_write(stream_, *msg, [self = shared_from_this(), msg](beast::error_code ec, size_t) {
      if (ec) return self->on_error(ec);
      if (msg->need_eof()) return self->on_error({});
      self->wait_for_request();
    });
  }

  // ---- event streams: header, then one chunk per batch of events, then the last chunk.
  void start_stream(HttpResponse res) {
    events_ = std::move(res.stream);
    streaming_ = true;
    shared_.metrics.streams++;
    stream_res_.emplace(static_cast<http::status>(res.status), version_);
    stream_res_->set(http::field::server, "tally-server");
    for (auto& [k, v] : res.headers) stream_res_->set(k, v);
    stream_res_->keep_alive(false);  // the stream ends the connection
    stream_res_->chunked(true);
    serializer_.emplace(*stream_res_);
    stream_.expires_after(secs(shared_.config.write_timeout_s));
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
      stream_.expires_after(secs(shared_.config.write_timeout_s));
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
    stream_.expires_never();
    std::weak_ptr<Session> weak = shared_from_this();
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
      self->stream_.expires_after(secs(self->shared_.config.write_timeout_s));
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
    stream_.expires_after(secs(shared_.config.write_timeout_s));
    net::async_write(stream_, http::make_chunk_last(), [self = shared_from_this()](beast::error_code, size_t) {
      self->on_error({});
    });
  }

  beast::tcp_stream stream_;
  Shared& shared_;
  bool reject_;
  beast::flat_buffer buffer_;
  std::optional<http::request_parser<http::string_body>> parser_;
  bool keep_alive_ = false;
  unsigned version_ = 11;
  // streaming
  std::shared_ptr<EventStream> events_;
  std::optional<http::response<http::empty_body>> stream_res_;
  std::optional<http::response_serializer<http::empty_body>> serializer_;
  std::string chunk_;
  net::steady_timer heartbeat_;
  bool streaming_ = false;
  bool parked_ = false;
  bool waiting_ = false;
};

}  // namespace

struct HttpServer::Impl {
  Impl(HttpServerConfig cfg, RequestHandler& handler, Metrics& metrics)
      : blocking(2), shared{std::move(cfg), handler, metrics, blocking, {}}, acceptor(ioc), signals(ioc, SIGINT, SIGTERM) {}

  // Declaration order matters: the io_context is destroyed before `shared`, so
  // sessions still queued in it when it dies can update the shared counters.

  void accept() {
    acceptor.async_accept(net::make_strand(ioc), [this](beast::error_code ec, tcp::socket socket) {
      if (ec) {
        if (ec == net::error::operation_aborted || !acceptor.is_open()) return;
      } else {
        const bool reject = shared.connections.load() >= shared.config.max_connections;
        std::make_shared<Session>(std::move(socket), shared, reject)->run();
      }
      if (acceptor.is_open()) accept();
    });
  }

  net::thread_pool blocking;
  Shared shared;
  net::io_context ioc;
  tcp::acceptor acceptor;
  net::signal_set signals;
  std::vector<std::thread> threads;
  uint16_t port = 0;
  std::optional<net::executor_work_guard<net::io_context::executor_type>> work;
};

HttpServer::HttpServer(HttpServerConfig config, RequestHandler& handler, Metrics& metrics)
    : impl_(std::make_unique<Impl>(std::move(config), handler, metrics)) {}

HttpServer::~HttpServer() { stop(0); }

uint16_t HttpServer::start() {
  Impl& s = *impl_;
  const tcp::endpoint ep(net::ip::make_address(s.shared.config.address), s.shared.config.port);
  s.acceptor.open(ep.protocol());
  s.acceptor.set_option(net::socket_base::reuse_address(true));
  s.acceptor.bind(ep);
  s.acceptor.listen(net::socket_base::max_listen_connections);
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

void HttpServer::stop_accepting() {
  net::post(impl_->ioc, [this] {
    beast::error_code ignored;
    impl_->acceptor.close(ignored);
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
}

}  // namespace tally
