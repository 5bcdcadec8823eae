#include "core/quadrature.h"
#include <cmath>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

void gauss_legendre_01(int n, std::vector<double> &x, std::vector<double> &w) {
    if (n < 1) throw MesoError(fmt::format("gauss_legendre_01: n must be >= 1, got {}", n));
    constexpr double kPi = 3.14159265358979323846;
    x.assign(size_t(n), 0.0);
    w.assign(size_t(n), 0.0);
    // P_n(z) by the three-term recurrence and P_n'(z) = n (z P_n - P_{n-1}) / (z² - 1).
    auto legendre = [n](double z, double &dp) {
        double p0 = 1.0, p1 = 0.0;
        for (int k = 1; k <= n; ++k) {
            const double p2 = p1;
            p1 = p0;
            p0 = ((2.0 * k - 1.0) * z * p1 - (k - 1.0) * p2) / k;
        }
        dp = n * (z * p0 - p1) / (z * z - 1.0);
        return p0;
    };
    for (int i = 0; i < (n + 1) / 2; ++i) {
        // Root of P_n on [-1, 1] by Newton from the Tricomi guess, then mapped to [0, 1].
        double z = std::cos(kPi * (i + 0.75) / (n + 0.5)), dp = 1.0;
        for (int it = 0; it < 100; ++it) {
            const double dz = legendre(z, dp) / dp;
            z -= dz;
            if (std::abs(dz) < 1e-16) break;
        }
        legendre(z, dp);  // the derivative at the converged root, for the weight
        const double wt = 2.0 / ((1.0 - z * z) * dp * dp);
        // z > 0 for i < n/2: node i is 0.5 - z/2, its mirror 0.5 + z/2.
        x[size_t(n - 1 - i)] = 0.5 + 0.5 * z;
        x[size_t(i)] = 0.5 - 0.5 * z;
        w[size_t(n - 1 - i)] = w[size_t(i)] = 0.5 * wt;
    }
    if (n % 2 == 1) x[size_t(n / 2)] = 0.5;  // exact middle node
}

}  // namespace meso
