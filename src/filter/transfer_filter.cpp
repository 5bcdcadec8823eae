#include "filter/transfer_filter.h"
#include <algorithm>
#include <cmath>
#include <map>
#include <mutex>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

namespace {
constexpr double kPi = 3.14159265358979323846;
constexpr double kInvSqrt2Pi = 0.39894228040143267794;
constexpr double kLambdaMax = 1e8;

double clamp_lambda(double l) {
    if (!(l > 0.0)) return 0.0;  // also NaN
    return std::min(l, kLambdaMax);
}

/// Index of the segment [x[i], x[i+1]] holding v (v inside [x0, xn]).
size_t segment_of(const std::vector<double> &x, double v) {
    size_t i = size_t(std::upper_bound(x.begin(), x.end(), v) - x.begin());
    return i == 0 ? 0 : std::min(i - 1, x.size() - 2);
}

/// int_{za}^{zb} z^k phi(z) dz for k = 0, 1, 2 (za <= zb, either may be infinite). Narrow
/// intervals (zb - za < 0.01) use 4-point Gauss-Legendre: the closed forms are differences of
/// nearly equal CDF values there and lose all precision when sigma dwarfs a ramp segment.
void normal_partial_moments(double za, double zb, double m[3]) {
    if (std::isfinite(za) && std::isfinite(zb) && zb - za < 1e-2) {
        static const double x[4] = {-0.86113631159405258, -0.33998104358485626, 0.33998104358485626,
                                    0.86113631159405258};
        static const double w[4] = {0.34785484513745386, 0.65214515486254614, 0.65214515486254614,
                                    0.34785484513745386};
        const double c = 0.5 * (za + zb), h = 0.5 * (zb - za);
        m[0] = m[1] = m[2] = 0.0;
        for (int i = 0; i < 4; ++i) {
            const double z = c + h * x[i], f = w[i] * h * std_normal_pdf(z);
            m[0] += f;
            m[1] += f * z;
            m[2] += f * z * z;
        }
        return;
    }
    const double pa = std::isinf(za) ? 0.0 : std_normal_pdf(za), pb = std::isinf(zb) ? 0.0 : std_normal_pdf(zb);
    const double Pa = std_normal_cdf(za), Pb = std_normal_cdf(zb);
    m[0] = Pb - Pa;
    m[1] = pa - pb;
    const double za_pa = std::isinf(za) ? 0.0 : za * pa, zb_pb = std::isinf(zb) ? 0.0 : zb * pb;
    m[2] = m[0] + za_pa - zb_pb;
}
}  // namespace

double std_normal_pdf(double z) { return kInvSqrt2Pi * std::exp(-0.5 * z * z); }
double std_normal_cdf(double z) { return 0.5 * std::erfc(-z * 0.70710678118654752440); }

// ---------------------------------------------------------------------------------- Ramp

Ramp::Ramp(std::vector<double> x, std::vector<double> values, int channels)
    : m_x(std::move(x)), m_v(std::move(values)), m_ch(channels) {
    if (m_ch < 1) throw MesoError("ramp: channels must be >= 1");
    if (m_x.empty()) throw MesoError("ramp: needs at least one stop");
    if (m_v.size() != m_x.size() * size_t(m_ch)) throw MesoError("ramp: stop and value counts differ");
    for (size_t i = 0; i < m_x.size(); ++i) {
        if (!std::isfinite(m_x[i])) throw MesoError("ramp: stop positions must be finite");
        if (i > 0 && !(m_x[i] > m_x[i - 1])) throw MesoError("ramp: stop positions must increase strictly");
    }
    for (double v : m_v)
        if (!std::isfinite(v)) throw MesoError("ramp: values must be finite");
}

void Ramp::eval(double v, double *out) const {
    const size_t n = m_x.size();
    if (n == 1 || !(v > m_x.front())) {
        for (int c = 0; c < m_ch; ++c) out[c] = m_v[c];
        return;
    }
    if (v >= m_x.back()) {
        for (int c = 0; c < m_ch; ++c) out[c] = m_v[(n - 1) * m_ch + c];
        return;
    }
    const size_t i = segment_of(m_x, v);
    const double t = (v - m_x[i]) / (m_x[i + 1] - m_x[i]);
    for (int c = 0; c < m_ch; ++c) out[c] = (1 - t) * m_v[i * m_ch + c] + t * m_v[(i + 1) * m_ch + c];
}

