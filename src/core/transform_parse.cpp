#include "core/transform_parse.h"
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/properties.h"

namespace meso {

namespace {

/// Scale factors: nonzero, of magnitude in [1e-8, kMaxSceneCoordinate].
void check_scale(const Properties &p, Vec3 s) {
    for (int i = 0; i < 3; ++i)
        if (!(std::abs(s[i]) >= 1e-8f && std::abs(s[i]) <= kMaxSceneCoordinate))
            p.fail("scale", fmt::format("expected scale factors of magnitude in [1e-08, {:g}], got {:g}", kMaxSceneCoordinate, s[i]));
}

/// The composed transform: finite, entries within kMaxSceneCoordinate, and a finite inverse.
Transform checked(const Properties &p, const Transform &t) {
    for (int i = 0; i < 4; ++i)
        for (int j = 0; j < 4; ++j) {
            if (!(std::abs(t.m[i][j]) <= kMaxSceneCoordinate))
                p.fail(fmt::format("the transform's entry ({}, {}) is {:g}; expected magnitudes at most {:g}", i, j,
                                   t.m[i][j], kMaxSceneCoordinate));
            if (!std::isfinite(t.inv[i][j]) || !std::isfinite(t.det3()) || t.det3() == 0.f)
                p.fail("the transform is not invertible in float precision");
        }
    return t;
}

Transform parse(const Properties &p) {
    if (p.has("matrix")) {
        auto m = p.get_floats("matrix");
        if (m.size() != 16) p.fail("matrix", "expected 16 numbers (row-major 4x4)");
        if (p.keys().size() > 1) p.fail("'matrix' cannot be combined with other keys");
        for (size_t i = 0; i < 16; ++i)
            if (!(std::abs(m[i]) <= kMaxSceneCoordinate))
                p.fail("matrix", fmt::format("element {}: expected a magnitude at most {:g}, got {:g}", i, kMaxSceneCoordinate, m[i]));
        return Transform::from_matrix(m.data());
    }
    if (p.has("look_at")) {
        Properties l = p.child("look_at");
        Transform t = Transform::look_at(l.get_position("origin"), l.get_position("target"), l.get_vec3("up", Vec3(0, 1, 0)));
        l.check_unused("look_at");
        p.check_unused("to_world");
        return t;
    }
    Transform t;
    if (p.has("scale")) {
        const auto &v = p.raw("scale");
        Vec3 s = v.is_number() ? Vec3(1, 1, 1) * p.get_float("scale") : p.get_vec3("scale");
        check_scale(p, s);
        t = Transform::scale(s);
    }
    if (p.has("rotate")) {
        const auto &v = p.raw("rotate");
        auto apply = [&](const Properties &r) {
            t = Transform::rotate(r.get_vec3("axis"), r.get_float("angle")) * t;
            r.check_unused("rotate");
        };
        if (v.is_array())
            for (auto &r : p.children("rotate")) apply(r);
        else
            apply(p.child("rotate"));
    }
    if (p.has("translate")) t = Transform::translate(p.get_position("translate")) * t;
    p.check_unused("to_world");
    return t;
}

}  // namespace

Transform parse_transform(const Properties &parent, const char *key) {
    if (!parent.has(key)) return Transform();
    Properties p = parent.child(key);
    try {
        return checked(p, parse(p));
    } catch (const MesoError &e) {
        std::string msg = e.what();
        // Errors from Transform itself carry no location: add it.
        if (msg.find(p.file()) == 0 && !p.file().empty()) throw;
        if (msg.find(p.path()) != std::string::npos) throw;
        p.fail(msg);
    }
}

}  // namespace meso
