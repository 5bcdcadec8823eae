// `constant` texture: one value everywhere. Plain numbers and [r,g,b] arrays in a scene
// become this.
//   value   spectrum   default 1   the value
#include <fmt/format.h>
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class ConstantTexture final : public Texture {
public:
    explicit ConstantTexture(Spectrum v) : m_value(v) {}
    Spectrum eval(const ShadingContext &) const override { return m_value; }
    float eval_float(const ShadingContext &) const override { return m_value.average(); }
    Spectrum mean() const override { return m_value; }
    bool is_constant() const override { return true; }
    std::string to_string() const override { return fmt::format("constant[{}, {}, {}]", m_value.r, m_value.g, m_value.b); }

private:
    Spectrum m_value;
};

MESO_REGISTER_TEXTURE("constant", "a constant value", [](const Properties &p) -> std::shared_ptr<Texture> {
    return std::make_shared<ConstantTexture>(p.get_spectrum("value", Spectrum(1.f)));
});

}  // namespace

std::shared_ptr<Texture> make_constant_texture(Spectrum value) { return std::make_shared<ConstantTexture>(value); }

}  // namespace meso