void Ramp::derivative(double v, double *out) const {
    const size_t n = m_x.size();
    for (int c = 0; c < m_ch; ++c) out[c] = 0.0;
    if (n == 1 || v < m_x.front() || v >= m_x.back() || std::isnan(v)) return;
    const size_t i = segment_of(m_x, v);
    const double dx = m_x[i + 1] - m_x[i];
    for (int c = 0; c < m_ch; ++c) out[c] = (m_v[(i + 1) * m_ch + c] - m_v[i * m_ch + c]) / dx;
}

// The closed forms below integrate a polynomial of v over each piece against N(mean, sigma^2):
// with z = (v - mean) / sigma, v = mean + sigma z, so any polynomial in v is one in z and the
// partial moments of phi do the rest. Pieces: (-inf, x0] and [xn, inf) (constant: beta = 0) and
// the segments. `piece(m, alpha, beta, c)` adds channel c's integral of a function of
// alpha + beta sigma z (the ramp's value, alpha at v = mean) given m = int z^k phi, k = 0..2.
template <class Piece>
void Ramp::for_each_piece(double mean, double sigma, Piece piece) const {
    const size_t n = m_x.size();
    double m[3];
    normal_partial_moments(-INFINITY, (m_x.front() - mean) / sigma, m);
    for (int c = 0; c < m_ch; ++c) piece(m, m_v[c], 0.0, c);
    normal_partial_moments((m_x.back() - mean) / sigma, INFINITY, m);
    for (int c = 0; c < m_ch; ++c) piece(m, m_v[(n - 1) * m_ch + c], 0.0, c);
    for (size_t i = 0; i + 1 < n; ++i) {
        const double za = (m_x[i] - mean) / sigma, zb = (m_x[i + 1] - mean) / sigma;
        if (zb < -40.0 || za > 40.0) continue;
        normal_partial_moments(za, zb, m);
        const double dx = m_x[i + 1] - m_x[i];
        for (int c = 0; c < m_ch; ++c) {
            const double beta = (m_v[(i + 1) * m_ch + c] - m_v[i * m_ch + c]) / dx;
            piece(m, m_v[i * m_ch + c] + beta * (mean - m_x[i]), beta, c);
        }
    }
}

void Ramp::gaussian_average(double mean, double sigma, double *out) const {
    if (std::isinf(sigma) && sigma > 0) {  // the average over the whole line: the mean of the two ends
        const size_t n = m_x.size();
        for (int c = 0; c < m_ch; ++c) out[c] = 0.5 * (m_v[c] + m_v[(n - 1) * m_ch + c]);
        return;
    }
    if (!(sigma > 0.0) || !std::isfinite(sigma) || !std::isfinite(mean)) {
        eval(mean, out);
        return;
    }
    for (int c = 0; c < m_ch; ++c) out[c] = 0.0;
    for_each_piece(mean, sigma, [&](const double *m, double alpha, double beta, int c) {
        out[c] += alpha * m[0] + beta * sigma * m[1];
    });
}

void Ramp::gaussian_average_square(double mean, double sigma, double *out) const {
    if (!(sigma > 0.0) || !std::isfinite(sigma) || !std::isfinite(mean)) {
        eval(std::isfinite(mean) ? mean : (mean > 0 ? m_x.back() : m_x.front()), out);
        for (int c = 0; c < m_ch; ++c) out[c] *= out[c];
        if (std::isinf(sigma)) {
            const size_t n = m_x.size();
            for (int c = 0; c < m_ch; ++c) out[c] = 0.5 * (m_v[c] * m_v[c] + m_v[(n - 1) * m_ch + c] * m_v[(n - 1) * m_ch + c]);
        }
        return;
    }
    for (int c = 0; c < m_ch; ++c) out[c] = 0.0;
    for_each_piece(mean, sigma, [&](const double *m, double alpha, double beta, int c) {
        const double b = beta * sigma;  // (alpha + b z)^2
        out[c] += alpha * alpha * m[0] + 2 * alpha * b * m[1] + b * b * m[2];
    });
}

