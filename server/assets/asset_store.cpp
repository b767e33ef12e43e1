#include "server/assets/asset_store.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "common/hash/digest.hpp"
#include "common/lighting/asset_resolver.hpp"
#include "common/log/log.hpp"

namespace tally {

namespace fs = std::filesystem;

namespace {

AssetError::Kind kind_of(int err) {
  return err == ENOSPC || err == EDQUOT ? AssetError::Kind::no_space : AssetError::Kind::io;
}

void fsync_dir(const fs::path& dir) {
  const int fd = ::open(dir.c_str(), O_RDONLY | O_DIRECTORY | O_CLOEXEC);
  if (fd < 0) throw AssetError(kind_of(errno), fmt::format("cannot open {}: {}", dir.string(), std::strerror(errno)));
  const int rc = ::fsync(fd);
  const int err = errno;
  ::close(fd);
  if (rc != 0) throw AssetError(kind_of(err), fmt::format("cannot fsync {}: {}", dir.string(), std::strerror(err)));
}

// An empty file, durable (owner records).
void touch_durable(const fs::path& p) {
  const int fd = ::open(p.c_str(), O_WRONLY | O_CREAT | O_CLOEXEC, 0644);
  if (fd < 0) throw AssetError(kind_of(errno), fmt::format("cannot create {}: {}", p.string(), std::strerror(errno)));
  ::close(fd);
  fsync_dir(p.parent_path());
}

}  // namespace

// The upload's SHA-256 (common/hash/digest.hpp), its failures as the store's I/O errors.
struct AssetUpload::Hasher {
  Sha256 sha;
  Hasher() try : sha() {
  } catch (const DigestError& e) {
    throw AssetError(AssetError::Kind::io, e.what());
  }
  void update(std::string_view s) {
    try {
      sha.update(s);
    } catch (const DigestError& e) {
      throw AssetError(AssetError::Kind::io, e.what());
    }
  }
  std::string hex() {
    try {
      return sha.finish_hex();
    } catch (const DigestError& e) {
      throw AssetError(AssetError::Kind::io, e.what());
    }
  }
};

AssetUpload::AssetUpload(AssetStore& store, std::string hex, std::string owner, uint64_t limit, uint64_t quota)
    : store_(store), hex_(std::move(hex)), owner_(std::move(owner)), limit_(limit), quota_(quota),
      hash_(std::make_unique<Hasher>()) {}

AssetUpload::~AssetUpload() { abort(); }

void AssetUpload::abort() noexcept {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  if (!done_ && !tmp_.empty()) {
    std::error_code ec;
    fs::remove(tmp_, ec);
    if (ec) log::warn("asset {}: cannot remove the unfinished upload {}: {}", hex_, tmp_.string(), ec.message());
  }
  done_ = true;
}

void AssetUpload::fail_io(const char* what, int err) {
  abort();
  const bool full = kind_of(err) == AssetError::Kind::no_space;
  log::warn("asset sha256:{}: {}: {} (principal \"{}\", {} bytes received)", hex_, what, std::strerror(err), owner_,
            bytes_);
  throw AssetError(full ? AssetError::Kind::no_space : AssetError::Kind::io,
                   full ? fmt::format("{}: the server's disk is full ({}); nothing was kept, retry later", what,
                                      std::strerror(err))
                        : fmt::format("{}: {}", what, std::strerror(err)));
}

void AssetUpload::write(std::string_view chunk) {
  if (done_) throw AssetError(AssetError::Kind::io, "the upload is already finished");
  if (chunk.size() > limit_ - bytes_) {
    abort();
    throw AssetError(AssetError::Kind::too_large,
                     fmt::format("the asset exceeds the server's limit of {} bytes (--max-asset-bytes)", limit_));
  }
  if (chunk.size() > allowance_ - std::min(allowance_, bytes_)) {
    abort();
    throw AssetError(AssetError::Kind::quota,
                     fmt::format("asset quota exceeded: {} bytes stored, this asset is more than {} bytes, the quota "
                                 "is {} bytes",
                                 used_at_begin_, bytes_ + chunk.size() - 1, quota_));
  }
  bytes_ += chunk.size();
  hash_->update(chunk);
  while (fd_ >= 0 && !chunk.empty()) {
    const ssize_t n = ::write(fd_, chunk.data(), chunk.size());
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) fail_io("cannot write the asset", n == 0 ? ENOSPC : errno);
    chunk.remove_prefix(static_cast<size_t>(n));
  }
}

