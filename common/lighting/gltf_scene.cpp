#include "common/lighting/gltf_scene.hpp"

#include <fmt/format.h>
#include <tiny_gltf.h>

#include <array>
#include <cmath>
#include <cstring>
#include <map>
#include <optional>
#include <algorithm>
#include <limits>
#include <stdexcept>

#include "common/lighting/gltf_census.hpp"
#include "common/lighting/texture.hpp"
#include "common/spec/json_depth.hpp"
#include "common/spec/spec_reader.hpp"
#include "common/sampling/safe_math.hpp"

namespace tally {

namespace {

constexpr double kCoordLimit = 1e12;
constexpr int kMaxNodeDepth = 256;

// The file system tinygltf sees: every path is relative to the asset directory and read
// through the scene's AssetReader (once: FileExists reads and keeps the bytes).
struct FsContext {
  const AssetReader* read = nullptr;
  std::string pointer;
  std::map<std::string, std::vector<unsigned char>> files;
  std::string refused;  // why the last file was refused (named in the error)
  std::map<std::string, std::string> refused_by_path;  // every refusal (images are optional to tinygltf)
};

bool fs_exists(const std::string& path, void* user) {
  auto* ctx = static_cast<FsContext*>(user);
  if (ctx->files.count(path) != 0) return true;
  try {
    const std::string bytes = (*ctx->read)(path, ctx->pointer);
    ctx->files[path] = std::vector<unsigned char>(bytes.begin(), bytes.end());
    return true;
  } catch (const SpecError& e) {
    ctx->refused = fmt::format("\"{}\": {}", path, e.detail());
  } catch (const std::exception& e) {
    ctx->refused = fmt::format("\"{}\": {}", path, e.what());
  }
  ctx->refused_by_path[path] = ctx->refused;
  return false;
}

std::string fs_expand(const std::string& path, void*) { return path; }  // no shell expansion

bool fs_read(std::vector<unsigned char>* out, std::string* err, const std::string& path, void* user) {
  auto* ctx = static_cast<FsContext*>(user);
  if (!fs_exists(path, user)) {
    if (err) *err = ctx->refused;
    return false;
  }
  *out = ctx->files[path];
  return true;
}

bool fs_write(std::string* err, const std::string&, const std::vector<unsigned char>&, void*) {
  if (err) *err = "writing is not allowed";
  return false;
}

// Images are not decoded by tinygltf (its stb_image would run on untrusted bytes): the
// encoded bytes are kept, and textures are decoded (or refused) by tally.
bool keep_encoded_image(tinygltf::Image* image, const int, std::string*, std::string*, int, int,
                        const unsigned char* bytes, int size, void*) {
  image->image.assign(bytes, bytes + std::max(size, 0));
  image->width = image->height = image->component = -1;
  return true;
}

struct Mat4 {
  std::array<double, 16> m{1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};  // column-major, as glTF
  double at(int row, int col) const { return m[static_cast<size_t>(col * 4 + row)]; }
  Vec3 point(const Vec3& p) const {
    return {at(0, 0) * p.x + at(0, 1) * p.y + at(0, 2) * p.z + at(0, 3),
            at(1, 0) * p.x + at(1, 1) * p.y + at(1, 2) * p.z + at(1, 3),
            at(2, 0) * p.x + at(2, 1) * p.y + at(2, 2) * p.z + at(2, 3)};
  }
  Vec3 vector(const Vec3& v) const {
    return {at(0, 0) * v.x + at(0, 1) * v.y + at(0, 2) * v.z, at(1, 0) * v.x + at(1, 1) * v.y + at(1, 2) * v.z,
            at(2, 0) * v.x + at(2, 1) * v.y + at(2, 2) * v.z};
  }
  Vec3 col(int c) const { return {at(0, c), at(1, c), at(2, c)}; }
  double det3() const { return dot(col(0), cross(col(1), col(2))); }
  // Normals: the cofactor matrix (det * inverse transpose) times the sign of det.
  Vec3 normal(const Vec3& n) const {
    const Vec3 c0 = cross(col(1), col(2)), c1 = cross(col(2), col(0)), c2 = cross(col(0), col(1));
    const Vec3 r = c0 * n.x + c1 * n.y + c2 * n.z;
    return det3() < 0 ? -r : r;
  }
};

Mat4 operator*(const Mat4& a, const Mat4& b) {
  Mat4 r;
  for (int c = 0; c < 4; ++c) {
    for (int row = 0; row < 4; ++row) {
      double s = 0;
      for (int k = 0; k < 4; ++k) s += a.at(row, k) * b.at(k, c);
      r.m[static_cast<size_t>(c * 4 + row)] = s;
    }
  }
  return r;
}

class GltfLoader {
 public:
  GltfLoader(Scene& scene, const GltfRequest& req, const JobLimits& limits, const tinygltf::Model& model,
             const FsContext& fs)
      : scene_(scene), req_(req), limits_(limits), model_(model), fs_(fs) {}

  [[noreturn]] void fail(const std::string& field, const std::string& what) const {
    throw SpecError(req_.pointer, fmt::format("glTF \"{}\" {}: {}", req_.file, field, what));
  }

  void check_finite(double x, const std::string& field) const {
    if (!std::isfinite(x) || std::fabs(x) > kCoordLimit) fail(field, "is not finite or out of range");
  }