void Ramp::gaussian_average_derivative(double mean, double sigma, int power, double *out) const {
    if (power != 1 && power != 2) throw MesoError("Ramp::gaussian_average_derivative: power must be 1 or 2");
    for (int c = 0; c < m_ch; ++c) out[c] = 0.0;
    if (!(sigma > 0.0) || !std::isfinite(sigma) || !std::isfinite(mean)) {
        if (std::isfinite(mean) && !(sigma > 0.0)) {
            derivative(mean, out);
            if (power == 2)
                for (int c = 0; c < m_ch; ++c) out[c] *= out[c];
        }
        return;  // infinite sigma or mean: the derivative's support is bounded, the average is 0
    }
    for_each_piece(mean, sigma, [&](const double *m, double, double beta, int c) {
        out[c] += (power == 1 ? beta : beta * beta) * m[0];  // the tails have beta = 0
    });
}

std::string Ramp::to_string() const {
    return fmt::format("ramp[{} stops over [{:.4g}, {:.4g}], {} channel{}]", m_x.size(), m_x.front(), m_x.back(),
                       m_ch, m_ch == 1 ? "" : "s");
}

// ----------------------------------------------------------------------- PreconvolvedTable

PreconvolvedTable::PreconvolvedTable(int channels, double mean_min, double mean_max, double sigma_max, int n_mean,
                                     int n_sigma, const Function &average)
    : m_ch(channels), m_nm(n_mean), m_ns(n_sigma), m_m0(mean_min), m_m1(mean_max), m_smax(sigma_max) {
    if (channels < 1 || n_mean < 2 || n_sigma < 2 || !(mean_max > mean_min) || !(sigma_max > 0.0) ||
        !std::isfinite(mean_min) || !std::isfinite(mean_max) || !std::isfinite(sigma_max))
        throw MesoError(fmt::format("preconvolved table: invalid size {} x {} or range [{}, {}], sigma_max {}",
                                    n_mean, n_sigma, mean_min, mean_max, sigma_max));
    m_data.resize(size_t(n_mean) * n_sigma * channels);
    std::vector<double> tmp(channels);
    for (int j = 0; j < n_sigma; ++j) {
        const double t = double(j) / (n_sigma - 1);
        const double s = sigma_max * t * t;
        for (int i = 0; i < n_mean; ++i) {
            const double mu = mean_min + (mean_max - mean_min) * double(i) / (n_mean - 1);
            average(mu, s, tmp.data());
            for (int c = 0; c < channels; ++c) m_data[(size_t(j) * n_mean + i) * channels + c] = float(tmp[c]);
        }
    }
}

PreconvolvedTable PreconvolvedTable::of_ramp(const Ramp &ramp, double sigma_max, int n_mean, int n_sigma) {
    if (ramp.empty()) throw MesoError("preconvolved table: empty ramp");
    double lo = ramp.x_min() - 4.0 * sigma_max, hi = ramp.x_max() + 4.0 * sigma_max;
    if (!(hi > lo)) {  // one stop and sigma_max = 0
        lo -= 1.0;
        hi += 1.0;
    }
    return PreconvolvedTable(ramp.channels(), lo, hi, sigma_max, n_mean, n_sigma,
                             [&](double v, double s, double *out) { ramp.gaussian_average(v, s, out); });
}

bool PreconvolvedTable::lookup(double mean, double sigma, float *out) const {
    bool in_range = true;
    if (!(sigma >= 0.0)) sigma = 0.0;  // NaN too
    if (sigma > m_smax) {
        sigma = m_smax;
        in_range = false;
    }
    if (!std::isfinite(mean)) mean = mean > 0 ? m_m1 : m_m0;  // NaN -> m_m0
    const double fx = std::clamp((mean - m_m0) / (m_m1 - m_m0), 0.0, 1.0) * (m_nm - 1);
    const double fy = std::sqrt(sigma / m_smax) * (m_ns - 1);  // sigma_j = smax (j/(n-1))^2
    const int i0 = std::min(int(fx), m_nm - 2), j0 = std::min(int(fy), m_ns - 2);
    const float tx = float(fx - i0), ty = float(fy - j0);
    for (int c = 0; c < m_ch; ++c) {
        auto at = [&](int i, int j) { return m_data[(size_t(j) * m_nm + i) * m_ch + c]; };
        const float a = at(i0, j0) * (1 - tx) + at(i0 + 1, j0) * tx;
        const float b = at(i0, j0 + 1) * (1 - tx) + at(i0 + 1, j0 + 1) * tx;
        out[c] = a * (1 - ty) + b * ty;
    }
    return in_range;
}

