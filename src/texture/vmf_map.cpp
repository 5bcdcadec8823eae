#include "texture/vmf_map.h"
#include <algorithm>
#include <cmath>
#include <vector>
#include "core/error.h"
#include "filter/vmf.h"

namespace meso {

namespace {
constexpr int kCells = 8;
constexpr int kNaiveChannels = 5;  // mu (3), kappa, weight per lobe index

int channels_for(VmfMode mode, int lobes) {
    switch (mode) {
        case VmfMode::Direct:
        case VmfMode::Naive: return kNaiveChannels * lobes;
        case VmfMode::Lean: return SlopeMomentCount;
        case VmfMode::Single: return 4;
        case VmfMode::Four: return 4 * 4;
        default: return 4 * kCells;
    }
}

/// Cell count stored for the r-averaging modes.
int stored_cells(VmfMode mode) { return mode == VmfMode::Single ? 1 : mode == VmfMode::Four ? 4 : kCells; }

/// A lobe from a characteristic-vector sum (Σ w r, Σ w).
VmfLobe lobe_of(double rx, double ry, double rz, double w) {
    VmfLobe L;
    L.weight = w;
    const double inv = 1.0 / w;
    rx *= inv, ry *= inv, rz *= inv;
    const double len = std::sqrt(rx * rx + ry * ry + rz * rz);
    if (len > 1e-30 && std::isfinite(len)) {
        L.mu = Vec3(float(rx / len), float(ry / len), float(rz / len));
        L.kappa = vmf::kappa_from_r(len);
    } else {
        L.mu = Vec3(0.f, 0.f, 1.f);
        L.kappa = 0.0;  // vectors cancelling exactly: no preferred direction
    }
    return L;
}
}  // namespace

SlopeGaussian vmf_lobe_slopes(Vec3 mu, double kappa) {
    const double hz = std::max(0.05, double(mu.z)), hx = mu.x, hy = mu.y;
    SlopeGaussian g;
    g.mx = -hx / hz;
    g.my = -hy / hz;
    // Σ_s = (1/κ) J Jᵀ (J μ = 0: s does not change along μ), J = ds/dh.
    const double iv = kappa > 1e-4 ? 1.0 / kappa : 1e4;
    const double z2 = hz * hz, z4 = z2 * z2;
    g.sxx = std::min(1e4, iv * (1.0 / z2 + hx * hx / z4));
    g.syy = std::min(1e4, iv * (1.0 / z2 + hy * hy / z4));
    g.sxy = std::clamp(iv * hx * hy / z4, -1e4, 1e4);
    return g;
}

int VmfMap::cell_of(Vec3 mu) {
    // Sectors centred on +x, +y, -x, -y.
    int sector;
    if (std::abs(mu.x) >= std::abs(mu.y)) sector = mu.x >= 0.f ? 0 : 2;
    else sector = mu.y >= 0.f ? 1 : 3;
    return sector * 2 + (mu.z > 0.5f ? 0 : 1);
}

double VmfMap::r_of(double kappa) const {
    return m_params.r_table ? vmf::RTable::get().lookup(kappa) : vmf::r_from_kappa(kappa);
}

VmfMap::VmfMap(int width, int height, int lobes_per_texel, const TexelLobes &texel_lobes, const Params &params,
               WrapMode wrap)
    : m_w(width), m_h(height), m_lobes(lobes_per_texel), m_params(params) {
    if (width < 1 || height < 1) throw MesoError("vMF map: empty grid");
    if (lobes_per_texel < 1 || lobes_per_texel > kMaxTexelLobes)
        throw MesoError("vMF map: 1 to 8 lobes per texel");
    const int C = channels_for(params.mode, lobes_per_texel);
    std::vector<float> data(size_t(width) * height * C, 0.f);
    const int cells = stored_cells(params.mode);
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            VmfLobe L[kMaxTexelLobes];
            const int n = std::min(texel_lobes(x, y, L), lobes_per_texel);
            float *t = &data[(size_t(y) * width + x) * C];
            switch (params.mode) {
                case VmfMode::Direct:
                case VmfMode::Naive:
                    for (int i = 0; i < n; ++i) {
                        float *c = t + kNaiveChannels * i;
                        c[0] = L[i].mu.x, c[1] = L[i].mu.y, c[2] = L[i].mu.z;
                        c[3] = float(std::min(L[i].kappa, vmf::kMaxKappa));
                        c[4] = float(L[i].weight);
                    }
                    break;
                case VmfMode::Lean: {
                    double m[SlopeMomentCount] = {0, 0, 0, 0, 0};
                    for (int i = 0; i < n; ++i) {
                        const SlopeGaussian g = vmf_lobe_slopes(L[i].mu, L[i].kappa);
                        const double w = L[i].weight;
                        m[MomentX] += w * g.mx;
                        m[MomentY] += w * g.my;
                        m[MomentXX] += w * (g.sxx + g.mx * g.mx);
                        m[MomentYY] += w * (g.syy + g.my * g.my);
                        m[MomentXY] += w * (g.sxy + g.mx * g.my);
                    }
                    for (int k = 0; k < SlopeMomentCount; ++k) t[k] = float(m[k]);
                    break;
                }
                default:
                    for (int i = 0; i < n; ++i) {
                        const int cell = cells == 1 ? 0 : cells == 4 ? cell_of(L[i].mu) / 2 : cell_of(L[i].mu);
                        const double r = r_of(L[i].kappa) * L[i].weight;
                        float *c = t + 4 * cell;
                        c[0] += float(r * L[i].mu.x), c[1] += float(r * L[i].mu.y), c[2] += float(r * L[i].mu.z);
                        c[3] += float(L[i].weight);
                    }
            }
        }
    m_mip = std::make_shared<MipMap>(width, height, C, std::move(data), wrap);
}

