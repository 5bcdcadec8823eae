// meso's own EXR (OpenEXR) and PNG (libpng) readers and writers against OpenImageIO as an
// independent reader and writer of the same files, the OpenImageIO module for every other
// format, and the promise behind them (issue 22): the meso binary does not load OpenImageIO
// unless a file needs it.
#include <gtest/gtest.h>
#include <Imath/half.h>
#include <OpenImageIO/imageio.h>
#include <png.h>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include "core/error.h"
#include "image/image.h"
#include "image/image_formats.h"
#include "cli_capture.h"
#include "scratch_dir.h"

using namespace meso;
namespace fs = std::filesystem;

namespace {

std::string tmp(const std::string &name) { return meso::test::scratch_dir("meso_test_image_formats") + "/" + name; }

/// What OpenImageIO reads from a file: channel names, pixels as float, string attributes.
struct OiioRead {
    std::vector<std::string> names;
    int width = 0, height = 0;
    OIIO::TypeDesc format;
    std::vector<float> pixels;
    std::map<std::string, std::string> strings;
};

/// `unassociated`: PNG colour as stored (OpenImageIO otherwise premultiplies it by alpha).
OiioRead oiio_read(const std::string &path, bool unassociated = false) {
    OIIO::ImageSpec config;
    if (unassociated) config.attribute("oiio:UnassociatedAlpha", 1);
    auto in = OIIO::ImageInput::open(path, &config);
    EXPECT_TRUE(in) << OIIO::geterror();
    OiioRead r;
    if (!in) return r;
    const OIIO::ImageSpec &s = in->spec();
    r.names = s.channelnames, r.width = s.width, r.height = s.height, r.format = s.format;
    r.pixels.resize(size_t(s.width) * s.height * s.nchannels);
    EXPECT_TRUE(in->read_image(0, 0, 0, s.nchannels, OIIO::TypeDesc::FLOAT, r.pixels.data())) << in->geterror();
    for (const auto &p : s.extra_attribs)
        if (p.type() == OIIO::TypeDesc::STRING) r.strings[p.name().string()] = p.get_string();
    return r;
}

/// Writes `values` (already in `type`'s range) with OpenImageIO.
void oiio_write(const std::string &path, int w, int h, const std::vector<std::string> &names, OIIO::TypeDesc type,
                const std::vector<float> &values, const std::vector<std::pair<std::string, std::string>> &attrs = {}) {
    OIIO::ImageSpec spec(w, h, int(names.size()), type);
    spec.channelnames = names;
    for (const auto &[k, v] : attrs) spec.attribute(k, v);
    if (type == OIIO::TypeDesc::UINT8 || type == OIIO::TypeDesc::UINT16) spec.attribute("oiio:UnassociatedAlpha", 1);
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out) << OIIO::geterror();
    ASSERT_TRUE(out->open(path, spec)) << out->geterror();
    if (type == OIIO::TypeDesc::UINT8 || type == OIIO::TypeDesc::UINT16) {
        // integer code values, passed as such (no float -> [0, max] scaling)
        std::vector<uint16_t> v16(values.begin(), values.end());
        std::vector<uint8_t> v8(values.begin(), values.end());
        ASSERT_TRUE(type == OIIO::TypeDesc::UINT8 ? out->write_image(type, v8.data()) : out->write_image(type, v16.data()));
    } else {
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, values.data())) << out->geterror();
    }
    ASSERT_TRUE(out->close());
}

/// Pixels of w x h x c with distinct, not-round values (sign, magnitudes, a denormal).
Image pattern(int w, int h, int c) {
    Image img(w, h, c);
    for (size_t i = 0; i < img.data.size(); ++i)
        img.data[i] = (i % 7 == 3 ? -1.f : 1.f) * (float(i) * 0.37f + 1e-3f) * (i % 11 == 5 ? 1e6f : 1.f);
    if (!img.data.empty()) img.data[0] = 1e-40f;
    return img;
}

/// Values a channel named "channelN", "R", "G", "B", "A" or "Y" of write_exr holds: its meso index.
int written_index(const std::string &name, int channels) {
    if (name == "Y") return 0;
    if (name == "A") return channels == 2 ? 1 : 3;
    if (name == "R" || name == "G" || name == "B") return name == "R" ? 0 : name == "G" ? 1 : 2;
    return std::stoi(name.substr(7));
}

}  // namespace

