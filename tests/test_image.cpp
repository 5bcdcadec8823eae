// Image I/O (OpenImageIO), error metrics, the false-colour map and `meso compare`.
#include <gtest/gtest.h>
#include <OpenImageIO/imageio.h>
#include <unistd.h>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include "app/commands.h"
#include "core/error.h"
#include "core/input_file.h"
#include "image/false_colour.h"
#include "image/image.h"

using namespace meso;
namespace fs = std::filesystem;

namespace {

/// A fresh directory per test, removed afterwards.
class ImageTmp : public ::testing::Test {
protected:
    void SetUp() override {
        const auto *info = ::testing::UnitTest::GetInstance()->current_test_info();
        dir = fs::temp_directory_path() /
              (std::string("meso_image_") + info->test_suite_name() + "_" + info->name() + "_" + std::to_string(getpid()));
        fs::remove_all(dir);
        fs::create_directories(dir);
    }
    void TearDown() override { fs::remove_all(dir); }
    std::string path(const std::string &name) const { return (dir / name).string(); }
    /// Files in the directory (to prove nothing half-written was left behind).
    std::vector<std::string> listing() const {
        std::vector<std::string> v;
        for (auto &e : fs::directory_iterator(dir)) v.push_back(e.path().filename().string());
        std::sort(v.begin(), v.end());
        return v;
    }
    fs::path dir;
};

std::string error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

bool starts_with(const std::string &s, const std::string &prefix) { return s.rfind(prefix, 0) == 0; }

Image filled(int w, int h, Spectrum c) {
    Image img(w, h, 3);
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x) img.set_rgb(x, y, c);
    return img;
}

int run(std::vector<std::string> args, std::string *out, std::string *err = nullptr) {
    std::vector<char *> argv;
    for (auto &a : args) argv.push_back(a.data());
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    int rc = run_cli(int(argv.size()), argv.data());
    std::fflush(stdout);
    std::fflush(stderr);
    *out = testing::internal::GetCapturedStdout();
    std::string e = testing::internal::GetCapturedStderr();
    if (err) *err = e;
    return rc;
}

class ImageIO : public ImageTmp {};
class Metrics : public ImageTmp {};
class Compare : public ImageTmp {};

}  // namespace

TEST_F(ImageIO, ExrRoundTripIsBitExactFloat) {
    Image img(5, 3, 3);
    const float special[] = {0.f, -0.f, 1e-8f, 1e-40f /* denormal */, 65504.f * 4, -3.25f, 0.1f, 1.f / 3.f, 7e30f};
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = special[i % 9] * (i % 2 ? 1.f : 1.0001f) + (i > 30 ? i : 0);
    std::string p = path("a.exr");
    write_exr(p, img);
    // The file holds 32-bit float channels R, G, B (never half).
    auto in = OIIO::ImageInput::open(p);
    ASSERT_TRUE(in);
    EXPECT_EQ(in->spec().format, OIIO::TypeDesc::FLOAT);
    for (auto f : in->spec().channelformats) EXPECT_EQ(f, OIIO::TypeDesc::FLOAT);
    EXPECT_EQ(in->spec().channelnames, (std::vector<std::string>{"R", "G", "B"}));
    in->close();
    Image back = read_image(p);
    ASSERT_EQ(back.width, 5);
    ASSERT_EQ(back.height, 3);
    ASSERT_EQ(back.channels, 3);
    EXPECT_EQ(std::memcmp(back.data.data(), img.data.data(), img.data.size() * sizeof(float)), 0);
    // Other channel counts survive too; no temporary files are left.
    for (int c : {1, 4}) {
        Image g(4, 2, c);
        for (size_t i = 0; i < g.data.size(); ++i) g.data[i] = float(i) * -0.37f + 1e-7f;
        write_exr(path("c.exr"), g);
        Image gb = read_image(path("c.exr"));
        ASSERT_EQ(gb.channels, c);
        EXPECT_EQ(std::memcmp(gb.data.data(), g.data.data(), g.data.size() * sizeof(float)), 0);
        EXPECT_EQ(gb.rgb(1, 1).r, g.at(1, 1, 0));
    }
    EXPECT_EQ(listing(), (std::vector<std::string>{"a.exr", "c.exr"}));
}

