// PNG files through libpng. Reading: 8/16-bit grey, grey + alpha, RGB, RGBA; palette, low bit
// depths and tRNS transparency are expanded (to RGB(A) or 8-bit grey), as OpenImageIO did. Values
// are code / 255 or code / 65535, as stored: colour is not premultiplied by alpha. A file with a
// gAMA of 1.0 and no sRGB chunk says it is linear; any other PNG is sRGB-encoded (iCCP ignored).
// tEXt/zTXt/iTXt chunks named "meso:KEY" are its metadata. Writing: 8-bit RGB with an sRGB chunk
// (rendered images) or 16-bit grey without one (height maps).
//
// libpng reports errors by longjmp: the functions that call setjmp hold no C++ object and
// call only libpng, so nothing is skipped; the rest of the code is ordinary C++.
#include <png.h>
#include <cerrno>
#include <csetjmp>
#include <cstdio>
#include <cstring>
#include <memory>
#include <stdexcept>
#include <fmt/format.h>
#include "core/error.h"
#include "image/image_formats.h"

namespace meso {

namespace {

/// What the setjmp-guarded steps share: plain data only.
struct PngState {
    png_structp png = nullptr;
    png_infop info = nullptr;
    FILE *file = nullptr;
    char error[256] = "";
};

/// What png_read_header learns (plain data: it is filled under setjmp).
struct PngHeader {
    png_uint_32 width = 0, height = 0;
    int bit_depth = 0, channels = 0;
    size_t row_bytes = 0;
    bool says_linear = false;
    png_textp text = nullptr;  ///< owned by the info struct
    int num_text = 0;
};

void on_error(png_structp png, png_const_charp msg) {
    auto *st = static_cast<PngState *>(png_get_error_ptr(png));
    std::snprintf(st->error, sizeof st->error, "%s", msg ? msg : "libpng error");
    png_longjmp(png, 1);
}

void on_warning(png_structp, png_const_charp) {}  // benign (unknown chunks, bad gamma): read on

/// Reads the header and sets up the expansions; false on a libpng error (st.error says why).
bool png_read_header(PngState &st, PngHeader &h) {
    if (setjmp(png_jmpbuf(st.png))) return false;
    png_init_io(st.png, st.file);
    png_read_info(st.png, st.info);
    png_set_expand(st.png);  // palette -> RGB, grey below 8 bits -> 8 bits, tRNS -> alpha
    if (png_get_bit_depth(st.png, st.info) == 16) {
        const uint16_t one = 1;
        if (*reinterpret_cast<const unsigned char *>(&one) == 1) png_set_swap(st.png);  // stored big-endian
    }
    png_set_interlace_handling(st.png);
    png_read_update_info(st.png, st.info);
    h.width = png_get_image_width(st.png, st.info);
    h.height = png_get_image_height(st.png, st.info);
    h.bit_depth = png_get_bit_depth(st.png, st.info);
    h.channels = png_get_channels(st.png, st.info);
    h.row_bytes = png_get_rowbytes(st.png, st.info);
    int intent = 0;
    double gamma = 0;
    h.says_linear = !png_get_sRGB(st.png, st.info, &intent) && png_get_gAMA(st.png, st.info, &gamma) && gamma == 1.0;
    h.num_text = png_get_text(st.png, st.info, &h.text, nullptr);
    return true;
}

/// Decodes every row; false on a libpng error (st.error says why).
bool png_read_rows(PngState &st, png_bytepp rows) {
    if (setjmp(png_jmpbuf(st.png))) return false;
    png_read_image(st.png, rows);
    png_read_end(st.png, nullptr);
    return true;
}

/// Writes a whole image; false on a libpng error (st.error says why).
bool png_write_all(PngState &st, int width, int height, int channels, int bit_depth, bool srgb, png_bytepp rows) {
    if (setjmp(png_jmpbuf(st.png))) return false;
    static const int colour[] = {PNG_COLOR_TYPE_GRAY, PNG_COLOR_TYPE_GRAY_ALPHA, PNG_COLOR_TYPE_RGB, PNG_COLOR_TYPE_RGB_ALPHA};
    png_init_io(st.png, st.file);
    png_set_IHDR(st.png, st.info, png_uint_32(width), png_uint_32(height), bit_depth, colour[channels - 1],
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    if (srgb) png_set_sRGB_gAMA_and_cHRM(st.png, st.info, PNG_sRGB_INTENT_PERCEPTUAL);
    png_write_info(st.png, st.info);
    if (bit_depth == 16) {
        const uint16_t one = 1;
        if (*reinterpret_cast<const unsigned char *>(&one) == 1) png_set_swap(st.png);
    }
    png_write_image(st.png, rows);
    png_write_end(st.png, st.info);
    return true;
}

/// Owns the libpng structs and the file (released on every path, exceptions included). The
/// constructor does not throw: `problem` says what failed.
struct PngFile {
    PngState st;
    std::string problem;
    const bool writing;
    PngFile(const std::string &path, bool for_writing) : writing(for_writing) {
        st.file = std::fopen(path.c_str(), writing ? "wb" : "rb");
        if (!st.file) {
            problem = std::strerror(errno);
            return;
        }
        st.png = writing ? png_create_write_struct(PNG_LIBPNG_VER_STRING, &st, on_error, on_warning)
                         : png_create_read_struct(PNG_LIBPNG_VER_STRING, &st, on_error, on_warning);
        if (st.png) st.info = png_create_info_struct(st.png);
        if (!st.png || !st.info) problem = "libpng could not start";
    }
    ~PngFile() {
        if (writing) png_destroy_write_struct(st.png ? &st.png : nullptr, st.info ? &st.info : nullptr);
        else png_destroy_read_struct(st.png ? &st.png : nullptr, st.info ? &st.info : nullptr, nullptr);
        if (st.file) std::fclose(st.file);
    }
    /// Closes the file, reporting a failed flush (a full disk).
    void close() {
        FILE *f = st.file;
        st.file = nullptr;
        if (std::fclose(f) != 0) throw std::runtime_error(std::strerror(errno));
    }
    PngFile(const PngFile &) = delete;
    PngFile &operator=(const PngFile &) = delete;
};

}  // namespace

DecodedImage read_png_file(const std::string &path, bool pixels) {
    PngFile r(path, /*for_writing=*/false);
    if (!r.problem.empty()) image_read_error(path, r.problem);
    PngHeader h;
    if (!png_read_header(r.st, h)) image_read_error(path, one_line(r.st.error, "not a valid PNG file"));
    DecodedImage d;
    set_header_size(d, h.width, h.height, h.channels);
    check_declared_size(path, h.width, h.height, h.channels, h.bit_depth == 16 ? 2 : 1);
    d.sample = h.bit_depth == 16 ? SampleType::UInt16 : SampleType::UInt8;
    d.says_linear = h.says_linear;
    d.alpha_channel = h.channels == 2 ? 1 : h.channels == 4 ? 3 : -1;
    static const char *names[4][4] = {{"Y"}, {"Y", "A"}, {"R", "G", "B"}, {"R", "G", "B", "A"}};
    d.channel_names.assign(names[h.channels - 1], names[h.channels - 1] + h.channels);
    for (int i = 0; i < h.num_text; ++i)
        if (std::strncmp(h.text[i].key, "meso:", 5) == 0 && h.text[i].text)
            d.meta.emplace_back(h.text[i].key + 5, h.text[i].text);
    if (!pixels) return d;

    std::vector<unsigned char> buf(h.row_bytes * h.height);
    std::vector<png_bytep> rows(h.height);
    for (size_t y = 0; y < h.height; ++y) rows[y] = buf.data() + y * h.row_bytes;
    if (!png_read_rows(r.st, rows.data())) image_read_error(path, one_line(r.st.error, "the pixel data is corrupt"));
    d.image = Image(int(h.width), int(h.height), h.channels);
    std::vector<float> &out = d.image.data;
    if (h.bit_depth == 16) {
        const uint16_t *v = reinterpret_cast<const uint16_t *>(buf.data());
        for (size_t i = 0; i < out.size(); ++i) out[i] = float(v[i]) * (1.f / 65535.f);
    } else {
        for (size_t i = 0; i < out.size(); ++i) out[i] = float(buf[i]) * (1.f / 255.f);
    }
    return d;
}

void write_png_file(const std::string &path, int width, int height, int channels, int bit_depth, const void *samples,
                    bool srgb) {
    if (channels < 1 || channels > 4 || (bit_depth != 8 && bit_depth != 16))
        throw std::runtime_error(fmt::format("PNG holds 1 to 4 channels of 8 or 16 bits, not {} of {}", channels, bit_depth));
    const size_t row_bytes = size_t(width) * size_t(channels) * size_t(bit_depth / 8);
    std::vector<png_bytep> rows(static_cast<size_t>(height));
    for (size_t y = 0; y < rows.size(); ++y)
        rows[y] = const_cast<png_bytep>(static_cast<const unsigned char *>(samples) + y * row_bytes);
    PngFile w(path, /*for_writing=*/true);
    if (!w.problem.empty()) throw std::runtime_error(w.problem);
    if (!png_write_all(w.st, width, height, channels, bit_depth, srgb, rows.data()))
        throw std::runtime_error(one_line(w.st.error, "libpng could not write the file"));
    w.close();
}

}  // namespace meso