// meso writes, OpenImageIO reads: every channel as 32-bit float under its name, metadata as
// string attributes; meso reads its own file back bit for bit, channels in order.
TEST(ImageFormats, ExrWrittenByMesoReadsTheSameInOpenImageIO) {
    const ImageMetadata meta = {{"defines", "[\"a=1\"]"}, {"scene_sha1", "abc"}, {"seed", "7"}};  // EXR sorts them
    for (int C : {1, 2, 3, 4, 31}) {
        SCOPED_TRACE("channels " + std::to_string(C));
        const Image img = pattern(5, 3, C);
        const std::string p = tmp("meso_" + std::to_string(C) + ".exr");
        write_exr(p, img, meta);
        OiioRead o = oiio_read(p);
        ASSERT_EQ(int(o.names.size()), C);
        EXPECT_EQ(o.format, OIIO::TypeDesc::FLOAT);
        for (int k = 0; k < C; ++k) {
            const int i = written_index(o.names[size_t(k)], C);
            for (size_t px = 0; px < 15; ++px)
                ASSERT_EQ(o.pixels[px * C + size_t(k)], img.data[px * C + size_t(i)]) << o.names[size_t(k)] << " pixel " << px;
        }
        for (const auto &[k, v] : meta) EXPECT_EQ(o.strings["meso:" + k], v) << k;
        const Image back = read_image(p);
        ASSERT_EQ(back.channels, C);
        EXPECT_EQ(std::memcmp(back.data.data(), img.data.data(), img.data.size() * sizeof(float)), 0);
        EXPECT_EQ(read_image_metadata(p), meta);
        EXPECT_EQ(stored_sample_type(p), SampleType::Float);
    }
}

// OpenImageIO writes (float, half, with a data window off the origin, odd channel names),
// meso reads: the same channels in the same order with the same values as OpenImageIO reads.
TEST(ImageFormats, ExrWrittenByOpenImageIOReadsTheSameInMeso) {
    struct Case {
        std::vector<std::string> names;
        OIIO::TypeDesc type;
    };
    std::vector<std::string> many = {"R", "G", "B", "A"};
    for (int c = 4; c < 31; ++c) many.push_back("channel" + std::to_string(c));
    const Case cases[] = {{{"Y"}, OIIO::TypeDesc::FLOAT},
                          {{"R", "G", "B"}, OIIO::TypeDesc::HALF},
                          {{"R", "G", "B", "A"}, OIIO::TypeDesc::FLOAT},
                          {many, OIIO::TypeDesc::HALF},
                          {{"Z", "diffuse.R", "diffuse.G", "N.X", "N.Y", "N.Z", "A", "foo", "B"}, OIIO::TypeDesc::FLOAT}};
    int n = 0;
    for (const Case &cs : cases) {
        const int C = int(cs.names.size());
        SCOPED_TRACE("case " + std::to_string(n) + ", channels " + std::to_string(C));
        const std::string p = tmp("oiio_" + std::to_string(n++) + ".exr");
        Image img = pattern(6, 4, C);
        for (float &v : img.data) v = std::fmod(v, 60000.f);  // in half's range
        oiio_write(p, 6, 4, cs.names, cs.type, img.data, {{"meso:spp", "64"}, {"Software", "test"}});
        const OiioRead o = oiio_read(p);
        const DecodedImage d = read_exr_file(p, true);
        EXPECT_EQ(d.channel_names, o.names);
        ASSERT_EQ(d.image.data.size(), o.pixels.size());
        EXPECT_EQ(std::memcmp(d.image.data.data(), o.pixels.data(), o.pixels.size() * sizeof(float)), 0);
        EXPECT_EQ(d.sample, cs.type == OIIO::TypeDesc::HALF ? SampleType::Half : SampleType::Float);
        EXPECT_EQ(read_image_metadata(p), (ImageMetadata{{"spp", "64"}}));
        if (cs.names == many) {  // write_exr's naming: read_image restores the order
            const Image back = read_image(p);
            for (size_t i = 0; i < img.data.size(); ++i) ASSERT_EQ(back.data[i], float(half(img.data[i]))) << i;
        }
    }
}

