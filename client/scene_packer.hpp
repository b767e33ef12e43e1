#pragma once
// Scene packing for `tally submit` (and, in Python, tally_client.packing): every local
// file a job spec's scene names, and every file *those* name, recursively:
//   "file" (glTF)  -> its buffers[].uri and images[].uri (.gltf JSON or .glb's JSON chunk);
//   "obj"  (OBJ)   -> its `mtllib` libraries -> their map_Kd (and other map_*) textures;
//   "map"          -> an image, which names nothing.
// Each file goes to a Store (the server's asset store over HTTP, see asset_upload.hpp)
// and the reference to it is rewritten to "sha256:<hex>"; a file whose references were
// rewritten is stored as the rewritten bytes. The server resolves "sha256:" names inside
// scene files as it does in the spec (common/lighting/asset_resolver.hpp: a glTF stored as
// "sha256:…" has no directory, so the names it holds are taken as they are).
//
// A spec field naming no local file is left alone (the server may have it in its
// --asset-dir). A file named inside a packed file must exist: a PackError names the
// user's path of the file holding the reference, its format, the reference and why.
#include <filesystem>
#include <map>
#include <nlohmann/json.hpp>
#include <stdexcept>
#include <string>

namespace tally {

class PackError : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

// Where packed files go. Both return the file's "sha256:<hex>" name; `ref` is computed
// by the packer, so a store need only make sure the server has those bytes.
class PackStore {
 public:
  virtual ~PackStore() = default;
  // A file sent as it is on disk (read as it is sent).
  virtual void put_file(const std::string& ref, const std::filesystem::path& path) = 0;
  // Bytes made by the packer (a file with rewritten references); `origin` is its path.
  virtual void put_bytes(const std::string& ref, const std::string& bytes, const std::filesystem::path& origin) = 0;
};

// SHA-256 in lowercase hex, of a file (read in pieces) or of bytes. Throw PackError.
std::string sha256_file_hex(const std::filesystem::path& path);
std::string sha256_bytes_hex(const std::string& bytes);

class ScenePacker {
 public:
  // Relative names in the spec are taken relative to `base_dir` (the spec file's directory).
  ScenePacker(PackStore& store, std::filesystem::path base_dir) : store_(store), base_(std::move(base_dir)) {}

  // Rewrites `spec` in place; throws PackError (or what the store throws).
  void pack_spec(nlohmann::json& spec);

  // "sha256:<hex>" -> the user's path of that file (as the user named it, joined to its
  // referrer's directory), for error messages: the server names stored files by hash.
  const std::map<std::string, std::string>& origins() const { return origins_; }

 private:
  enum class Format { gltf, obj, mtl, plain };
  std::string pack(const std::filesystem::path& path, Format format);
  std::string pack_gltf(const std::filesystem::path& path);
  std::string pack_obj(const std::filesystem::path& path);
  std::string pack_mtl(const std::filesystem::path& path, const std::filesystem::path& obj_dir);
  // A file named by `name` inside `referrer` (whose directory is `dir`): packed, or a
  // PackError "<referrer> (<format>): <what> names "<name>": <why>".
  std::string nested(const std::filesystem::path& referrer, const char* format, const std::string& what,
                     const std::string& name, const std::filesystem::path& dir, Format kind);
  std::string store_bytes(const std::string& bytes, const std::filesystem::path& origin);
  // The file at `path` as it is (`rewritten` null: sent from disk) or as rewritten.
  std::string store_packed(const std::filesystem::path& path, const std::string& original,
                           const std::string* rewritten);

  PackStore& store_;
  std::filesystem::path base_;
  std::map<std::string, std::string> done_;     // normalised local path -> ref
  std::map<std::string, std::string> origins_;  // ref -> user's path
  std::filesystem::path obj_dir_;               // of the OBJ whose .mtl is being packed
  int depth_ = 0;                               // OBJ -> MTL -> texture is 2 deep; a cycle is refused
};

}  // namespace tally