TEST_F(ImageIO, PngIs8BitSrgb) {
    Image img(5, 1, 3);
    img.set_rgb(0, 0, Spectrum(0.f));
    img.set_rgb(1, 0, Spectrum(0.5f));
    img.set_rgb(2, 0, Spectrum(1.f));
    img.set_rgb(3, 0, Spectrum(-1.f, 7.f, NAN));  // clamped; NaN -> 0
    img.set_rgb(4, 0, Spectrum(0.25f, 0.002f, 0.f));
    std::string p = path("a.png");
    write_png(p, img);
    auto in = OIIO::ImageInput::open(p);
    ASSERT_TRUE(in);
    EXPECT_EQ(in->spec().format, OIIO::TypeDesc::UINT8);
    EXPECT_EQ(in->spec().nchannels, 3);
    std::vector<uint8_t> px(15);
    ASSERT_TRUE(in->read_image(0, 0, 0, 3, OIIO::TypeDesc::UINT8, px.data()));
    in->close();
    // sRGB(0.5) = 1.055 * 0.5^(1/2.4) - 0.055 = 0.735357 -> 187.52 -> 188.
    // sRGB(0.25) = 0.537098 -> 136.96 -> 137; sRGB(0.002) = 12.92 * 0.002 -> 6.59 -> 7.
    const uint8_t expect[15] = {0, 0, 0, 188, 188, 188, 255, 255, 255, 0, 255, 0, 137, 7, 0};
    for (int i = 0; i < 15; ++i) EXPECT_EQ(px[i], expect[i]) << i;
    // Reading back: raw code values, or decoded to linear on request.
    Image raw = read_image(p), lin = read_image(p, true);
    EXPECT_FLOAT_EQ(raw.at(1, 0, 0), 188.f / 255.f);
    EXPECT_NEAR(lin.at(1, 0, 0), 0.5f, 0.003f);
    EXPECT_EQ(lin.at(2, 0, 1), 1.f);
    // Exposure: +1 stop doubles the linear value.
    Image quarter = filled(1, 1, Spectrum(0.25f));
    write_png(path("b.png"), quarter, 1.f);
    EXPECT_FLOAT_EQ(read_image(path("b.png")).at(0, 0, 0), 188.f / 255.f);
}

TEST_F(ImageIO, SrgbTransferRoundTrip) {
    EXPECT_EQ(linear_to_srgb(0.f), 0.f);
    EXPECT_FLOAT_EQ(linear_to_srgb(1.f), 1.f);
    EXPECT_NEAR(linear_to_srgb(0.5f), 0.735357f, 1e-5f);
    for (float v = 0.f; v <= 1.f; v += 1.f / 64)
        EXPECT_NEAR(srgb_to_linear(linear_to_srgb(v)), v, 1e-5f);
    // Continuous at the knee.
    EXPECT_NEAR(linear_to_srgb(0.0031308f), 0.04045f, 1e-5f);
}

TEST_F(ImageIO, MissingGarbageAndTruncatedFilesGiveOneMessage) {
    std::string missing = path("missing.exr");
    std::string e = error_of([&] { read_image(missing); });
    EXPECT_TRUE(starts_with(e, missing + ": cannot read image: ")) << e;

    std::string garbage = path("x.exr");
    {
        std::ofstream f(garbage, std::ios::binary);
        for (int i = 0; i < 1000; ++i) f.put(char((i * 7919) & 0xff));
    }
    e = error_of([&] { read_image(garbage); });
    EXPECT_TRUE(starts_with(e, garbage + ": cannot read image: ")) << e;
    EXPECT_EQ(e.find('\n'), std::string::npos) << e;

    // A valid EXR cut in the middle of its pixel data.
    Image big(64, 64, 3);
    for (size_t i = 0; i < big.data.size(); ++i) big.data[i] = std::sin(float(i));
    std::string t = path("t.exr");
    write_exr(t, big);
    fs::resize_file(t, fs::file_size(t) * 6 / 10);
    e = error_of([&] { read_image(t); });
    EXPECT_TRUE(starts_with(e, t + ": cannot read image: ")) << e;

    std::string empty = path("empty.png");
    std::ofstream(empty).close();
    e = error_of([&] { read_image(empty); });
    EXPECT_TRUE(starts_with(e, empty + ": cannot read image: ")) << e;
}

