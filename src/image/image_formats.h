// Internal to image/: the readers and writers behind image.h's read_image, read_image_metadata,
// stored_sample_type, write_exr and write_png. EXR goes through OpenEXR (image/exr_file.cpp),
// PNG through libpng (image/png_file.cpp), everything else through the OpenImageIO module
// (image/oiio_loader.cpp, loaded on first use). image_io.cpp picks one by the file's first bytes.
#pragma once
#include <cstdint>
#include <string>
#include <vector>
#include "image/image.h"
#include "image/oiio_abi.h"

namespace meso {

/// A file's image as its reader presents it: pixels (or, header only, just the size) plus what
/// read_image needs to finish the job (channel order, sRGB decoding) and the metadata.
struct DecodedImage {
    Image image;                             ///< data empty when only the header was read
    std::vector<std::string> channel_names;  ///< in the image's channel order
    SampleType sample = SampleType::Float;   ///< stored sample type (widest channel)
    bool says_linear = false;                ///< the file declares linear colour (PNG gAMA 1.0, ...)
    int alpha_channel = -1;
    ImageMetadata meta;  ///< "meso:KEY" string attributes, KEY without the prefix
};

[[noreturn]] void image_read_error(const std::string &path, const std::string &why);
/// `s` on one line without trailing blanks (libraries' messages may span several), or `fallback`.
std::string one_line(std::string s, const char *fallback);
/// Refuses (image_read_error) a declared size that decoded_size_problem refuses, or one that
/// does not fit an Image, before any pixel is allocated.
void check_declared_size(const std::string &path, int64_t width, int64_t height, int64_t channels,
                         int bytes_per_value);
/// A header-only DecodedImage: the size set, no pixels allocated.
void set_header_size(DecodedImage &d, int64_t width, int64_t height, int channels);

/// The readers: the whole image, or (pixels = false) the header only. Each throws
/// image_read_error on failure.
DecodedImage read_exr_file(const std::string &path, bool pixels);
DecodedImage read_png_file(const std::string &path, bool pixels);
/// Radiance RGBE in the standard orientation (image/hdr_file.cpp); other .hdr files go to the module.
DecodedImage read_hdr_file(const std::string &path, bool pixels);
bool is_plain_rgbe_file(const std::string &path);
DecodedImage read_oiio_file(const std::string &path, bool pixels);

/// The writers write `path` (a temporary file: image_io.cpp renames it into place) and throw
/// any std::exception with the reason on failure.
void write_exr_file(const std::string &path, const Image &img, const std::vector<std::string> &channel_names,
                    const ImageMetadata &meta);
/// `samples`: width * height * channels values of bit_depth 8 (uint8_t) or 16 (uint16_t);
/// channels 1 (grey), 2 (grey + alpha), 3 (RGB) or 4 (RGBA); `srgb`: write an sRGB chunk.
void write_png_file(const std::string &path, int width, int height, int channels, int bit_depth,
                    const void *samples, bool srgb);

/// The OpenImageIO module (image/oiio_abi.h): where it is looked for, in order: next to the
/// executable, the build tree it was built in, then $MESO_OIIO_MODULE.
std::vector<std::string> oiio_module_candidates();
/// Loads the first candidate that is a module of meso's ABI version; null when none is, with
/// every path tried and why it failed in `problem`. Exposed for tests; read_oiio_file loads
/// the module once, from oiio_module_candidates().
const MesoOiioApi *load_oiio_module(const std::vector<std::string> &candidates, std::string &problem);

}  // namespace meso
