// The "sha256:" names a stored scene file holds inside itself, which asset retention
// keeps (server/assets/asset_refs.hpp).
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <fstream>
#include <string>
#include <vector>

#include "server/assets/asset_refs.hpp"

namespace tally {
namespace {

namespace fs = std::filesystem;

const std::string kA(64, 'a'), kB = std::string(63, 'b') + "c", kC(64, 'c'), kD(64, 'd');

struct File {
  explicit File(const std::string& bytes)
      : path(fs::temp_directory_path() / ("tally_asset_refs_" + std::to_string(::getpid()) + "_" + std::to_string(n++))) {
    std::ofstream(path, std::ios::binary) << bytes;
  }
  ~File() { fs::remove(path); }
  fs::path path;
  static inline int n = 0;
};

std::vector<std::string> refs(const std::string& bytes) {
  File f(bytes);
  std::vector<std::string> out = asset_refs_in_file(f.path);
  std::sort(out.begin(), out.end());
  out.erase(std::unique(out.begin(), out.end()), out.end());
  return out;
}

// The .glb of a JSON text and a binary chunk.
std::string glb(std::string js, const std::string& bin) {
  while (js.size() % 4 != 0) js.push_back(' ');
  std::string out;
  auto u32 = [&](uint32_t x) { out.append(reinterpret_cast<const char*>(&x), 4); };
  u32(0x46546C67u);
  u32(2);
  u32(static_cast<uint32_t>(12 + 8 + js.size() + 8 + bin.size()));
  u32(static_cast<uint32_t>(js.size()));
  u32(0x4E4F534Au);
  out += js;
  u32(static_cast<uint32_t>(bin.size()));
  u32(0x004E4942u);
  return out + bin;
}

// The scan matched the literal text "sha256:<hex>" only, but the glTF loader unescapes
// JSON strings and percent-decodes URIs first: a buffer named "sha256\u003a<hex>" or
// "sha256%3A<hex>" was read by the job and not kept by retention (the job's spec then no
// longer compiled after a restart, as in issue 27 N6).
TEST(AssetRefs, GltfNamesAreReadAsTheLoaderReadsThem) {
  const std::string gltf = R"({"asset":{"version":"2.0"},"buffers":[)"
                           R"({"uri":"sha256\u003a)" + kA + R"(","byteLength":36},)"
                           R"({"uri":"sha256%3A)" + kB + R"(","byteLength":36},)"
                           R"({"uri":"\u0073ha256:)" + std::string(63, 'c') + R"(\u0063","byteLength":36}],)"
                           R"("images":[{"uri":"sha256:)" + kD + R"("}]})";
  EXPECT_EQ(refs(gltf), (std::vector<std::string>{kA, kB, kC, kD}));
  EXPECT_EQ(refs("\n  " + gltf), (std::vector<std::string>{kA, kB, kC, kD}));  // leading white space
  // The same JSON as a .glb's JSON chunk, a binary chunk after it.
  EXPECT_EQ(refs(glb(gltf, std::string(8, '\0'))), (std::vector<std::string>{kA, kB, kC, kD}));
}

TEST(AssetRefs, LiteralNamesInAnyFileAndNothingElse) {
  // OBJ and .mtl: the literal text (their readers do not unescape names).
  EXPECT_EQ(refs("mtllib sha256:" + kA + "\nv 0 0 0\n"), std::vector<std::string>{kA});
  EXPECT_EQ(refs("newmtl m\nmap_Kd sha256:" + kB + "\n"), std::vector<std::string>{kB});
  // Not names: upper-case hex, 63 digits, an escaped name in a file that is not JSON.
  EXPECT_EQ(refs("mtllib sha256:" + std::string(64, 'A') + "\n"), std::vector<std::string>{});
  EXPECT_EQ(refs(R"({"uri":"sha256:)" + std::string(63, 'a') + R"("})"), std::vector<std::string>{});
  EXPECT_EQ(refs("mtllib sha256%3A" + kA + "\n"), std::vector<std::string>{});
  // A malformed or deeply nested JSON text ends the JSON scan without throwing; the
  // literal names before and after are still found.
  EXPECT_EQ(refs(R"({"a":"sha256:)" + kA + R"(", oops "sha256:)" + kB + "\"}"), (std::vector<std::string>{kA, kB}));
  EXPECT_EQ(refs("{\"a\":" + std::string(100000, '[') + "\"sha256%3A" + kC + "\"" + std::string(100000, ']') + "}"),
            std::vector<std::string>{kC});
}

}  // namespace
}  // namespace tally