  void run() {
    triangles_ = scene_.triangle_count();
    vertices_ = scene_.vertex_count();
    materials_.assign(model_.materials.size(), UINT32_MAX);
    if (model_.scenes.empty()) {
      // No scene: every node that is nobody's child is a root.
      std::vector<bool> child(model_.nodes.size(), false);
      for (const auto& n : model_.nodes) {
        for (int c : n.children) {
          if (c >= 0 && static_cast<size_t>(c) < child.size()) child[static_cast<size_t>(c)] = true;
        }
      }
      for (size_t i = 0; i < model_.nodes.size(); ++i) {
        if (!child[i]) visit(static_cast<int>(i), Mat4{}, 0, fmt::format("/nodes/{}", i));
      }
    } else {
      const int s = model_.defaultScene >= 0 ? model_.defaultScene : 0;
      if (static_cast<size_t>(s) >= model_.scenes.size()) fail("/scene", "names no scene");
      const auto& nodes = model_.scenes[static_cast<size_t>(s)].nodes;
      for (size_t i = 0; i < nodes.size(); ++i) {
        visit(nodes[i], Mat4{}, 0, fmt::format("/scenes/{}/nodes/{}", s, i));
      }
    }
    if (req_.camera) {
      if (!camera_found_) {
        fail("/cameras", std::holds_alternative<size_t>(*req_.camera)
                             ? fmt::format("camera {} is not used by any node of the scene", std::get<size_t>(*req_.camera))
                             : fmt::format("no node of the scene uses a camera named \"{}\"", std::get<std::string>(*req_.camera)));
      }
    }
  }

 private:
  bool wanted_camera(size_t index) const {
    if (!req_.camera) return false;
    if (std::holds_alternative<size_t>(*req_.camera)) return std::get<size_t>(*req_.camera) == index;
    return model_.cameras[index].name == std::get<std::string>(*req_.camera);
  }

  Mat4 local_transform(const tinygltf::Node& n, const std::string& np) const {
    Mat4 m;
    if (!n.matrix.empty()) {
      if (n.matrix.size() != 16) fail(np + "/matrix", "must have 16 numbers");
      for (size_t i = 0; i < 16; ++i) {
        check_finite(n.matrix[i], fmt::format("{}/matrix/{}", np, i));
        m.m[i] = n.matrix[i];
      }
      return m;
    }
    Mat4 t, r, s;
    if (!n.translation.empty()) {
      if (n.translation.size() != 3) fail(np + "/translation", "must have 3 numbers");
      for (size_t i = 0; i < 3; ++i) {
        check_finite(n.translation[i], fmt::format("{}/translation/{}", np, i));
        t.m[12 + i] = n.translation[i];
      }
    }
    if (!n.rotation.empty()) {
      if (n.rotation.size() != 4) fail(np + "/rotation", "must be a quaternion [x, y, z, w]");
      for (size_t i = 0; i < 4; ++i) check_finite(n.rotation[i], fmt::format("{}/rotation/{}", np, i));
      double x = n.rotation[0], y = n.rotation[1], z = n.rotation[2], w = n.rotation[3];
      const double len = std::sqrt(x * x + y * y + z * z + w * w);
      if (!(len > 0)) fail(np + "/rotation", "must be a non-zero quaternion");
      x /= len, y /= len, z /= len, w /= len;
      r.m = {1 - 2 * (y * y + z * z), 2 * (x * y + z * w), 2 * (x * z - y * w), 0,
             2 * (x * y - z * w), 1 - 2 * (x * x + z * z), 2 * (y * z + x * w), 0,
             2 * (x * z + y * w), 2 * (y * z - x * w), 1 - 2 * (x * x + y * y), 0,
             0, 0, 0, 1};
    }
    if (!n.scale.empty()) {
      if (n.scale.size() != 3) fail(np + "/scale", "must have 3 numbers");
      for (size_t i = 0; i < 3; ++i) {
        check_finite(n.scale[i], fmt::format("{}/scale/{}", np, i));
        s.m[i * 5] = n.scale[i];
      }
    }
    // Identity factors are skipped so that a plain translation adds exactly.
    Mat4 out = t;
    if (!n.rotation.empty()) out = out * r;
    if (!n.scale.empty()) out = out * s;
    return out;
  }

  void visit(int index, const Mat4& parent, int depth, const std::string& from) {
    if (index < 0 || static_cast<size_t>(index) >= model_.nodes.size()) fail(from, "names no node");
    if (depth > kMaxNodeDepth) fail(from, fmt::format("the node hierarchy is deeper than {} (a cycle?)", kMaxNodeDepth));
    if (++nodes_visited_ > 1'000'000) fail("/nodes", "more than 10^6 node instances");
    const std::string np = fmt::format("/nodes/{}", index);
    const tinygltf::Node& n = model_.nodes[static_cast<size_t>(index)];
    const Mat4 m = parent * local_transform(n, np);
    if (n.mesh >= 0) add_mesh(n.mesh, m, np + "/mesh");
    if (n.camera >= 0) {
      if (static_cast<size_t>(n.camera) >= model_.cameras.size()) fail(np + "/camera", "names no camera");
      if (!camera_found_ && wanted_camera(static_cast<size_t>(n.camera))) add_camera(static_cast<size_t>(n.camera), m);
    }
    auto ext = n.extensions.find("KHR_lights_punctual");
    if (ext != n.extensions.end()) {
      const std::string lp = np + "/extensions/KHR_lights_punctual/light";
      if (!ext->second.IsObject() || !ext->second.Has("light") || !ext->second.Get("light").IsNumber()) {
        fail(lp, "must be a light index");
      }
      const double li = ext->second.Get("light").GetNumberAsDouble();
      if (!(li >= 0) || li != std::floor(li) || li >= static_cast<double>(model_.lights.size())) fail(lp, "names no light");
      add_light(static_cast<size_t>(li), m, fmt::format("/extensions/KHR_lights_punctual/lights/{}", static_cast<size_t>(li)));
    }
    for (size_t i = 0; i < n.children.size(); ++i) visit(n.children[i], m, depth + 1, fmt::format("{}/children/{}", np, i));
  }

