// Textures: spatially varying parameters, evaluated at a shading point. Filtered
// textures use the ray-differential footprint (ctx.dudx ... ctx.dvdy).
#pragma once
#include <memory>
#include <string>
#include "core/registry.h"  // make_constant_texture
#include "geometry/shading.h"

namespace meso {

class Texture {
public:
    virtual ~Texture() = default;
    virtual Spectrum eval(const ShadingContext &ctx) const = 0;
    /// Scalar value (the average of the RGB channels unless the texture is scalar).
    virtual float eval_float(const ShadingContext &ctx) const { return eval(ctx).average(); }
    /// Mean value over the texture (used for light power and AOV hints).
    virtual Spectrum mean() const = 0;
    /// True when the texture is a constant (materials may precompute from it).
    virtual bool is_constant() const { return false; }
    virtual std::string to_string() const = 0;
};


}  // namespace meso
