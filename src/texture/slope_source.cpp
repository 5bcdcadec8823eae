#include "texture/slope_source.h"
#include <algorithm>
#include <cmath>
#include <fmt/format.h>
#include "geometry/displacement.h"
#include "core/error.h"
#include "geometry/heightfield.h"
#include "filter/transfer_filter.h"
#include "core/properties.h"

namespace meso {

SlopeSource::SlopeSource(const SlopeGaussian &constant) : m_const(constant) {}

SlopeSource::SlopeSource(const Heightfield &field, float tiling_u, float tiling_v, Filter filter, float max_anisotropy,
                         std::string source)
    : m_mip(std::make_shared<MipMap>(build_slope_moments(field, 1.0 / tiling_u, 1.0 / tiling_v))),
      m_tu(tiling_u),
      m_tv(tiling_v),
      m_filter(filter),
      m_max_aniso(max_anisotropy),
      m_source(std::move(source)) {
    double sum = 0;
    for (int j = 0; j < field.height(); ++j)
        for (int i = 0; i < field.width(); ++i) sum += field.vertex(i, j);
    m_hcenter = sum / (double(field.width()) * field.height());
    m_hmip = std::make_shared<MipMap>(build_height_moments(field, m_hcenter));
}

void SlopeSource::map_height_moments(const ShadingContext &ctx, double &mean, double &variance) const {
    float m[2];
    const float u = ctx.uv.x * m_tu, v = ctx.uv.y * m_tv;
    const float dudx = ctx.dudx * m_tu, dudy = ctx.dudy * m_tu, dvdx = ctx.dvdx * m_tv, dvdy = ctx.dvdy * m_tv;
    m_hmip->lookup(m_filter, u, v, dudx, dudy, dvdx, dvdy, m, m_max_aniso);
    mean = m_hcenter + m[0];
    // Below one texel the footprint sees only part of a cell's height variance (MipMap).
    variance = m_hmip->magnified_variance(std::max(0.0, double(m[1]) - double(m[0]) * m[0]), dudx, dudy, dvdx, dvdy);
}

bool SlopeSource::height_moments(const ShadingContext &ctx, double &mean, double &variance) const {
    if (!m_hmip) {
        mean = m_const_hmean;
        variance = m_const_hvar;
        return m_has_const_h;
    }
    map_height_moments(ctx, mean, variance);
    if (m_transfer) {
        const TransferMoments t = transfer_moments(*m_transfer, mean, std::sqrt(variance));
        mean = m_toffset + m_tscale * t.g;
        variance = m_tscale * m_tscale * std::max(0.0, t.g2 - t.g * t.g);
    }
    return true;
}

void SlopeSource::set_height_transfer(std::shared_ptr<const Ramp> g, double scale, double offset) {
    if (!m_mip) throw MesoError("SlopeSource: a height transfer needs a map source");
    if (!g || g->channels() != 1) throw MesoError("SlopeSource: the height transfer must be a one-channel ramp");
    m_transfer = std::move(g);
    m_tscale = scale;
    m_toffset = offset;
}

void SlopeSource::apply_transfer(const float fm[SlopeMomentCount], double f_mean, double f_var,
                                 float out[SlopeMomentCount], double *h_mean, double *h_var) const {
    const TransferMoments t = transfer_moments(*m_transfer, f_mean, std::sqrt(std::max(0.0, f_var)));
    // f's texture-space slope Gaussian (J = identity), eq. 24-26, then the world height scale.
    const TransferredStatistics ts = transferred_statistics(t, slope_gaussian(fm, 1, 0, 0, 1));
    const double k = m_tscale;
    const double mx = k * ts.slopes.mx, my = k * ts.slopes.my;
    out[MomentX] = float(mx);
    out[MomentY] = float(my);
    out[MomentXX] = float(k * k * ts.slopes.sxx + mx * mx);
    out[MomentYY] = float(k * k * ts.slopes.syy + my * my);
    out[MomentXY] = float(k * k * ts.slopes.sxy + mx * my);
    if (h_mean) *h_mean = m_toffset + k * ts.h_mean;
    if (h_var) *h_var = k * k * ts.h_var;
}

void SlopeSource::set_constant_height(double mean, double sigma) {
    m_const_hmean = mean;
    m_const_hvar = sigma * sigma;
    m_has_const_h = true;
}

bool SlopeSource::present(const Properties &p) {
    for (const char *k : {"heightmap", "mean_slope", "covariance", "filter", "max_anisotropy", "transfer_filter"})
        if (p.has(k)) return true;
    return false;
}

SlopeSource SlopeSource::parse(const Properties &p) {
    if (p.has("heightmap")) {
        for (const char *k : {"mean_slope", "covariance"})
            if (p.has(k)) p.fail(k, "give either \"heightmap\" (statistics from a map) or constant statistics, not both");
        const Properties hp = p.child("heightmap");
        const bool gaussian = p.get_enum<bool>("transfer_filter", "exact", {{"exact", false}, {"gaussian", true}});
        if (p.has("transfer_filter") && !hp.has("transfer"))
            p.fail("transfer_filter", "only meaningful with a \"transfer\" (a height transfer function g) in the "
                                      "\"heightmap\" block");
        // "gaussian": the pyramids of the untransformed f (map units); g is applied per footprint.
        Displacement d = parse_displacement(hp, 0, /*apply_transfer=*/!gaussian);
        const Filter filter = parse_footprint_filter(p, "filter");
        const float aniso = p.get_float("max_anisotropy", 8.f, Range::at_least(1.0));
        SlopeSource src(*d.field, d.tiling_u, d.tiling_v, filter, aniso, d.source);
        if (gaussian) src.set_height_transfer(d.transfer, d.scale, d.offset);
        return src;
    }
    for (const char *k : {"filter", "max_anisotropy", "transfer_filter"})
        if (p.has(k)) p.fail(k, "only meaningful with a \"heightmap\"");
    SlopeGaussian g;
    if (p.has("mean_slope")) {
        std::vector<float> m = p.get_floats("mean_slope");
        if (m.size() != 2 || !std::isfinite(m[0]) || !std::isfinite(m[1]))
            p.fail("mean_slope", "expected [x, y], finite");
        g.mx = m[0], g.my = m[1];
    }
    if (p.has("covariance")) {
        std::vector<float> c = p.get_floats("covariance");
        if (c.size() != 3 || !(c[0] >= 0.f) || !(c[1] >= 0.f) || !std::isfinite(c[0]) || !std::isfinite(c[1]) ||
            !std::isfinite(c[2]))
            p.fail("covariance", "expected [sigma_x^2, sigma_y^2, c_xy] with finite, non-negative variances");
        if (double(c[2]) * c[2] > double(c[0]) * c[1] * (1 + 1e-6))
            p.fail("covariance", "expected |c_xy| <= sqrt(sigma_x^2 sigma_y^2) (a covariance matrix)");
        g.sxx = c[0], g.syy = c[1], g.sxy = c[2];
    }
    return SlopeSource(g);
}

void SlopeSource::moments(const ShadingContext &ctx, float out[SlopeMomentCount]) const {
    if (!m_mip) {
        out[MomentX] = float(m_const.mx), out[MomentY] = float(m_const.my);
        out[MomentXX] = float(m_const.sxx + m_const.mx * m_const.mx);
        out[MomentYY] = float(m_const.syy + m_const.my * m_const.my);
        out[MomentXY] = float(m_const.sxy + m_const.mx * m_const.my);
        return;
    }
    const float u = ctx.uv.x * m_tu, v = ctx.uv.y * m_tv;
    if (!m_transfer) {
        m_mip->lookup(m_filter, u, v, ctx.dudx * m_tu, ctx.dudy * m_tu, ctx.dvdx * m_tv, ctx.dvdy * m_tv, out,
                      m_max_aniso);
        return;
    }
    float fm[SlopeMomentCount];
    m_mip->lookup(m_filter, u, v, ctx.dudx * m_tu, ctx.dudy * m_tu, ctx.dvdx * m_tv, ctx.dvdy * m_tv, fm, m_max_aniso);
    double f_mean, f_var;
    map_height_moments(ctx, f_mean, f_var);
    apply_transfer(fm, f_mean, f_var, out, nullptr, nullptr);
}

SlopeGaussian SlopeSource::eval(const ShadingContext &ctx) const {
    if (!m_mip) return m_const;
    float m[SlopeMomentCount];
    moments(ctx, m);
    const double dpdu[3] = {ctx.dpdu.x, ctx.dpdu.y, ctx.dpdu.z}, dpdv[3] = {ctx.dpdv.x, ctx.dpdv.y, ctx.dpdv.z};
    const double s[3] = {ctx.frame.s.x, ctx.frame.s.y, ctx.frame.s.z}, t[3] = {ctx.frame.t.x, ctx.frame.t.y, ctx.frame.t.z};
    double dudx, dvdx, dudy, dvdy;
    if (!uv_per_tangent(dpdu, dpdv, s, t, dudx, dvdx, dudy, dvdy)) return SlopeGaussian{};
    SlopeGaussian g = slope_gaussian(m, dudx, dvdx, dudy, dvdy);
    if (ctx.side < 0.f) g.mx = -g.mx, g.my = -g.my;
    return g;
}

SlopeGaussian SlopeSource::mean_over_map() const {
    if (!m_mip) return m_const;
    float m[SlopeMomentCount];
    m_mip->level_mean(0, m);
    if (m_transfer) {
        float hm[2], fm[SlopeMomentCount];
        m_hmip->level_mean(0, hm);
        std::copy(m, m + SlopeMomentCount, fm);
        apply_transfer(fm, m_hcenter + hm[0], double(hm[1]) - double(hm[0]) * hm[0], m, nullptr, nullptr);
    }
    return slope_gaussian(m, 1, 0, 0, 1);
}

std::string SlopeSource::to_string() const {
    if (!m_mip)
        return fmt::format("mean slope ({:.4g}, {:.4g}), covariance ({:.4g}, {:.4g}, {:.4g})", m_const.mx, m_const.my,
                           m_const.sxx, m_const.syy, m_const.sxy);
    static const char *filters[] = {"trilinear", "ewa", "none"};
    return fmt::format("slope moments of {} ({}x{}, tiling {}x{}, {} filter{}, {:.2f} MB)", m_source, m_mip->width(),
                       m_mip->height(), m_tu, m_tv, filters[int(m_filter)],
                       m_transfer ? fmt::format(", gaussian transfer filter (paper 001 §7), h = {:.4g} + {:.4g} g(f)",
                                                m_toffset, m_tscale)
                                  : std::string(),
                       m_mip->memory_bytes() / 1048576.0);
}

}  // namespace meso