TEST(ImageFormats, ExrDataWindowAndUintChannels) {
    const std::string p = tmp("window.exr");
    {
        OIIO::ImageSpec spec(3, 2, 1, OIIO::TypeDesc::FLOAT);
        spec.x = -5, spec.y = 7, spec.full_x = 0, spec.full_y = 0, spec.full_width = 10, spec.full_height = 10;
        spec.channelnames = {"Y"};
        auto out = OIIO::ImageOutput::create(p);
        ASSERT_TRUE(out && out->open(p, spec));
        const float v[6] = {1, 2, 3, 4, 5, 6};
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, v));
        out->close();
    }
    const Image img = read_image(p);  // the data window, as OpenImageIO read it
    ASSERT_EQ(img.width, 3);
    ASSERT_EQ(img.height, 2);
    EXPECT_EQ(img.data, (std::vector<float>{1, 2, 3, 4, 5, 6}));
    // uint channels (object ids) are read as their values
    const std::string u = tmp("ids.exr");
    {
        OIIO::ImageSpec spec(2, 1, 1, OIIO::TypeDesc::UINT32);
        spec.channelnames = {"id"};
        auto out = OIIO::ImageOutput::create(u);
        ASSERT_TRUE(out && out->open(u, spec));
        const uint32_t ids[2] = {7, 123456};
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT32, ids));
        out->close();
    }
    EXPECT_EQ(read_image(u).data, (std::vector<float>{7.f, 123456.f}));
    EXPECT_EQ(stored_sample_type(u), SampleType::UInt32);
}

// OpenImageIO writes PNG (8 and 16 bits; grey, grey + alpha, RGB, RGBA; alpha stored as given),
// meso reads the same code values / max as OpenImageIO does with colour kept unassociated.
TEST(ImageFormats, PngWrittenByOpenImageIOReadsTheSameInMeso) {
    const std::vector<std::string> layouts[] = {{"Y"}, {"Y", "A"}, {"R", "G", "B"}, {"R", "G", "B", "A"}};
    for (OIIO::TypeDesc type : {OIIO::TypeDesc::UINT8, OIIO::TypeDesc::UINT16}) {
        const float max = type == OIIO::TypeDesc::UINT8 ? 255.f : 65535.f;
        for (const auto &names : layouts) {
            const int C = int(names.size());
            SCOPED_TRACE(std::to_string(C) + " channels, " + std::to_string(type.size() * 8) + " bits");
            std::vector<float> codes(size_t(7) * 5 * C);
            for (size_t i = 0; i < codes.size(); ++i) codes[i] = std::fmod(float(i) * 97.f + float(i * i) * 13.f, max + 1.f);
            const std::string p = tmp("oiio_" + std::to_string(C) + "_" + std::to_string(type.size()) + ".png");
            oiio_write(p, 7, 5, names, type, codes, {{"meso:seed", "42"}});
            const OiioRead o = oiio_read(p, /*unassociated=*/true);
            const Image raw = read_image(p);
            ASSERT_EQ(raw.channels, C);
            ASSERT_EQ(raw.data.size(), o.pixels.size());
            for (size_t i = 0; i < o.pixels.size(); ++i) {
                ASSERT_EQ(raw.data[i], o.pixels[i]) << i;
                ASSERT_EQ(std::lround(raw.data[i] * max), long(codes[i])) << i;
            }
            EXPECT_EQ(stored_sample_type(p), type == OIIO::TypeDesc::UINT8 ? SampleType::UInt8 : SampleType::UInt16);
            EXPECT_EQ(read_image_metadata(p), (ImageMetadata{{"seed", "42"}}));
            // sRGB-decoded on request, alpha never
            const Image lin = read_image(p, true);
            for (size_t i = 0; i < lin.data.size(); ++i) {
                const bool alpha = (C == 2 && i % 2 == 1) || (C == 4 && i % 4 == 3);
                ASSERT_EQ(lin.data[i], alpha ? raw.data[i] : srgb_to_linear(raw.data[i])) << i;
            }
        }
    }
    // A PNG that says it is linear (gAMA 1.0) is not decoded.
    const std::string p = tmp("linear.png");
    oiio_write(p, 2, 1, {"R", "G", "B"}, OIIO::TypeDesc::UINT8, {0, 64, 128, 192, 255, 10}, {{"oiio:ColorSpace", "Linear"}});
    EXPECT_EQ(read_image(p, true).data, read_image(p).data);
    EXPECT_FLOAT_EQ(read_image(p).data[2], 128.f / 255.f);
}

