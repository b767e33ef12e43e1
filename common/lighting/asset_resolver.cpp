#include "common/lighting/asset_resolver.hpp"

#include <fcntl.h>
#include <fmt/format.h>
#include <sys/stat.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstring>

#include "common/spec/spec_reader.hpp"

namespace tally {

std::filesystem::path resolve_asset(const std::string& asset_dir, const std::string& relative,
                                    const std::string& pointer) {
  namespace fs = std::filesystem;
  if (asset_dir.empty()) {
    // Any scene file (OBJ, glTF, .bin, texture, map) lands here: name none of them by kind.
    throw SpecError(pointer, fmt::format("\"{}\" is a file name, but this server has no asset directory (--asset-dir): "
                                         "upload the file and name it \"sha256:<hex>\" (tally submit and the Python "
                                         "client do both)",
                                         relative));
  }
  const fs::path rel(relative);
  if (rel.empty() || rel.is_absolute() || rel.has_root_name() || rel.has_root_directory()) {
    throw SpecError(pointer, "must be a relative path inside the asset directory");
  }
  for (const auto& part : rel) {
    if (part == "..") throw SpecError(pointer, "must not contain \"..\"");
  }
  std::error_code ec;
  const fs::path root = fs::canonical(asset_dir, ec);
  if (ec) throw SpecError(pointer, "the asset directory does not exist");
  const fs::path full = fs::canonical(root / rel, ec);  // resolves symlinks
  if (ec) throw SpecError(pointer, fmt::format("asset \"{}\" not found", relative));
  const auto [root_end, unused] = std::mismatch(root.begin(), root.end(), full.begin(), full.end());
  (void)unused;
  if (root_end != root.end()) throw SpecError(pointer, "resolves outside the asset directory");
  if (!fs::is_regular_file(full, ec)) throw SpecError(pointer, "is not a regular file");
  return full;
}

std::string read_asset_file(const std::filesystem::path& path, const std::string& pointer, size_t max_bytes) {
  // O_NOFOLLOW and O_NONBLOCK: a symlink or FIFO swapped in after resolve_asset's
  // checks neither escapes nor blocks; fstat on the open descriptor decides.
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) throw SpecError(pointer, fmt::format("cannot open asset: {}", std::strerror(errno)));
  struct Closer {
    int fd;
    ~Closer() { ::close(fd); }
  } closer{fd};
  struct stat st {};
  if (::fstat(fd, &st) != 0 || !S_ISREG(st.st_mode)) throw SpecError(pointer, "is not a regular file");
  if (static_cast<uint64_t>(st.st_size) > max_bytes) {
    throw SpecError(pointer, fmt::format("asset is larger than {} bytes", max_bytes));
  }
  std::string out(static_cast<size_t>(st.st_size), '\0');
  size_t got = 0;
  while (got < out.size()) {
    const ssize_t n = ::read(fd, out.data() + got, out.size() - got);
    if (n < 0 && errno == EINTR) continue;
    if (n < 0) throw SpecError(pointer, fmt::format("cannot read asset: {}", std::strerror(errno)));
    if (n == 0) break;  // the file shrank
    got += static_cast<size_t>(n);
  }
  out.resize(got);
  return out;
}

std::filesystem::path resolve_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer) {
  if (!looks_like_asset_ref(name)) return resolve_asset(limits.asset_dir, name, pointer);
  const auto hex = asset_ref_hex(name);
  if (!hex) throw SpecError(pointer, "an asset reference must be \"sha256:\" and 64 lowercase hex digits");
  if (limits.asset_store.empty()) {
    throw SpecError(pointer, fmt::format("asset {} cannot be used: this runner has no asset store", name));
  }
  const std::filesystem::path p = stored_asset_path(limits.asset_store, *hex);
  std::error_code ec;
  // Not the submitter's and not stored read alike: the same error, the same pointer.
  const bool readable = !limits.may_read_asset || limits.may_read_asset(*hex);
  if (!readable || !std::filesystem::is_regular_file(std::filesystem::symlink_status(p, ec))) {
    throw SpecError(pointer, fmt::format("asset {} is not stored on this server; upload it with PUT /v1/assets/{}",
                                         name, name));
  }
  return p;
}

std::string read_scene_file(const std::string& name, const JobLimits& limits, const std::string& pointer,
                            size_t max_bytes) {
  return read_asset_file(resolve_scene_file(name, limits, pointer), pointer, max_bytes);
}

AssetReader scene_asset_reader(const JobLimits& limits) {
  return [limits](const std::string& name, const std::string& pointer) {
    return read_scene_file(name, limits, pointer);
  };
}

}  // namespace tally