// ------------------------------------------------------------------------ Height filter

double average_visibility(double lambda_o, double lambda_i) {
    const double lo = clamp_lambda(lambda_o), li = clamp_lambda(lambda_i);
    if (std::isinf(lambda_i) && lambda_i > 0) return 0.0;
    return (1.0 + lo) / (1.0 + lo + li);
}

HeightFilter height_filter_fit(double sigma_h, double lambda_sum, const HeightFitParams &f) {
    const double L = clamp_lambda(lambda_sum), s = std::max(0.0, std::isfinite(sigma_h) ? sigma_h : 0.0);
    HeightFilter r;
    r.mu = f.a_mu * s * std::log1p(f.b_mu * L);
    r.sigma = s / (1.0 + f.a_sigma * std::log1p(f.b_sigma * L));
    return r;
}

HeightFilter height_filter_exact(double sigma_h, double lambda_sum) {
    const double L = clamp_lambda(lambda_sum), s = std::max(0.0, std::isfinite(sigma_h) ? sigma_h : 0.0);
    // D(z) = (L + 1) Phi(z)^L phi(z). Its mass sits around sqrt(2 ln(L + 1)) (< 6.1 for L <=
    // 1e8) with width >= ~0.2; Simpson over [-9, 12] with 4200 intervals (h = 0.005).
    const int n = 4200;
    const double a = -9.0, b = 12.0, h = (b - a) / n;
    double m0 = 0, m1 = 0, m2 = 0;
    for (int k = 0; k <= n; ++k) {
        const double z = a + h * k;
        const double lphi = std::log(std::max(std_normal_cdf(z), 1e-300));
        const double d = std::exp(L * lphi) * std_normal_pdf(z);
        const double w = (k == 0 || k == n) ? 1.0 : (k % 2 ? 4.0 : 2.0);
        m0 += w * d;
        m1 += w * d * z;
        m2 += w * d * z * z;
    }
    HeightFilter r;
    if (!(m0 > 0.0)) return r;
    const double mu = m1 / m0;
    r.mu = s * mu;
    r.sigma = s * std::sqrt(std::max(0.0, m2 / m0 - mu * mu));
    return r;
}

HeightFilterTable::HeightFilterTable() {
    const int n = 256;
    const double xmax = std::log1p(kLambdaMax);
    m_dx = xmax / (n - 1);
    m_mu.resize(n);
    m_sigma.resize(n);
    for (int i = 0; i < n; ++i) {
        const HeightFilter f = height_filter_exact(1.0, std::expm1(m_dx * i));
        m_mu[i] = f.mu;
        m_sigma[i] = f.sigma;
    }
}

HeightFilter HeightFilterTable::lookup(double sigma_h, double lambda_sum) const {
    const double s = std::max(0.0, std::isfinite(sigma_h) ? sigma_h : 0.0);
    const double x = std::log1p(clamp_lambda(lambda_sum)) / m_dx;
    const int n = int(m_mu.size());
    const int i = std::min(int(x), n - 2);
    const double t = std::min(1.0, x - i);
    return {s * ((1 - t) * m_mu[i] + t * m_mu[i + 1]), s * ((1 - t) * m_sigma[i] + t * m_sigma[i + 1])};
}

const HeightFilterTable &HeightFilterTable::instance() {
    static const HeightFilterTable table;
    return table;
}

// ------------------------------------------------------------------------ Slope filter

