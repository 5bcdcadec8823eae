// Image pixels and file I/O: picks the reader by the file's first bytes and finishes the job.
//
// Reading: EXR through OpenEXR (image/exr_file.cpp), PNG through libpng (image/png_file.cpp),
// any other format through the OpenImageIO module (image/oiio_loader.cpp), loaded on first use.
// All channels are kept, as 32-bit float. 8/16-bit integer files are sRGB-encoded by
// convention (PNG, JPEG, TIFF colour textures); with linearize_srgb they are decoded to linear
// unless the file itself says it is linear. Alpha is never decoded, and colour channels are read
// as stored, never multiplied by alpha (glTF base colours are not premultiplied; alpha there
// means coverage).
// Writing: EXR as full 32-bit float (half would clip above 65504 and quantise dark values:
// openexr #237); PNG as 8-bit sRGB. Both write "<path>.tmp-<pid>" first and rename it into
// place, so a failed write never leaves a partial file under <path>.
#include <unistd.h>
#include <algorithm>
#include <climits>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <fmt/format.h>
#include "core/error.h"
#include "core/input_file.h"
#include "image/image.h"
#include "image/image_formats.h"

namespace meso {

namespace fs = std::filesystem;

Spectrum Image::rgb(int x, int y) const {
    const float *p = &data[(size_t(y) * width + x) * channels];
    if (channels >= 3) return Spectrum(p[0], p[1], p[2]);
    return Spectrum(p[0]);  // grey (+ alpha)
}

void Image::set_rgb(int x, int y, Spectrum s) {
    float *p = &data[(size_t(y) * width + x) * channels];
    if (channels >= 3) {
        p[0] = s.r, p[1] = s.g, p[2] = s.b;
    } else {
        p[0] = s.luminance();  // grey image: store the luminance
    }
}

float linear_to_srgb(float v) {
    if (!(v > 0.f)) return 0.f * v;  // keeps -0/0; NaN stays NaN
    if (v <= 0.0031308f) return 12.92f * v;
    return 1.055f * std::pow(v, 1.f / 2.4f) - 0.055f;
}

float srgb_to_linear(float v) {
    if (!(v > 0.f)) return 0.f * v;
    if (v <= 0.04045f) return v * (1.f / 12.92f);
    return std::pow((v + 0.055f) * (1.f / 1.055f), 2.4f);
}

std::string one_line(std::string s, const char *fallback) {
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ' || s.back() == '\r')) s.pop_back();
    std::replace(s.begin(), s.end(), '\n', ';');
    return s.empty() ? std::string(fallback) : s;
}

void image_read_error(const std::string &path, const std::string &why) {
    throw MesoError(fmt::format("{}: cannot read image: {}", path, why));
}

void check_declared_size(const std::string &path, int64_t width, int64_t height, int64_t channels, int bytes_per_value) {
    if (width <= 0 || height <= 0 || channels <= 0 || width > INT_MAX || height > INT_MAX || channels > INT_MAX)
        image_read_error(path, fmt::format("unsupported image size {}x{} with {} channels", width, height, channels));
    std::error_code ec;
    const uint64_t values = uint64_t(width) * uint64_t(height) * uint64_t(channels);
    if (std::string why = decoded_size_problem(values, uint64_t(std::max(bytes_per_value, 1)), fs::file_size(path, ec),
                                               values * sizeof(float));
        !why.empty())
        image_read_error(path, fmt::format("{}x{} with {} channels: {}", width, height, channels, why));
}

void set_header_size(DecodedImage &d, int64_t width, int64_t height, int channels) {
    d.image.width = int(width), d.image.height = int(height), d.image.channels = channels;
    d.image.data.clear();
}

namespace {

[[noreturn]] void write_error(const std::string &path, const std::string &why) {
    throw MesoError(fmt::format("cannot write '{}': {}", path, why));
}

/// Calls `write` on a temporary file next to `path`, then renames it into place; on any
/// failure removes the temporary and throws MesoError("cannot write '<path>': <reason>").
void write_atomically(const std::string &path, const std::function<void(const std::string &)> &write) {
    fs::path parent = fs::path(path).parent_path();
    std::error_code ec;
    if (!parent.empty() && !fs::is_directory(parent, ec))
        write_error(path, fmt::format("directory '{}' does not exist", parent.string()));
    if (fs::is_directory(path, ec)) write_error(path, "it is a directory");

    const std::string tmp = fmt::format("{}.tmp-{}", path, long(getpid()));
    std::string why;
    try {
        write(tmp);
        fs::rename(tmp, path, ec);
        if (ec) why = ec.message();
    } catch (const std::exception &e) {
        why = one_line(e.what(), "write failed");
    }
    if (!why.empty()) {
        fs::remove(tmp, ec);
        write_error(path, why);
    }
}

void check_image(const std::string &path, const Image &img) {
    if (img.width <= 0 || img.height <= 0 || img.channels <= 0)
        write_error(path, fmt::format("empty image ({}x{}, {} channels)", img.width, img.height, img.channels));
    if (img.data.size() != size_t(img.width) * img.height * img.channels)
        write_error(path, "pixel buffer size does not match the image size");
}

enum class FileKind { Exr, Png, Hdr, Other };

/// The reader for a file, by its first bytes (not its name): EXR and PNG are read here, any
/// other file goes to the OpenImageIO module, which tells the formats it knows apart.
FileKind file_kind(const std::string &path) {
    std::ifstream f(path, std::ios::binary);
    unsigned char magic[8] = {};
    f.read(reinterpret_cast<char *>(magic), 8);
    const std::streamsize n = f.gcount();
    if (n >= 4 && std::memcmp(magic, "\x76\x2f\x31\x01", 4) == 0) return FileKind::Exr;
    if (n == 8 && std::memcmp(magic, "\x89PNG\r\n\x1a\n", 8) == 0) return FileKind::Png;
    if (n >= 2 && magic[0] == '#' && magic[1] == '?' && is_plain_rgbe_file(path)) return FileKind::Hdr;
    return FileKind::Other;
}

/// The checks every read starts with, then the reader for the file.
DecodedImage read_file(const std::string &path, bool pixels) {
    std::error_code ec;
    if (!fs::exists(path, ec)) image_read_error(path, "file does not exist");
    if (fs::is_directory(path, ec)) image_read_error(path, "it is a directory");
    if (std::string why = input_file_problem(path, kMaxImageFileBytes, "image"); !why.empty()) image_read_error(path, why);
    if (fs::file_size(path, ec) == 0) image_read_error(path, "the file is empty");
    switch (file_kind(path)) {
    case FileKind::Exr: return read_exr_file(path, pixels);
    case FileKind::Png: return read_png_file(path, pixels);
    case FileKind::Hdr: return read_hdr_file(path, pixels);
    default: return read_oiio_file(path, pixels);
    }
}

}  // namespace

/// OpenEXR stores channels sorted by name and the EXR reader presents them in OpenImageIO's
/// order (RGBA first): write_exr's R, G, B, A, channel4, ..., channel30 would come back as R, G,
/// B, A, channel10, ..., channel19, channel20, ..., channel4, ..., channel9. Channels named
/// that way (R, G, B, A, "channelN") are put back at index N; other namings are kept as read.
static void restore_written_order(Image &img, const std::vector<std::string> &names) {
    const int C = img.channels;
    if (C <= 4 || int(names.size()) != C) return;
    std::vector<int> dst(size_t(C), -1);
    std::vector<char> used(size_t(C), 0);
    for (int k = 0; k < C; ++k) {
        const std::string &n = names[size_t(k)];
        int i = -1;
        if (n == "R") i = 0;
        else if (n == "G") i = 1;
        else if (n == "B") i = 2;
        else if (n == "A") i = 3;
        else if (n.size() > 7 && n.size() < 12 && n.compare(0, 7, "channel") == 0 &&
                 std::all_of(n.begin() + 7, n.end(), [](char ch) { return ch >= '0' && ch <= '9'; }))
            i = std::stoi(n.substr(7));
        if (i < 0 || i >= C || used[size_t(i)]) return;
        used[size_t(i)] = 1;
        dst[size_t(k)] = i;
    }
    std::vector<float> out(img.data.size());
    const size_t px = size_t(img.width) * img.height;
    for (size_t p = 0; p < px; ++p)
        for (int k = 0; k < C; ++k) out[p * C + size_t(dst[size_t(k)])] = img.data[p * C + size_t(k)];
    img.data.swap(out);
}

Image read_image(const std::string &path, bool linearize_srgb) {
    DecodedImage d = read_file(path, /*pixels=*/true);
    Image &img = d.image;
    restore_written_order(img, d.channel_names);
    if (linearize_srgb && integer_encoded(d.sample) && !d.says_linear) {
        for (size_t i = 0; i < img.data.size(); ++i) {
            int c = int(i % size_t(img.channels));
            if (c == d.alpha_channel) continue;
            img.data[i] = srgb_to_linear(img.data[i]);
        }
    }
    return std::move(img);
}

int image_channel_count(const std::string &path) {
    try {
        return std::max(read_file(path, /*pixels=*/false).image.channels, 0);
    } catch (const MesoError &) {
        return 0;  // read_image reports the problem when the image is read
    }
}

ImageMetadata read_image_metadata(const std::string &path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) image_read_error(path, "not a regular file");
    return read_file(path, /*pixels=*/false).meta;
}

