// Error metrics of a test image against a reference (see image/image.h).
//
// Over the N pixels included and their three RGB channels (grey images count as
// r = g = b):
//   MSE    = 1/(3N) sum (t - r)^2
//   relMSE = 1/(3N) sum (t - r)^2 / (r^2 + 1e-2)     (eps as in paper 004 / LoD literature)
//   RMSE   = sqrt(MSE)
//   PSNR   = 10 log10(peak^2 / MSE) with peak = 1 (display white of a linear HDR image;
//            +inf when MSE = 0). Radiance above 1 is not clamped, so PSNR of HDR images
//            is only comparable between renders of the same scene.
//   mean luminance ratio = mean Y(test) / mean Y(ref) (Rec. 709 Y); 1 when both are 0.
// A pixel whose test value has a NaN/Inf channel is counted in `nonfinite` and left out
// of every sum; so is a pixel whose reference is not finite (a reference should never
// have any; it is not counted). Sums in double precision.
#include <cmath>
#include <fmt/format.h>
#include <limits>
#include "core/error.h"
#include "image/image.h"

namespace meso {

ImageMetrics compute_metrics(const Image &test, const Image &ref) {
    if (test.width != ref.width || test.height != ref.height)
        throw MesoError(fmt::format("image sizes differ: {}x{} vs {}x{}", test.width, test.height, ref.width, ref.height));
    ImageMetrics m;
    double se = 0, rel = 0, lum_t = 0, lum_r = 0;
    long n = 0;
    for (int y = 0; y < test.height; ++y)
        for (int x = 0; x < test.width; ++x) {
            Spectrum t = test.rgb(x, y), r = ref.rgb(x, y);
            if (!t.is_finite()) {
                ++m.nonfinite;
                continue;
            }
            if (!r.is_finite()) continue;
            for (int c = 0; c < 3; ++c) {
                double d = double(t[c]) - double(r[c]);
                se += d * d;
                rel += d * d / (double(r[c]) * double(r[c]) + 1e-2);
            }
            lum_t += t.luminance();
            lum_r += r.luminance();
            ++n;
        }
    if (n == 0) {
        double nan = std::numeric_limits<double>::quiet_NaN();
        m.mse = m.relmse = m.rmse = m.psnr = m.mean_luminance_ratio = nan;
        return m;
    }
    m.mse = se / (3.0 * n);
    m.relmse = rel / (3.0 * n);
    m.rmse = std::sqrt(m.mse);
    m.psnr = m.mse > 0 ? 10.0 * std::log10(1.0 / m.mse) : std::numeric_limits<double>::infinity();
    if (lum_r != 0) m.mean_luminance_ratio = lum_t / lum_r;
    else m.mean_luminance_ratio = lum_t == 0 ? 1.0 : std::numeric_limits<double>::infinity();
    return m;
}

}  // namespace meso
