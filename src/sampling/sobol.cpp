// `sobol` sampler: Owen-scrambled, shuffled 2D Sobol points per dimension pair
// (Burley 2020, "Practical Hash-based Owen Scrambling", JCGT 9(4), sections 3-5; the
// same construction as pbrt-v4's PaddedSobolSampler with FastOwen scrambling).
//
// Construction, for sample `index` of pixel p and the call that consumes dimension slot d:
//  1. h = hash(p, d, seed), one 64-bit hash per (pixel, dimension slot).
//  2. Shuffle: i' = nested_uniform_scramble(index, h_lo). Owen scrambling of the index
//     as a base-2 fraction with reversed digits; the first 2^k indices map one-to-one
//     onto an aligned block of 2^k Sobol indices, so every power-of-two prefix of a
//     pixel's samples is still a net, while different dimension pairs see the points in
//     independent random orders (this is what decorrelates the pairs: "padding").
//  3. Points: get_2d returns (Sobol dim 0, Sobol dim 1) of i' - van der Corput and
//     Pascal's matrix, a (0, 2)-sequence, generated in closed form (sampling/owen.h) -
//     each coordinate Owen-scrambled with its own seed derived from h.
//     get_1d returns the Owen-scrambled van der Corput value of i' (1D padding).
// Owen scrambling keeps the (0, m, 2)-net property: for N = 2^m samples per pixel each
// elementary interval of area 1/N of every dimension pair holds exactly one point; for
// smooth integrands the error falls like N^-1.5 instead of N^-0.5. Sample counts need
// not be powers of two (any prefix is well distributed) but powers of two are best.
// A sample is a pure function of (pixel, index, seed, dimension), as the Sampler
// contract requires; the number of samples per pixel is not needed.
//
// | parameter | type | default | meaning                                |
// |-----------|------|---------|----------------------------------------|
// | seed      | int  | 0       | decorrelates renders of the same scene |
// ("sample_count" is read by the scene loader, not here.)
#include <memory>
#include "sampling/owen.h"
#include "sampling/rng.h"
#include "sampling/sampler.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class SobolSampler final : public Sampler {
public:
    explicit SobolSampler(uint64_t seed) { set_seed(seed); }

    void start(int px, int py, uint32_t index) override {
        m_pixel_hash = hash_combine(mix_bits(uint64_t(uint32_t(px)) | (uint64_t(uint32_t(py)) << 32)), m_seed);
        m_index = index;
        m_dimension = 0;
    }
    float get_1d() override {
        uint64_t h = next_hash(1);
        uint32_t i = nested_uniform_scramble(m_index, uint32_t(h));
        return fixed_to_float(nested_uniform_scramble(sobol_dim0(i), uint32_t(h >> 32)));
    }
    Vec2 get_2d() override {
        uint64_t h = next_hash(2);
        uint64_t h2 = mix_bits(h ^ 0x6a09e667f3bcc909ULL);
        uint32_t i = nested_uniform_scramble(m_index, uint32_t(h));
        float x = fixed_to_float(nested_uniform_scramble(sobol_dim0(i), uint32_t(h >> 32)));
        float y = fixed_to_float(nested_uniform_scramble(sobol_dim1(i), uint32_t(h2)));
        return Vec2(x, y);
    }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<SobolSampler>(m_seed); }
    std::string name() const override { return "sobol"; }

private:
    /// Hash of (pixel, seed, dimension slot); a 2D request consumes two slots (as pbrt).
    uint64_t next_hash(uint32_t slots) {
        uint64_t h = hash_combine(m_pixel_hash, m_dimension);
        m_dimension += slots;
        return h;
    }

    uint64_t m_pixel_hash = 0;
    uint32_t m_index = 0, m_dimension = 0;
};

MESO_REGISTER_SAMPLER("sobol",
                      "Owen-scrambled, shuffled 2D Sobol (0,2)-sequence per dimension pair (Burley 2020); "
                      "parameter: seed",
                      [](const Properties &p) -> std::shared_ptr<Sampler> {
                          return std::make_shared<SobolSampler>(uint64_t(p.get_int("seed", 0, Range::non_negative())));
                      });

}  // namespace
}  // namespace meso
