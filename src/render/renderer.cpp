#include "render/renderer.h"
#include "core/phase.h"
#include <sys/resource.h>
#include <tbb/blocked_range2d.h>
#include <tbb/enumerable_thread_specific.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/partitioner.h>
#include <unistd.h>
#include <atomic>
#include <chrono>
#include <cmath>
#include <fstream>
#include <fmt/format.h>
#include "core/distributed.h"
#include "core/error.h"
#include "core/progress.h"
#include "sampling/sampler.h"
#include "render/scene.h"

namespace meso {

double peak_rss_mb() {
    struct rusage ru;
    getrusage(RUSAGE_SELF, &ru);
    return ru.ru_maxrss / 1024.0;  // kB on Linux
}

size_t film_bytes(int width, int height) { return size_t(width) * size_t(height) * (3 * sizeof(double) + 3 * sizeof(float)); }

namespace {

/// Accumulates samples per pixel in double precision. Each pixel is written by one
/// thread per pass and its samples are added in sample-index order, so the image is
/// independent of the thread count.
struct Film {
    int w, h;
    std::vector<double> sum;
    std::atomic<long> nan_count{0};
    Film(int w_, int h_) : w(w_), h(h_), sum(size_t(w_) * h_ * 3, 0.0) {}
    Image resolve(int spp) const {
        Image img(w, h, 3);
        double inv = spp > 0 ? 1.0 / spp : 0.0;
        for (size_t i = 0; i < sum.size(); ++i) img.data[i] = float(sum[i] * inv);
        return img;
    }
};

/// 16x16 tiles: a 320x240 pass has 300 of them, so that the threads' last tiles (whose cost
/// varies tenfold between background and detailed surface) leave little idle time at the
/// pass's end (32x32: 80 tiles, 5 per thread at 16 threads; scripts/experiments/thread_scaling).
constexpr int TileSize = 16;

}  // namespace

void check_crop(const std::array<int, 4> &c, int width, int height) {
    if (!(0 <= c[0] && c[0] < c[2] && c[2] <= width && 0 <= c[1] && c[1] < c[3] && c[3] <= height))
        throw MesoError(fmt::format("--crop {},{},{},{}: the window must lie in the {}x{} image "
                                    "(0 <= X0 < X1 <= {}, 0 <= Y0 < Y1 <= {})",
                                    c[0], c[1], c[2], c[3], width, height, width, height));
}

namespace {

/// The pixels rendered: [x0, x0 + w) x [y0, y0 + h) of the full image (the whole image without
/// --crop). Pixel coordinates stay those of the full image, so every sample is seeded as in a
/// full render.
struct Window {
    int x0, y0, w, h;
};

/// One pass: sample indices [first, first + n) of every pixel of the window, tiles in parallel.
void render_pass(const Scene &scene, const RenderOptions &opts, const Window &win, int first, int n, float diff_scale,
                 Film &film, tbb::enumerable_thread_specific<RenderStats> &stats) {
    const int tiles_x = (win.w + TileSize - 1) / TileSize, tiles_y = (win.h + TileSize - 1) / TileSize;
    // Camera rays carry differentials only where the integrator reads them (asked after its
    // preprocess): otherwise two camera rays less per sample.
    const bool differentials = scene.integrator->camera_differentials(scene);
    // One task a tile (simple_partitioner): the auto partitioner hands out chunks of several
    // tiles, and the last chunk of a pass kept the other threads waiting.
    tbb::parallel_for(
        tbb::blocked_range2d<int>(0, tiles_y, 1, 0, tiles_x, 1),
        [&](const tbb::blocked_range2d<int> &r) {
        std::unique_ptr<Sampler> sampler = scene.sampler->clone();
        if (opts.seed) sampler->set_seed(*opts.seed);
        RenderStats &st = stats.local();
        for (int ty = r.rows().begin(); ty < r.rows().end(); ++ty)
            for (int tx = r.cols().begin(); tx < r.cols().end(); ++tx) {
                // Tiles are laid over the window; x, y are full-image pixel coordinates.
                const int x1 = win.x0 + std::min(win.w, (tx + 1) * TileSize);
                const int y1 = win.y0 + std::min(win.h, (ty + 1) * TileSize);
                for (int y = win.y0 + ty * TileSize; y < y1; ++y)
                    for (int x = win.x0 + tx * TileSize; x < x1; ++x) {
                        double *px = &film.sum[(size_t(y - win.y0) * win.w + (x - win.x0)) * 3];
                        for (int s = first; s < first + n; ++s) {
                            sampler->start_pixel_sample(x, y, uint32_t(s));
                            CameraSample cs;
                            Vec2 j = sampler->get_2d();
                            cs.film = Vec2(x + j.x, y + j.y);
                            cs.lens = sampler->get_2d();
                            RayDifferential ray;
                            float w;
                            {
                                PhaseScope phase(Phase::Camera);
                                if (differentials) {
                                    w = scene.camera->generate_ray(cs, ray);
                                    ray.scale_differentials(diff_scale);
                                } else {
                                    w = scene.camera->generate_ray_no_differentials(cs, ray);
                                    ray.footprint_scale *= diff_scale;
                                }
                            }
                            Spectrum L = scene.integrator->li(scene, ray, *sampler, st) * w;
                            if (!L.is_finite()) {
                                film.nan_count.fetch_add(1, std::memory_order_relaxed);
                                continue;
                            }
                            PhaseScope phase(Phase::Film);
                            px[0] += L.r;
                            px[1] += L.g;
                            px[2] += L.b;
                        }
                    }
            }
        },
        tbb::simple_partitioner());
}

/// The --convergence log (pass, elapsed, spp, MSE, relMSE after every pass), or null.
std::unique_ptr<std::ofstream> open_convergence_log(const RenderOptions &opts, int ranks) {
    if (opts.convergence_csv.empty()) return nullptr;
    if (!opts.reference) throw MesoError("--convergence needs --reference");
    if (ranks > 1) throw MesoError("--convergence is not supported with several MPI ranks (it needs the whole film after every pass)");
    auto csv = std::make_unique<std::ofstream>(opts.convergence_csv);
    if (!*csv) throw MesoError(fmt::format("cannot write '{}'", opts.convergence_csv));
    *csv << "pass,elapsed_s,spp,mse,relmse\n";
    return csv;
}

/// The ranks' films and counters summed on rank 0 (the other ranks keep their partial film);
/// returns the slowest rank's wall time.
double reduce_ranks(Film &film, tbb::enumerable_thread_specific<RenderStats> &stats, double wall) {
    dist::reduce_sum_to_root(film.sum.data(), film.sum.size());
    uint64_t counts[3] = {uint64_t(film.nan_count.load()), 0, 0};
    for (auto &s : stats) counts[1] += s.rays, counts[2] += s.shadow_rays;
    dist::reduce_sum_to_root(counts, 3);
    film.nan_count.store(long(counts[0]));
    stats.clear();
    stats.local().rays = counts[1];
    stats.local().shadow_rays = counts[2];
    return dist::allreduce_max(wall);
}

}  // namespace

RenderResult render(const Scene &scene, const RenderOptions &opts) {
    if (!scene.camera || !scene.integrator || !scene.sampler) throw MesoError("scene is incomplete (camera, integrator or sampler missing)");
    const std::array<int, 4> crop = opts.crop.value_or(std::array<int, 4>{0, 0, scene.camera->width(), scene.camera->height()});
    check_crop(crop, scene.camera->width(), scene.camera->height());
    const Window win{crop[0], crop[1], crop[2] - crop[0], crop[3] - crop[1]};
    const int total_spp = opts.spp > 0 ? opts.spp : scene.spp;
    const bool timed = opts.time_budget_s > 0;
    // Ranks (MPI, docs/cluster.md): rank r renders, in every pass, its own block of n consecutive
    // sample indices after the blocks of ranks 0..r-1, so after P passes the ranks together hold
    // exactly the sample indices 0 .. P*ranks*n - 1 of a single-process render with the same seed.
    const int ranks = dist::size(), rank = dist::rank();
    // Default threads: the node's cores shared among the ranks on it.
    int threads = opts.threads > 0 ? opts.threads : std::max(1, tbb::info::default_concurrency() / dist::local_size());
    tbb::global_control limit(tbb::global_control::max_allowed_parallelism, size_t(threads));

    // Passes of at least ~64k samples (over the window's pixels) keep the per-pass overhead negligible; a pass is a
    // contiguous range of sample indices, so passes compose to exactly the same samples.
    // Under a time budget, passes are smaller (>= 8k samples, 1 spp from 90x90 pixels up) so
    // that the budget is used to within a few per cent even for small images and short
    // budgets (equal-time comparisons, `meso bench`).
    // With many threads a pass is larger still (>= 32k or 4k samples a thread): each pass ends
    // with the threads waiting for the slowest tile, a fixed cost that a 16-thread pass of 1 spp
    // at 320x240 (about 20 ms) paid 64 times for 64 spp.
    const double pass_samples = timed ? std::max(8192.0, 4096.0 * threads) : std::max(65536.0, 32768.0 * threads);
    const int spp_per_pass = std::max(1, int(std::ceil(pass_samples / (double(win.w) * win.h))));
    // pbrt-v4: scale camera differentials by max(1/8, 1/sqrt(spp)) (footprint of one sample).
    const float diff_scale = std::max(0.125f, 1.f / std::sqrt(float(timed ? std::max(total_spp, 1) : total_spp)));

    Film film(win.w, win.h);
    tbb::enumerable_thread_specific<RenderStats> stats;
    std::unique_ptr<std::ofstream> csv = open_convergence_log(opts, ranks);

    scene.integrator->set_samples_per_pixel(total_spp);
    scene.integrator->preprocess(scene);
    Progress progress(opts.progress && rank == 0, timed ? opts.time_budget_s : double(total_spp), timed ? "s" : "spp");
    dist::barrier();  // every rank starts the clock (and the time budget) together
    auto t0 = std::chrono::steady_clock::now();
    auto elapsed = [&] { return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count(); };

    int spp_done = 0, passes = 0;
    bool interrupted = false;
    double last_pass_s = 0.0, pass_start = 0.0;
    for (;;) {
        // spp_done: samples per pixel of all ranks so far; this rank's block of the pass.
        const int block = spp_per_pass;
        if (!timed && spp_done >= total_spp) break;
        const int first = spp_done + rank * block;
        const int n = timed ? block : std::max(0, std::min(block, total_spp - first));
        if (timed && passes > 0) {
            // Start a pass only if it is expected to finish within the budget, predicted from
            // the last pass (the first one also pays for warm-up: caches, lazy page faults).
            // Rank 0 decides for all, so every rank stops after the same pass.
            if (dist::broadcast(elapsed() + last_pass_s > opts.time_budget_s)) break;
        }
        pass_start = elapsed();
        render_pass(scene, opts, win, first, n, diff_scale, film, stats);
        spp_done += timed ? ranks * block : std::min(ranks * block, total_spp - spp_done);
        ++passes;
        double t = elapsed();
        last_pass_s = t - pass_start;
        if (csv) {
            ImageMetrics m = compute_metrics(film.resolve(spp_done), *opts.reference);
            *csv << fmt::format("{},{:.6f},{},{:.9g},{:.9g}\n", passes, t, spp_done, m.mse, m.relmse);
        }
        progress.update(timed ? t : double(spp_done), t, fmt::format("{} spp", spp_done));
        if (!timed && spp_done >= total_spp) break;
        // Every rank asks (a collective); rank 0's answer counts, so all stop after the same pass.
        if (opts.stop && dist::broadcast(opts.stop())) {
            interrupted = true;
            break;
        }
    }
    progress.finish(elapsed());

    double wall = elapsed();
    if (ranks > 1) wall = reduce_ranks(film, stats, wall);
    RenderResult res;
    res.ranks = ranks;
    res.wall_s = wall;
    res.spp = spp_done;
    res.passes = passes;
    res.interrupted = interrupted;
    res.threads = threads;
    res.image = film.resolve(spp_done);
    for (auto &s : stats) {
        res.rays += s.rays;
        res.shadow_rays += s.shadow_rays;
    }
    res.rays_per_s = res.wall_s > 0 ? res.rays / res.wall_s : 0;
    res.nan_count = film.nan_count.load();
    return res;
}

}  // namespace meso
