// The only client translation unit that includes Beast.
#include <utility>  // before Asio: Boost 1.74's awaitable.hpp misses it under GCC 12

#include "client/http_client.hpp"

#include <boost/asio/connect.hpp>
#include <boost/asio/io_context.hpp>
#include <boost/asio/ip/tcp.hpp>
#include <boost/asio/write.hpp>
#include <boost/beast/core.hpp>
#include <boost/beast/http.hpp>
#include <boost/beast/ssl.hpp>
#include <boost/asio/ssl/host_name_verification.hpp>

#include <fmt/format.h>

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

// Blocking calls built from async operations, so tcp_stream's timeouts apply. Over
// https the same calls go through an ssl_stream that verified the server.
class Connection {
 public:
  Connection(const HttpUrl& url, const ClientSecurity& sec, double timeout_s) {
    tcp::resolver resolver(ioc_);
    beast::error_code ec;
    const auto results = resolver.resolve(url.host, url.port, ec);
    if (ec) throw ConnectionError("cannot resolve " + url.host + ": " + ec.message());
    if (url.tls) {
      ctx_.emplace(net::ssl::context::tls_client);
      ctx_->set_options(net::ssl::context::default_workarounds | net::ssl::context::no_sslv2 |
                        net::ssl::context::no_sslv3 | net::ssl::context::no_tlsv1 | net::ssl::context::no_tlsv1_1);
      try {
        if (sec.ca_file.empty()) {
          ctx_->set_default_verify_paths();
        } else {
          ctx_->load_verify_file(sec.ca_file);
        }
      } catch (const std::exception& e) {
        throw ConnectionError("cannot load the CA certificates " + sec.ca_file + ": " + e.what());
      }
      ctx_->set_verify_mode(net::ssl::verify_peer);
      ssl_.emplace(ioc_, *ctx_);
      ssl_->set_verify_callback(net::ssl::host_name_verification(url.host));
      // SNI, so a server with several names picks the right certificate.
      SSL_ctrl(ssl_->native_handle(), SSL_CTRL_SET_TLSEXT_HOSTNAME, TLSEXT_NAMETYPE_host_name,
               const_cast<char*>(url.host.c_str()));
    } else {
      tcp_.emplace(ioc_);
    }
    beast::tcp_stream& low = lowest();
    low.expires_after(secs(timeout_s));
    low.async_connect(results, [&](beast::error_code e, const tcp::endpoint&) { ec = e; });
    run();
    if (ec) throw ConnectionError("cannot connect to " + url.host + ":" + url.port + ": " + ec.message());
    if (ssl_) {
      low.expires_after(secs(timeout_s));
      ssl_->async_handshake(net::ssl::stream_base::client, [&](beast::error_code e) { ec = e; });
      run();
      if (ec) {
        throw ConnectionError("TLS handshake with " + url.host + ":" + url.port + " failed: " + ec.message() +
                              " (is the certificate trusted? --ca-file)");
      }
    }
  }

  // `op(stream, handler)` starts one async operation on the plain or TLS stream.
  template <class Op>
  beast::error_code call(double timeout_s, Op&& op) {
    beast::error_code ec;
    lowest().expires_after(secs(timeout_s));
    auto h = [&](beast::error_code e, size_t) { ec = e; };
    if (ssl_) {
      op(*ssl_, h);
    } else {
      op(*tcp_, h);
    }
    run();
    return ec;
  }

 private:
  beast::tcp_stream& lowest() { return ssl_ ? beast::get_lowest_layer(*ssl_) : *tcp_; }
  void run() {
    ioc_.restart();
    ioc_.run();
  }
  net::io_context ioc_;
  std::optional<net::ssl::context> ctx_;
  std::optional<beast::tcp_stream> tcp_;
  std::optional<beast::ssl_stream<beast::tcp_stream>> ssl_;
};

void fill_headers(const http::fields& f, HeaderList& out) {
  for (const auto& h : f) out.emplace_back(std::string(h.name_string()), std::string(h.value()));
}

}  // namespace

std::optional<HttpUrl> parse_http_url(std::string_view url) {
  HttpUrl u;
  if (url.substr(0, 7) == "http://") {
    url.remove_prefix(7);
  } else if (url.substr(0, 8) == "https://") {
    url.remove_prefix(8);
    u.tls = true;
  } else {
    return std::nullopt;
  }
  const std::string default_port = u.tls ? "443" : "80";
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
      u.port = default_port;
    }
  } else {
    const size_t colon = hostport.rfind(':');
    u.host = std::string(hostport.substr(0, colon));
    u.port = colon == std::string_view::npos ? default_port : std::string(hostport.substr(colon + 1));
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
  Connection c(url_, security_, timeout_s_);
  http::request<http::string_body> req(http::string_to_verb(method), url_.base_path + std::string(target), 11);
  req.set(http::field::host, host_header());
  req.set(http::field::user_agent, "tally-cli");
  if (!security_.token.empty()) req.set(http::field::authorization, "Bearer " + security_.token);
  bool has_ct = false;
  for (const auto& [k, v] : headers) {
    req.set(k, v);
    has_ct = has_ct || iequal(k, "content-type");
  }
  if (!body.empty() && !has_ct) req.set(http::field::content_type, "application/json");
  req.body() = std::string(body);
  req.keep_alive(false);
  req.prepare_payload();
  if (auto ec = c.call(timeout_s_, [&](auto& s, auto h) { http::async_write(s, req, h); })) {
    throw ConnectionError("sending the request failed: " + ec.message());
  }
  beast::flat_buffer buf;
  http::response_parser<http::string_body> parser;
  parser.body_limit(std::numeric_limits<uint64_t>::max());
  if (auto ec = c.call(timeout_s_, [&](auto& s, auto h) { http::async_read(s, buf, parser, h); })) {
    throw ConnectionError("reading the response failed: " + ec.message());
  }
  ClientResponse r;
  r.status = static_cast<int>(parser.get().result_int());
  fill_headers(parser.get().base(), r.headers);
  r.body = std::move(parser.get().body());
  return r;
}

