// The only client translation unit that includes Beast.
#include <utility>  // before Asio: Boost 1.74's awaitable.hpp misses it under GCC 12

#include "client/http_client.hpp"

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>

#include <chrono>
#include <thread>

namespace tally {

namespace beast = boost::beast;
namespace http = beast::http;
namespace net = boost::asio;
using tcp = net::ip::tcp;

namespace {

std::chrono::steady_clock::duration secs(double s) {
  return std::chrono::duration_cast<std::chrono::steady_clock::duration>(std::chrono::duration<double>(s));
}

bool iequal(std::string_view a, std::string_view b) {
  if (a.size() != b.size()) return false;
  for (size_t i = 0; i < a.size(); ++i) {
    if (std::tolower(static_cast<unsigned char>(a[i])) != std::tolower(static_cast<unsigned char>(b[i]))) return false;
  }
  return true;
}

// Blocking calls built from async operations, so tcp_stream's timeouts apply.
class Connection {
 public:
  Connection(const HttpUrl& url, double timeout_s) : stream_(ioc_) {
    tcp::resolver resolver(ioc_);
    beast::error_code ec;
    const auto results = resolver.resolve(url.host, url.port, ec);
    if (ec) throw ConnectionError("cannot resolve " + url.host + ": " + ec.message());
    stream_.expires_after(secs(timeout_s));
    stream_.async_connect(results, [&](beast::error_code e, const tcp::endpoint&) { ec = e; });
    run();
    if (ec) throw ConnectionError("cannot connect to " + url.host + ":" + url.port + ": " + ec.message());
  }

  template <class Op>
  beast::error_code call(double timeout_s, Op&& op) {
    beast::error_code ec;
    stream_.expires_after(secs(timeout_s));
    op([&](beast::error_code e, size_t) { ec = e; });
    run();
    return ec;
  }

  beast::tcp_stream& stream() { return stream_; }

