#include "image/false_colour.h"
#include <cmath>

namespace meso {

namespace {
// matplotlib's viridis at t = i / 16, i = 0..16 (sRGB-encoded). Piecewise-linear
// interpolation over 17 points deviates from the 256-entry table by < 1/255.
constexpr float kViridis[17][3] = {
    {0.267004f, 0.004874f, 0.329415f}, {0.282327f, 0.094955f, 0.417331f}, {0.278826f, 0.175490f, 0.483397f},
    {0.258965f, 0.251537f, 0.524736f}, {0.229739f, 0.322361f, 0.545706f}, {0.199430f, 0.387607f, 0.554642f},
    {0.172719f, 0.448791f, 0.557885f}, {0.149039f, 0.508051f, 0.557250f}, {0.127568f, 0.566949f, 0.550556f},
    {0.120638f, 0.625828f, 0.533488f}, {0.157851f, 0.683765f, 0.501686f}, {0.246070f, 0.738910f, 0.452024f},
    {0.369214f, 0.788888f, 0.382914f}, {0.515992f, 0.831158f, 0.294279f}, {0.678489f, 0.863742f, 0.189503f},
    {0.845561f, 0.887322f, 0.099702f}, {0.993248f, 0.906157f, 0.143936f},
};
}  // namespace

Spectrum viridis_srgb(float t) {
    t = std::isnan(t) ? 0.f : clamp(t, 0.f, 1.f);
    float x = t * 16.f;
    int i = std::min(int(x), 15);
    float f = x - float(i);
    Spectrum c;
    for (int k = 0; k < 3; ++k) c[k] = (1.f - f) * kViridis[i][k] + f * kViridis[i + 1][k];
    return c;
}

Spectrum viridis_linear(float t) {
    Spectrum c = viridis_srgb(t);
    return Spectrum(srgb_to_linear(c.r), srgb_to_linear(c.g), srgb_to_linear(c.b));
}

Image false_colour_log(const std::vector<double> &values, int width, int height, double log_lo, double log_hi) {
    Image img(width, height, 3);
    double span = log_hi > log_lo ? log_hi - log_lo : 1.0;
    for (int y = 0; y < height; ++y)
        for (int x = 0; x < width; ++x) {
            double v = values[size_t(y) * width + x];
            Spectrum c;
            if (!std::isfinite(v)) c = Spectrum(1.f, 0.f, 1.f);
            else if (v <= 0) c = viridis_linear(0.f);
            else c = viridis_linear(float((std::log10(v) - log_lo) / span));
            img.set_rgb(x, y, c);
        }
    return img;
}

}  // namespace meso
