#pragma once
// A streamed checkpoint encoded into an unlinked file before the store is locked
// (job_store_sqlite.cpp): the encoding waits for the job's passes (JobRecorder::store
// encodes each piece under the job's state lock) and takes seconds for an image, and a
// store that encoded under its own lock held every other save (a submit waiting to be
// acknowledged, every other job's checkpoint) for all of it. The store then copies the
// spooled bytes in under its lock: the others wait for that copy only. Memory stays one
// piece; disk is the checkpoint's size, released when the spool is destroyed.
//
// Not thread-safe: one spool per save, on the saving thread.
#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <string>

#include "server/jobs/job_store.hpp"

namespace tally {

class CheckpointSpool {
 public:
  // Runs `stream` into a new unlinked file in `dir`. Throws std::runtime_error naming
  // the directory if the file cannot be made or written (a full disk), and whatever
  // `stream` throws (an abandoned checkpoint).
  CheckpointSpool(const std::filesystem::path& dir, const CheckpointStream& stream);

  uint64_t size() const { return size_; }
  // The bytes again from the start, in pieces of at most `piece_bytes` (the last may be
  // shorter; none for an empty checkpoint).
  void replay(size_t piece_bytes, const CheckpointSink& sink);

 private:
  std::unique_ptr<std::FILE, int (*)(std::FILE*)> file_{nullptr, &std::fclose};
  std::filesystem::path dir_;
  uint64_t size_ = 0;
};

}  // namespace tally
