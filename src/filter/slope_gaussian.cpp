#include "filter/slope_gaussian.h"
#include <algorithm>
#include <cmath>

namespace meso {

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
