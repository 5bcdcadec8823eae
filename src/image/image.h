// Float images and their I/O (OpenImageIO). EXR is written as full 32-bit float (never
// half); PNG is tone-mapped sRGB. Writes go to a temporary file renamed into place, so an
// error never leaves a half-written output.
#pragma once
#include <string>
#include <utility>
#include <vector>
#include "core/spectrum.h"

namespace meso {

struct Image {
    int width = 0, height = 0, channels = 3;
    std::vector<float> data;  ///< row-major, top row first, interleaved channels

    Image() = default;
    Image(int w, int h, int c = 3) : width(w), height(h), channels(c), data(size_t(w) * h * c, 0.f) {}
    float &at(int x, int y, int c) { return data[(size_t(y) * width + x) * channels + c]; }
    float at(int x, int y, int c) const { return data[(size_t(y) * width + x) * channels + c]; }
    /// RGB of a pixel (grey images replicate their channel; alpha is ignored).
    Spectrum rgb(int x, int y) const;
    void set_rgb(int x, int y, Spectrum s);
};

/// Reads any format OpenImageIO knows as float. `linearize_srgb`: decode 8/16-bit sRGB
/// encoded files (PNG/JPEG colour textures) to linear; float formats are taken as linear.
/// Throws MesoError("<path>: cannot read image: <reason>") on failure.
Image read_image(const std::string &path, bool linearize_srgb = false);
/// Throws MesoError naming the file when it is an EXR with a corrupt header (an attribute claiming
/// more bytes than the file has, which OpenEXR would allocate); other files pass. read_image calls it.
void check_exr_headers(const std::string &path);
/// Provenance of an image: string attributes stored in the EXR header, each named "meso:KEY"
/// (scene_sha1, seed, spp, crop, full_size, version; see `meso render`).
using ImageMetadata = std::vector<std::pair<std::string, std::string>>;
/// Full-float EXR (RGB or the image's channels) with `meta` as "meso:KEY" header attributes.
/// Throws MesoError on failure.
void write_exr(const std::string &path, const Image &img, const ImageMetadata &meta = {});
/// The "meso:KEY" attributes of an image file's header, KEY without the prefix (empty if none).
/// Throws MesoError("<path>: cannot read image: ...") if the file cannot be opened.
ImageMetadata read_image_metadata(const std::string &path);
/// 8-bit sRGB PNG of exposure-scaled, clamped linear RGB.
void write_png(const std::string &path, const Image &img, float exposure_stops = 0.f);
/// Linear -> sRGB transfer (and inverse) for one channel value.
float linear_to_srgb(float v);
float srgb_to_linear(float v);

/// Error metrics of `test` against `ref` (same size; RGB). relMSE is per pixel and channel
/// (t - r)^2 / (r^2 + eps) with eps = 1e-2 (as in the LoD literature), averaged.
struct ImageMetrics {
    double mse = 0, relmse = 0, rmse = 0, psnr = 0;
    double mean_luminance_ratio = 0;  ///< mean luminance of test / mean luminance of ref
    long nonfinite = 0;               ///< NaN/Inf pixels found in test (excluded from the sums)
};
ImageMetrics compute_metrics(const Image &test, const Image &ref);

}  // namespace meso
