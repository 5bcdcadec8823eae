// EXR files through OpenEXR's C++ API: reading any channel count (half, float and uint
// channels as float, in OpenImageIO's channel order so files read as they did through it),
// string attributes as metadata; writing full-float channels with ZIP compression. Before
// OpenEXR sees a file its headers are walked here (check_exr_headers): OpenEXR trusts declared
// sizes and allocates from them.
#include <ImfChannelList.h>
#include <ImfFrameBuffer.h>
#include <ImfHeader.h>
#include <ImfInputFile.h>
#include <ImfOutputFile.h>
#include <ImfStringAttribute.h>
#include <ImfThreading.h>
#include <algorithm>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <thread>
#include <fmt/format.h>
#include "core/error.h"
#include "core/input_file.h"
#include "image/image_formats.h"

namespace meso {

namespace fs = std::filesystem;

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
/// part's declared size goes through decoded_size_problem here, before OpenEXR opens it.
void check_exr_headers(const std::string &path) {
    std::ifstream f(path, std::ios::binary);
    char magic[8] = {};
    if (!f.read(magic, 8) || std::memcmp(magic, "\x76\x2f\x31\x01", 4) != 0) return;  // not an EXR: its own reader decides
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
        if (part.width <= 0 || part.height <= 0 || part.channels <= 0) return;  // OpenEXR reports these
        const uint64_t values = uint64_t(part.width) * uint64_t(part.height) * uint64_t(part.channels);
        if (std::string why = decoded_size_problem(values, uint64_t(part.bytes_per_value), file_size, values * sizeof(float));
            !why.empty())
            image_read_error(path, fmt::format("{}x{} with {} channels: {}", part.width, part.height, part.channels, why));
    };
    std::string name, type, value;
    ExrPartSize part;
    for (int headers = 0; f;) {
        if (!read_cstr(name))
            image_read_error(path, fmt::format("corrupt EXR header (an attribute name is truncated or longer than {} bytes)", max_name));
        if (name.empty()) {  // end of one header; a multi-part file ends its list with another
            check_part(part);
            part = ExrPartSize();
            if (!multipart || ++headers > 1024 || f.peek() == 0 || f.peek() == EOF) return;
            continue;
        }
        int32_t size = 0;
        if (!read_cstr(type) || !f.read(reinterpret_cast<char *>(&size), 4))
            image_read_error(path, fmt::format("corrupt EXR header (attribute '{}' is truncated)", name));
        const uint64_t at = uint64_t(f.tellg());
        if (size < 0 || at + uint64_t(size) > file_size)
            image_read_error(path, fmt::format("corrupt EXR header: attribute '{}' claims {} bytes, the file has {} left", name,
                                         size, file_size - std::min(file_size, at)));
        if (type == "box2i" && size != 16)
            image_read_error(path, fmt::format("corrupt EXR header: attribute '{}' of type box2i has {} bytes, expected 16", name, size));
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

namespace {

/// OpenEXR decodes and encodes with its global thread pool; started on the first EXR, sized
/// to the machine (as OpenImageIO did), never at start-up.
void start_exr_threads() {
    static const bool started = [] {
        Imf::setGlobalThreadCount(int(std::max(1u, std::thread::hardware_concurrency())));
        return true;
    }();
    (void)started;
}

bool iequals(const std::string &a, const char *b) {
    const size_t n = std::strlen(b);
    if (a.size() != n) return false;
    for (size_t i = 0; i < n; ++i)
        if (std::tolower(static_cast<unsigned char>(a[i])) != std::tolower(static_cast<unsigned char>(b[i]))) return false;
    return true;
}

/// One channel as OpenImageIO presents it: layer ("diffuse." of "diffuse.R"), suffix ("R").
struct ExrChannel {
    std::string name, layer, suffix;
    Imf::Channel channel;
    int rank = 10000;  ///< place of a reserved suffix (R, G, B, ..., A, Z); others after, by name
};

/// OpenImageIO's channel order (so files read as they did through it): by layer, then reserved
/// suffixes (R, G, B first, A after colour, Z after that), then the rest by name. A layer with
/// X and Y or Z holds positions or normals: X, Y, Z come before A there.
std::vector<ExrChannel> presentation_order(const Imf::ChannelList &list) {
    static const char *usual[] = {"R",  "Red", "G",  "Green", "B",  "Blue", "Y", "real",  "imag",  "A",
                                  "Alpha", "AR", "RA", "AG", "GA", "AB", "BA", "Z", "Depth", "Zback", nullptr};
    static const char *xyz[] = {"R",  "Red", "G",  "Green", "B",  "Blue", "X",  "Y",     "Z",     "real", "imag",
                                "A", "Alpha", "AR", "RA", "AG", "GA", "AB", "BA", "Depth", "Zback", nullptr};
    std::vector<ExrChannel> v;
    for (auto it = list.begin(); it != list.end(); ++it) {
        ExrChannel c{it.name(), "", "", it.channel()};
        const size_t dot = c.name.find_last_of('.');
        c.layer = dot == std::string::npos ? "" : c.name.substr(0, dot + 1);
        c.suffix = dot == std::string::npos ? c.name : c.name.substr(dot + 1);
        v.push_back(c);
    }
    std::stable_sort(v.begin(), v.end(), [](const ExrChannel &a, const ExrChannel &b) { return a.layer < b.layer; });
    for (size_t begin = 0, end; begin < v.size(); begin = end) {
        bool x = false, yz = false;
        for (end = begin; end < v.size() && v[end].layer == v[begin].layer; ++end) {
            x = x || iequals(v[end].suffix, "X");
            yz = yz || iequals(v[end].suffix, "Y") || iequals(v[end].suffix, "Z");
        }
        const char **names = x && yz ? xyz : usual;
        for (size_t i = begin; i < end; ++i)
            for (int k = 0; names[k]; ++k)
                if (iequals(v[i].suffix, names[k])) {
                    v[i].rank = k;
                    break;
                }
        std::sort(v.begin() + long(begin), v.begin() + long(end), [](const ExrChannel &a, const ExrChannel &b) {
            return a.rank != b.rank ? a.rank < b.rank : a.suffix < b.suffix;
        });
    }
    return v;
}

SampleType sample_type_of(Imf::PixelType t) {
    switch (t) {
    case Imf::HALF: return SampleType::Half;
    case Imf::FLOAT: return SampleType::Float;
    case Imf::UINT: return SampleType::UInt32;
    default: return SampleType::Other;
    }
}

/// Channels, sample type and metadata of a header (DecodedImage without the pixels).
DecodedImage describe(const std::string &path, const Imf::Header &h, const std::vector<ExrChannel> &channels) {
    DecodedImage d;
    const Imath::Box2i dw = h.dataWindow();
    set_header_size(d, int64_t(dw.max.x) - dw.min.x + 1, int64_t(dw.max.y) - dw.min.y + 1, int(channels.size()));
    for (size_t c = 0; c < channels.size(); ++c) {
        const ExrChannel &ch = channels[c];
        if (ch.channel.xSampling != 1 || ch.channel.ySampling != 1)
            image_read_error(path, fmt::format("channel '{}' is subsampled ({}x{}), which is not supported", ch.name,
                                               ch.channel.xSampling, ch.channel.ySampling));
        const SampleType t = sample_type_of(ch.channel.type);
        d.sample = c == 0 || t == d.sample ? t : SampleType::Float;  // mixed: read as float
        if (d.alpha_channel < 0 && (iequals(ch.suffix, "A") || iequals(ch.suffix, "Alpha"))) d.alpha_channel = int(c);
        d.channel_names.push_back(ch.name);
    }
    for (auto it = h.begin(); it != h.end(); ++it) {
        const std::string name = it.name();
        if (name.rfind("meso:", 0) != 0) continue;
        if (std::strcmp(it.attribute().typeName(), Imf::StringAttribute::staticTypeName()) == 0)
            d.meta.emplace_back(name.substr(5), static_cast<const Imf::StringAttribute &>(it.attribute()).value());
    }
    return d;
}

}  // namespace

DecodedImage read_exr_file(const std::string &path, bool pixels) {
    check_exr_headers(path);
    start_exr_threads();
    try {
        Imf::InputFile in(path.c_str());
        const std::vector<ExrChannel> channels = presentation_order(in.header().channels());
        if (channels.empty()) image_read_error(path, "the file has no channels");
        DecodedImage d = describe(path, in.header(), channels);
        const int W = d.image.width, H = d.image.height, C = d.image.channels;
        int bytes = 0;
        for (const ExrChannel &ch : channels) bytes = std::max(bytes, ch.channel.type == Imf::HALF ? 2 : 4);
        check_declared_size(path, W, H, C, bytes);
        if (!pixels) return d;
        d.image = Image(W, H, C);
        Imf::FrameBuffer fb;
        const Imath::Box2i dw = in.header().dataWindow();
        for (int c = 0; c < C; ++c)
            fb.insert(channels[size_t(c)].name, Imf::Slice::Make(Imf::FLOAT, d.image.data.data() + c, dw, sizeof(float) * C,
                                                                 sizeof(float) * size_t(C) * size_t(W)));
        in.setFrameBuffer(fb);
        in.readPixels(dw.min.y, dw.max.y);
        return d;
    } catch (const MesoError &) {
        throw;
    } catch (const std::exception &e) {
        image_read_error(path, one_line(e.what(), "OpenEXR could not read the file"));
    }
}

void write_exr_file(const std::string &path, const Image &img, const std::vector<std::string> &channel_names,
                    const ImageMetadata &meta) {
    start_exr_threads();
    Imf::Header h(img.width, img.height);
    h.compression() = Imf::ZIP_COMPRESSION;
    const size_t C = size_t(img.channels);
    for (const std::string &n : channel_names) h.channels().insert(n, Imf::Channel(Imf::FLOAT));
    for (const auto &[key, value] : meta) h.insert("meso:" + key, Imf::StringAttribute(value));
    Imf::OutputFile out(path.c_str(), h);
    Imf::FrameBuffer fb;
    for (size_t c = 0; c < C; ++c)
        fb.insert(channel_names[c], Imf::Slice(Imf::FLOAT, const_cast<char *>(reinterpret_cast<const char *>(img.data.data() + c)),
                                               sizeof(float) * C, sizeof(float) * C * size_t(img.width)));
    out.setFrameBuffer(fb);
    out.writePixels(img.height);
}

}  // namespace meso
