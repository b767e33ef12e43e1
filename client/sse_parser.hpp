#pragma once
// Incremental parser for text/event-stream (the WHATWG SSE format) and for the
// NDJSON variant of the event stream, fed with whatever pieces the socket gives.
#include <functional>
#include <string>
#include <string_view>

namespace tally {

struct SseEvent {
  std::string id;     // "" if the event carried none
  std::string event;  // "message" if unnamed
  std::string data;   // data lines joined with '\n'
};

class SseParser {
 public:
  explicit SseParser(std::function<void(const SseEvent&)> on_event) : on_event_(std::move(on_event)) {}
  void feed(std::string_view bytes);
  const std::string& last_event_id() const { return last_id_; }

 private:
  void line(std::string_view l);
  std::function<void(const SseEvent&)> on_event_;
  std::string buf_;
  SseEvent cur_;
  bool has_data_ = false;
  std::string last_id_;
};

// NDJSON stream: one {"id":..,"event":..,"data":{..}} object per line.
class NdjsonParser {
 public:
  explicit NdjsonParser(std::function<void(const SseEvent&)> on_event) : on_event_(std::move(on_event)) {}
  void feed(std::string_view bytes);  // throws on a line that is not such an object

 private:
  std::function<void(const SseEvent&)> on_event_;
  std::string buf_;
};

}  // namespace tally
