// `combine`: a weighted sum or product of textures (paper 001 §6's linear and non-linear
// combinations of colour maps, e.g. the ground truth C = k0 C0 + k1 C(h) + k2 C(s) built from
// `colormap` and `microcolormap` terms).
//
// Parameters
//   name    type                 default  notes
//   op      string               "sum"    "sum": sum of weight x term; "product": product of weight x term
//   terms   [{texture, weight}]  required at least one; texture: any texture value (number, [r,g,b],
//                                         inline object or a declared name); weight: float, default 1
#include <cmath>
#include <fmt/format.h>
#include "texture/texture.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class CombineTexture final : public Texture {
public:
    CombineTexture(bool product, std::vector<std::pair<std::shared_ptr<Texture>, float>> terms)
        : m_product(product), m_terms(std::move(terms)) {}

    Spectrum eval(const ShadingContext &ctx) const override {
        Spectrum acc(m_product ? 1.f : 0.f);
        for (const auto &[t, w] : m_terms) {
            if (m_product) acc *= t->eval(ctx) * w;
            else acc += t->eval(ctx) * w;
        }
        return acc;
    }
    Spectrum mean() const override {  // exact for sums; a hint (product of means) for products
        Spectrum acc(m_product ? 1.f : 0.f);
        for (const auto &[t, w] : m_terms) {
            if (m_product) acc *= t->mean() * w;
            else acc += t->mean() * w;
        }
        return acc;
    }
    bool is_constant() const override {
        for (const auto &term : m_terms)
            if (!term.first->is_constant()) return false;
        return true;
    }
    std::string to_string() const override {
        std::string s = m_product ? "combine[product:" : "combine[sum:";
        for (const auto &[t, w] : m_terms) s += fmt::format(" {:.3g} x {}", w, t->to_string());
        return s + "]";
    }

private:
    bool m_product;
    std::vector<std::pair<std::shared_ptr<Texture>, float>> m_terms;
};

std::shared_ptr<Texture> make_combine(const Properties &p) {
    const bool product = p.get_enum<bool>("op", "sum", {{"sum", false}, {"product", true}});
    std::vector<std::pair<std::shared_ptr<Texture>, float>> terms;
    for (const Properties &t : p.children("terms")) {
        const float w = t.get_float("weight", 1.f);
        if (!std::isfinite(w)) t.fail("weight", "expected a finite number");
        terms.emplace_back(t.get_texture("texture"), w);
        t.check_unused("combine term");
    }
    if (terms.empty()) p.fail("terms", "expected at least one {\"texture\": ..., \"weight\": ...} term");
    return std::make_shared<CombineTexture>(product, std::move(terms));
}

}  // namespace

MESO_REGISTER_TEXTURE("combine", "weighted sum or product of textures (op, terms: [{texture, weight}])", make_combine);

}  // namespace meso
