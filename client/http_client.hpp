#pragma once
// A small blocking HTTP/1.1 client for the CLI and the end-to-end tests. Only
// http_client.cpp includes Beast. One connection per call: the CLI makes a handful
// of requests, so keep-alive would buy nothing.
#include <CLI/CLI.hpp>
#include <functional>
#include <optional>
#include <stdexcept>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

namespace tally {

// Could not connect, timed out, or the connection broke.
class ConnectionError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

struct HttpUrl {
  std::string host = "127.0.0.1";
  std::string port = "8080";
  std::string base_path;  // prefix without trailing '/', usually ""
  bool tls = false;       // https: the server's certificate is verified (chain and host name)
};
// "http://host:port[/prefix]" or "https://..."; nullopt if neither.
std::optional<HttpUrl> parse_http_url(std::string_view url);

using HeaderList = std::vector<std::pair<std::string, std::string>>;

struct ClientResponse {
  int status = 0;
  HeaderList headers;
  std::string body;
  std::string header(std::string_view name) const;  // case-insensitive; "" if absent
};

// Credentials and trust: a bearer token sent on every request (never printed), and the
// CA certificates (PEM) that vouch for an https server ("" = the system's).
struct ClientSecurity {
  std::string token;
  std::string ca_file;
};

// Adds --token (TALLY_TOKEN) and --ca-file (TALLY_CA_FILE) to a command.
void add_security_options(CLI::App* cmd, ClientSecurity& security);

class HttpClient {
 public:
  explicit HttpClient(HttpUrl url, double timeout_s = 30.0, ClientSecurity security = {})
      : url_(std::move(url)), timeout_s_(timeout_s), security_(std::move(security)) {}

  ClientResponse request(std::string_view method, std::string_view target, std::string_view body = {},
                         const HeaderList& headers = {});
  // Sends a file as the body (read as it is sent, never whole in memory), e.g. PUT
  // /v1/assets/...; the write may take timeout_s + size / (2 MB/s).
  ClientResponse send_file(std::string_view method, std::string_view target, const std::string& path,
                           const HeaderList& headers = {});
  // GET a streaming body: `on_data` gets each piece as it arrives and returns false
  // to stop early. `idle_timeout_s` bounds the wait for each piece. The returned
  // response has the status and headers (and the body only for non-2xx answers).
  ClientResponse stream(std::string_view target, const HeaderList& headers,
                        const std::function<bool(std::string_view)>& on_data, double idle_timeout_s);
  // Sends `raw` bytes as they are, `pause_s` between bytes if > 0, then reads the
  // answer until the server closes. For tests of malformed and slow requests.
  // Returns the raw response text ("" if the server closed without answering).
  std::string raw_exchange(std::string_view raw, double pause_s = 0.0);

  const HttpUrl& url() const { return url_; }

 private:
  std::string host_header() const;  // host[:port] as a browser would send it (the server's Host check)
  HttpUrl url_;
  double timeout_s_;
  ClientSecurity security_;
};

}  // namespace tally