  void add_camera(size_t index, const Mat4& m) {
    const tinygltf::Camera& c = model_.cameras[index];
    const std::string cp = fmt::format("/cameras/{}", index);
    if (c.type != "perspective") fail(cp + "/type", fmt::format("\"{}\" cameras are not supported (only perspective)", c.type));
    const double yfov = c.perspective.yfov;
    if (!(yfov > 0) || !(yfov < kPi)) fail(cp + "/perspective/yfov", "must be in (0, pi)");
    Camera cam;
    cam.position = m.point({0, 0, 0});
    const Vec3 fwd = m.vector({0, 0, -1});
    const Vec3 up = m.vector({0, 1, 0});
    if (!(length(fwd) > 0) || !(length(cross(fwd, up)) > 1e-12 * length(fwd))) {
      fail(cp, "the node's transform is degenerate");
    }
    cam.look_at = cam.position + normalize(fwd);
    cam.up = normalize(up);
    cam.fov_deg = yfov * (180.0 / kPi);
    cam.width = req_.width;
    cam.height = req_.height;
    scene_.camera = cam;
    camera_found_ = true;
  }

  Rgb color3(const std::vector<double>& v, double hi, const std::string& field) const {
    if (v.size() < 3) fail(field, "must have 3 components");
    Rgb c{v[0], v[1], v[2]};
    for (int i = 0; i < 3; ++i) {
      if (!(c[i] >= 0 && c[i] <= hi)) fail(fmt::format("{}/{}", field, i), fmt::format("must be in [0, {}]", hi));
    }
    return c;
  }

  void add_light(size_t index, const Mat4& m, const std::string& lp) {
    const tinygltf::Light& l = model_.lights[index];
    const Rgb color = l.color.empty() ? Rgb{1, 1, 1} : color3(l.color, 1e6, lp + "/color");
    if (!(l.intensity >= 0 && l.intensity <= 1e15)) fail(lp + "/intensity", "must be in [0, 1e15]");
    DeltaLight d;
    d.intensity = color * l.intensity;
    const Vec3 axis = m.vector({0, 0, -1});
    if (l.type == "point" || l.type == "spot") {
      d.type = l.type == "point" ? DeltaLightType::point : DeltaLightType::spot;
      d.position = m.point({0, 0, 0});
      if (d.type == DeltaLightType::spot) {
        if (!(length(axis) > 0)) fail(lp, "the node's transform is degenerate");
        d.direction = normalize(axis);
        const double inner = l.spot.innerConeAngle, outer = l.spot.outerConeAngle;
        if (!(outer > 0 && outer <= 0.5 * kPi)) fail(lp + "/spot/outerConeAngle", "must be in (0, pi/2]");
        if (!(inner >= 0 && inner < outer)) fail(lp + "/spot/innerConeAngle", "must be in [0, outerConeAngle)");
        d.cos_inner = std::cos(inner);
        d.cos_outer = std::cos(outer);
      }
    } else if (l.type == "directional") {
      d.type = DeltaLightType::directional;
      if (!(length(axis) > 0)) fail(lp, "the node's transform is degenerate");
      d.direction = -normalize(axis);  // tally: towards the light
    } else {
      fail(lp + "/type", fmt::format("unknown light type \"{}\"", l.type));
    }
    if (scene_.delta_lights.size() >= 4096) fail("/extensions/KHR_lights_punctual", "too many light instances (limit 4096)");
    scene_.delta_lights.push_back(d);
  }

