#include "core/registry.h"
#include <fmt/format.h>
#include "core/error.h"
#include "core/properties.h"

namespace meso {

Registry &registry() {
    static Registry r;
    return r;
}

template <typename T>
static std::shared_ptr<T> create(const PluginTable<T> &table, const char *kind, const Properties &props) {
    std::string type = props.type();
    auto it = table.factories.find(type);
    if (it == table.factories.end()) {
        std::string known;
        for (auto &kv : table.factories) known += (known.empty() ? "" : ", ") + kv.first;
        props.fail("type", fmt::format("unknown {} type '{}' (known: {})", kind, type, known));
    }
    std::shared_ptr<T> obj = it->second(props);
    props.check_unused(fmt::format("{} '{}'", kind, type));
    return obj;
}

std::shared_ptr<Material> create_material(const Properties &p) { return create(registry().materials, "material", p); }
std::shared_ptr<Texture> create_texture(const Properties &p) { return create(registry().textures, "texture", p); }
std::shared_ptr<Light> create_light(const Properties &p) { return create(registry().lights, "light", p); }
std::shared_ptr<Integrator> create_integrator(const Properties &p) { return create(registry().integrators, "integrator", p); }
std::shared_ptr<Sampler> create_sampler(const Properties &p) { return create(registry().samplers, "sampler", p); }
std::shared_ptr<Camera> create_camera(const Properties &p) { return create(registry().cameras, "camera", p); }
std::shared_ptr<Shape> create_shape(const Properties &p) { return create(registry().shapes, "shape", p); }

}  // namespace meso
