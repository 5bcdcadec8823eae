// Helpers for tests of single materials: build one from JSON text, directions in degrees.
#pragma once
#include <cmath>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include "core/vec.h"
#include "bsdf/material.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso::test {

/// The default shading context (flat surface, no footprint).
inline const ShadingContext kCtx{};

/// A material from an inline JSON object (errors as from a scene file named "material").
inline std::shared_ptr<Material> make_material(const std::string &json_text) {
    nlohmann::json j = nlohmann::json::parse(json_text);
    return create_material(Properties(j, "material", std::make_shared<LoadContext>()));
}

/// Unit direction from degrees (θ from the normal, φ from s); θ = 90 exactly gives z = 0.
inline Vec3 dir_deg(double theta, double phi) {
    constexpr double kDeg = 3.14159265358979323846 / 180.0;
    const double t = theta * kDeg, p = phi * kDeg;
    const double z = theta == 90.0 ? 0.0 : std::cos(t);
    return Vec3(float(std::sin(t) * std::cos(p)), float(std::sin(t) * std::sin(p)), float(z));
}

}  // namespace meso::test
