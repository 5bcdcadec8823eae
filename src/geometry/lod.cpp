#include "geometry/lod.h"
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

float footprint_texels(float dudx, float dudy, float dvdx, float dvdy, double width, double height) {
    const double ax = std::hypot(double(dudx) * width, double(dvdx) * height);
    const double ay = std::hypot(double(dudy) * width, double(dvdy) * height);
    const double w = std::max(ax, ay);
    if (!(w >= 0.0) || !std::isfinite(w)) return 0.f;
    return float(std::min(w, 3.0e38));
}

LodChain::LodChain(std::vector<float> factors, const std::string &where) : m_factors(std::move(factors)) {
    auto fail = [&](const std::string &msg) {
        throw MesoError(where.empty() ? msg : where + ": " + msg);
    };
    if (m_factors.empty()) fail("a LoD chain needs at least one level");
    for (size_t i = 0; i < m_factors.size(); ++i) {
        float f = m_factors[i];
        if (!std::isfinite(f) || f < 1.f)
            fail(fmt::format("level {}: expected a downsampling factor >= 1, got {}", i, f));
        if (i > 0 && !(f > m_factors[i - 1]))
            fail(fmt::format("level {}: factors must increase strictly (got {} after {})", i, f, m_factors[i - 1]));
    }
    m_log.resize(m_factors.size());
    for (size_t i = 0; i < m_factors.size(); ++i) m_log[i] = std::log(m_factors[i]);
}

LodSelection LodChain::select(float texels, float bias) const {
    LodSelection s;
    const double w = double(texels) * double(bias);
    const int n = levels();
    if (!(w > double(m_factors[0])) || n == 1) return s;  // also NaN / zero footprints
    if (w >= double(m_factors[size_t(n - 1)])) {
        s.lo = s.hi = n - 1;
        return s;
    }
    const double lw = std::log(w);
    int i = int(std::upper_bound(m_factors.begin(), m_factors.end(), float(w)) - m_factors.begin()) - 1;
    i = std::clamp(i, 0, n - 2);
    s.lo = i;
    s.hi = i + 1;
    // The transition to `hi` spans at most the octave below its factor (see lod.h).
    const double span = std::min(double(m_log[size_t(i + 1)]) - m_log[size_t(i)], std::log(2.0));
    s.t = float(std::clamp((lw - m_log[size_t(i + 1)]) / span + 1.0, 0.0, 1.0));
    if (s.t == 0.f) s.hi = s.lo;
    return s;
}

int LodChain::choose(float texels, float u, float bias) const {
    LodSelection s = select(texels, bias);
    return u < s.t ? s.hi : s.lo;
}

float LodChain::position(float texels, float bias) const {
    LodSelection s = select(texels, bias);
    return float(s.lo) + (s.hi != s.lo ? s.t : 0.f);
}

LodSelection select_path_level(const LodGroup &g, float dudx, float dudy, float dvdx, float dvdy) {
    const float w = footprint_texels(dudx, dudy, dvdx, dvdy, g.texel_w, g.texel_h);
    return g.chain.select(w, g.bias);
}

}  // namespace meso
