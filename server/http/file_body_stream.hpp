#pragma once
// A response body read from a file a part at a time (the session sends each part as a
// chunk): GET /v1/jobs/{id}/image.exr writes a 4K frame's EXR (over 100 MB) to a file
// strip by strip and sends it from there, instead of holding the image and its encoding
// in memory. The file is unlinked when the stream opens it, so it goes away with the
// stream (or with the process) whatever happens to the request. Not thread-safe: the
// session polls it from one strand.
#include <cstdio>
#include <filesystem>
#include <functional>
#include <memory>
#include <string>

#include "server/http/event_stream.hpp"

namespace tally {

class FileBodyStream final : public EventStream {
 public:
  static constexpr size_t kPartBytes = size_t{1} << 20;

  // Opens `path` and unlinks it. Throws std::runtime_error naming the path if it cannot
  // be opened.
  explicit FileBodyStream(const std::filesystem::path& path);
  bool poll(std::string& out) override;
  void on_ready(std::function<void()> wake) override { wake(); }  // a file is always ready

 private:
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file_;
  std::filesystem::path path_;  // for error messages
};

}  // namespace tally
