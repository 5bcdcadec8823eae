// glTF materials to meso material JSON (gltf_material.h).
#include "scene/gltf_material.h"
#include <cmath>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include "core/error.h"
#include "image/image.h"

namespace meso::gltf_detail {

namespace fs = std::filesystem;

namespace {
/// The image file of glTF image `index`: an external URI relative to the glTF file, or the
/// bytes of a bufferView image (GLB) written once to a file in the temporary directory.
/// Empty (with a warning naming the material) for data URIs and broken references.
std::string image_file(const std::string &path, const tinygltf::Model &model, int index, const std::string &mat) {
    if (index < 0 || size_t(index) >= model.images.size()) {
        warn(path, fmt::format("material '{}': image {} does not exist; texture ignored", mat, index));
        return "";
    }
    const tinygltf::Image &img = model.images[size_t(index)];
    if (!img.uri.empty()) {
        if (img.uri.rfind("data:", 0) == 0) {
            warn(path, fmt::format("material '{}': image {} is a data: URI, which meso does not read; texture ignored", mat, index));
            return "";
        }
        return img.uri;
    }
    if (img.bufferView < 0 || size_t(img.bufferView) >= model.bufferViews.size()) {
        warn(path, fmt::format("material '{}': image {} has neither a URI nor a valid bufferView; texture ignored", mat, index));
        return "";
    }
    const tinygltf::BufferView &bv = model.bufferViews[size_t(img.bufferView)];
    if (bv.buffer < 0 || size_t(bv.buffer) >= model.buffers.size() ||
        bv.byteOffset + bv.byteLength > model.buffers[size_t(bv.buffer)].data.size()) {
        warn(path, fmt::format("material '{}': image {}'s bufferView is out of range; texture ignored", mat, index));
        return "";
    }
    const char *ext = img.mimeType == "image/jpeg" ? ".jpg" : img.mimeType == "image/png" ? ".png" : ".img";
    const unsigned char *bytes = model.buffers[size_t(bv.buffer)].data.data() + bv.byteOffset;
    std::string content(reinterpret_cast<const char *>(bytes), bv.byteLength);
    std::error_code ec;
    fs::path out = fs::temp_directory_path(ec) /
                   fmt::format("meso_gltf_{:016x}{}", std::hash<std::string>()(content), ext);
    if (!fs::exists(out, ec)) {
        fs::path tmp = out;
        tmp += fmt::format(".{}", std::hash<std::string>()(path));
        std::ofstream f(tmp, std::ios::binary);
        f.write(content.data(), std::streamsize(content.size()));
        f.close();
        if (!f || (fs::rename(tmp, out, ec), ec)) {
            warn(path, fmt::format("material '{}': cannot write embedded image {} to {}; texture ignored", mat, index, out.string()));
            return "";
        }
    }
    return out.string();
}

/// KHR_texture_transform → the bitmap's `tiling` (scale), `rotation` and `offset` (the bitmap
/// applies them in the extension's order, uv' = T R S uv); a texCoord override is not
/// supported (warning).
void texture_transform(const std::string &path, const tinygltf::Value &v, const std::string &mat, const char *what, json &j) {
    auto pair = [&](const char *key, double def, double out[2]) {
        out[0] = out[1] = def;
        if (!v.Has(key)) return;
        const tinygltf::Value &a = v.Get(key);
        if (a.IsArray() && a.ArrayLen() == 2 && a.Get(0).IsNumber() && a.Get(1).IsNumber()) {
            out[0] = a.Get(0).GetNumberAsDouble(), out[1] = a.Get(1).GetNumberAsDouble();
        } else {
            warn(path, fmt::format("material '{}': {}: KHR_texture_transform.{} is not two numbers; ignored", mat, what, key));
        }
    };
    double scale[2], offset[2];
    pair("scale", 1.0, scale);
    pair("offset", 0.0, offset);
    const bool scale_ok = scale[0] > 0 && scale[0] <= 1e6 && scale[1] > 0 && scale[1] <= 1e6;
    if (!scale_ok)
        warn(path, fmt::format("material '{}': {}: KHR_texture_transform scale must be in (0, 1e6]; ignored", mat, what));
    else if (scale[0] != 1.0 || scale[1] != 1.0)
        j["tiling"] = json::array({scale[0], scale[1]});
    if (offset[0] != 0.0 || offset[1] != 0.0) j["offset"] = json::array({offset[0], offset[1]});
    if (v.Has("rotation")) {
        const tinygltf::Value &r = v.Get("rotation");
        const double rot = r.IsNumber() ? r.GetNumberAsDouble() : std::nan("");
        if (!(std::abs(rot) <= 1e6))
            warn(path, fmt::format("material '{}': {}: KHR_texture_transform.rotation is not a number in [-1e6, 1e6]; "
                                   "ignored", mat, what));
        else if (rot != 0.0)
            j["rotation"] = rot;
    }
    if (v.Has("texCoord"))
        warn(path, fmt::format("material '{}': {}: KHR_texture_transform texCoord is not supported; ignored", mat, what));
}

}  // namespace

/// A `bitmap` texture for a glTF textureInfo, or null (with a warning) when it cannot be read.
json texture_json(const std::string &path, const tinygltf::Model &model, int tex, int texcoord,
                  const tinygltf::ExtensionMap &exts, const std::string &mat, const char *what, bool raw,
                  const char *channel) {
    if (tex < 0) return json();
    if (size_t(tex) >= model.textures.size()) {
        warn(path, fmt::format("material '{}': {} {} does not exist; ignored", mat, what, tex));
        return json();
    }
    if (texcoord != 0) warn(path, fmt::format("material '{}': {} uses TEXCOORD_{}; meso reads TEXCOORD_0", mat, what, texcoord));
    const tinygltf::Texture &t = model.textures[size_t(tex)];
    std::string file = image_file(path, model, t.source, mat);
    if (file.empty()) return json();
    json j = {{"type", "bitmap"}, {"filename", file}, {"raw", raw}};
    for (const auto &e : exts) {
        if (e.first == "KHR_texture_transform" && e.second.IsObject()) {
            texture_transform(path, e.second, mat, what, j);
            continue;
        }
        warn(path, fmt::format("material '{}': {}: extension {} is not supported; ignored", mat, what, e.first));
    }
    if (channel) j["channel"] = channel;
    if (t.sampler >= 0 && size_t(t.sampler) < model.samplers.size()) {
        int w = model.samplers[size_t(t.sampler)].wrapS;
        if (w != model.samplers[size_t(t.sampler)].wrapT)
            warn(path, fmt::format("material '{}': {}: different wrapS and wrapT; using wrapS", mat, what));
        j["wrap_mode"] = w == TINYGLTF_TEXTURE_WRAP_CLAMP_TO_EDGE ? "clamp"
                         : w == TINYGLTF_TEXTURE_WRAP_MIRRORED_REPEAT ? "mirror" : "repeat";
        if (model.samplers[size_t(t.sampler)].magFilter == TINYGLTF_TEXTURE_FILTER_NEAREST) j["filter_type"] = "nearest";
    }
    return j;
}

/// factor × texture as a meso texture value (the factor alone without a texture).
json scaled(json tex, json factor) {
    if (tex.is_null()) return factor;
    if (factor.is_number()) {
        tex["scale"] = factor;
        return tex;
    }
    if (factor == json::array({1.f, 1.f, 1.f})) return tex;
    return {{"type", "combine"}, {"op", "product"}, {"terms", json::array({{{"texture", tex}}, {{"texture", factor}}})}};
}

namespace {

/// Whether a bitmap's image file (relative to the glTF file) has an alpha channel.
bool image_has_alpha(const std::string &path, const std::string &file) {
    fs::path f(file);
    if (f.is_relative()) f = fs::path(path).parent_path() / f;
    const int channels = image_channel_count(f.string());
    return channels == 2 || channels == 4;  // grey + alpha, RGBA (the bitmap's "a" channel)
}

/// The shape keys "alpha" and "alpha_cutoff" (docs/scene-format.md, "Shapes") of a material
/// with alphaMode MASK, or BLEND (rendered as MASK at 0.5, with a warning): the alpha of
/// `base_tex` (its "a" channel, raw: glTF alpha is linear) × baseColorFactor[3], or the factor
/// alone when there is no texture or it has no alpha channel. Null for OPAQUE.
json alpha_keys(const std::string &path, const tinygltf::Material &m, const json &base_tex) {
    if (m.alphaMode == "OPAQUE" || m.alphaMode.empty()) return json();
    double cutoff = m.alphaCutoff;
    if (m.alphaMode == "BLEND") {
        warn(path, fmt::format("material '{}': alphaMode BLEND is rendered as MASK with alphaCutoff 0.5 (meso does "
                               "not blend)", m.name));
        cutoff = 0.5;
    } else if (m.alphaMode != "MASK") {
        warn(path, fmt::format("material '{}': unknown alphaMode '{}'; rendered opaque", m.name, m.alphaMode));
        return json();
    } else if (!(cutoff >= 0.0 && cutoff <= 1.0)) {
        warn(path, fmt::format("material '{}': alphaCutoff {} is outside [0, 1]; 0.5 is used", m.name, cutoff));
        cutoff = 0.5;
    }
    const auto &f = m.pbrMetallicRoughness.baseColorFactor;
    const double factor = f.size() >= 4 && std::isfinite(f[3]) ? std::min(std::max(f[3], 0.0), 1.0) : 1.0;
    json alpha = factor;
    if (!base_tex.is_null() && image_has_alpha(path, base_tex["filename"])) {
        json a = base_tex;
        a["raw"] = true;
        a["channel"] = "a";
        alpha = scaled(a, factor);
    }
    return {{"alpha", alpha}, {"alpha_cutoff", cutoff}};
}

}  // namespace

/// glTF metallic-roughness → meso `gltf_pbr` (docs/scene-format.md, "Materials"), wrapped in
/// `normalmap` when the material has a normal texture; `*alpha` receives alpha_keys().
json map_material(const std::string &path, const tinygltf::Model &model, const tinygltf::Material &m, json *alpha) {
    const auto &pbr = m.pbrMetallicRoughness;
    Vec3 base(1, 1, 1);
    if (pbr.baseColorFactor.size() >= 3) base = Vec3(float(pbr.baseColorFactor[0]), float(pbr.baseColorFactor[1]), float(pbr.baseColorFactor[2]));
    auto clamp01 = [](double v) { return std::isfinite(v) ? std::min(std::max(v, 0.0), 1.0) : 0.0; };
    base = Vec3(float(clamp01(base.x)), float(clamp01(base.y)), float(clamp01(base.z)));
    double metallic = clamp01(pbr.metallicFactor), roughness = clamp01(pbr.roughnessFactor);
    for (const auto &e : m.extensions)
        if (e.first != "KHR_materials_emissive_strength")
            warn(path, fmt::format("material '{}': extension {} is not supported; ignored", m.name, e.first));
    if (m.occlusionTexture.index >= 0)
        warn(path, fmt::format("material '{}': occlusionTexture is ignored (a path tracer computes occlusion)", m.name));
    json base_tex = texture_json(path, model, pbr.baseColorTexture.index, pbr.baseColorTexture.texCoord,
                                 pbr.baseColorTexture.extensions, m.name, "baseColorTexture", false, nullptr);
    *alpha = alpha_keys(path, m, base_tex);
    const auto &mr = pbr.metallicRoughnessTexture;
    json metal_tex = texture_json(path, model, mr.index, mr.texCoord, mr.extensions, m.name, "metallicRoughnessTexture", true, "b");
    json rough_tex = metal_tex;  // the same texture (and KHR_texture_transform), read once, warned once
    if (!rough_tex.is_null()) rough_tex["channel"] = "g";
    json mat = {{"type", "gltf_pbr"},
                {"base_color", scaled(base_tex, vec3_json(base))},
                {"metallic", scaled(metal_tex, metallic)},
                {"roughness", scaled(rough_tex, roughness)}};
    const auto &nt = m.normalTexture;
    json normals = texture_json(path, model, nt.index, nt.texCoord, nt.extensions, m.name, "normalTexture", true, nullptr);
    if (normals.is_null()) return mat;
    json wrapped = {{"type", "normalmap"}, {"normals", normals["filename"]}, {"bsdf", mat}};
    if (normals.contains("tiling")) wrapped["tiling"] = normals["tiling"];  // normalmap repeats the image itself
    if (normals.contains("offset") || normals.contains("rotation"))
        warn(path, fmt::format("material '{}': normalTexture: KHR_texture_transform offset and rotation are not "
                               "applied to normal maps (scale is)", m.name));
    if (nt.scale != 1.0) {
        if (std::isfinite(nt.scale) && std::abs(nt.scale) <= 1000.0)
            wrapped["scale"] = nt.scale;
        else
            warn(path, fmt::format("material '{}': normalTexture scale {} is outside [-1000, 1000]; 1 is used", m.name, nt.scale));
    }
    return wrapped;
}

/// emissiveFactor × KHR_materials_emissive_strength (zero when not finite or negative).
Vec3 emission(const tinygltf::Material &m) {
    if (m.emissiveFactor.size() < 3) return Vec3();
    double strength = 1.0;
    auto it = m.extensions.find("KHR_materials_emissive_strength");
    if (it != m.extensions.end() && it->second.IsObject() && it->second.Has("emissiveStrength") &&
        it->second.Get("emissiveStrength").IsNumber())
        strength = it->second.Get("emissiveStrength").GetNumberAsDouble();
    Vec3 e(float(m.emissiveFactor[0] * strength), float(m.emissiveFactor[1] * strength), float(m.emissiveFactor[2] * strength));
    if (!is_finite(e) || e.x < 0 || e.y < 0 || e.z < 0) return Vec3();
    return e;
}

}  // namespace meso::gltf_detail
