#pragma once
// A blocking TCP socket to a port on 127.0.0.1, for the tests and benches that speak
// raw HTTP bytes (half-sent bodies, many idle streams) where a client library would
// hide what they test.
#include <netinet/in.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <cstdint>
#include <string_view>

namespace tally::test {

// A connected socket, or -1. With `read_timeout_s` > 0 a read waits at most that long.
inline int connect_loopback(uint16_t port, double read_timeout_s = 0) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  if (fd < 0) return -1;
  if (read_timeout_s > 0) {
    timeval tv{};
    tv.tv_sec = static_cast<time_t>(read_timeout_s);
    tv.tv_usec = static_cast<suseconds_t>((read_timeout_s - static_cast<double>(tv.tv_sec)) * 1e6);
    ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &tv, sizeof tv);
  }
  sockaddr_in addr{};
  addr.sin_family = AF_INET;
  addr.sin_port = htons(port);
  addr.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  if (::connect(fd, reinterpret_cast<sockaddr*>(&addr), sizeof addr) != 0) {
    ::close(fd);
    return -1;
  }
  return fd;
}

// Writes all of `bytes`; false if the peer went away.
inline bool send_all(int fd, std::string_view bytes) {
  while (!bytes.empty()) {
    const ssize_t n = ::send(fd, bytes.data(), bytes.size(), MSG_NOSIGNAL);
    if (n <= 0) return false;
    bytes.remove_prefix(static_cast<size_t>(n));
  }
  return true;
}

}  // namespace tally::test
