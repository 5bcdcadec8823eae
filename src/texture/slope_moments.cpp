#include "texture/slope_moments.h"
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

MipMap build_slope_moments(const Heightfield &hf, double tile_u, double tile_v) {
    if (!(tile_u > 0.0) || !(tile_v > 0.0) || !std::isfinite(tile_u) || !std::isfinite(tile_v))
        throw MesoError(fmt::format("slope moments: tile size in uv must be positive, got {} x {}", tile_u, tile_v));
    const int w = hf.width(), h = hf.height();
    // Cells per unit uv: slopes per cell times these are slopes per unit uv.
    const double su = double(w) / tile_u, sv = double(h) / tile_v;
    std::vector<float> data(size_t(w) * h * SlopeMomentCount);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double h00 = hf.vertex(i, j), h10 = hf.vertex(i + 1, j), h01 = hf.vertex(i, j + 1),
                         h11 = hf.vertex(i + 1, j + 1);
            const double e = (h10 - h00) * su, f = (h01 - h00) * sv;
            const double gx = (h00 + h11 - h10 - h01) * su, gy = (h00 + h11 - h10 - h01) * sv;
            float *m = &data[(size_t(j) * w + i) * SlopeMomentCount];
            m[MomentX] = float(e + gx / 2);
            m[MomentY] = float(f + gy / 2);
            m[MomentXX] = float(e * e + e * gx + gx * gx / 3);
            m[MomentYY] = float(f * f + f * gy + gy * gy / 3);
            m[MomentXY] = float((e + gx / 2) * (f + gy / 2));
        }
    return MipMap(w, h, SlopeMomentCount, std::move(data), WrapMode::Repeat);
}

MipMap build_height_moments(const Heightfield &hf, double center) {
    const int w = hf.width(), h = hf.height();
    std::vector<float> data(size_t(w) * h * 2);
    for (int j = 0; j < h; ++j)
        for (int i = 0; i < w; ++i) {
            const double a = hf.vertex(i, j) - center, b = hf.vertex(i + 1, j) - center,
                         c = hf.vertex(i, j + 1) - center, d = hf.vertex(i + 1, j + 1) - center;
            float *m = &data[(size_t(j) * w + i) * 2];
            m[0] = float((a + b + c + d) / 4);
            // E[w_i w_k] over one axis: 1/3 for the same end, 1/6 for opposite ends.
            m[1] = float((a * a + b * b + c * c + d * d) / 9 + (a * b + a * c + b * d + c * d) / 9 + (a * d + b * c) / 18);
        }
    return MipMap(w, h, 2, std::move(data), WrapMode::Repeat);
}

SlopeGaussian slope_gaussian(const float m[SlopeMomentCount], double dudx, double dvdx, double dudy, double dvdy,
                             double eta, double base_variance) {
    // Texture-space mean and covariance (eq. 9), height-scaled.
    const double mu = eta * m[MomentX], mv = eta * m[MomentY];
    const double suu = std::max(0.0, eta * eta * (double(m[MomentXX]) - double(m[MomentX]) * m[MomentX]));
    const double svv = std::max(0.0, eta * eta * (double(m[MomentYY]) - double(m[MomentY]) * m[MomentY]));
    const double cuv = eta * eta * (double(m[MomentXY]) - double(m[MomentX]) * m[MomentY]);
    // x = u_x U + v_x V, y = u_y U + v_y V (eq. 12).
    SlopeGaussian g;
    g.mx = dudx * mu + dvdx * mv;
    g.my = dudy * mu + dvdy * mv;
    g.sxx = dudx * dudx * suu + dvdx * dvdx * svv + 2 * dudx * dvdx * cuv + base_variance;
    g.syy = dudy * dudy * suu + dvdy * dvdy * svv + 2 * dudy * dvdy * cuv + base_variance;
    g.sxy = dudx * dudy * suu + dvdx * dvdy * svv + (dudx * dvdy + dvdx * dudy) * cuv;
    g.sxx = std::max(g.sxx, 0.0);
    g.syy = std::max(g.syy, 0.0);
    return g;
}

bool uv_per_tangent(const double dpdu[3], const double dpdv[3], const double t[3], const double b[3], double &dudx,
                    double &dvdx, double &dudy, double &dvdy) {
    auto dot3 = [](const double *a, const double *c) { return a[0] * c[0] + a[1] * c[1] + a[2] * c[2]; };
    // [x; y] = M [u; v] with M = [[dpdu.t, dpdv.t], [dpdu.b, dpdv.b]]; J = M^-1.
    const double a = dot3(dpdu, t), bb = dot3(dpdv, t), c = dot3(dpdu, b), d = dot3(dpdv, b);
    const double det = a * d - bb * c;
    const double scale = std::abs(a * d) + std::abs(bb * c);
    if (!(std::abs(det) > 1e-12 * scale) || !std::isfinite(det)) {
        dudx = dvdx = dudy = dvdy = 0;
        return false;
    }
    dudx = d / det;
    dudy = -bb / det;
    dvdx = -c / det;
    dvdy = a / det;
    return true;
}

}  // namespace meso
