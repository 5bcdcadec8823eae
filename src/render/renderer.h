// The shared render loop: whole-image passes of tiles rendered in parallel with TBB,
// under a sample budget (--spp) or a wall-clock budget (--time), with progress, a NaN
// guard, and optional per-pass error against a reference. A crop window (--crop) renders
// only its pixels, with exactly the samples a full render gives them.
#pragma once
#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <string>
#include <vector>
#include "image/image.h"

namespace meso {

class Scene;

struct RenderOptions {
    int spp = 0;                ///< total samples per pixel (0: the scene's sampler count)
    double time_budget_s = 0;   ///< > 0: equal-time mode, render whole passes until spent
    int threads = 0;            ///< 0: all cores
    std::optional<uint64_t> seed;  ///< overrides the sampler's seed when set
    bool progress = true;       ///< progress/ETA on stderr
    /// Render only the pixels [x0, x1) x [y0, y1) of the camera's image ({x0, y0, x1, y1}); pixel
    /// coordinates (and so every sample) stay those of the full image, and the result's image is
    /// the window's size. Checked by check_crop.
    std::optional<std::array<int, 4>> crop;
    const Image *reference = nullptr;    ///< per-pass error (for --convergence); the window's size
    std::string convergence_csv;         ///< write "pass,elapsed_s,spp,mse,relmse" rows here
    /// Polled after every pass (on rank 0; its answer is broadcast): true ends the render early,
    /// keeping the passes done (RenderResult::interrupted). E.g. core/interrupt.h's
    /// interrupt_requested for Ctrl-C.
    std::function<bool()> stop;
};

struct RenderResult {
    Image image;
    double wall_s = 0;       ///< rendering time (excludes loading and BVH build)
    int spp = 0;             ///< samples per pixel actually rendered
    int passes = 0;
    uint64_t rays = 0;       ///< all rays (camera, extension and shadow)
    uint64_t shadow_rays = 0;
    double rays_per_s = 0;
    long nan_count = 0;      ///< NaN/Inf samples caught by the film (counted as 0)
    int threads = 0;         ///< per rank
    int ranks = 1;           ///< MPI ranks that rendered (the image, spp and counters are their sum)
    bool interrupted = false;  ///< stopped early by RenderOptions::stop (spp < the budget)
};

/// With several MPI ranks (core/distributed.h) every rank must call this; the result's image and
/// counters are complete on rank 0 only.
RenderResult render(const Scene &scene, const RenderOptions &opts);

/// Throws MesoError naming --crop and the image size unless 0 <= x0 < x1 <= width and
/// 0 <= y0 < y1 <= height.
void check_crop(const std::array<int, 4> &crop, int width, int height);

/// Peak resident memory of this process in MB (getrusage).
double peak_rss_mb();

/// Bytes of the film of a w x h render (double sums + the float image), as `--plan` counts it.
size_t film_bytes(int width, int height);


}  // namespace meso