TEST_F(ImageIO, FailedWriteLeavesNoFile) {
    Image img = filled(4, 4, Spectrum(0.5f));
    std::string p = (dir / "no_such_dir" / "out.exr").string();
    EXPECT_EQ(error_of([&] { write_exr(p, img); }),
              "cannot write '" + p + "': directory '" + (dir / "no_such_dir").string() + "' does not exist");
    EXPECT_TRUE(starts_with(error_of([&] { write_png(p, img); }), "cannot write '" + p + "': "));
    EXPECT_FALSE(fs::exists(dir / "no_such_dir"));
    // A bad image over an existing file: the old file stays intact, no temporary remains.
    std::string good = path("good.exr");
    write_exr(good, img);
    Image bad(4, 4, 3);
    bad.data.resize(5);
    EXPECT_TRUE(starts_with(error_of([&] { write_exr(good, bad); }), "cannot write '" + good + "': "));
    EXPECT_TRUE(starts_with(error_of([&] { write_png(path("x.png"), Image()); }), "cannot write '"));
    EXPECT_EQ(read_image(good).data, img.data);
    // Writing onto a directory fails cleanly too.
    fs::create_directory(dir / "d.exr");
    EXPECT_TRUE(starts_with(error_of([&] { write_exr(path("d.exr"), img); }), "cannot write '"));
    EXPECT_EQ(listing(), (std::vector<std::string>{"d.exr", "good.exr"}));
}

TEST_F(Metrics, HandComputedValues) {
    Image ref(3, 1, 3), test(3, 1, 3);
    ref.set_rgb(0, 0, Spectrum(0.f));
    test.set_rgb(0, 0, Spectrum(0.1f));
    ref.set_rgb(1, 0, Spectrum(1.f));
    test.set_rgb(1, 0, Spectrum(1.f, 1.f, 1.3f));
    ref.set_rgb(2, 0, Spectrum(2.f));
    test.set_rgb(2, 0, Spectrum(NAN, 0.f, 0.f));  // excluded and counted
    ImageMetrics m = compute_metrics(test, ref);
    EXPECT_EQ(m.nonfinite, 1);
    // Squared errors: 3 x 0.01 (pixel 0), 0.09 (pixel 1) over 6 values.
    const double d0 = double(0.1f) * double(0.1f), d1 = sqr(double(1.3f) - 1.0);
    EXPECT_NEAR(m.mse, (3 * d0 + d1) / 6, 1e-12);
    EXPECT_NEAR(m.relmse, (3 * d0 / 0.01 + d1 / 1.01) / 6, 1e-12);
    EXPECT_NEAR(m.rmse, std::sqrt((3 * d0 + d1) / 6), 1e-12);
    EXPECT_NEAR(m.psnr, 10 * std::log10(6 / (3 * d0 + d1)), 1e-9);
    EXPECT_NEAR(m.psnr, 16.9897, 1e-3);  // 10 log10(1 / 0.02)
    double lt = 0.1 + (0.2126 + 0.7152 + 0.0722 * 1.3), lr = 0 + 1;
    EXPECT_NEAR(m.mean_luminance_ratio, lt / lr, 1e-6);

    // Identical images: zero error, infinite PSNR, ratio 1.
    ImageMetrics same = compute_metrics(ref, ref);
    EXPECT_EQ(same.mse, 0);
    EXPECT_TRUE(std::isinf(same.psnr));
    EXPECT_EQ(same.mean_luminance_ratio, 1);
    // A grey image compares as r = g = b.
    Image grey(1, 1, 1), rgb = filled(1, 1, Spectrum(0.5f));
    grey.data[0] = 0.5f;
    EXPECT_EQ(compute_metrics(grey, rgb).mse, 0);
}

TEST_F(Metrics, DifferentSizesAreAnError) {
    EXPECT_EQ(error_of([] { compute_metrics(Image(64, 64), Image(32, 32)); }), "image sizes differ: 64x64 vs 32x32");
}

TEST(ImageColormap, ViridisEndpointsAndMonotoneLightness) {
    Spectrum lo = viridis_srgb(0.f), hi = viridis_srgb(1.f), mid = viridis_srgb(0.5f);
    EXPECT_NEAR(lo.r, 0.267004f, 1e-6f);
    EXPECT_NEAR(lo.b, 0.329415f, 1e-6f);
    EXPECT_NEAR(hi.g, 0.906157f, 1e-6f);
    EXPECT_NEAR(mid.g, 0.566949f, 1e-6f);  // matplotlib viridis(0.5) = (0.128, 0.567, 0.551)
    float prev = -1;
    for (int i = 0; i <= 100; ++i) {
        float y = viridis_linear(i / 100.f).luminance();
        EXPECT_GT(y, prev) << i;
        prev = y;
    }
    EXPECT_EQ(viridis_srgb(-3.f).r, lo.r);
    EXPECT_EQ(viridis_srgb(NAN).r, lo.r);
}