  uint32_t material(int index, const std::string& from) {
    if (index < 0) {
      // glTF's default material: base colour 1, metallic 1, roughness 1.
      if (default_material_ == UINT32_MAX) {
        Material m;
        m.type = MaterialType::metallic_roughness;
        m.base_color = {1, 1, 1};
        m.metallic = 1.0;
        m.roughness = 1.0;
        m.model = MaterialModel::gltf_reference;
        m.name = fmt::format("{}#default", req_.file);
        default_material_ = push_material(std::move(m));
      }
      return default_material_;
    }
    if (static_cast<size_t>(index) >= model_.materials.size()) fail(from, "names no material");
    uint32_t& slot = materials_[static_cast<size_t>(index)];
    if (slot != UINT32_MAX) return slot;
    const tinygltf::Material& g = model_.materials[static_cast<size_t>(index)];
    const std::string mp = fmt::format("/materials/{}", index);
    const auto& pbr = g.pbrMetallicRoughness;
    Material m;
    m.type = MaterialType::metallic_roughness;
    m.model = MaterialModel::gltf_reference;
    m.name = fmt::format("{}#{}", req_.file, g.name.empty() ? std::to_string(index) : g.name);
    m.base_color = pbr.baseColorFactor.empty() ? Rgb{1, 1, 1}
                                               : color3(pbr.baseColorFactor, 1.0, mp + "/pbrMetallicRoughness/baseColorFactor");
    if (!(pbr.metallicFactor >= 0 && pbr.metallicFactor <= 1)) fail(mp + "/pbrMetallicRoughness/metallicFactor", "must be in [0, 1]");
    if (!(pbr.roughnessFactor >= 0 && pbr.roughnessFactor <= 1)) fail(mp + "/pbrMetallicRoughness/roughnessFactor", "must be in [0, 1]");
    m.metallic = pbr.metallicFactor;
    m.roughness = pbr.roughnessFactor;
    double strength = 1.0;
    auto ext = g.extensions.find("KHR_materials_emissive_strength");
    if (ext != g.extensions.end()) {
      const std::string sp = mp + "/extensions/KHR_materials_emissive_strength/emissiveStrength";
      if (!ext->second.IsObject() || !ext->second.Has("emissiveStrength") ||
          !ext->second.Get("emissiveStrength").IsNumber()) {
        fail(sp, "must be a number");
      }
      strength = ext->second.Get("emissiveStrength").GetNumberAsDouble();
      if (!(strength >= 0 && strength <= 1e12)) fail(sp, "must be in [0, 1e12]");
    }
    if (!g.emissiveFactor.empty()) m.emission = color3(g.emissiveFactor, 1.0, mp + "/emissiveFactor") * strength;
    m.two_sided = g.doubleSided;
    // Colour textures are sRGB, the metallic-roughness texture linear (glTF 2.0 3.9.2).
    // normalTexture and occlusionTexture are ignored (docs/lighting.md, glTF).
    m.base_color_texture = texture(pbr.baseColorTexture, mp + "/pbrMetallicRoughness/baseColorTexture", true);
    m.metallic_roughness_texture =
        texture(pbr.metallicRoughnessTexture, mp + "/pbrMetallicRoughness/metallicRoughnessTexture", false);
    m.emission_texture = texture(g.emissiveTexture, mp + "/emissiveTexture", true);
    specular(g, mp, m);
    slot = push_material(std::move(m));
    return slot;
  }

  // KHR_materials_specular: specularFactor (default 1, in [0, 1]), specularColorFactor
  // (default [1, 1, 1], each >= 0) and specularColorTexture (sRGB RGB). specularTexture
  // scales by its alpha channel, which tally's texels do not keep: refused.
  void specular(const tinygltf::Material& g, const std::string& mp, Material& m) {
    auto ext = g.extensions.find("KHR_materials_specular");
    if (ext == g.extensions.end()) return;
    const std::string ep = mp + "/extensions/KHR_materials_specular";
    const tinygltf::Value& v = ext->second;
    if (!v.IsObject()) fail(ep, "must be an object");
    if (v.Has("specularFactor")) {
      const tinygltf::Value& f = v.Get("specularFactor");
      const double x = f.IsNumber() ? f.GetNumberAsDouble() : -1.0;
      if (!(x >= 0 && x <= 1)) fail(ep + "/specularFactor", "must be a number in [0, 1]");
      m.specular = x;
    }
    if (v.Has("specularColorFactor")) {
      const tinygltf::Value& c = v.Get("specularColorFactor");
      const std::string cp = ep + "/specularColorFactor";
      if (!c.IsArray() || c.ArrayLen() != 3) fail(cp, "must be an array of 3 numbers");
      double rgb[3];
      for (int i = 0; i < 3; ++i) {
        const tinygltf::Value& e = c.Get(i);
        rgb[i] = e.IsNumber() ? e.GetNumberAsDouble() : -1.0;
        if (!(rgb[i] >= 0 && rgb[i] <= 1e6)) fail(fmt::format("{}/{}", cp, i), "must be a number in [0, 1e6]");
      }
      m.specular_color = {rgb[0], rgb[1], rgb[2]};
    }
    if (v.Has("specularTexture")) {
      fail(ep + "/specularTexture", "is not supported (it scales by the alpha channel, which tally's textures do not keep)");
    }
    if (v.Has("specularColorTexture")) {
      const std::string tp = ep + "/specularColorTexture";
      const tinygltf::Value& t = v.Get("specularColorTexture");
      if (!t.IsObject() || !t.Has("index") || !t.Get("index").IsInt()) fail(tp + "/index", "must be an integer");
      tinygltf::TextureInfo info;
      info.index = t.Get("index").GetNumberAsInt();
      if (info.index < 0) fail(tp + "/index", "must be >= 0");
      if (t.Has("texCoord")) info.texCoord = t.Get("texCoord").IsInt() ? t.Get("texCoord").GetNumberAsInt() : -1;
      if (t.Has("extensions") && t.Get("extensions").Has("KHR_texture_transform")) {
        fail(tp + "/extensions/KHR_texture_transform", "is not supported");
      }
      m.specular_color_texture = texture(info, tp, true);
    }
  }

