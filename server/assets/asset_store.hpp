#pragma once
// The server's content-addressed asset store (PUT /v1/assets/sha256:<hex>), under
// <data-dir>/assets:
//   sha256/<hex>            the bytes, named by their SHA-256 (JobLimits::asset_store)
//   tmp/<hex>.<n>.part      uploads in progress (removed when they fail; at start)
//   owners/<principal>/<hex> who uploaded what (empty files; principal name hex-encoded)
// An upload is hashed while it streams to its temp file, fsynced, compared with its
// name, and only then renamed into place: nothing half-written or wrong is ever kept.
// Tenancy: bytes are stored once for everyone, but a principal sees (HEAD, scenes) only
// the assets it uploaded itself; admins and a server without access control see all.
// Thread-safe. No sockets, no JSON.
#include <chrono>
#include <cstdint>
#include <filesystem>
#include <memory>
#include <mutex>
#include <optional>
#include <set>
#include <stdexcept>
#include <string>
#include <string_view>

namespace tally {

class AssetError : public std::runtime_error {
 public:
  // no_space: the disk (or the file system's quota) is full (ENOSPC, EDQUOT): 507.
  enum class Kind { bad_name, too_large, quota, mismatch, io, no_space };
  AssetError(Kind k, const std::string& what) : std::runtime_error(what), kind_(k) {}
  Kind kind() const noexcept { return kind_; }

 private:
  Kind kind_;
};

class AssetStore;

// One PUT in progress. Not thread-safe (one request feeds it); the destructor of an
// unfinished upload removes its temp file.
class AssetUpload {
 public:
  ~AssetUpload();
  AssetUpload(const AssetUpload&) = delete;
  AssetUpload& operator=(const AssetUpload&) = delete;

  // Hashes and writes the next part. Throws, with the temp file removed, as soon as the
  // running total passes a limit: AssetError(too_large) past --max-asset-bytes,
  // AssetError(quota) past what the owner's quota leaves (a chunked body declares no
  // length, so this is where its quota is enforced); AssetError(no_space) on a full
  // disk, AssetError(io) on another write error.
  void write(std::string_view chunk);
  // The whole body arrived: verifies the hash, makes the asset durable and records
  // the owner. Returns true when the bytes were new to the store (false: they were
  // already there and were not rewritten). Throws AssetError(mismatch | quota | io).
  bool finish();
  uint64_t bytes() const { return bytes_; }

 private:
  friend class AssetStore;
  AssetUpload(AssetStore& store, std::string hex, std::string owner, uint64_t limit, uint64_t quota);
  [[noreturn]] void fail_io(const char* what, int err);
  void abort() noexcept;
  struct Hasher;
  AssetStore& store_;
  std::string hex_, owner_;
  uint64_t limit_, quota_;
  uint64_t allowance_ = UINT64_MAX;  // bytes the owner's quota leaves for this asset (begin)
  uint64_t used_at_begin_ = 0;       // the owner's usage when the upload began (for the message)
  uint64_t bytes_ = 0;
  std::unique_ptr<Hasher> hash_;
  int fd_ = -1;  // -1: the bytes are already stored, only hashed (not rewritten)
  std::filesystem::path tmp_;
  bool done_ = false;
};

struct RetentionResult {
  size_t removed = 0, kept = 0;
  uint64_t removed_bytes = 0;
};

class AssetStore {
 public:
  // Creates the layout if needed and removes uploads a crash left behind.
  AssetStore(std::filesystem::path root, uint64_t max_asset_bytes);

  std::filesystem::path blob_dir() const { return root_ / "sha256"; }  // JobLimits::asset_store
  uint64_t max_asset_bytes() const { return max_bytes_; }

  // Size of the stored asset if `owner` may see it (`see_all`: admins, no access control).
  std::optional<uint64_t> find(const std::string& hex, const std::string& owner, bool see_all) const;
  // Bytes of the assets `owner` uploaded (what its quota counts).
  uint64_t usage(const std::string& owner) const;

  // Starts a PUT of `hex` by `owner` whose body declares `content_length` bytes (nullopt:
  // chunked). Throws AssetError: bad_name, too_large (over --max-asset-bytes), quota
  // (`quota` bytes in all for this owner), no_space (the temp file cannot be created on a
  // full disk). A chunked body is held to both limits as its bytes arrive (write).
  std::unique_ptr<AssetUpload> begin(const std::string& hex, const std::string& owner,
                                     std::optional<uint64_t> content_length, uint64_t quota);

  // Removes every stored asset not named in `referenced` whose last upload is older
  // than `min_age`, with its owner records.
  RetentionResult sweep(const std::set<std::string>& referenced, std::chrono::seconds min_age);

 private:
  friend class AssetUpload;
  std::filesystem::path owner_dir(const std::string& owner) const;
  uint64_t usage_locked(const std::string& owner) const;
  std::filesystem::path root_;
  uint64_t max_bytes_;
  mutable std::mutex mu_;  // serializes finish (quota check + rename + owner record) and sweep
  uint64_t next_tmp_ = 0;
};


}  // namespace tally