bool AssetUpload::finish() {
  if (done_) throw AssetError(AssetError::Kind::io, "the upload is already finished");
  const std::string got = hash_->hex();
  if (got != hex_) {
    abort();
    throw AssetError(AssetError::Kind::mismatch,
                     fmt::format("the body's SHA-256 is {} but the asset is named sha256:{}; nothing was kept", got, hex_));
  }
  if (fd_ >= 0 && ::fsync(fd_) != 0) fail_io("cannot fsync the asset", errno);
  std::lock_guard lock(store_.mu_);
  const fs::path blob = stored_asset_path(store_.blob_dir(), hex_);
  const fs::path owner_record = store_.owner_dir(owner_) / hex_;
  std::error_code ec;
  const bool owned = fs::exists(owner_record, ec);
  if (!owned) {
    const uint64_t used = store_.usage_locked(owner_);
    if (bytes_ > quota_ || used > quota_ - bytes_) {
      abort();
      throw AssetError(AssetError::Kind::quota,
                       fmt::format("asset quota exceeded: {} bytes stored, this asset is {} bytes, the quota is {} bytes",
                                   used, bytes_, quota_));
    }
  }
  bool created = false;
  if (fs::exists(blob, ec)) {
    // Already stored (by this or another upload): not rewritten; the upload time is
    // refreshed so that retention counts from the last PUT.
    ::utimensat(AT_FDCWD, blob.c_str(), nullptr, 0);
  } else {
    if (fd_ < 0) throw AssetError(AssetError::Kind::io, "the asset vanished during the upload; send it again");
    ::close(fd_);
    fd_ = -1;
    fs::rename(tmp_, blob, ec);
    if (ec) fail_io("cannot store the asset", ec.value());
    tmp_.clear();
    fsync_dir(store_.blob_dir());
    created = true;
  }
  abort();  // closes and removes a temp file that was not needed
  if (!owned) {
    fs::create_directories(owner_record.parent_path());
    touch_durable(owner_record);
  }
  log::info("asset sha256:{} {} ({} bytes, principal \"{}\")", hex_, created ? "stored" : "already stored", bytes_,
            owner_);
  return created || !owned;
}

AssetStore::AssetStore(fs::path root, uint64_t max_asset_bytes) : root_(std::move(root)), max_bytes_(max_asset_bytes) {
  fs::create_directories(root_ / "sha256");
  fs::create_directories(root_ / "owners");
  fs::create_directories(root_ / "tmp");
  size_t stale = 0;
  for (const auto& e : fs::directory_iterator(root_ / "tmp")) {
    std::error_code ec;
    fs::remove(e.path(), ec);
    if (!ec) ++stale;
  }
  if (stale > 0) log::info("asset store {}: removed {} unfinished uploads", root_.string(), stale);
}

fs::path AssetStore::owner_dir(const std::string& owner) const {
  // Principal names are hex-encoded: any name is a safe, distinct directory name.
  const std::string enc = owner.empty() ? std::string("-")
                                        : hex_encode(reinterpret_cast<const unsigned char*>(owner.data()), owner.size());
  return root_ / "owners" / enc;
}

std::optional<uint64_t> AssetStore::find(const std::string& hex, const std::string& owner, bool see_all) const {
  if (!is_sha256_hex(hex)) return std::nullopt;
  std::error_code ec;
  const uint64_t size = fs::file_size(stored_asset_path(blob_dir(), hex), ec);
  if (ec) return std::nullopt;
  if (!see_all && !fs::exists(owner_dir(owner) / hex, ec)) return std::nullopt;
  return size;
}

