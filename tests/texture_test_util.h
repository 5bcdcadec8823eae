// Helpers for texture tests: build a texture from JSON as a scene file in `base_dir` would, the
// error text of a bad one, and a shading context with a uv footprint.
#pragma once
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include "core/error.h"
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso::test {

/// A texture from JSON at path "textures.tex" of a scene "scene.json" in base_dir.
inline std::shared_ptr<Texture> make_texture_in(const std::string &base_dir, const nlohmann::json &j) {
    auto ctx = std::make_shared<LoadContext>();
    ctx->file = "scene.json";
    ctx->base_dir = base_dir;
    return create_texture(Properties(j, "textures.tex", ctx));
}

/// The MesoError text of make_texture_in, or "(no error)".
inline std::string texture_error_in(const std::string &base_dir, const nlohmann::json &j) {
    try {
        make_texture_in(base_dir, j);
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

/// A shading context at uv with the footprint derivatives (zero: no footprint).
inline ShadingContext uv_context(double u, double v, double dudx = 0, double dudy = 0, double dvdx = 0,
                                 double dvdy = 0) {
    ShadingContext ctx;
    ctx.uv = Vec2(float(u), float(v));
    ctx.dudx = float(dudx), ctx.dudy = float(dudy), ctx.dvdx = float(dvdx), ctx.dvdy = float(dvdy);
    return ctx;
}

}  // namespace meso::test