  // glTF sampler filters: NEAREST (9728) magnification, or, with no magFilter, a
  // NEAREST / NEAREST_MIPMAP_* (9728, 9984, 9986) minification, gives nearest-texel
  // lookups; anything else bilinear (tally keeps no mipmaps).
  static TextureFilter filter_mode(const tinygltf::Sampler& smp) {
    if (smp.magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST) return TextureFilter::nearest;
    if (smp.magFilter < 0 && (smp.minFilter == TINYGLTF_TEXTURE_FILTER_NEAREST ||
                              smp.minFilter == TINYGLTF_TEXTURE_FILTER_NEAREST_MIPMAP_NEAREST ||
                              smp.minFilter == TINYGLTF_TEXTURE_FILTER_NEAREST_MIPMAP_LINEAR)) {
      return TextureFilter::nearest;
    }
    return TextureFilter::linear;
  }

  static TextureWrap wrap_mode(int gl, const std::string& field, const GltfLoader& self) {
    switch (gl) {
      case TINYGLTF_TEXTURE_WRAP_REPEAT: return TextureWrap::repeat;
      case TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE: return TextureWrap::clamp_to_edge;
      case TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT: return TextureWrap::mirrored_repeat;
      default: self.fail(field, fmt::format("unknown wrap mode {} (10497, 33071 or 33648)", gl));
    }
  }

  // The texture a material's textureInfo at `field` names, as an index into
  // scene.textures (-1: none). Each image is decoded once per colour space.
  int32_t texture(const tinygltf::TextureInfo& info, const std::string& field, bool srgb) {
    if (info.index < 0) return -1;
    if (info.texCoord != 0) fail(field + "/texCoord", "only texture coordinate set 0 (TEXCOORD_0) is supported");
    if (info.extensions.count("KHR_texture_transform") != 0) {
      fail(field + "/extensions/KHR_texture_transform", "is not supported");
    }
    if (static_cast<size_t>(info.index) >= model_.textures.size()) fail(field + "/index", "names no texture");
    const std::string tp = fmt::format("/textures/{}", info.index);
    const tinygltf::Texture& t = model_.textures[static_cast<size_t>(info.index)];
    if (t.source < 0) fail(tp + "/source", "is missing (texture extensions such as KHR_texture_basisu are not supported)");
    if (static_cast<size_t>(t.source) >= model_.images.size()) fail(tp + "/source", "names no image");
    Texture tex;
    if (t.sampler >= 0) {
      if (static_cast<size_t>(t.sampler) >= model_.samplers.size()) fail(tp + "/sampler", "names no sampler");
      const std::string sp = fmt::format("/samplers/{}", t.sampler);
      const tinygltf::Sampler& smp = model_.samplers[static_cast<size_t>(t.sampler)];
      tex.wrap_s = wrap_mode(smp.wrapS, sp + "/wrapS", *this);
      tex.wrap_t = wrap_mode(smp.wrapT, sp + "/wrapT", *this);
      tex.filter = filter_mode(smp);
    }
    tex.texels = texels(t.source, srgb);
    for (size_t i = 0; i < scene_.textures.size(); ++i) {
      const Texture& o = scene_.textures[i];
      if (o.texels == tex.texels && o.wrap_s == tex.wrap_s && o.wrap_t == tex.wrap_t && o.filter == tex.filter) return static_cast<int32_t>(i);
    }
    if (scene_.textures.size() >= 4096) fail("/textures", "too many textures (limit 4096 in the scene)");
    scene_.textures.push_back(std::move(tex));
    return static_cast<int32_t>(scene_.textures.size() - 1);
  }

  std::shared_ptr<const TexelGrid> texels(int index, bool srgb) {
    auto& cached = texels_[{index, srgb}];
    if (cached) return cached;
    const std::string ip = fmt::format("/images/{}", index);
    const tinygltf::Image& im = model_.images[static_cast<size_t>(index)];
    if (im.image.empty()) {
      // tinygltf keeps an external image it could not read as a bare uri.
      std::string why;
      for (const auto& [path, reason] : fs_.refused_by_path) {
        if (!im.uri.empty() && path.size() >= im.uri.size() && path.compare(path.size() - im.uri.size(), im.uri.size(), im.uri) == 0) {
          why = reason;
        }
      }
      fail(im.uri.empty() ? ip : ip + "/uri", why.empty() ? "the image has no data" : fmt::format("cannot be read: {}", why));
    }
    uint64_t charged = 0;
    try {
      cached = decode_texels(std::string_view(reinterpret_cast<const char*>(im.image.data()), im.image.size()), srgb,
                             texture_decode_limits(scene_, limits_), &charged);
    } catch (const std::exception& e) {
      const std::string what = e.what();
      fail(ip, fmt::format("cannot be used as a texture: {}{}", what,
                           what.find("more than the limit") == std::string::npos
                               ? ""
                               : fmt::format(" (the job's textures may take {} bytes decoded, {} a texel)",
                                             limits_.max_texture_bytes, kTexelBytes)));
    }
    scene_.texture_bytes += cached->bytes();
    scene_.decode_bytes += charged;
    return cached;
  }

  uint32_t push_material(Material m) {
    if (scene_.materials.size() >= 4096) fail("/materials", "too many materials (limit 4096 in the scene)");
    scene_.materials.push_back(std::move(m));
    return static_cast<uint32_t>(scene_.materials.size() - 1);
  }

