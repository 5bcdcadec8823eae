// Image pixels and file I/O through OpenImageIO.
//
// Reading: any format OpenImageIO knows, converted to 32-bit float, all channels kept.
// 8/16-bit integer files are sRGB-encoded by convention (PNG, JPEG, TIFF colour
// textures); with linearize_srgb they are decoded to linear unless the file itself says
// it is linear (oiio:ColorSpace "Linear"). Alpha is never decoded.
// Writing: EXR as full 32-bit float (half would clip above 65504 and quantise dark
// values: openexr #237); PNG as 8-bit sRGB. Both write "<path>.tmp-<pid>" first and
// rename it into place, so a failed write never leaves a partial file under <path>.
#include <OpenImageIO/imageio.h>
#include <unistd.h>
#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include "core/error.h"
#include "core/input_file.h"
#include "image/image.h"

namespace meso {

namespace fs = std::filesystem;
using OIIO::ImageInput;
using OIIO::ImageOutput;
using OIIO::ImageSpec;
using OIIO::TypeDesc;

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

namespace {

std::string trimmed(std::string s, const char *fallback) {
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ' || s.back() == '\r')) s.pop_back();
    // OIIO may accumulate several lines; one line is enough for the user.
    std::replace(s.begin(), s.end(), '\n', ';');
    return s.empty() ? std::string(fallback) : s;
}

[[noreturn]] void read_error(const std::string &path, const std::string &why) {
    throw MesoError(fmt::format("{}: cannot read image: {}", path, why));
}

[[noreturn]] void write_error(const std::string &path, const std::string &why) {
    throw MesoError(fmt::format("cannot write '{}': {}", path, why));
}

/// Writes `pixels` (width x height x nchannels of `type`) with the OIIO plugin `format`
/// to a temporary file next to `path`, then renames it into place.
void write_atomically(const std::string &path, const char *format, const ImageSpec &spec, const void *pixels) {
    fs::path parent = fs::path(path).parent_path();
    std::error_code ec;
    if (!parent.empty() && !fs::is_directory(parent, ec))
        write_error(path, fmt::format("directory '{}' does not exist", parent.string()));
    if (fs::is_directory(path, ec)) write_error(path, "it is a directory");

    std::string tmp = fmt::format("{}.tmp-{}", path, long(getpid()));
    auto fail = [&](const std::string &why) {
        fs::remove(tmp, ec);
        write_error(path, why);
    };
    auto out = ImageOutput::create(format);
    if (!out) fail(trimmed(OIIO::geterror(), "no image writer"));
    if (!out->open(tmp, spec)) fail(trimmed(out->geterror(), "cannot open file"));
    bool ok = out->write_image(spec.format, pixels);
    std::string err = ok ? std::string() : trimmed(out->geterror(), "write failed");
    if (!out->close() && ok) {
        ok = false;
        err = trimmed(out->geterror(), "close failed");
    }
    out.reset();
    if (!ok) fail(err);
    fs::rename(tmp, path, ec);
    if (ec) fail(ec.message());
}

void check_image(const std::string &path, const Image &img) {
    if (img.width <= 0 || img.height <= 0 || img.channels <= 0)
        write_error(path, fmt::format("empty image ({}x{}, {} channels)", img.width, img.height, img.channels));
    if (img.data.size() != size_t(img.width) * img.height * img.channels)
        write_error(path, "pixel buffer size does not match the image size");
}

}  // namespace

/// OpenEXR stores channels sorted by name and OIIO returns them in the file's order (RGBA
/// first): write_exr's R, G, B, A, channel4, ..., channel30 would come back as R, G, B, A,
/// channel10, ..., channel19, channel20, ..., channel4, ..., channel9. Channels named that
/// way (R, G, B, A, "channelN") are put back at index N; other namings are kept as read.
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

namespace {

/// One EXR part's declared size, from its dataWindow and channels attributes.
struct ExrPartSize {
    int64_t width = 0, height = 0;
    int channels = 0, bytes_per_value = 0;  ///< largest channel type: half 2, uint/float 4
};

/// The values of a chlist attribute: channel count and largest stored type.
void parse_chlist(const std::string &bytes, ExrPartSize &part) {
    for (size_t i = 0; i < bytes.size() && bytes[i] != '\0';) {
        const size_t end = bytes.find('\0', i);
        if (end == std::string::npos || end + 1 + 16 > bytes.size()) return;
        int32_t type = 0;
        std::memcpy(&type, bytes.data() + end + 1, 4);
        part.channels += 1;
        part.bytes_per_value = std::max(part.bytes_per_value, type == 1 ? 2 : 4);
        i = end + 1 + 16;  // pixel type, pLinear + 3 reserved, x and y sampling
    }
}

}  // namespace

/// OpenEXR trusts each header attribute's declared size: a 570-byte file declaring a 1.9 GB
/// string made the reader allocate 2 GB for 2.5 s before failing (found by fuzz/, issue 24).
/// So an EXR's headers are walked first, and an attribute that claims more bytes than the file
/// has left is refused. OpenEXR also sizes its line buffers from dataWindow when the file is
/// opened (a 1.5 KB file declaring 16777023 x 64 pixels made it allocate 537 MB), so each
/// part's declared size goes through decoded_size_problem here, before OpenImageIO opens it.
void check_exr_headers(const std::string &path) {
    std::ifstream f(path, std::ios::binary);
    char magic[8] = {};
    if (!f.read(magic, 8) || std::memcmp(magic, "\x76\x2f\x31\x01", 4) != 0) return;  // not an EXR: OIIO decides
    std::error_code ec;
    const uint64_t file_size = fs::file_size(path, ec);
    const bool multipart = (uint8_t(magic[5]) & 0x10) != 0;  // version flag bit 12
    // Names of attributes and types: at most 31 bytes, or 255 with the long-names flag (bit 10).
    // Longer ones are corrupt (a mutated 104-byte name kept OpenEXR busy for 11 s under ASan).
    const size_t max_name = (uint8_t(magic[5]) & 0x04) ? 255 : 31;
    auto read_cstr = [&](std::string &out) {
        out.clear();
        for (char c; f.get(c);) {
            if (c == '\0') return true;
            if (out.size() >= max_name) return false;
            out += c;
        }
        return false;
    };
    auto check_part = [&](const ExrPartSize &part) {
        if (part.width <= 0 || part.height <= 0 || part.channels <= 0) return;  // OIIO reports these
        const uint64_t values = uint64_t(part.width) * uint64_t(part.height) * uint64_t(part.channels);
        if (std::string why = decoded_size_problem(values, uint64_t(part.bytes_per_value), file_size, values * sizeof(float));
            !why.empty())
            read_error(path, fmt::format("{}x{} with {} channels: {}", part.width, part.height, part.channels, why));
    };
    std::string name, type, value;
    ExrPartSize part;
    for (int headers = 0; f;) {
        if (!read_cstr(name))
            read_error(path, fmt::format("corrupt EXR header (an attribute name is truncated or longer than {} bytes)", max_name));
        if (name.empty()) {  // end of one header; a multi-part file ends its list with another
            check_part(part);
            part = ExrPartSize();
            if (!multipart || ++headers > 1024 || f.peek() == 0 || f.peek() == EOF) return;
            continue;
        }
        int32_t size = 0;
        if (!read_cstr(type) || !f.read(reinterpret_cast<char *>(&size), 4))
            read_error(path, fmt::format("corrupt EXR header (attribute '{}' is truncated)", name));
        const uint64_t at = uint64_t(f.tellg());
        if (size < 0 || at + uint64_t(size) > file_size)
            read_error(path, fmt::format("corrupt EXR header: attribute '{}' claims {} bytes, the file has {} left", name,
                                         size, file_size - std::min(file_size, at)));
        if (type == "box2i" && size != 16)
            read_error(path, fmt::format("corrupt EXR header: attribute '{}' of type box2i has {} bytes, expected 16", name, size));
        if ((name == "dataWindow" && type == "box2i") || (name == "channels" && type == "chlist")) {
            value.assign(size_t(size), '\0');
            f.read(value.data(), size);
            if (name == "channels") {
                parse_chlist(value, part);
            } else {
                int32_t box[4];
                std::memcpy(box, value.data(), 16);
                part.width = int64_t(box[2]) - box[0] + 1, part.height = int64_t(box[3]) - box[1] + 1;
            }
        } else {
            f.seekg(std::streamoff(size), std::ios::cur);
        }
    }
}

Image read_image(const std::string &path, bool linearize_srgb) {
    std::error_code ec;
    if (!fs::exists(path, ec)) read_error(path, "file does not exist");
    if (fs::is_directory(path, ec)) read_error(path, "it is a directory");
    if (std::string why = input_file_problem(path, kMaxImageFileBytes, "image"); !why.empty()) read_error(path, why);
    check_exr_headers(path);
    auto in = ImageInput::open(path);
    if (!in) read_error(path, trimmed(OIIO::geterror(), "unknown format"));
    const ImageSpec &spec = in->spec();
    if (spec.width <= 0 || spec.height <= 0 || spec.nchannels <= 0 || spec.depth > 1)
        read_error(path, fmt::format("unsupported image size {}x{}x{} with {} channels", spec.width, spec.height,
                                     spec.depth, spec.nchannels));
    const uint64_t values = uint64_t(spec.width) * uint64_t(spec.height) * uint64_t(spec.nchannels);
    if (std::string why = decoded_size_problem(values, uint64_t(spec.format.size()), fs::file_size(path, ec),
                                               values * sizeof(float));
        !why.empty())
        read_error(path, fmt::format("{}x{} with {} channels: {}", spec.width, spec.height, spec.nchannels, why));
    Image img(spec.width, spec.height, spec.nchannels);
    if (!in->read_image(0, 0, 0, spec.nchannels, TypeDesc::FLOAT, img.data.data()))
        read_error(path, trimmed(in->geterror(), "read failed"));
    if (in->has_error()) read_error(path, trimmed(in->geterror(), "read failed"));
    restore_written_order(img, spec.channelnames);

    TypeDesc::BASETYPE base = TypeDesc::BASETYPE(spec.format.basetype);
    bool integer_encoded = base == TypeDesc::UINT8 || base == TypeDesc::UINT16;
    std::string cs = spec.get_string_attribute("oiio:ColorSpace");
    bool says_linear = cs == "Linear" || cs == "linear" || cs == "lin_srgb" || cs == "scene_linear";
    if (linearize_srgb && integer_encoded && !says_linear) {
        for (size_t i = 0; i < img.data.size(); ++i) {
            int c = int(i % size_t(img.channels));
            if (c == spec.alpha_channel) continue;
            img.data[i] = srgb_to_linear(img.data[i]);
        }
    }
    return img;
}

ImageMetadata read_image_metadata(const std::string &path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec)) read_error(path, "not a regular file");
    auto in = ImageInput::open(path);
    if (!in) read_error(path, trimmed(OIIO::geterror(), "unknown format"));
    ImageMetadata meta;
    for (const OIIO::ParamValue &p : in->spec().extra_attribs) {
        const std::string name = p.name().string();
        if (name.rfind("meso:", 0) == 0 && p.type() == TypeDesc::STRING)
            meta.emplace_back(name.substr(5), p.get_string());
    }
    return meta;
}

void write_exr(const std::string &path, const Image &img, const ImageMetadata &meta) {
    check_image(path, img);
    ImageSpec spec(img.width, img.height, img.channels, TypeDesc::FLOAT);
    spec.channelnames.clear();
    spec.alpha_channel = -1;
    static const char *rgba[] = {"R", "G", "B", "A"};
    for (int c = 0; c < img.channels; ++c) {
        if (img.channels == 1) spec.channelnames.push_back("Y");
        else if (img.channels == 2) spec.channelnames.push_back(c == 0 ? "Y" : "A");
        else if (c < 4) spec.channelnames.push_back(rgba[c]);
        else spec.channelnames.push_back(fmt::format("channel{}", c));
    }
    if (img.channels == 2) spec.alpha_channel = 1;
    if (img.channels >= 4) spec.alpha_channel = 3;
    spec.attribute("compression", "zip");
    for (const auto &[key, value] : meta) spec.attribute("meso:" + key, value);
    write_atomically(path, "openexr", spec, img.data.data());
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
    ImageSpec spec(img.width, img.height, 3, TypeDesc::UINT8);
    spec.attribute("oiio:ColorSpace", "sRGB");
    write_atomically(path, "png", spec, px.data());
}

}  // namespace meso