SlopeGaussian visible_slope_gaussian(const SlopeGaussian &p, const Vec3 &wo, double *norm) {
    const double wz = std::max(1e-6, double(wo.z));
    const double tx = wo.x / wz, ty = wo.y / wz;
    const double a = std::sqrt(tx * tx + ty * ty);
    if (norm) *norm = 1.0;
    if (!(a > 1e-12) || !std::isfinite(a)) {
        if (norm) *norm = 1.0;
        return p;
    }
    const double ex = tx / a, ey = ty / a;  // t_hat
    // Sigma t_hat, v = t_hat^T Sigma t_hat, m = t_hat . s_bar
    const double qx = p.sxx * ex + p.sxy * ey, qy = p.sxy * ex + p.syy * ey;
    const double v = ex * qx + ey * qy, m = ex * p.mx + ey * p.my;
    if (!(v > 1e-300)) {  // no spread along t_hat: the weight is a constant
        if (norm) *norm = std::max(0.0, 1.0 - a * m);
        return p;
    }
    const double sd = std::sqrt(v);
    const double z = (1.0 - a * m) / (a * sd);  // (c - m) / sd, c = 1 / a
    double mu_u, var_u, M0;
    if (z < -12.0) {
        // Far below the mesosurface horizon: u = c - x, x ~ Gamma(2, sd / |z|).
        const double c = 1.0 / a;
        mu_u = c - 2.0 * sd / -z;
        var_u = 2.0 * v / (z * z);
        M0 = a * sd * (std_normal_pdf(z) + z * std_normal_cdf(z));
        if (!(M0 > 0.0)) M0 = 0.0;
    } else {
        const double P = std_normal_cdf(z), f = std_normal_pdf(z);
        const double c = 1.0 / a;
        // Truncated moments E[u^k 1{u < c}], k = 0..3.
        const double T0 = P;
        const double T1 = m * P - sd * f;
        const double T2 = (m * m + v) * P - sd * (c + m) * f;
        const double T3 = (m * m * m + 3 * m * v) * P - f * (3 * m * m * sd + 3 * m * v * z + v * sd * (z * z + 2));
        M0 = T0 - a * T1;
        const double M1 = T1 - a * T2, M2 = T2 - a * T3;
        if (!(M0 > 1e-300)) return p;
        mu_u = M1 / M0;
        var_u = std::max(0.0, M2 / M0 - mu_u * mu_u);
    }
    if (norm) *norm = M0;
    SlopeGaussian d;
    const double k1 = (mu_u - m) / v;
    d.mx = p.mx + qx * k1;
    d.my = p.my + qy * k1;
    const double k2 = (v - var_u) / (v * v);
    d.sxx = std::max(0.0, p.sxx - qx * qx * k2);
    d.syy = std::max(0.0, p.syy - qy * qy * k2);
    d.sxy = p.sxy - qx * qy * k2;
    return d;
}

// ------------------------------------------------------------------------ Gauss-Hermite

void gauss_hermite_normal(int n, std::vector<double> &x, std::vector<double> &w) {
    if (n < 1 || n > 64) throw MesoError(fmt::format("gauss_hermite_normal: order {} outside [1, 64]", n));
    static std::mutex mutex;
    static std::map<int, std::pair<std::vector<double>, std::vector<double>>> cache;
    {
        std::lock_guard<std::mutex> lock(mutex);
        auto it = cache.find(n);
        if (it != cache.end()) {
            x = it->second.first;
            w = it->second.second;
            return;
        }
    }
    // Physicists' rule (weight exp(-t^2)) by Newton on the orthonormal recurrence
    // (Numerical Recipes' gauher), then t -> sqrt(2) t, w -> w / sqrt(pi).
    std::vector<double> t(n), wt(n);
    const double pim4 = 0.7511255444649425;  // pi^(-1/4)
    double z = 0;
    for (int i = 0; i < (n + 1) / 2; ++i) {
        if (i == 0) z = std::sqrt(2.0 * n + 1) - 1.85575 * std::pow(2.0 * n + 1, -0.16667);
        else if (i == 1) z -= 1.14 * std::pow(double(n), 0.426) / z;
        else if (i == 2) z = 1.86 * z - 0.86 * t[0];
        else if (i == 3) z = 1.91 * z - 0.91 * t[1];
        else z = 2.0 * z - t[i - 2];
        double pp = 0;
        for (int it = 0; it < 100; ++it) {
            double p1 = pim4, p2 = 0;
            for (int j = 0; j < n; ++j) {
                const double p3 = p2;
                p2 = p1;
                p1 = z * std::sqrt(2.0 / (j + 1)) * p2 - std::sqrt(double(j) / (j + 1)) * p3;
            }
            pp = std::sqrt(2.0 * n) * p2;
            const double z1 = z;
            z = z1 - p1 / pp;
            if (std::fabs(z - z1) <= 1e-15) break;
        }
        t[i] = z;
        t[n - 1 - i] = -z;
        wt[i] = wt[n - 1 - i] = 2.0 / (pp * pp);
    }
    x.assign(n, 0.0);
    w.assign(n, 0.0);
    double sum = 0;
    for (int i = 0; i < n; ++i) {
        x[n - 1 - i] = std::sqrt(2.0) * t[i];  // ascending
        w[n - 1 - i] = wt[i] / std::sqrt(kPi);
        sum += w[n - 1 - i];
    }
    for (double &v : w) v /= sum;  // exactly 1 (round-off)
    std::lock_guard<std::mutex> lock(mutex);
    cache[n] = {x, w};
}