SampleType stored_sample_type(const std::string &path) { return read_file(path, /*pixels=*/false).sample; }

void write_exr(const std::string &path, const Image &img, const ImageMetadata &meta) {
    check_image(path, img);
    std::vector<std::string> names;
    static const char *rgba[] = {"R", "G", "B", "A"};
    for (int c = 0; c < img.channels; ++c) {
        if (img.channels == 1) names.push_back("Y");
        else if (img.channels == 2) names.push_back(c == 0 ? "Y" : "A");
        else if (c < 4) names.push_back(rgba[c]);
        else names.push_back(fmt::format("channel{}", c));
    }
    write_atomically(path, [&](const std::string &tmp) { write_exr_file(tmp, img, names, meta); });
}

void write_png(const std::string &path, const Image &img, float exposure_stops) {
    check_image(path, img);
    float scale = std::exp2(exposure_stops);
    std::vector<uint8_t> px(size_t(img.width) * img.height * 3);
    for (int y = 0; y < img.height; ++y)
        for (int x = 0; x < img.width; ++x) {
            Spectrum s = img.rgb(x, y);
            for (int c = 0; c < 3; ++c) {
                float v = s[c] * scale;
                v = std::isnan(v) ? 0.f : clamp(v, 0.f, 1.f);
                px[(size_t(y) * img.width + x) * 3 + c] = uint8_t(std::lround(linear_to_srgb(v) * 255.f));
            }
        }
    write_atomically(path, [&](const std::string &tmp) {
        write_png_file(tmp, img.width, img.height, 3, 8, px.data(), /*srgb=*/true);
    });
}

void write_png16_grey(const std::string &path, int width, int height, const std::vector<uint16_t> &values) {
    if (width <= 0 || height <= 0 || values.size() != size_t(width) * size_t(height))
        write_error(path, fmt::format("empty image or pixel buffer size does not match {}x{}", width, height));
    write_atomically(path, [&](const std::string &tmp) {
        write_png_file(tmp, width, height, 1, 16, values.data(), /*srgb=*/false);
    });
}

}  // namespace meso
