#pragma once
// What a glTF's JSON holds, counted before tinygltf parses it: tinygltf's parser recurses
// once a nesting level (a file of 15,000 '[' overflowed the stack) and builds every node,
// accessor and primitive as a large struct (4.5 MB of empty nodes took 1.1 GB). The JSON
// (the .gltf, or the JSON chunk of a .glb) is checked here against JobLimits first: its
// nesting depth by json_nesting_depth's flat scan (common/spec/json_depth.hpp, the
// same pre-scan as request bodies), then the sizes of its top-level arrays and the
// number of mesh primitives by nlohmann's SAX parser, which does not recurse.
#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>

namespace tally {

struct GltfCensus {
  std::map<std::string, uint64_t> arrays;  // top-level array -> entries ("nodes" -> 3)
  uint64_t primitives = 0;                 // entries of every /meshes/*/primitives
};

// The JSON chunk of a binary glTF (.glb): nullopt when the header or the chunk's length
// is malformed.
std::optional<std::string_view> glb_json_chunk(std::string_view glb);
// Whether every chunk of a .glb after its JSON chunk (the BIN chunk) has a whole header
// and ends within the file. tinygltf (2.5, Debian's) reads a BIN chunk by its declared
// length without that check: a chunk claiming more bytes than the file holds was read
// past the end of the buffer (fuzz_scene_files).
bool glb_chunks_fit(std::string_view glb);

// Counts what `json` declares. The text must already be within the depth limit; a parse
// error ends the count (tinygltf reports the error afterwards).
GltfCensus gltf_census(std::string_view json);

}  // namespace tally