ClientResponse HttpClient::send_file(std::string_view method, std::string_view target, const std::string& path,
                                     const HeaderList& headers) {
  Connection c(url_, security_, timeout_s_);
  http::request<http::file_body> req(http::string_to_verb(method), url_.base_path + std::string(target), 11);
  beast::error_code ec;
  req.body().open(path.c_str(), beast::file_mode::scan, ec);
  if (ec) throw std::runtime_error(fmt::format("cannot open {}: {}", path, ec.message()));
  req.set(http::field::host, host_header());
  req.set(http::field::user_agent, "tally-cli");
  req.set(http::field::content_type, "application/octet-stream");
  if (!security_.token.empty()) req.set(http::field::authorization, "Bearer " + security_.token);
  for (const auto& [k, v] : headers) req.set(k, v);
  req.keep_alive(false);
  req.prepare_payload();
  const double write_timeout = timeout_s_ + static_cast<double>(req.body().size()) / 2e6;
  if (auto wec = c.call(write_timeout, [&](auto& s, auto h) { http::async_write(s, req, h); })) {
    throw ConnectionError("sending the file failed: " + wec.message());
  }
  beast::flat_buffer buf;
  http::response_parser<http::string_body> parser;
  parser.body_limit(std::numeric_limits<uint64_t>::max());
  if (auto rec = c.call(timeout_s_, [&](auto& s, auto h) { http::async_read(s, buf, parser, h); })) {
    throw ConnectionError("reading the response failed: " + rec.message());
  }
  ClientResponse r;
  r.status = static_cast<int>(parser.get().result_int());
  fill_headers(parser.get().base(), r.headers);
  r.body = std::move(parser.get().body());
  return r;
}

ClientResponse HttpClient::stream(std::string_view target, const HeaderList& headers,
                                  const std::function<bool(std::string_view)>& on_data, double idle_timeout_s) {
  Connection c(url_, security_, timeout_s_);
  http::request<http::empty_body> req(http::verb::get, url_.base_path + std::string(target), 11);
  req.set(http::field::host, host_header());
  req.set(http::field::user_agent, "tally-cli");
  if (!security_.token.empty()) req.set(http::field::authorization, "Bearer " + security_.token);
  for (const auto& [k, v] : headers) req.set(k, v);
  if (auto ec = c.call(timeout_s_, [&](auto& s, auto h) { http::async_write(s, req, h); })) {
    throw ConnectionError("sending the request failed: " + ec.message());
  }
  beast::flat_buffer buf;
  http::response_parser<http::buffer_body> parser;
  parser.body_limit(std::numeric_limits<uint64_t>::max());
  if (auto ec = c.call(timeout_s_, [&](auto& s, auto h) { http::async_read_header(s, buf, parser, h); })) {
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
    // read_some: hand each piece over as it arrives (async_read would wait until the
    // 16 KiB buffer is full, holding back a slow event stream).
    auto ec = c.call(idle_timeout_s, [&](auto& s, auto h) { http::async_read_some(s, buf, parser, h); });
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
  Connection c(url_, security_, timeout_s_);
  beast::error_code ec;
  if (pause_s > 0) {
    for (char ch : raw) {
      ec = c.call(timeout_s_, [&](auto& s, auto h) { net::async_write(s, net::buffer(&ch, 1), h); });
      if (ec) break;  // the server cut us off
      std::this_thread::sleep_for(secs(pause_s));
    }
  } else {
    ec = c.call(timeout_s_, [&](auto& s, auto h) { net::async_write(s, net::buffer(raw.data(), raw.size()), h); });
  }
  std::string out;
  char b[4096];
  for (;;) {
    size_t got = 0;
    ec = c.call(timeout_s_, [&](auto& s, auto h) {
      s.async_read_some(net::buffer(b), [&, h](beast::error_code e, size_t n) mutable {
        got = n;
        h(e, n);
      });
    });
    out.append(b, got);
    if (ec) break;
  }
  return out;
}

void add_security_options(CLI::App* cmd, ClientSecurity& security) {
  cmd->add_option("--token", security.token, "bearer token for a server with access control")->envname("TALLY_TOKEN");
  cmd->add_option("--ca-file", security.ca_file, "PEM CA certificates that sign an https server's certificate")
      ->envname("TALLY_CA_FILE");
}

std::string HttpClient::host_header() const {
  const bool default_port = url_.port == (url_.tls ? "443" : "80");
  const std::string host = url_.host.find(':') != std::string::npos ? "[" + url_.host + "]" : url_.host;
  return default_port ? host : host + ":" + url_.port;
}

}  // namespace tally