// meso writes PNG (8-bit sRGB RGB; 16-bit grey for height maps), OpenImageIO reads the same.
TEST(ImageFormats, PngWrittenByMesoReadsTheSameInOpenImageIO) {
    Image img(4, 3, 3);
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = float(i) / float(img.data.size());
    const std::string p8 = tmp("meso8.png");
    write_png(p8, img);
    const OiioRead o8 = oiio_read(p8);
    EXPECT_EQ(o8.format, OIIO::TypeDesc::UINT8);
    EXPECT_EQ(o8.strings.at("oiio:ColorSpace"), "sRGB");
    const Image back8 = read_image(p8);
    EXPECT_EQ(back8.data, o8.pixels);
    for (size_t i = 0; i < img.data.size(); ++i) EXPECT_NEAR(srgb_to_linear(back8.data[i]), img.data[i], 0.01f) << i;

    std::vector<uint16_t> heights(5 * 2);
    for (size_t i = 0; i < heights.size(); ++i) heights[i] = uint16_t(i * 6553 + (i % 3) * 17);
    const std::string p16 = tmp("meso16.png");
    write_png16_grey(p16, 5, 2, heights);
    const OiioRead o16 = oiio_read(p16);
    EXPECT_EQ(o16.format, OIIO::TypeDesc::UINT16);
    ASSERT_EQ(o16.pixels.size(), heights.size());
    for (size_t i = 0; i < heights.size(); ++i) EXPECT_EQ(std::lround(o16.pixels[i] * 65535.f), heights[i]) << i;
    EXPECT_EQ(read_image(p16).data, o16.pixels);
    EXPECT_EQ(stored_sample_type(p16), SampleType::UInt16);
}

namespace {

/// A PNG written with libpng directly: a 4-bit grey image and a palette image with transparency,
/// the layouts OpenImageIO and meso expand (to 8-bit grey and to RGBA).
void write_png_with_libpng(const std::string &path, bool palette) {
    FILE *f = std::fopen(path.c_str(), "wb");
    ASSERT_TRUE(f);
    png_structp png = png_create_write_struct(PNG_LIBPNG_VER_STRING, nullptr, nullptr, nullptr);
    png_infop info = png_create_info_struct(png);
    png_init_io(png, f);
    png_set_IHDR(png, info, 4, 2, palette ? 8 : 4, palette ? PNG_COLOR_TYPE_PALETTE : PNG_COLOR_TYPE_GRAY,
                 PNG_INTERLACE_NONE, PNG_COMPRESSION_TYPE_DEFAULT, PNG_FILTER_TYPE_DEFAULT);
    png_color colours[3] = {{255, 0, 0}, {10, 200, 30}, {1, 2, 3}};
    png_byte alpha[3] = {255, 128, 0};
    if (palette) {
        png_set_PLTE(png, info, colours, 3);
        png_set_tRNS(png, info, alpha, 3, nullptr);
    }
    png_write_info(png, info);
    png_byte rows[2][4] = {{0, 1, 2, 1}, {2, 2, 0, 1}};
    png_byte packed[2][2] = {{0x0f, 0x7a}, {0x31, 0xe0}};  // 4-bit grey: two pixels a byte
    for (int y = 0; y < 2; ++y) png_write_row(png, palette ? rows[y] : packed[y]);
    png_write_end(png, info);
    png_destroy_write_struct(&png, &info);
    std::fclose(f);
}

}  // namespace