void gaussian_expectation_2d(const SlopeGaussian &g, int n, int channels,
                             const std::function<void(double, double, double *)> &f, double *out) {
    std::vector<double> x, w;
    gauss_hermite_normal(n, x, w);
    const double sxx = std::max(0.0, g.sxx), syy = std::max(0.0, g.syy);
    const double l00 = std::sqrt(sxx);
    const double l10 = l00 > 0.0 ? g.sxy / l00 : 0.0;
    const double l11 = std::sqrt(std::max(0.0, syy - l10 * l10));
    std::vector<double> tmp(channels);
    for (int c = 0; c < channels; ++c) out[c] = 0.0;
    for (int i = 0; i < n; ++i)
        for (int j = 0; j < n; ++j) {
            const double sx = g.mx + l00 * x[i], sy = g.my + l10 * x[i] + l11 * x[j];
            f(sx, sy, tmp.data());
            const double ww = w[i] * w[j];
            for (int c = 0; c < channels; ++c) out[c] += ww * tmp[c];
        }
}

void gaussian_average_steepness(const Ramp &ramp, const SlopeGaussian &g, double *out) {
    const int ch = ramp.channels();
    const double sxx = std::max(0.0, g.sxx), syy = std::max(0.0, g.syy);
    const double tr = sxx + syy, dd = std::sqrt(std::max(0.0, 0.25 * (sxx - syy) * (sxx - syy) + g.sxy * g.sxy));
    const double smax = std::sqrt(0.5 * tr + dd), smin = std::sqrt(std::max(0.0, 0.5 * tr - dd));
    const double mlen = std::sqrt(g.mx * g.mx + g.my * g.my);
    if (!(smax > 0.0) || smax < 0.2 * mlen || !std::isfinite(smax) || !std::isfinite(mlen)) {
        // |s| is smooth over the whole distribution: Gauss-Hermite converges fast.
        gaussian_expectation_2d(g, 12, ch, [&](double x, double y, double *o) { ramp.eval(std::sqrt(x * x + y * y), o); },
                                out);
        return;
    }
    // Polar coordinates about s = 0. Along a direction u the density is r N(r u) =
    // norm K(u) r exp(-(r - m)^2 / (2 s^2)) with a = u^T P u, b = u^T P mean, m = b / a, s^2 = 1 / a,
    // K = exp(-(c - b^2 / a) / 2), c = mean^T P mean (P = Sigma^-1): on each piece of the ramp
    // (alpha + beta r) the radial integral is closed-form in the partial moments of phi. The angle
    // is integrated by the trapezoid rule (periodic and smooth: spectral accuracy) with enough
    // nodes for the distribution's angular width seen from s = 0.
    const double eps = 1e-12 * tr + 1e-300;
    const double A = sxx + eps, B = g.sxy, Cc = syy + eps;
    const double det = std::max(A * Cc - B * B, 1e-30 * A * Cc);
    const double pa = Cc / det, pb = -B / det, pc = A / det;
    const double c0 = pa * g.mx * g.mx + 2 * pb * g.mx * g.my + pc * g.my * g.my;
    const double width = std::max(1e-3, smin / std::max(mlen, smax));  // radians, roughly
    const int nphi = std::clamp(int(std::ceil(2.0 * kPi / (0.7 * width))), 16, 256);
    const std::vector<double> &xs = ramp.x(), &vs = ramp.values();
    const size_t nstops = xs.size();
    std::vector<double> acc(static_cast<size_t>(ch), 0.0), al(static_cast<size_t>(ch)), be(static_cast<size_t>(ch));
    double mass = 0;
    for (int k = 0; k < nphi; ++k) {
        const double phi = 2.0 * kPi * k / nphi, ux = std::cos(phi), uy = std::sin(phi);
        const double a = pa * ux * ux + 2 * pb * ux * uy + pc * uy * uy;
        const double b = pa * ux * g.mx + pb * (ux * g.my + uy * g.mx) + pc * uy * g.my;
        if (!(a > 0.0)) continue;
        const double m = b / a, sd = 1.0 / std::sqrt(a);
        const double lk = -0.5 * (c0 - b * b / a);
        if (lk < -700.0) continue;
        const double K = std::exp(lk) * sd;  // with the 1/sqrt(2 pi) of phi folded into norm below
        // Pieces in r: [0, x_i] ... with C = alpha + beta r; constant beyond the end stops.
        auto piece = [&](double r0, double r1, const double *alpha, const double *beta) {
            if (!(r1 > r0)) return;
            double M[3];
            normal_partial_moments((r0 - m) / sd, std::isinf(r1) ? INFINITY : (r1 - m) / sd, M);
            // int r (alpha + beta r) phi dz with r = m + sd z
            const double I1 = m * M[0] + sd * M[1];                          // int r
            const double I2 = m * m * M[0] + 2 * m * sd * M[1] + sd * sd * M[2];  // int r^2
            mass += K * I1;
            for (int c = 0; c < ch; ++c) acc[size_t(c)] += K * (alpha[c] * I1 + (beta ? beta[c] * I2 : 0.0));
        };
        double r = 0.0;
        size_t s0 = 0;
        while (s0 < nstops && xs[s0] <= 0.0) ++s0;  // stops at or below r = 0
        // Below the first positive stop: the ramp between stop s0 - 1 and s0 (or constant).
        for (size_t i = s0; i <= nstops; ++i) {
            const double r1 = i < nstops ? xs[i] : INFINITY;
            if (i == 0 || i == nstops) {  // constant beyond an end stop
                const size_t e = i == 0 ? 0 : nstops - 1;
                for (int c = 0; c < ch; ++c) al[size_t(c)] = vs[e * size_t(ch) + size_t(c)];
                piece(r, r1, al.data(), nullptr);
            } else {
                const double dx = xs[i] - xs[i - 1];
                for (int c = 0; c < ch; ++c) {
                    const double v0 = vs[(i - 1) * size_t(ch) + size_t(c)], v1 = vs[i * size_t(ch) + size_t(c)];
                    be[size_t(c)] = (v1 - v0) / dx;
                    al[size_t(c)] = v0 - be[size_t(c)] * xs[i - 1];
                }
                piece(r, r1, al.data(), be.data());
            }
            r = r1;
        }
    }
    if (!(mass > 0.0)) {
        gaussian_expectation_2d(g, 12, ch, [&](double x, double y, double *o) { ramp.eval(std::sqrt(x * x + y * y), o); },
                                out);
        return;
    }
    for (int c = 0; c < ch; ++c) out[c] = acc[size_t(c)] / mass;
}

