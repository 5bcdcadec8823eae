// Radiance RGBE (.hdr / .pic) reading without OpenImageIO: most environment maps are .hdr, and
// loading the OpenImageIO module costs every such run 0.2 s and 118 MB (issue 22).
//
// Format (Greg Ward, "Real Pixels", Graphics Gems II, and the Radiance reference): a text header
// starting "#?" (RADIANCE, RGBE, ...), lines up to an empty line (FORMAT=32-bit_rle_rgbe; other
// lines such as EXPOSURE= are ignored, as OpenImageIO does), then the resolution line. Only the
// standard orientation "-Y H +X W" (rows top to bottom, left to right) is read here; the rare
// others and XYZE files go to the OpenImageIO module. Each scanline is either the "new" run-length
// encoding (bytes 2, 2, width high, width low, then the R, G, B, E planes, each a sequence of
// runs: a count above 128 repeats the next byte count - 128 times, otherwise count literal bytes)
// or flat 4-byte pixels (with the old RLE: 1, 1, 1, n repeats the previous pixel n << shift times).
// A pixel is (R, G, B) * 2^(E - 136) and 0 when E = 0: Ward's rgbe2float, what OpenImageIO
// returns, bit for bit (ImageFormats.HdrMatchesOpenImageIO).
#include <cmath>
#include <cstdio>
#include <cstring>
#include <fstream>
#include <fmt/format.h>
#include "image/image_formats.h"

namespace meso {

namespace {

struct HdrHeader {
    int width = 0, height = 0;
    bool standard = false;  ///< "-Y H +X W" and 32-bit_rle_rgbe: readable here
};

/// Reads the text header and the resolution line; false when the file is not a Radiance file.
bool read_hdr_header(std::istream &f, HdrHeader &h) {
    std::string line;
    if (!std::getline(f, line) || line.compare(0, 2, "#?") != 0) return false;
    bool rgbe = true;
    for (int lines = 0; std::getline(f, line); ++lines) {
        if (lines > 10000) return false;
        if (line.empty()) break;
        if (line.compare(0, 7, "FORMAT=") == 0) rgbe = line == "FORMAT=32-bit_rle_rgbe";
    }
    if (!std::getline(f, line)) return false;
    char ya[3] = {}, xa[3] = {};
    int a = 0, b = 0;
    if (std::sscanf(line.c_str(), "%2s %d %2s %d", ya, &a, xa, &b) != 4) return false;
    h.standard = rgbe && std::strcmp(ya, "-Y") == 0 && std::strcmp(xa, "+X") == 0;
    h.height = a, h.width = b;
    if (std::strchr("+-", ya[0]) && ya[1] == 'X') h.width = a, h.height = b;  // transposed orientations
    return h.width > 0 && h.height > 0;
}

/// One scanline of `w` RGBE pixels into `out` (4 w bytes); false on corrupt or truncated data.
bool read_scanline(std::istream &f, int w, unsigned char *out) {
    unsigned char p[4];
    if (!f.read(reinterpret_cast<char *>(p), 4)) return false;
    if (w < 8 || w > 0x7fff || p[0] != 2 || p[1] != 2 || (p[2] & 0x80)) {  // flat (old RLE)
        int x = 0, shift = 0;
        for (;;) {
            if (p[0] == 1 && p[1] == 1 && p[2] == 1) {  // repeat the previous pixel
                if (x == 0) return false;
                const long n = long(p[3]) << shift;
                if (x + n > w || shift > 24) return false;
                for (long k = 0; k < n; ++k, ++x) std::memcpy(out + 4 * x, out + 4 * (x - 1), 4);
                shift += 8;
            } else {
                std::memcpy(out + 4 * x++, p, 4);
                shift = 0;
            }
            if (x >= w) return true;
            if (!f.read(reinterpret_cast<char *>(p), 4)) return false;
        }
    }
    if (((int(p[2]) << 8) | p[3]) != w) return false;
    for (int c = 0; c < 4; ++c)
        for (int x = 0; x < w;) {
            int count = f.get();
            if (count == EOF || count == 0) return false;
            if (count > 128) {
                count -= 128;
                const int v = f.get();
                if (v == EOF || x + count > w) return false;
                for (int k = 0; k < count; ++k) out[4 * x++ + c] = (unsigned char)v;
            } else {
                if (x + count > w) return false;
                for (int k = 0; k < count; ++k) {
                    const int v = f.get();
                    if (v == EOF) return false;
                    out[4 * x++ + c] = (unsigned char)v;
                }
            }
        }
    return true;
}

}  // namespace

bool is_plain_rgbe_file(const std::string &path) {
    std::ifstream f(path, std::ios::binary);
    HdrHeader h;
    return read_hdr_header(f, h) && h.standard;
}

DecodedImage read_hdr_file(const std::string &path, bool pixels) {
    std::ifstream f(path, std::ios::binary);
    HdrHeader h;
    if (!read_hdr_header(f, h) || !h.standard) image_read_error(path, "not a Radiance RGBE file in the standard orientation");
    DecodedImage d;
    set_header_size(d, h.width, h.height, 3);
    check_declared_size(path, h.width, h.height, 3, 1);
    d.sample = SampleType::Float;
    d.says_linear = true;
    d.channel_names = {"R", "G", "B"};
    if (!pixels) return d;
    d.image = Image(h.width, h.height, 3);
    std::vector<unsigned char> line(size_t(h.width) * 4);
    for (int y = 0; y < h.height; ++y) {
        if (!read_scanline(f, h.width, line.data()))
            image_read_error(path, fmt::format("the pixel data is corrupt or truncated at row {} of {}", y, h.height));
        float *row = &d.image.data[size_t(y) * h.width * 3];
        for (int x = 0; x < h.width; ++x) {
            const unsigned char *q = &line[size_t(x) * 4];
            const float s = q[3] ? float(std::ldexp(1.0, int(q[3]) - (128 + 8))) : 0.f;
            row[3 * x] = q[0] * s, row[3 * x + 1] = q[1] * s, row[3 * x + 2] = q[2] * s;
        }
    }
    return d;
}

}  // namespace meso