TEST_F(Compare, PrintsMetricsAndJson) {
    Image ref = filled(8, 4, Spectrum(0.5f)), test = ref;
    test.set_rgb(2, 1, Spectrum(0.5f, 0.5f, 1.5f));  // one value off by 1: MSE = 1 / 96
    write_exr(path("ref.exr"), ref);
    write_exr(path("test.exr"), test);

    std::string out, err;
    ASSERT_EQ(run({"meso", "compare", path("test.exr"), path("ref.exr")}, &out, &err), 0) << err;
    EXPECT_NE(out.find("MSE:    1.041667e-02\n"), std::string::npos) << out;
    EXPECT_NE(out.find("RMSE:   1.020621e-01\n"), std::string::npos) << out;
    EXPECT_NE(out.find("PSNR:   19.823 dB"), std::string::npos) << out;
    EXPECT_NE(out.find("relMSE: 4.006410e-02\n"), std::string::npos) << out;  // (1 / 0.26) / 96
    // Mean luminance ratio 1 + 0.0722 / (32 * 0.5) = 1.0045125.
    EXPECT_NE(out.find("mean luminance ratio (test/ref): 1.00451"), std::string::npos) << out;

    ASSERT_EQ(run({"meso", "compare", path("test.exr"), path("ref.exr"), "--json", "--error-image", path("err.png")},
                  &out, &err),
              0)
        << err;
    auto j = nlohmann::json::parse(out);
    EXPECT_NEAR(j["mse"].get<double>(), 1.0 / 96, 1e-9);
    EXPECT_NEAR(j["psnr"].get<double>(), 10 * std::log10(96.0), 1e-6);
    EXPECT_EQ(j["nonfinite"].get<long>(), 0);
    EXPECT_EQ(j["width"].get<int>(), 8);
    EXPECT_NEAR(j["mean_luminance_ratio"].get<double>(), 1.0045125, 1e-6);
    EXPECT_NEAR(j["relmse"].get<double>(), 1 / 0.26 / 96, 1e-9);
    // Squared error luminance of the one bad pixel: 0.0722 * 1^2.
    auto range = j["error_image"]["log10_range"];
    EXPECT_NEAR(range[1].get<double>(), std::log10(0.0722), 1e-5);
    EXPECT_EQ(j["error_image"]["colormap"], "viridis");
    Image e = read_image(path("err.png"), true);
    ASSERT_EQ(e.width, 8);
    // The bad pixel is the brightest (top of viridis), the rest the bottom colour.
    EXPECT_NEAR(e.rgb(2, 1).r, viridis_linear(1.f).r, 0.01f);
    EXPECT_NEAR(e.rgb(0, 0).b, viridis_linear(0.f).b, 0.01f);

    // Human-readable output names the scale; a raw .exr error image holds the values.
    ASSERT_EQ(run({"meso", "compare", path("test.exr"), path("ref.exr"), "--error-image", path("err.exr"),
                   "--error-range", "-4", "0"},
                  &out, &err),
              0)
        << err;
    EXPECT_NE(out.find("error image: "), std::string::npos) << out;
    Image raw = read_image(path("err.exr"));
    EXPECT_EQ(raw.channels, 1);
    EXPECT_NEAR(raw.at(2, 1, 0), 0.0722f, 1e-6f);
    EXPECT_EQ(raw.at(0, 0, 0), 0.f);
    ASSERT_EQ(run({"meso", "compare", path("test.exr"), path("ref.exr"), "--error-image", path("err2.png"),
                   "--error-range", "-4", "0"},
                  &out, &err),
              0)
        << err;
    EXPECT_NE(out.find("0.0001 (dark) .. 1 (bright), log10 [-4.00, 0.00]"), std::string::npos) << out;
}

TEST_F(Compare, ErrorsExitNonZeroWithOneLine) {
    write_exr(path("a.exr"), filled(64, 64, Spectrum(1.f)));
    write_exr(path("b.exr"), filled(32, 32, Spectrum(1.f)));
    std::string out, err;
    EXPECT_EQ(run({"meso", "compare", path("a.exr"), path("b.exr")}, &out, &err), 1);
    EXPECT_EQ(err, "meso: error: image sizes differ: 64x64 vs 32x32\n");
    EXPECT_EQ(run({"meso", "compare", path("a.exr"), path("nope.exr")}, &out, &err), 1);
    EXPECT_TRUE(starts_with(err, "meso: error: " + path("nope.exr") + ": cannot read image: ")) << err;
    // An unwritable error image leaves nothing behind.
    EXPECT_EQ(run({"meso", "compare", path("a.exr"), path("a.exr"), "--error-image", path("no/err.png")}, &out, &err),
              1);
    EXPECT_TRUE(starts_with(err, "meso: error: --error-image " + path("no/err.png") + ": directory '")) << err;
}

