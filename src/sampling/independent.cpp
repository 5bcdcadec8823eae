// `independent` sampler: uniform pseudo-random numbers, no stratification.
//
// Each pixel sample owns one PCG32 stream selected by hashing (pixel x, pixel y, sample
// index, seed); dimension d is the d-th number drawn from that stream. A sample is thus
// a pure function of (x, y, index, seed, dimension): independent of threads, tile order
// and of what other pixels or samples were drawn before.
//
// | parameter | type | default | meaning                                  |
// |-----------|------|---------|------------------------------------------|
// | seed      | int  | 0       | decorrelates renders of the same scene   |
// ("sample_count" is read by the scene loader, not here.)
#include <memory>
#include "sampling/rng.h"
#include "sampling/sampler.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

class IndependentSampler final : public Sampler {
public:
    explicit IndependentSampler(uint64_t seed) { set_seed(seed); }

    void start(int px, int py, uint32_t index) override {
        uint64_t pixel = uint64_t(uint32_t(px)) | (uint64_t(uint32_t(py)) << 32);
        uint64_t h = hash_combine(hash_combine(mix_bits(pixel), index), m_seed);
        // Stream (increment) and start state both from the hash: distinct samples get
        // distinct streams, not just offsets on one stream.
        m_rng.seed(mix_bits(h ^ 0xa0761d6478bd642fULL), h);
    }
    float get_1d() override { return m_rng.next_float(); }
    Vec2 get_2d() override {
        float x = m_rng.next_float();
        float y = m_rng.next_float();
        return Vec2(x, y);
    }
    std::unique_ptr<Sampler> clone() const override { return std::make_unique<IndependentSampler>(m_seed); }
    std::string name() const override { return "independent"; }

private:
    PCG32 m_rng;
};

MESO_REGISTER_SAMPLER("independent", "uniform pseudo-random samples (PCG32 per pixel sample); parameter: seed",
                      [](const Properties &p) -> std::shared_ptr<Sampler> {
                          return std::make_shared<IndependentSampler>(uint64_t(p.get_int("seed", 0, Range::non_negative())));
                      });

}  // namespace
}  // namespace meso
