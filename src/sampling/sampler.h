// Samplers hand out the random numbers of one pixel sample. A sample is identified by
// (pixel, sample index, seed) alone, so images are independent of thread count and tile
// order, and a render can be split over sample ranges (passes, ranks) deterministically.
#pragma once
#include <memory>
#include <string>
#include "core/vec.h"

namespace meso {

class Properties;

class Sampler {
public:
    virtual ~Sampler() = default;
    /// Positions the sampler at sample `index` of pixel (px, py), dimension 0.
    void start_pixel_sample(int px, int py, uint32_t index) {
        m_px = px;
        m_py = py;
        start(px, py, index);
    }
    /// The pixel of the current sample (start_pixel_sample's); (-1, -1) before the first. An
    /// integrator may key per-pixel state on it (path.cpp: the LoD level hint of a pixel).
    int pixel_x() const { return m_px; }
    int pixel_y() const { return m_py; }
    virtual float get_1d() = 0;
    virtual Vec2 get_2d() = 0;
    /// Independent copy for another thread (same seed and settings).
    virtual std::unique_ptr<Sampler> clone() const = 0;
    virtual std::string name() const = 0;
    uint64_t seed() const { return m_seed; }
    void set_seed(uint64_t s) { m_seed = s; }

protected:
    /// start_pixel_sample of the implementation.
    virtual void start(int px, int py, uint32_t index) = 0;
    uint64_t m_seed = 0;

private:
    int m_px = -1, m_py = -1;
};

}  // namespace meso