uint64_t AssetStore::usage_locked(const std::string& owner) const {
  uint64_t total = 0;
  std::error_code ec;
  for (fs::directory_iterator it(owner_dir(owner), ec), end; !ec && it != end; it.increment(ec)) {
    std::error_code ec2;
    const uint64_t n = fs::file_size(stored_asset_path(blob_dir(), it->path().filename().string()), ec2);
    if (!ec2) total += n;
  }
  return total;
}

uint64_t AssetStore::usage(const std::string& owner) const {
  std::lock_guard lock(mu_);
  return usage_locked(owner);
}

std::unique_ptr<AssetUpload> AssetStore::begin(const std::string& hex, const std::string& owner,
                                               std::optional<uint64_t> content_length, uint64_t quota) {
  if (!is_sha256_hex(hex)) {
    throw AssetError(AssetError::Kind::bad_name, "an asset is named sha256:<64 lowercase hex digits>");
  }
  if (content_length && *content_length > max_bytes_) {
    throw AssetError(AssetError::Kind::too_large,
                     fmt::format("the asset is {} bytes, over the server's limit of {} bytes (--max-asset-bytes)",
                                 *content_length, max_bytes_));
  }
  std::unique_ptr<AssetUpload> up(new AssetUpload(*this, hex, owner, max_bytes_, quota));
  std::lock_guard lock(mu_);
  std::error_code ec;
  const bool owned = fs::exists(owner_dir(owner) / hex, ec);
  if (!owned && quota != UINT64_MAX) {
    const uint64_t used = usage_locked(owner);
    if (content_length && (*content_length > quota || used > quota - *content_length)) {
      throw AssetError(AssetError::Kind::quota,
                       fmt::format("asset quota exceeded: {} bytes stored, this asset is {} bytes, the quota is {} bytes",
                                   used, *content_length, quota));
    }
    // What is left, enforced by write as the bytes arrive (finish checks again under the
    // lock: uploads running side by side each see the usage at their start).
    up->allowance_ = used >= quota ? 0 : quota - used;
    up->used_at_begin_ = used;
  }
  if (!fs::exists(stored_asset_path(blob_dir(), hex), ec)) {
    up->tmp_ = root_ / "tmp" / fmt::format("{}.{}.part", hex, ++next_tmp_);
    up->fd_ = ::open(up->tmp_.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0644);
    if (up->fd_ < 0) {
      const int err = errno;
      up->tmp_.clear();
      up->fail_io("cannot create the upload file", err);
    }
  }
  return up;
}

RetentionResult AssetStore::sweep(const std::set<std::string>& referenced, std::chrono::seconds min_age) {
  std::lock_guard lock(mu_);
  RetentionResult r;
  const auto now = fs::file_time_type::clock::now();
  std::set<std::string> removed;
  std::error_code ec;
  for (fs::directory_iterator it(blob_dir(), ec), end; !ec && it != end; it.increment(ec)) {
    const std::string hex = it->path().filename().string();
    std::error_code e2;
    const auto mtime = fs::last_write_time(it->path(), e2);
    if (referenced.count(hex) || e2 || now - mtime < min_age) {
      ++r.kept;
      continue;
    }
    const uint64_t size = fs::file_size(it->path(), e2);
    if (fs::remove(it->path(), e2)) {
      ++r.removed;
      r.removed_bytes += size;
      removed.insert(hex);
      log::info("asset retention: removed sha256:{} ({} bytes): no job names it", hex, size);
    } else if (e2) {
      log::warn("asset retention: cannot remove sha256:{}: {}", hex, e2.message());
    }
  }
  if (!removed.empty()) {
    for (fs::directory_iterator od(root_ / "owners", ec), end; !ec && od != end; od.increment(ec)) {
      for (const auto& hex : removed) {
        std::error_code e2;
        fs::remove(od->path() / hex, e2);
      }
    }
  }
  return r;
}

}  // namespace tally