TEST(ImageFormats, PaletteAndLowBitDepthPngAreExpandedAsOpenImageIODoes) {
    for (bool palette : {false, true}) {
        const std::string p = tmp(palette ? "palette.png" : "grey4.png");
        write_png_with_libpng(p, palette);
        const OiioRead o = oiio_read(p, /*unassociated=*/true);
        const Image img = read_image(p);
        EXPECT_EQ(img.channels, palette ? 4 : 1);
        EXPECT_EQ(img.data, o.pixels);
        EXPECT_EQ(stored_sample_type(p), SampleType::UInt8);
    }
    const Image grey = read_image(tmp("grey4.png"));
    EXPECT_EQ(grey.data[1], 1.f);  // 4-bit 15 -> 255
    const Image pal = read_image(tmp("palette.png"));
    EXPECT_FLOAT_EQ(pal.data[4 + 1], 200.f / 255.f);  // palette entry 1, green
    EXPECT_FLOAT_EQ(pal.data[4 + 3], 128.f / 255.f);  // its transparency
}

// Radiance .hdr is read natively (image/hdr_file.cpp), other formats through the OpenImageIO
// module; both equal what OpenImageIO reads directly, bit for bit.
TEST(ImageFormats, HdrAndTiffThroughTheModuleEqualOpenImageIO) {
    const std::string hdr = std::string(MESO_SOURCE_DIR) + "/scenes/assets/sky.hdr";
    const OiioRead o = oiio_read(hdr);
    const Image img = read_image(hdr);
    ASSERT_EQ(img.width, o.width);
    ASSERT_EQ(img.data.size(), o.pixels.size());
    EXPECT_EQ(std::memcmp(img.data.data(), o.pixels.data(), o.pixels.size() * sizeof(float)), 0);
    EXPECT_EQ(stored_sample_type(hdr), SampleType::Float);

    // An RLE-encoded .hdr written by OpenImageIO (width >= 8: new RLE), with zeros and a wide range.
    const std::string hdr2 = tmp("rle.hdr");
    std::vector<float> v(size_t(37) * 5 * 3);
    for (size_t i = 0; i < v.size(); ++i) v[i] = i % 7 == 0 ? 0.f : float(std::ldexp(1.0 + 0.37 * double(i % 11), int(i % 23) - 11));
    oiio_write(hdr2, 37, 5, {"R", "G", "B"}, OIIO::TypeDesc::FLOAT, v);
    EXPECT_EQ(read_image(hdr2).data, oiio_read(hdr2).pixels);
    // Truncated: the error names the file and the row.
    const std::string cut = tmp("cut.hdr");
    {
        std::ifstream in(hdr2, std::ios::binary);
        std::string bytes((std::istreambuf_iterator<char>(in)), std::istreambuf_iterator<char>());
        std::ofstream(cut, std::ios::binary) << bytes.substr(0, bytes.size() - 40);
    }
    try {
        read_image(cut);
        ADD_FAILURE() << "a truncated .hdr was read";
    } catch (const MesoError &e) {
        EXPECT_NE(std::string(e.what()).find("cut.hdr"), std::string::npos) << e.what();
        EXPECT_NE(std::string(e.what()).find("truncated at row"), std::string::npos) << e.what();
    }

    const std::string tif = tmp("a.tif");
    oiio_write(tif, 3, 1, {"R", "G", "B"}, OIIO::TypeDesc::UINT16, {0, 1000, 30000, 65535, 5, 6, 7, 8, 9});
    EXPECT_EQ(stored_sample_type(tif), SampleType::UInt16);
    EXPECT_EQ(read_image(tif).data, oiio_read(tif).pixels);
    EXPECT_FLOAT_EQ(read_image(tif, true).data[2], srgb_to_linear(30000.f / 65535.f));
    EXPECT_EQ(read_image_metadata(tif), ImageMetadata{});
}

TEST(ImageFormats, ModuleThatCannotBeLoadedIsNamedWithEveryPathTried) {
    const std::string not_a_module = tmp("not_a_module.so");
    std::ofstream(not_a_module) << "not an ELF file";
    std::string problem;
    EXPECT_EQ(load_oiio_module({"/nonexistent/libmeso_oiio.so", not_a_module}, problem), nullptr);
    EXPECT_NE(problem.find("/nonexistent/libmeso_oiio.so (not found)"), std::string::npos) << problem;
    EXPECT_NE(problem.find(not_a_module + " ("), std::string::npos) << problem;
    // The search: next to the executable first, then the build tree (where this test finds it).
    const auto candidates = oiio_module_candidates();
    ASSERT_GE(candidates.size(), 2u);
    EXPECT_EQ(fs::path(candidates[0]).filename(), "libmeso_oiio.so");
    EXPECT_NE(load_oiio_module(candidates, problem), nullptr) << problem;
}

