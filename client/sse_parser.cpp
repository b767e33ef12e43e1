#include "client/sse_parser.hpp"

#include <nlohmann/json.hpp>

namespace tally {

void SseParser::feed(std::string_view bytes) {
  buf_.append(bytes);
  size_t start = 0;
  for (;;) {
    const size_t nl = buf_.find_first_of("\r\n", start);
    if (nl == std::string::npos) break;
    // A CR at the very end might be half of CRLF: wait for the next byte.
    if (buf_[nl] == '\r' && nl + 1 == buf_.size()) break;
    line(std::string_view(buf_).substr(start, nl - start));
    start = nl + ((buf_[nl] == '\r' && buf_[nl + 1] == '\n') ? 2 : 1);
  }
  buf_.erase(0, start);
}

void SseParser::line(std::string_view l) {
  if (l.empty()) {
    if (has_data_) {
      if (cur_.event.empty()) cur_.event = "message";
      if (!cur_.id.empty()) last_id_ = cur_.id;
      on_event_(cur_);
    }
    cur_ = SseEvent{};
    has_data_ = false;
    return;
  }
  if (l.front() == ':') return;  // comment (keep-alive)
  const size_t colon = l.find(':');
  std::string_view field = l.substr(0, colon);
  std::string_view value = colon == std::string_view::npos ? std::string_view{} : l.substr(colon + 1);
  if (!value.empty() && value.front() == ' ') value.remove_prefix(1);
  if (field == "data") {
    if (has_data_) cur_.data.push_back('\n');
    cur_.data.append(value);
    has_data_ = true;
  } else if (field == "event") {
    cur_.event = std::string(value);
  } else if (field == "id") {
    cur_.id = std::string(value);
  }
}

void NdjsonParser::feed(std::string_view bytes) {
  buf_.append(bytes);
  size_t start = 0;
  for (size_t nl; (nl = buf_.find('\n', start)) != std::string::npos; start = nl + 1) {
    std::string_view l = std::string_view(buf_).substr(start, nl - start);
    if (l.empty()) continue;
    const auto j = nlohmann::json::parse(l);
    SseEvent e;
    e.id = j.at("id").dump();
    e.event = j.at("event").get<std::string>();
    e.data = j.at("data").dump();
    on_event_(e);
  }
  buf_.erase(0, start);
}

}  // namespace tally