// OpenEXR sorts channels by name; write_exr + read_image must still round-trip an image with
// many channels in order (prefilter/model.h's lobes.exr has 31).
TEST(ImageChannels, ManyChannelsRoundTripInOrder) {
    meso::Image img(3, 2, 31);
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = float(i % 31) + 0.001f * float(i / 31);
    const std::string path = ::testing::TempDir() + "/meso_many_channels.exr";
    meso::write_exr(path, img);
    meso::Image back = meso::read_image(path);
    ASSERT_EQ(back.channels, 31);
    for (size_t i = 0; i < img.data.size(); ++i) ASSERT_EQ(back.data[i], img.data[i]) << "index " << i;
}

// Found by the scene-loader fuzzer (issue 24, docs/fuzzing.md): a 570-byte EXR whose 'capDate'
// attribute claims 1.9 GB made OpenEXR allocate 2 GB before failing. The header walk refuses it
// at once, naming the file and the attribute.
TEST(ImageRead, ExrAttributeClaimingMoreThanTheFileIsRefusedBeforeReading) {
    const std::string path = std::string(MESO_SOURCE_DIR) + "/fuzz/regressions/exr_attribute_claims_1.9GB.exr";
    try {
        meso::read_image(path);
        FAIL() << "read_image accepted " << path;
    } catch (const meso::MesoError &e) {
        std::string msg = e.what();
        EXPECT_NE(msg.find(path), std::string::npos) << msg;
        EXPECT_NE(msg.find("corrupt EXR header: attribute 'capDate' claims 1953702419 bytes"), std::string::npos) << msg;
    }
}

// Found by the scene-loader fuzzer (issue 24): a 1349-byte EXR whose dataWindow declares
// 16777023 x 64 pixels made read_image allocate 4 GB before OpenEXR read a line. A decoded size
// no codec can reach from the file's size is refused before the pixels are allocated.
// The second file is ZIP-compressed: OpenEXR sized a 537 MB line buffer from its dataWindow when
// the file was opened (over 10 s under ASan), so the header walk refuses it before OpenImageIO
// opens it.
TEST(ImageRead, SmallFileDeclaringAHugeImageIsRefusedBeforeAllocating) {
    const std::pair<const char *, const char *> cases[] = {
        {"exr_datawindow_16777023x64_allocates_4GB.exr", "16777023x64"},
        {"exr_zip_16777023x64_line_buffer_537MB.exr", "16777023x64"},
        // a 104-byte attribute name (31 is the limit without the long-names flag): 11 s in OpenEXR under ASan
        {"exr_long_attribute_name_and_short_box2i.exr", "longer than 31 bytes"}};
    for (const auto &[name, expected] : cases) {
        const std::string path = std::string(MESO_SOURCE_DIR) + "/fuzz/regressions/" + name;
        for (int header_only = 0; header_only < 2; ++header_only) {
            try {
                if (header_only) meso::check_exr_headers(path);
                else meso::read_image(path);
                FAIL() << "accepted " << path;
            } catch (const meso::MesoError &e) {
                std::string msg = e.what();
                EXPECT_NE(msg.find(path), std::string::npos) << msg;
                EXPECT_NE(msg.find(expected), std::string::npos) << msg;
                EXPECT_NE(msg.find("corrupt"), std::string::npos) << msg;
            }
        }
    }
}

TEST(ImageRead, DecodedSizeLimits) {
    using meso::decoded_size_problem;
    // A constant 4096^2 RGBA float map compresses well but within what zlib reaches.
    const uint64_t v = uint64_t(4096) * 4096 * 4;
    EXPECT_EQ(decoded_size_problem(v, 4, v * 4 / 1000, v * 4), "");
    EXPECT_NE(decoded_size_problem(v, 4, v * 4 / 5000, v * 4), "");
    // Small images are never refused for their ratio (a 1-value file can be a few hundred bytes).
    EXPECT_EQ(decoded_size_problem(1024, 4, 10, 4096), "");
    EXPECT_NE(decoded_size_problem(meso::kMaxImageValues + 1, 1, ~uint64_t(0) >> 2, 4), "");
    if (meso::physical_memory_bytes() > 0) {
        EXPECT_NE(decoded_size_problem(1 << 20, 1, 1 << 20, meso::physical_memory_bytes() + 1).find("memory"),
                  std::string::npos);
    }
}