Vec3 slope_to_normal(double sx, double sy) {
    const double inv = 1.0 / std::sqrt(1.0 + sx * sx + sy * sy);
    return Vec3(float(-sx * inv), float(-sy * inv), float(inv));
}

// ------------------------------------------------------------------------ Transfer (§7)

TransferMoments transfer_moments(const Ramp &g, double f_bar, double sigma_f) {
    if (g.channels() != 1) throw MesoError("transfer_moments: the transfer function must have one channel");
    TransferMoments m;
    g.gaussian_average(f_bar, sigma_f, &m.g);
    g.gaussian_average_square(f_bar, sigma_f, &m.g2);
    g.gaussian_average_derivative(f_bar, sigma_f, 1, &m.dg);
    g.gaussian_average_derivative(f_bar, sigma_f, 2, &m.dg2);
    return m;
}

TransferredStatistics transferred_statistics(const TransferMoments &m, const SlopeGaussian &f) {
    TransferredStatistics r;
    r.h_mean = m.g;
    r.h_var = std::max(0.0, m.g2 - m.g * m.g);
    // Second moments of f's slopes (about zero), then eq. (24-26), then centred again.
    const double exx = f.sxx + f.mx * f.mx, eyy = f.syy + f.my * f.my, exy = f.sxy + f.mx * f.my;
    r.slopes.mx = m.dg * f.mx;
    r.slopes.my = m.dg * f.my;
    r.slopes.sxx = std::max(0.0, m.dg2 * exx - r.slopes.mx * r.slopes.mx);
    r.slopes.syy = std::max(0.0, m.dg2 * eyy - r.slopes.my * r.slopes.my);
    r.slopes.sxy = m.dg2 * exy - r.slopes.mx * r.slopes.my;
    return r;
}

}  // namespace meso
