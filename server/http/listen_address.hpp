#pragma once
// "--listen 127.0.0.1:8080", "[::1]:0", "localhost:8080", ":8080" (loopback).
#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

namespace tally {

struct ListenAddress {
  std::string host = "127.0.0.1";
  uint16_t port = 8080;
};

std::optional<ListenAddress> parse_listen_address(std::string_view text);

}  // namespace tally