  // An accessor's elements read in place (nothing is copied until a primitive takes
  // the vertices it uses), every byte checked against its buffer view and buffer first.
  struct AccessorView {
    const unsigned char* base = nullptr;
    uint64_t stride = 0;
    size_t count = 0;
    int ncomp = 0, csize = 0, component_type = 0;
    bool normalized = false;
    double get(size_t i, int c) const {
      const unsigned char* p = base + i * stride + static_cast<size_t>(c * csize);
      double v = 0;
      switch (component_type) {
        case TINYGLTF_COMPONENT_TYPE_FLOAT: {
          float f;
          std::memcpy(&f, p, 4);
          return static_cast<double>(f);
        }
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE: v = *p; break;
        case TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT: {
          uint16_t x;
          std::memcpy(&x, p, 2);
          v = x;
          break;
        }
        default: {
          uint32_t x;
          std::memcpy(&x, p, 4);
          v = x;
          break;
        }
      }
      if (normalized) v /= component_type == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE ? 255.0 : 65535.0;
      return v;
    }
  };

  AccessorView view_accessor(int index, const std::string& from, int want_type, bool allow_ints) const {
    if (index < 0 || static_cast<size_t>(index) >= model_.accessors.size()) fail(from, "names no accessor");
    const std::string ap = fmt::format("/accessors/{}", index);
    const tinygltf::Accessor& a = model_.accessors[static_cast<size_t>(index)];
    if (a.sparse.isSparse) fail(ap + "/sparse", "sparse accessors are not supported");
    if (a.type != want_type) fail(ap + "/type", "has the wrong type for this attribute");
    const int ncomp = tinygltf::GetNumComponentsInType(static_cast<uint32_t>(a.type));
    const int csize = tinygltf::GetComponentSizeInBytes(static_cast<uint32_t>(a.componentType));
    const bool is_float = a.componentType == TINYGLTF_COMPONENT_TYPE_FLOAT;
    const bool is_uint = a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_BYTE ||
                         a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_SHORT ||
                         a.componentType == TINYGLTF_COMPONENT_TYPE_UNSIGNED_INT;
    if (ncomp <= 0 || csize <= 0 || !(is_float || (allow_ints && is_uint))) {
      fail(ap + "/componentType", "is not allowed for this attribute");
    }
    if (a.count == 0) fail(ap + "/count", "must be at least 1");
    if (a.count > (size_t{1} << 32)) fail(ap + "/count", fmt::format("{} exceeds the limit of {}", a.count, size_t{1} << 32));
    if (a.bufferView < 0 || static_cast<size_t>(a.bufferView) >= model_.bufferViews.size()) {
      fail(ap + "/bufferView", "names no buffer view");
    }
    const std::string vp = fmt::format("/bufferViews/{}", a.bufferView);
    const tinygltf::BufferView& bv = model_.bufferViews[static_cast<size_t>(a.bufferView)];
    if (bv.buffer < 0 || static_cast<size_t>(bv.buffer) >= model_.buffers.size()) fail(vp + "/buffer", "names no buffer");
    const auto& data = model_.buffers[static_cast<size_t>(bv.buffer)].data;
    const uint64_t elem = static_cast<uint64_t>(ncomp) * static_cast<uint64_t>(csize);
    const uint64_t stride = bv.byteStride == 0 ? elem : bv.byteStride;
    if (stride < elem || stride > 252 || stride % static_cast<uint64_t>(csize) != 0) {
      fail(vp + "/byteStride", "is smaller than the element, over 252 or not a multiple of the component size");
    }
    if (bv.byteOffset > data.size() || bv.byteLength > data.size() - bv.byteOffset) {
      fail(vp + "/byteLength", fmt::format("the view [{}, +{}) lies outside its buffer of {} bytes", bv.byteOffset,
                                           bv.byteLength, data.size()));
    }
    // count <= 2^32 and stride <= 252: no overflow in 64 bits.
    const uint64_t need = static_cast<uint64_t>(a.byteOffset) + stride * (a.count - 1) + elem;
    if (a.byteOffset > bv.byteLength || need > bv.byteLength) {
      fail(ap + "/count", fmt::format("{} elements from byte {} need {} bytes; the buffer view has {}", a.count,
                                      a.byteOffset, need, bv.byteLength));
    }
    if (static_cast<uint64_t>(a.byteOffset + bv.byteOffset) % static_cast<uint64_t>(csize) != 0) {
      fail(ap + "/byteOffset", "is not aligned to the component size");
    }
    AccessorView v;
    v.base = data.data() + bv.byteOffset + a.byteOffset;
    v.stride = stride;
    v.count = a.count;
    v.ncomp = ncomp;
    v.csize = csize;
    v.component_type = a.componentType;
    v.normalized = a.normalized && !is_float;
    return v;
  }