void VmfMap::lookup(FootprintFilter filter, float u, float v, float dudx, float dudy, float dvdx, float dvdy,
                    float max_anisotropy, VmfLookup &out) const {
    out.count = 0;
    out.gaussian = false;
    out.cells = 0;
    float buf[4 * kCells > kNaiveChannels * kMaxTexelLobes ? 4 * kCells : kNaiveChannels * kMaxTexelLobes];
    if (m_params.mode == VmfMode::Direct)
        m_mip->nearest(0, u, v, buf);
    else
        m_mip->lookup(filter, u, v, dudx, dudy, dvdx, dvdy, buf, max_anisotropy);

    switch (m_params.mode) {
        case VmfMode::Direct:
        case VmfMode::Naive:
            for (int i = 0; i < m_lobes; ++i) {
                const float *c = buf + kNaiveChannels * i;
                if (!(c[4] > 0.f)) continue;
                VmfLobe L;
                const double len = std::sqrt(double(c[0]) * c[0] + double(c[1]) * c[1] + double(c[2]) * c[2]);
                L.mu = len > 1e-30 ? Vec3(float(c[0] / len), float(c[1] / len), float(c[2] / len)) : Vec3(0.f, 0.f, 1.f);
                L.kappa = std::max(0.0, double(c[3]));
                L.weight = c[4];
                out.lobes[out.count++] = L;
            }
            return;
        case VmfMode::Lean: {
            SlopeGaussian g;
            g.mx = buf[MomentX], g.my = buf[MomentY];
            g.sxx = std::max(0.0, double(buf[MomentXX]) - g.mx * g.mx);
            g.syy = std::max(0.0, double(buf[MomentYY]) - g.my * g.my);
            g.sxy = double(buf[MomentXY]) - g.mx * g.my;
            out.gaussian = true;
            out.slopes = g;
            return;
        }
        default: break;
    }

    const int stored = stored_cells(m_params.mode);
    auto emit = [&](double rx, double ry, double rz, double w) {
        if (w > 1e-12) out.lobes[out.count++] = lobe_of(rx, ry, rz, w);
    };
    if (stored == 1) {
        emit(buf[0], buf[1], buf[2], buf[3]);
        out.cells = 1;
        return;
    }
    if (stored == 4) {
        for (int i = 0; i < 4; ++i) emit(buf[4 * i], buf[4 * i + 1], buf[4 * i + 2], buf[4 * i + 3]);
        out.cells = 4;
        return;
    }
    if (m_params.mode == VmfMode::Eight) {
        for (int i = 0; i < kCells; ++i) emit(buf[4 * i], buf[4 * i + 1], buf[4 * i + 2], buf[4 * i + 3]);
        out.cells = 8;
        return;
    }
    // Adaptive (Algorithm 1).
    double s[4][4];  // 1×4 sums
    double t[4] = {0, 0, 0, 0};
    for (int i = 0; i < 4; ++i)
        for (int k = 0; k < 4; ++k) {
            s[i][k] = double(buf[8 * i + k]) + double(buf[8 * i + 4 + k]);
            t[k] += s[i][k];
        }
    auto length_of = [](const double *c) {
        if (!(c[3] > 1e-12)) return 0.0;
        return std::sqrt(c[0] * c[0] + c[1] * c[1] + c[2] * c[2]) / c[3];
    };
    if (length_of(t) >= m_params.eps0) {
        emit(t[0], t[1], t[2], t[3]);
        out.cells = 1;
        return;
    }
    out.cells = 4;
    for (int i = 0; i < 4; ++i) {
        if (!(s[i][3] > 1e-12)) continue;
        if (length_of(s[i]) >= m_params.eps1) {
            emit(s[i][0], s[i][1], s[i][2], s[i][3]);
        } else {
            out.cells = 8;
            for (int b = 0; b < 2; ++b) {
                const float *c = buf + 8 * i + 4 * b;
                emit(c[0], c[1], c[2], c[3]);
            }
        }
    }
}

}  // namespace meso
