#include "core/transform_parse.h"
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/properties.h"

namespace meso {

Transform parse_transform(const Properties &parent, const char *key) {
    if (!parent.has(key)) return Transform();
    Properties p = parent.child(key);
    try {
        if (p.has("matrix")) {
            auto m = p.get_floats("matrix");
            if (m.size() != 16) p.fail("matrix", "expected 16 numbers (row-major 4x4)");
            if (p.keys().size() > 1) p.fail("'matrix' cannot be combined with other keys");
            return Transform::from_matrix(m.data());
        }
        if (p.has("look_at")) {
            Properties l = p.child("look_at");
            Transform t = Transform::look_at(l.get_vec3("origin"), l.get_vec3("target"), l.get_vec3("up", Vec3(0, 1, 0)));
            l.check_unused("look_at");
            p.check_unused("to_world");
            return t;
        }
        Transform t;
        if (p.has("scale")) {
            const auto &v = p.raw("scale");
            Vec3 s = v.is_number() ? Vec3(1, 1, 1) * p.get_float("scale") : p.get_vec3("scale");
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
        if (p.has("translate")) t = Transform::translate(p.get_vec3("translate")) * t;
        p.check_unused("to_world");
        return t;
    } catch (const MesoError &e) {
        std::string msg = e.what();
        // Errors from Transform itself carry no location: add it.
        if (msg.find(p.file()) == 0 && !p.file().empty()) throw;
        if (msg.find(p.path()) != std::string::npos) throw;
        p.fail(msg);
    }
}

}  // namespace meso
