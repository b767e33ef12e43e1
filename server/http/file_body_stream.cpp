#include "server/http/file_body_stream.hpp"

#include <fmt/format.h>

#include <cerrno>
#include <cstring>
#include <stdexcept>
#include <system_error>

#include "common/log/log.hpp"

namespace tally {

FileBodyStream::FileBodyStream(const std::filesystem::path& path)
    : file_(std::fopen(path.c_str(), "rb"), &std::fclose), path_(path) {
  if (!file_) throw std::runtime_error(fmt::format("cannot open {}: {}", path.string(), std::strerror(errno)));
  std::error_code ec;
  std::filesystem::remove(path, ec);  // the open file stays readable; nothing is left behind
  if (ec) throw std::runtime_error(fmt::format("cannot unlink {}: {}", path.string(), ec.message()));
}

bool FileBodyStream::poll(std::string& out) {
  const size_t at = out.size();
  out.resize(at + kPartBytes);
  const size_t n = std::fread(out.data() + at, 1, kPartBytes, file_.get());
  out.resize(at + n);
  if (n == kPartBytes) return true;
  if (std::ferror(file_.get())) {
    // Mid-response the status is sent already: the body ends short (an EXR reader
    // refuses it) and the failure is logged. poll runs on an I/O thread: never throw.
    log::error("reading {} for a response body failed: {}", path_.string(), std::strerror(errno));
  }
  return false;
}

}  // namespace tally
