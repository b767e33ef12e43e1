#include "server/jobs/checkpoint_spool.hpp"

#include <fmt/format.h>
#include <unistd.h>

#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <algorithm>
#include <stdexcept>

namespace tally {

namespace {
std::runtime_error spool_error(const std::filesystem::path& dir, const char* what) {
  return std::runtime_error(
      fmt::format("spooling a checkpoint in {} failed ({}): {}", dir.string(), what, std::strerror(errno)));
}
}  // namespace

CheckpointSpool::CheckpointSpool(const std::filesystem::path& dir, const CheckpointStream& stream) : dir_(dir) {
  std::string name = (dir / ".checkpoint-spool-XXXXXX").string();
  const int fd = ::mkstemp(name.data());
  if (fd < 0) throw spool_error(dir_, "create");
  ::unlink(name.c_str());  // anonymous from now: gone with the descriptor, even after a crash
  file_.reset(::fdopen(fd, "w+b"));
  if (!file_.get()) {
    ::close(fd);
    throw spool_error(dir_, "open");
  }
  stream([&](std::string_view piece) {
    if (!piece.empty() && std::fwrite(piece.data(), 1, piece.size(), file_.get()) != piece.size()) {
      throw spool_error(dir_, "write");
    }
    size_ += piece.size();
  });
  if (std::fflush(file_.get()) != 0) throw spool_error(dir_, "write");
}

void CheckpointSpool::replay(size_t piece_bytes, const CheckpointSink& sink) {
  if (std::fseek(file_.get(), 0, SEEK_SET) != 0) throw spool_error(dir_, "seek");
  std::string buf;
  for (uint64_t left = size_; left > 0;) {
    const size_t n = static_cast<size_t>(std::min<uint64_t>(left, piece_bytes));
    buf.resize(n);
    if (std::fread(buf.data(), 1, n, file_.get()) != n) throw spool_error(dir_, "read");
    sink(buf);
    left -= n;
  }
}

}  // namespace tally
