// Gauss–Legendre quadrature rules of any order (the fixed small tables used by hot paths,
// e.g. render/microfacet's 32-point rule, stay where they are).
#pragma once
#include <vector>

namespace meso {

/// n-point Gauss–Legendre nodes (ascending) and weights on [0, 1] (n >= 1; roots of P_n by
/// Newton from Tricomi's guess, double precision; weights sum to 1). MesoError for n < 1.
void gauss_legendre_01(int n, std::vector<double> &x, std::vector<double> &w);

}  // namespace meso
