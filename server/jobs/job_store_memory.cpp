// The in-memory JobStore: tests, and runs that need no persistence.
#include <algorithm>
#include <map>
#include <mutex>
#include <string_view>

#include "server/jobs/job_store.hpp"

namespace tally {

namespace {

class MemoryJobStore final : public JobStore {
 public:
  bool probe() override { return true; }
  void save(const StoredJob& j) override {
    // A streamed checkpoint is encoded before the lock, as the SQLite store does: other
    // saves do not wait for its encoding.
    StoredJob row = j;
    row.checkpoint_stream = nullptr;
    if (!j.checkpoint && j.checkpoint_stream) {
      row.checkpoint.emplace();
      j.checkpoint_stream([&](std::string_view piece) { row.checkpoint->append(piece); });
    }
    std::lock_guard lock(mu_);
    auto [it, inserted] = jobs_.try_emplace(j.id, row);
    if (!inserted) {
      auto keep = std::move(it->second.checkpoint);
      it->second = std::move(row);
      if (!it->second.checkpoint) it->second.checkpoint = std::move(keep);
    }
  }
  std::vector<StoredJob> load_all() override {
    std::lock_guard lock(mu_);
    std::vector<StoredJob> out;
    for (const auto& [id, j] : jobs_) {
      out.push_back(j);
      StoredJob& o = out.back();
      o.stored_bytes = o.spec.size() + o.result.size() + o.facts.size() + (o.checkpoint ? o.checkpoint->size() : 0);
      if (o.state != "queued" && o.state != "running") o.checkpoint.reset();
    }
    std::sort(out.begin(), out.end(), [](const StoredJob& a, const StoredJob& b) { return a.seq < b.seq; });
    return out;
  }
  std::optional<std::string> load_checkpoint(const std::string& id) override {
    std::lock_guard lock(mu_);
    auto it = jobs_.find(id);
    return it == jobs_.end() ? std::nullopt : it->second.checkpoint;
  }
  bool remove(const std::string& id) override {
    std::lock_guard lock(mu_);
    return jobs_.erase(id) > 0;
  }
  uint64_t next_epoch() override {
    std::lock_guard lock(mu_);
    return ++epoch_;
  }

 private:
  std::mutex mu_;
  std::map<std::string, StoredJob> jobs_;
  uint64_t epoch_ = 0;
};

}  // namespace

std::unique_ptr<JobStore> make_memory_store() { return std::make_unique<MemoryJobStore>(); }

}  // namespace tally