  void add_mesh(int index, const Mat4& m, const std::string& from) {
    if (index < 0 || static_cast<size_t>(index) >= model_.meshes.size()) fail(from, "names no mesh");
    const tinygltf::Mesh& mesh = model_.meshes[static_cast<size_t>(index)];
    const bool flip = m.det3() < 0;  // mirroring transform: glTF turns the winding around
    for (size_t pi = 0; pi < mesh.primitives.size(); ++pi) {
      const tinygltf::Primitive& prim = mesh.primitives[pi];
      const std::string pp = fmt::format("/meshes/{}/primitives/{}", index, pi);
      if (prim.mode != -1 && prim.mode != TINYGLTF_MODE_TRIANGLES) {
        fail(pp + "/mode", "only triangles (mode 4) are supported");
      }
      if (scene_.shapes.size() >= limits_.max_shapes) {
        fail(pp, fmt::format("one shape more than the limit of {} in the scene (max_shapes)", limits_.max_shapes));
      }
      auto pos_it = prim.attributes.find("POSITION");
      if (pos_it == prim.attributes.end()) fail(pp + "/attributes", "has no POSITION");
      const AccessorView pos = view_accessor(pos_it->second, pp + "/attributes/POSITION", TINYGLTF_TYPE_VEC3, false);
      const size_t nv = pos.count;
      std::optional<AccessorView> nrm, uv;
      if (auto it = prim.attributes.find("NORMAL"); it != prim.attributes.end()) {
        nrm = view_accessor(it->second, pp + "/attributes/NORMAL", TINYGLTF_TYPE_VEC3, false);
        if (nrm->count != nv) fail(fmt::format("/accessors/{}/count", it->second), "NORMAL and POSITION counts differ");
      }
      if (auto it = prim.attributes.find("TEXCOORD_0"); it != prim.attributes.end()) {
        uv = view_accessor(it->second, pp + "/attributes/TEXCOORD_0", TINYGLTF_TYPE_VEC2, true);
        if (uv->count != nv) fail(fmt::format("/accessors/{}/count", it->second), "TEXCOORD_0 and POSITION counts differ");
      }
      Shape s;
      s.type = ShapeType::mesh;
      s.pointer = fmt::format("{} ({}{})", req_.pointer, req_.file, pp);
      s.material = material(prim.material, pp + "/material");
      if (!uv && scene_.materials[s.material].textured()) {
        fail(pp + "/attributes", "has no TEXCOORD_0, but its material has textures");
      }
      // The triangles first (their count is checked before anything is copied), then
      // only the vertices they use: primitives that share one large accessor each keep
      // their own few vertices, not a copy of all of them.
      const size_t ni = prim.indices >= 0 ? view_accessor(prim.indices, pp + "/indices", TINYGLTF_TYPE_SCALAR, true).count : nv;
      if (ni % 3 != 0) fail(prim.indices >= 0 ? fmt::format("/accessors/{}/count", prim.indices) : pp, "is not a multiple of 3");
      if (triangles_ + ni / 3 > limits_.max_triangles) {
        fail(pp, fmt::format("{} more triangles, more than the limit of {} in the scene (max_triangles)", ni / 3,
                             limits_.max_triangles));
      }
      std::vector<uint32_t> used;  // the vertices the triangles use, ascending
      if (prim.indices >= 0) {
        const AccessorView idx = view_accessor(prim.indices, pp + "/indices", TINYGLTF_TYPE_SCALAR, true);
        if (idx.component_type == TINYGLTF_COMPONENT_TYPE_FLOAT) {
          fail(fmt::format("/accessors/{}/componentType", prim.indices), "indices must be integers");
        }
        s.triangles.resize(ni / 3);
        for (size_t t = 0; t < ni / 3; ++t) {
          for (size_t k = 0; k < 3; ++k) {
            const double v = idx.get(3 * t + k, 0);
            if (!(v < static_cast<double>(nv))) {
              fail(fmt::format("/accessors/{}", prim.indices), fmt::format("index {} = {} is out of range ({} vertices)", 3 * t + k, v, nv));
            }
            s.triangles[t][k] = static_cast<uint32_t>(v);
          }
        }
        used.reserve(ni);
        for (const auto& t : s.triangles) used.insert(used.end(), t.begin(), t.end());
        std::sort(used.begin(), used.end());
        used.erase(std::unique(used.begin(), used.end()), used.end());
        for (auto& t : s.triangles) {
          for (uint32_t& v : t) v = static_cast<uint32_t>(std::lower_bound(used.begin(), used.end(), v) - used.begin());
        }
      } else {
        s.triangles.resize(ni / 3);
        for (size_t t = 0; t < ni / 3; ++t) {
          for (size_t k = 0; k < 3; ++k) s.triangles[t][k] = static_cast<uint32_t>(3 * t + k);
        }
      }
      const size_t nu = prim.indices >= 0 ? used.size() : nv;
      auto source = [&](size_t i) { return prim.indices >= 0 ? static_cast<size_t>(used[i]) : i; };
      if (vertices_ + nu > limits_.max_vertices) {
        fail(pp, fmt::format("{} more vertices, more than the limit of {} in the scene (max_vertices)", nu,
                             limits_.max_vertices));
      }
      vertices_ += nu;
      triangles_ += ni / 3;
      s.vertices.resize(nu);
      for (size_t i = 0; i < nu; ++i) {
        const size_t j = source(i);
        const Vec3 p = m.point({pos.get(j, 0), pos.get(j, 1), pos.get(j, 2)});
        for (int c = 0; c < 3; ++c) {
          if (!std::isfinite(p[c]) || std::fabs(p[c]) > kCoordLimit) {
            fail(fmt::format("/accessors/{}", pos_it->second), fmt::format("vertex {} is not finite or out of range", j));
          }
        }
        s.vertices[i] = p;
      }
      if (nrm) {
        s.normals.resize(nu);
        for (size_t i = 0; i < nu; ++i) {
          const size_t j = source(i);
          const Vec3 w = m.normal({nrm->get(j, 0), nrm->get(j, 1), nrm->get(j, 2)});
          const double len = length(w);
          s.normals[i] = len > 0 && std::isfinite(len) ? w / len : Vec3{};  // zero: no shading normal there
        }
      }
      if (uv) {
        s.uvs.resize(nu);
        for (size_t i = 0; i < nu; ++i) {
          const size_t j = source(i);
          const double u = uv->get(j, 0), v = uv->get(j, 1);
          if (!std::isfinite(u) || !std::isfinite(v)) {
            fail(fmt::format("/accessors/{}", prim.attributes.at("TEXCOORD_0")), "texture coordinates must be finite");
          }
          s.uvs[i] = {u, v};
        }
      }
      if (flip) {
        for (auto& t : s.triangles) std::swap(t[1], t[2]);
      }
      scene_.shapes.push_back(std::move(s));
    }
  }