 private:
  void run() {
    ioc_.restart();
    ioc_.run();
  }
  net::io_context ioc_;
  beast::tcp_stream stream_;
};

void fill_headers(const http::fields& f, HeaderList& out) {
  for (const auto& h : f) out.emplace_back(std::string(h.name_string()), std::string(h.value()));
}

}  // namespace

std::optional<HttpUrl> parse_http_url(std::string_view url) {
  constexpr std::string_view scheme = "http://";
  if (url.substr(0, scheme.size()) != scheme) return std::nullopt;
  url.remove_prefix(scheme.size());
  HttpUrl u;
  const size_t slash = url.find('/');
  std::string_view hostport = url.substr(0, slash);
  if (slash != std::string_view::npos) {
    u.base_path = std::string(url.substr(slash));
    while (!u.base_path.empty() && u.base_path.back() == '/') u.base_path.pop_back();
  }
  if (!hostport.empty() && hostport.front() == '[') {
    const size_t close = hostport.find(']');
    if (close == std::string_view::npos) return std::nullopt;
    u.host = std::string(hostport.substr(1, close - 1));
    if (close + 1 < hostport.size()) {
      if (hostport[close + 1] != ':') return std::nullopt;
      u.port = std::string(hostport.substr(close + 2));
    } else {
      u.port = "80";
    }
  } else {
    const size_t colon = hostport.rfind(':');
    u.host = std::string(hostport.substr(0, colon));
    u.port = colon == std::string_view::npos ? "80" : std::string(hostport.substr(colon + 1));
  }
  if (u.host.empty() || u.port.empty()) return std::nullopt;
  return u;
}

std::string ClientResponse::header(std::string_view name) const {
  for (const auto& [k, v] : headers) {
    if (iequal(k, name)) return v;
  }
  return {};
}

ClientResponse HttpClient::request(std::string_view method, std::string_view target, std::string_view body,
                                   const HeaderList& headers) {
  Connection c(url_, timeout_s_);
  http::request<http::string_body> req(http::string_to_verb(method), url_.base_path + std::string(target), 11);
  req.set(http::field::host, url_.host);
  req.set(http::field::user_agent, "tally-cli");
  bool has_ct = false;
  for (const auto& [k, v] : headers) {
    req.set(k, v);
    has_ct = has_ct || iequal(k, "content-type");
  }
  if (!body.empty() && !has_ct) req.set(http::field::content_type, "application/json");
  req.body() = std::string(body);
  req.keep_alive(false);
  req.prepare_payload();
  if (auto ec = c.call(timeout_s_, [&](auto h) { http::async_write(c.stream(), req, h); })) {
    throw ConnectionError("sending the request failed: " + ec.message());
  }
  beast::flat_buffer buf;
  http::response_parser<http::string_body> parser;
  parser.body_limit(std::numeric_limits<uint64_t>::max());
  if (auto ec = c.call(timeout_s_, [&](auto h) { http::async_read(c.stream(), buf, parser, h); })) {
    throw ConnectionError("reading the response failed: " + ec.message());
  }
  ClientResponse r;
  r.status = static_cast<int>(parser.get().result_int());
  fill_headers(parser.get().base(), r.headers);
  r.body = std::move(parser.get().body());
  return r;
}

ClientResponse HttpClient::stream(std::string_view target, const HeaderList& headers,
                                  const std::function<bool(std::string_view)>& on_data, double idle_timeout_s) {
  Connection c(url_, timeout_s_);
  http::request<http::empty_body> req(http::verb::get, url_.base_path + std::string(target), 11);
  req.set(http::field::host, url_.host);
  req.set(http::field::user_agent, "tally-cli");
  for (const auto& [k, v] : headers) req.set(k, v);
  if (auto ec = c.call(timeout_s_, [&](auto h) { http::async_write(c.stream(), req, h); })) {
    throw ConnectionError("sending the request failed: " + ec.message());
  }
  beast::flat_buffer buf;
  http::response_parser<http::buffer_body> parser;
  parser.body_limit(std::numeric_limits<uint64_t>::max());
  if (auto ec = c.call(timeout_s_, [&](auto h) { http::async_read_header(c.stream(), buf, parser, h); })) {
    throw ConnectionError("reading the response failed: " + ec.message());
  }
  ClientResponse r;
  r.status = static_cast<int>(parser.get().result_int());
  fill_headers(parser.get().base(), r.headers);
  const bool ok = r.status >= 200 && r.status < 300;
  char chunk[16384];
  while (!parser.is_done()) {
    parser.get().body().data = chunk;
    parser.get().body().size = sizeof chunk;
    auto ec = c.call(idle_timeout_s, [&](auto h) { http::async_read(c.stream(), buf, parser, h); });
    if (ec == http::error::need_buffer) ec = {};
    const size_t n = sizeof chunk - parser.get().body().size;
    if (n > 0) {
      if (ok) {
        if (!on_data(std::string_view(chunk, n))) return r;
      } else {
        r.body.append(chunk, n);
      }
    }
    if (ec == http::error::end_of_stream || ec == http::error::partial_message) break;
    if (ec == beast::error::timeout) throw ConnectionError("the event stream went quiet for too long");
    if (ec) throw ConnectionError("the stream broke: " + ec.message());
  }
  return r;
}

std::string HttpClient::raw_exchange(std::string_view raw, double pause_s) {
  Connection c(url_, timeout_s_);
  beast::error_code ec;
  if (pause_s > 0) {
    for (char ch : raw) {
      ec = c.call(timeout_s_, [&](auto h) { net::async_write(c.stream(), net::buffer(&ch, 1), h); });
      if (ec) break;  // the server cut us off
      std::this_thread::sleep_for(secs(pause_s));
    }
  } else {
    ec = c.call(timeout_s_, [&](auto h) { net::async_write(c.stream(), net::buffer(raw.data(), raw.size()), h); });
  }
  std::string out;
  char b[4096];
  for (;;) {
    size_t got = 0;
    ec = c.call(timeout_s_, [&](auto h) {
      c.stream().async_read_some(net::buffer(b), [&, h](beast::error_code e, size_t n) mutable {
        got = n;
        h(e, n);
      });
    });
    out.append(b, got);
    if (ec) break;
  }
  return out;
}

}  // namespace tally