TEST(ImageFormats, UnknownAndCorruptFilesNameTheFile) {
    const std::string junk = tmp("junk.xyz");
    std::ofstream(junk) << "this is no image at all";
    std::string e = meso::test::meso_error_of([&] { read_image(junk); });
    EXPECT_EQ(e.rfind(junk + ": cannot read image: ", 0), 0u) << e;
    // a PNG cut inside its pixel data
    Image img = pattern(64, 64, 3);
    for (float &v : img.data) v = std::fabs(std::sin(v));
    const std::string cut = tmp("cut.png");
    write_png(cut, img);
    fs::resize_file(cut, fs::file_size(cut) / 2);
    e = meso::test::meso_error_of([&] { read_image(cut); });
    EXPECT_EQ(e.rfind(cut + ": cannot read image: ", 0), 0u) << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;
}

namespace {

/// Runs a shell command, returning what it wrote to stdout and stderr.
std::string run_shell(const std::string &cmd) {
    std::string out;
    FILE *p = popen((cmd + " 2>&1").c_str(), "r");
    if (!p) return out;
    char buf[4096];
    for (size_t n; (n = std::fread(buf, 1, sizeof buf, p)) > 0;) out.append(buf, n);
    pclose(p);
    return out;
}

bool mentions_openimageio(const std::string &s) {
    std::string lower(s);
    for (char &c : lower) c = char(std::tolower(static_cast<unsigned char>(c)));
    return lower.find("openimageio") != std::string::npos;
}

}  // namespace

// Issue 22: the meso binary does not link OpenImageIO (0.2 s and 130 MB at every start-up), and
// reading and writing EXR, PNG and Radiance .hdr does not load it; a TIFF loads the module.
TEST(ImageFormats, MesoLoadsOpenImageIOOnlyForOtherFormats) {
    const std::string meso = MESO_BINARY;
    const std::string libs = run_shell("LD_TRACE_LOADED_OBJECTS=1 '" + meso + "'");  // what ldd prints
    EXPECT_NE(libs.find("libOpenEXR"), std::string::npos) << libs;
    EXPECT_FALSE(mentions_openimageio(libs)) << libs;

    const std::string exr = tmp("conv.exr"), png = tmp("conv.png"), out = tmp("conv_out.exr");
    write_exr(exr, pattern(8, 8, 3));
    std::string log = run_shell("LD_DEBUG=files '" + meso + "' convert '" + exr + "' '" + png + "'");
    ASSERT_TRUE(fs::exists(png)) << log;
    log += run_shell("LD_DEBUG=files '" + meso + "' convert '" + png + "' '" + out + "'");
    ASSERT_TRUE(fs::exists(out)) << log;
    EXPECT_FALSE(mentions_openimageio(log));
    EXPECT_EQ(log.find("libmeso_oiio"), std::string::npos);

    const std::string hdr = std::string(MESO_SOURCE_DIR) + "/scenes/assets/sky.hdr";
    log = run_shell("LD_DEBUG=files '" + meso + "' convert '" + hdr + "' '" + tmp("sky.exr") + "'");
    EXPECT_TRUE(fs::exists(tmp("sky.exr")));
    EXPECT_EQ(log.find("libmeso_oiio"), std::string::npos);
    const std::string tif = tmp("mod.tif");
    oiio_write(tif, 2, 1, {"R", "G", "B"}, OIIO::TypeDesc::UINT8, {0, 10, 20, 30, 40, 50});
    log = run_shell("LD_DEBUG=files '" + meso + "' convert '" + tif + "' '" + tmp("tif.exr") + "'");
    EXPECT_NE(log.find("libmeso_oiio"), std::string::npos);
    EXPECT_TRUE(mentions_openimageio(log));
    EXPECT_TRUE(fs::exists(tmp("tif.exr")));
}