  Scene& scene_;
  const GltfRequest& req_;
  const JobLimits& limits_;
  const tinygltf::Model& model_;
  const FsContext& fs_;
  std::map<std::pair<int, bool>, std::shared_ptr<const TexelGrid>> texels_;  // (image, sRGB) -> decoded
  std::vector<uint32_t> materials_;
  uint32_t default_material_ = UINT32_MAX;
  bool camera_found_ = false;
  size_t nodes_visited_ = 0;
  size_t triangles_ = 0;  // in the scene so far (shapes before the glTF included)
  size_t vertices_ = 0;   // likewise
};

// The glTF's JSON against the limits before tinygltf parses it (gltf_census.hpp).
void check_gltf_json(std::string_view bytes, bool binary, const GltfRequest& req, const JobLimits& limits) {
  auto refuse = [&](const std::string& what) {
    return SpecError(req.pointer, fmt::format("glTF \"{}\": {}", req.file, what));
  };
  const std::optional<std::string_view> json = binary ? glb_json_chunk(bytes) : std::optional<std::string_view>(bytes);
  if (!json) throw refuse("the .glb header or its JSON chunk is malformed");
  if (binary && !glb_chunks_fit(bytes)) throw refuse("a chunk of the .glb runs past the end of the file");
  if (json_nesting_depth(*json, limits.max_file_json_depth) > limits.max_file_json_depth) {
    throw refuse(fmt::format("the JSON nests deeper than {} levels (max_file_json_depth)", limits.max_file_json_depth));
  }
  const GltfCensus census = gltf_census(*json);
  for (const auto& [name, count] : census.arrays) {
    if (count > limits.max_gltf_nodes) {
      throw refuse(fmt::format("/{} has {} entries, more than the limit of {} (max_gltf_nodes)", name, count,
                               limits.max_gltf_nodes));
    }
  }
  if (census.primitives > limits.max_shapes) {
    throw refuse(fmt::format("/meshes declare {} primitives, more than the limit of {} (max_shapes)", census.primitives,
                             limits.max_shapes));
  }
}

}  // namespace

void load_gltf(Scene& scene, const GltfRequest& req, const AssetReader& read, const JobLimits& limits) {
  const std::string bytes = read(req.file, req.pointer);
  // Binary glTF by its magic, not its name: a store reference ("sha256:...") has none.
  const bool binary = bytes.size() >= 4 && bytes.compare(0, 4, "glTF") == 0;
  if (bytes.size() > std::numeric_limits<unsigned int>::max()) throw SpecError(req.pointer, "glTF file is too large");
  check_gltf_json(bytes, binary, req, limits);

  FsContext ctx;
  ctx.read = &read;
  ctx.pointer = req.pointer;
  tinygltf::TinyGLTF gltf;
  gltf.SetFsCallbacks(tinygltf::FsCallbacks{&fs_exists, &fs_expand, &fs_read, &fs_write, &ctx});
  gltf.SetImageLoader(&keep_encoded_image, nullptr);
  const auto slash = req.file.find_last_of('/');
  const std::string base_dir = slash == std::string::npos ? std::string() : req.file.substr(0, slash);

  tinygltf::Model model;
  std::string err, warn;
  bool ok = false;
  try {
    ok = binary ? gltf.LoadBinaryFromMemory(&model, &err, &warn, reinterpret_cast<const unsigned char*>(bytes.data()),
                                            static_cast<unsigned int>(bytes.size()), base_dir)
                : gltf.LoadASCIIFromString(&model, &err, &warn, bytes.data(), static_cast<unsigned int>(bytes.size()),
                                           base_dir);
  } catch (const std::exception& e) {
    err = e.what();
  }
  if (!ok) {
    while (!err.empty() && (err.back() == '\n' || err.back() == ' ')) err.pop_back();
    throw SpecError(req.pointer, fmt::format("cannot read glTF \"{}\": {}{}", req.file, err.empty() ? "invalid file" : err,
                                             ctx.refused.empty() ? "" : fmt::format(" (refused {})", ctx.refused)));
  }
  if (req.camera && std::holds_alternative<size_t>(*req.camera) && std::get<size_t>(*req.camera) >= model.cameras.size()) {
    throw SpecError(req.camera_pointer, fmt::format("the glTF has {} camera(s)", model.cameras.size()));
  }
  GltfLoader(scene, req, limits, model, ctx).run();
}

}  // namespace tally
