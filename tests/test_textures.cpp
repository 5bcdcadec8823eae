// Textures: filtered checkerboard (closed-form box filter against brute-force averages),
// bitmap lookups (nearest / bilinear exact on a 4x4 image, wrap modes, sRGB decoding),
// MIP pyramid (level selection, means preserved for odd sizes, trilinear blending) and
// error messages for missing or malformed files.
#include <gtest/gtest.h>
#include "scratch_dir.h"
#include "texture_test_util.h"
#include <OpenImageIO/imageio.h>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <unistd.h>
#include "core/error.h"
#include "texture/texture.h"
#include "sampling/rng.h"
#include "core/properties.h"
#include "core/registry.h"
#include "texture/mipmap.h"

using namespace meso;
using json = nlohmann::json;
namespace fs = std::filesystem;

namespace {

/// Per-process scratch directory, removed at exit.
std::string tmp_dir() { return meso::test::scratch_dir("meso_test_textures"); }

std::shared_ptr<Texture> make_texture(const json &j) { return meso::test::make_texture_in(tmp_dir(), j); }
std::string texture_error(const json &j) { return meso::test::texture_error_in(tmp_dir(), j); }

ShadingContext at(float u, float v, float dudx = 0, float dudy = 0, float dvdx = 0, float dvdy = 0) {
    return meso::test::uv_context(u, v, dudx, dudy, dvdx, dvdy);
}

/// Writes w x h x c values with OpenImageIO (float EXR, or 8-bit for .png).
void write_image(const std::string &name, int w, int h, int c, const std::vector<float> &v) {
    std::string path = tmp_dir() + "/" + name;
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out) << OIIO::geterror();
    bool png = name.size() > 4 && name.substr(name.size() - 4) == ".png";
    OIIO::ImageSpec spec(w, h, c, png ? OIIO::TypeDesc::UINT8 : OIIO::TypeDesc::FLOAT);
    ASSERT_TRUE(out->open(path, spec));
    if (png) {
        std::vector<uint8_t> b(v.size());
        for (size_t i = 0; i < v.size(); ++i) b[i] = uint8_t(v[i]);
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::UINT8, b.data()));
    } else {
        ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, v.data()));
    }
    out->close();
}

/// 4x4 grey image with texel (x, y) = 10 y + x.
void write_4x4() {
    std::vector<float> v(16);
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) v[y * 4 + x] = float(10 * y + x);
    write_image("grid4.exr", 4, 4, 1, v);
}

double srgb_decode(double c) { return c <= 0.04045 ? c / 12.92 : std::pow((c + 0.055) / 1.055, 2.4); }

}  // namespace

// --------------------------------------------------------------------------------------
// Checkerboard

TEST(Checkerboard, PointValuesAndHugeFootprint) {
    auto t = make_texture({{"type", "checkerboard"}, {"color0", {1, 0, 0}}, {"color1", {{"type", "constant"}, {"value", 0.5}}}});
    // Default scale 2: [0, .5)^2 is color0.
    EXPECT_FLOAT_EQ(t->eval(at(0.1f, 0.1f)).r, 1.f);
    EXPECT_FLOAT_EQ(t->eval(at(0.3f, 0.4f)).g, 0.f);
    EXPECT_FLOAT_EQ(t->eval(at(0.6f, 0.1f)).g, 0.5f);
    EXPECT_FLOAT_EQ(t->eval(at(0.6f, 0.7f)).r, 1.f);
    EXPECT_FLOAT_EQ(t->eval(at(-0.1f, 0.1f)).g, 0.5f);  // cell -1 is odd
    EXPECT_FLOAT_EQ(t->eval(at(123.2f, -77.9f)).r, 1.f);  // 246 + (-156) even
    // A footprint covering thousands of checks averages the two colours.
    Spectrum s = t->eval(at(0.37f, 0.61f, 1000.f, 0.f, 0.f, 1000.f));
    EXPECT_NEAR(s.r, 0.75f, 1e-3f);
    EXPECT_NEAR(s.g, 0.25f, 1e-3f);
    EXPECT_NEAR(s.b, 0.25f, 1e-3f);
    s = t->eval(at(0.37f, 0.61f, 1e12f, 0.f, 0.f, 1e12f));
    EXPECT_NEAR(s.r, 0.75f, 1e-3f);
    EXPECT_NEAR(t->mean().r, 0.75f, 1e-6f);
    EXPECT_EQ(texture_error({{"type", "checkerboard"}, {"scale", 0}}), "scene.json: textures.tex.scale: must be positive");
}

TEST(Checkerboard, BoxFilterMatchesBruteForce) {
    // Compare the closed-form weight with a dense average of the point pattern over the box.
    auto t = make_texture({{"type", "checkerboard"}, {"color0", 0}, {"color1", 1}, {"scale", 3}});
    PCG32 rng(4);
    const int G = 400;  // G x G midpoint grid: error < 2 lines / G of the box
    for (int k = 0; k < 20; ++k) {
        float u = rng.next_float() * 4 - 2, v = rng.next_float() * 4 - 2;
        float dudx = (rng.next_float() - 0.5f) * 2.f, dudy = (rng.next_float() - 0.5f) * 0.4f;
        float dvdx = (rng.next_float() - 0.5f) * 0.3f, dvdy = (rng.next_float() - 0.5f) * 1.5f;
        float got = t->eval(at(u, v, dudx, dudy, dvdx, dvdy)).r;
        // The box: half-widths 0.5 · max(|du|) and 0.5 · max(|dv|) in uv.
        double hu = 0.5 * std::max(std::abs(dudx), std::abs(dudy)), hv = 0.5 * std::max(std::abs(dvdx), std::abs(dvdy));
        double acc = 0;
        for (int i = 0; i < G; ++i)
            for (int j = 0; j < G; ++j) {
                double s = 3 * (u - hu + 2 * hu * (i + 0.5) / G), tt = 3 * (v - hv + 2 * hv * (j + 0.5) / G);
                acc += (long(std::floor(s)) + long(std::floor(tt))) & 1L;
            }
        double ref = acc / (double(G) * G);
        // Grid error: the checks' edges crossing the box cut at most 3·2(hu + hv) + 2 lines of G
        // cells, each misweighted by < 1/G.
        double tol = (3 * 2 * (hu + hv) + 2) / G + 1e-6;
        EXPECT_NEAR(got, ref, tol) << "u " << u << " v " << v;
    }
}

// --------------------------------------------------------------------------------------
// Bitmap

TEST(TextureBitmap, NearestAndBilinearExact) {
    write_4x4();
    auto nearest = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", "nearest"}});
    auto bilinear = make_texture({{"type", "image"}, {"filename", "grid4.exr"}, {"filter_type", "bilinear"}});
    for (int y = 0; y < 4; ++y)
        for (int x = 0; x < 4; ++x) {
            float u = (x + 0.5f) / 4, v = (y + 0.5f) / 4;
            EXPECT_FLOAT_EQ(nearest->eval(at(u, v)).g, float(10 * y + x));
            EXPECT_FLOAT_EQ(bilinear->eval(at(u, v)).b, float(10 * y + x));
            EXPECT_FLOAT_EQ(nearest->eval(at(u + 0.12f, v - 0.12f)).r, float(10 * y + x));  // inside the texel
        }
    // Half-way between texel centres (1,1), (2,1), (1,2), (2,2): the average 16.5.
    EXPECT_NEAR(bilinear->eval(at(0.5f, 0.5f)).r, 16.5f, 1e-5f);
    // A quarter of the way from (1,1) to (2,1): 11 + 0.25.
    EXPECT_NEAR(bilinear->eval(at((1.5f + 0.25f) / 4, 1.5f / 4)).r, 11.25f, 1e-5f);
    EXPECT_NEAR(bilinear->eval_float(at((1.5f + 0.25f) / 4, 1.5f / 4)), 11.25f, 1e-5f);
    EXPECT_NEAR(nearest->mean().r, 16.5f, 1e-5f);
    auto scaled = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", "nearest"}, {"scale", 2}});
    EXPECT_FLOAT_EQ(scaled->eval(at(0.9f, 0.9f)).r, 66.f);
    // offset after tiling: uv' = uv · 2 + (0.25, 0.5) -> (0.1, 0.1) looks up (0.45, 0.7), texel (1, 2).
    auto moved = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", "nearest"}, {"tiling", 2},
                               {"offset", {0.25, 0.5}}});
    EXPECT_FLOAT_EQ(moved->eval(at(0.1f, 0.1f)).r, 21.f);
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"offset", {1}}}),
              "scene.json: textures.tex.offset: expected [u, v], each finite with |value| <= 1e6");
}

TEST(TextureBitmap, RotationIsKhrTextureTransform) {
    // KHR_texture_transform: uv' = T R S uv, R = [[cos r, sin r], [−sin r, cos r]]. A rotated,
    // tiled, offset lookup at uv equals the untransformed lookup at uv', and a trilinear/EWA
    // footprint (du/dx, dv/dx), (du/dy, dv/dy) maps through the same linear part R S.
    write_4x4();
    const double r = 0.7, tu = 2.0, tv = 0.5, ou = 0.125, ov = -0.25, c = std::cos(r), sn = std::sin(r);
    for (const char *filter : {"nearest", "bilinear", "trilinear", "ewa"}) {
        SCOPED_TRACE(filter);
        auto plain = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", filter}});
        auto moved = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", filter},
                                   {"tiling", {tu, tv}}, {"rotation", r}, {"offset", {ou, ov}}});
        PCG32 rng(5);
        for (int i = 0; i < 50; ++i) {
            const double u = rng.next_float(), v = rng.next_float();
            const double fx[2] = {0.2 * rng.next_float(), 0.2 * rng.next_float()};  // (du/dx, dv/dx)
            const double fy[2] = {0.05 * rng.next_float(), 0.05 * rng.next_float()};  // (du/dy, dv/dy)
            auto map = [&](double a, double b, double *out) {  // the linear part R S
                out[0] = c * tu * a + sn * tv * b;
                out[1] = -sn * tu * a + c * tv * b;
            };
            double p[2], dx[2], dy[2];
            map(u, v, p);
            map(fx[0], fx[1], dx);
            map(fy[0], fy[1], dy);
            const Spectrum got = moved->eval(at(u, v, fx[0], fy[0], fx[1], fy[1]));
            const Spectrum want = plain->eval(at(p[0] + ou, p[1] + ov, dx[0], dy[0], dx[1], dy[1]));
            EXPECT_NEAR(got.r, want.r, 1e-3 * (1 + std::abs(want.r))) << "uv " << u << ", " << v;
        }
    }
    // rotation 0 is the plain tiling; a quarter turn maps (u, v) to (v, −u): on the grid,
    // texel (x, y) = 10 y + x at uv (0.375, 0.125) is read at (0.125, −0.375) → texel (0, 2) with repeat.
    auto quarter = make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", "nearest"},
                                 {"rotation", Pi / 2}});
    EXPECT_FLOAT_EQ(quarter->eval(at(0.375f, 0.125f)).r, 20.f);
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"rotation", 1e7}}),
              "scene.json: textures.tex.rotation: expected a number in [-1e+06, 1e+06], got 1e+07");
}

TEST(TextureBitmap, WrapModes) {
    write_4x4();
    auto make = [](const char *wrap, const char *filter) {
        return make_texture({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", filter}, {"wrap_mode", wrap}});
    };
    auto rep = make("repeat", "nearest"), clampt = make("clamp", "nearest"), mir = make("mirror", "nearest");
    // u = 1.1 -> texel coordinate 4.4: repeat -> 0, clamp -> 3, mirror -> 3; u = 1.9 -> 7.6.
    EXPECT_FLOAT_EQ(rep->eval(at(1.1f, 0.1f)).r, 0.f);
    EXPECT_FLOAT_EQ(clampt->eval(at(1.1f, 0.1f)).r, 3.f);
    EXPECT_FLOAT_EQ(mir->eval(at(1.1f, 0.1f)).r, 3.f);
    EXPECT_FLOAT_EQ(rep->eval(at(1.9f, 0.1f)).r, 3.f);
    EXPECT_FLOAT_EQ(mir->eval(at(1.9f, 0.1f)).r, 0.f);
    EXPECT_FLOAT_EQ(rep->eval(at(-0.1f, -0.1f)).r, 33.f);
    EXPECT_FLOAT_EQ(clampt->eval(at(-5.f, 0.3f)).r, 10.f);
    EXPECT_FLOAT_EQ(mir->eval(at(-0.1f, 0.1f)).r, 0.f);  // mirrored back onto texel 0
    // Bilinear across the u = 0 seam: repeat blends texel 3 and 0, clamp stays at texel 0.
    auto repb = make("repeat", "bilinear"), clampb = make("clamp", "bilinear");
    EXPECT_NEAR(repb->eval(at(0.f, 0.125f)).r, 1.5f, 1e-5f);
    EXPECT_NEAR(clampb->eval(at(0.f, 0.125f)).r, 0.f, 1e-5f);
    EXPECT_TRUE(std::isfinite(repb->eval(at(1e9f, -1e9f)).r));
    EXPECT_TRUE(std::isfinite(repb->eval(at(std::nanf(""), 0.5f)).r));
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"wrap_mode", "wrap"}}),
              "scene.json: textures.tex.wrap_mode: expected \"repeat\", \"clamp\" or \"mirror\", got \"wrap\"");
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "grid4.exr"}, {"filter_type", "box"}}),
              "scene.json: textures.tex.filter_type: expected \"nearest\", \"bilinear\", \"trilinear\" or \"ewa\", got \"box\"");
}

TEST(TextureBitmap, SrgbDecodeOf8BitPng) {
    write_image("srgb.png", 2, 1, 3, {128, 64, 255, 0, 10, 200});
    auto t = make_texture({{"type", "bitmap"}, {"filename", "srgb.png"}, {"filter_type", "nearest"}});
    Spectrum s = t->eval(at(0.25f, 0.5f));
    EXPECT_NEAR(s.r, srgb_decode(128 / 255.0), 1e-5);
    EXPECT_NEAR(s.g, srgb_decode(64 / 255.0), 1e-5);
    EXPECT_NEAR(s.b, 1.0, 1e-5);
    Spectrum s2 = t->eval(at(0.75f, 0.5f));
    EXPECT_NEAR(s2.g, srgb_decode(10 / 255.0), 1e-6);  // linear segment
    auto raw = make_texture({{"type", "bitmap"}, {"filename", "srgb.png"}, {"filter_type", "nearest"}, {"raw", true}});
    EXPECT_NEAR(raw->eval(at(0.25f, 0.5f)).r, 128 / 255.0, 1e-5);
}

TEST(TextureBitmap, ChannelSelectsOneChannelAsGrey) {
    // glTF's metallicRoughness texture: B = metallic, G = roughness (raw, no sRGB decoding).
    write_image("orm.png", 2, 1, 3, {10, 128, 255, 0, 64, 30});
    auto g = make_texture({{"type", "bitmap"}, {"filename", "orm.png"}, {"filter_type", "nearest"}, {"raw", true}, {"channel", "g"}});
    auto b = make_texture({{"type", "bitmap"}, {"filename", "orm.png"}, {"filter_type", "nearest"}, {"raw", true}, {"channel", "b"}});
    Spectrum sg = g->eval(at(0.25f, 0.5f)), sb = b->eval(at(0.75f, 0.5f));
    EXPECT_NEAR(sg.r, 128 / 255.0, 1e-5);
    EXPECT_NEAR(sg.b, 128 / 255.0, 1e-5);  // grey
    EXPECT_NEAR(g->eval_float(at(0.75f, 0.5f)), 64 / 255.0, 1e-5);
    EXPECT_NEAR(sb.g, 30 / 255.0, 1e-5);
    EXPECT_NEAR(b->mean().r, (255 + 30) / 2.0 / 255.0, 1e-5);
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "orm.png"}, {"channel", "a"}}),
              "scene.json: textures.tex.channel: " + tmp_dir() + "/orm.png: the image has 3 channel(s), no alpha");
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "orm.png"}, {"channel", "x"}}),
              "scene.json: textures.tex.channel: expected \"rgb\", \"r\", \"g\", \"b\" or \"a\", got \"x\"");
}

TEST(TextureBitmap, AlphaIsNotMultipliedIntoColour) {
    // scenes/tests/alpha_half.png: two sRGB-188 grey texels with alpha 255 and 0 (PNG stores
    // colour unassociated). The colour is read as stored whatever the alpha (OpenImageIO would
    // premultiply it: 0 for the transparent texel); channel "a" reads the alpha, linear.
    const std::string file = std::string(MESO_SOURCE_DIR) + "/scenes/tests/alpha_half.png";
    auto rgb = make_texture({{"type", "bitmap"}, {"filename", file}, {"filter_type", "nearest"}, {"raw", true}});
    auto a = make_texture({{"type", "bitmap"}, {"filename", file}, {"filter_type", "nearest"}, {"channel", "a"}});
    for (float u : {0.25f, 0.75f}) EXPECT_NEAR(rgb->eval(at(u, 0.5f)).g, 188 / 255.0, 1e-5) << u;
    EXPECT_NEAR(a->eval_float(at(0.25f, 0.5f)), 1.0, 1e-6);
    EXPECT_NEAR(a->eval_float(at(0.75f, 0.5f)), 0.0, 1e-6);
}

TEST(TextureBitmap, MissingAndMalformedFiles) {
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "missing.png"}}),
              "scene.json: textures.tex.filename: file not found: '" + tmp_dir() + "/missing.png'");
    {
        std::ofstream f(tmp_dir() + "/garbage.png");
        f << "definitely not a PNG";
    }
    std::string msg = texture_error({{"type", "bitmap"}, {"filename", "garbage.png"}});
    EXPECT_EQ(msg.rfind("scene.json: textures.tex.filename: ", 0), 0u) << msg;
    EXPECT_NE(msg.find("garbage.png"), std::string::npos) << msg;
    std::vector<float> v = {1, 2, std::numeric_limits<float>::infinity(), 4};
    write_image("inf.exr", 2, 2, 1, v);
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", "inf.exr"}}),
              "scene.json: textures.tex.filename: " + tmp_dir() + "/inf.exr: 1 texel value(s) are NaN or infinite");
}

// --------------------------------------------------------------------------------------
// MIP map

TEST(MipMap, LevelSelection) {
    MipMap m(64, 64, 1, std::vector<float>(64 * 64, 1.f));
    ASSERT_EQ(m.levels(), 7);
    for (int k : {1, 2, 4, 8, 16, 32, 64}) EXPECT_FLOAT_EQ(m.level_for_footprint(k / 64.f, 0, 0, 0), std::log2(float(k)));
    EXPECT_FLOAT_EQ(m.level_for_footprint(0, 0, 0, 8 / 64.f), 3.f);      // v-footprint in y
    EXPECT_FLOAT_EQ(m.level_for_footprint(3 / 64.f, 0, 4 / 64.f, 0), std::log2(5.f));  // length of (du, dv)
    EXPECT_FLOAT_EQ(m.level_for_footprint(0, 0, 0, 0), 0.f);
    EXPECT_FLOAT_EQ(m.level_for_footprint(0.2f / 64, 0, 0, 0), 0.f);      // sub-texel
    EXPECT_FLOAT_EQ(m.level_for_footprint(1000.f, 0, 0, 0), 6.f);         // clamped to 1x1
    EXPECT_FLOAT_EQ(m.level_for_footprint(std::nanf(""), 0, 0, 0), 0.f);
    // Non-square: footprints scale by the resolution of each axis.
    MipMap r(64, 16, 1, std::vector<float>(64 * 16, 1.f));
    EXPECT_EQ(r.levels(), 7);
    EXPECT_FLOAT_EQ(r.level_for_footprint(4 / 64.f, 0, 0, 0), 2.f);
    EXPECT_FLOAT_EQ(r.level_for_footprint(0, 0, 0, 4 / 16.f), 2.f);
}

TEST(MipMap, MeansPreservedForOddSizes) {
    for (auto [w, h] : {std::pair{13, 7}, std::pair{16, 16}, std::pair{5, 1}, std::pair{1, 9}, std::pair{33, 20}}) {
        PCG32 rng(w * 100 + h);
        std::vector<float> data(size_t(w) * h * 2);
        for (auto &x : data) x = rng.next_float() * 10;
        MipMap m(w, h, 2, data);
        float m0[2], ml[2];
        m.level_mean(0, m0);
        for (int l = 1; l < m.levels(); ++l) {
            EXPECT_EQ(m.width(l), std::max(1, m.width(l - 1) / 2));
            EXPECT_EQ(m.height(l), std::max(1, m.height(l - 1) / 2));
            m.level_mean(l, ml);
            EXPECT_NEAR(ml[0], m0[0], 1e-5f * m0[0]) << w << "x" << h << " level " << l;
            EXPECT_NEAR(ml[1], m0[1], 1e-5f * m0[1]) << w << "x" << h << " level " << l;
        }
        EXPECT_EQ(m.width(m.levels() - 1), 1);
        EXPECT_EQ(m.height(m.levels() - 1), 1);
    }
    // Even sizes: the plain 2x2 box.
    MipMap e(2, 2, 1, {1, 2, 3, 6});
    EXPECT_FLOAT_EQ(*e.texel(1, 0, 0), 3.f);
    // Odd: 3 -> 1 averages all three; 5 -> 2 splits the middle texel.
    MipMap o(5, 1, 1, {0, 10, 20, 30, 40});
    EXPECT_FLOAT_EQ(*o.texel(1, 0, 0), (0 + 10 + 0.5f * 20) / 2.5f);
    EXPECT_FLOAT_EQ(*o.texel(1, 1, 0), (0.5f * 20 + 30 + 40) / 2.5f);
}

TEST(MipMap, TrilinearLookup) {
    // One-texel checker 0/1: level 0 exact at texel centres, level >= 1 is 0.5 everywhere.
    const int N = 16;
    std::vector<float> d(N * N);
    for (int y = 0; y < N; ++y)
        for (int x = 0; x < N; ++x) d[y * N + x] = float((x + y) & 1);
    MipMap m(N, N, 1, d);
    float out;
    float u = 3.5f / N, v = 4.5f / N;  // texel (3, 4): value 1
    m.filtered(u, v, 0, 0, 0, 0, &out);
    EXPECT_FLOAT_EQ(out, 1.f);
    m.filtered(u, v, 2.f / N, 0, 0, 2.f / N, &out);  // 2 texels -> level 1
    EXPECT_FLOAT_EQ(out, 0.5f);
    m.filtered(u, v, std::sqrt(2.f) / N, 0, 0, 0, &out);  // level 0.5: half of each
    EXPECT_NEAR(out, 0.75f, 1e-5f);
    m.filtered(u, v, 100.f, 0, 0, 0, &out);  // beyond the last level
    EXPECT_FLOAT_EQ(out, 0.5f);
    // Through the texture plugin: the same selection from the shading context.
    std::vector<float> rgb(N * N * 3);
    for (int i = 0; i < N * N; ++i) rgb[3 * i] = rgb[3 * i + 1] = rgb[3 * i + 2] = d[i];
    write_image("checker16.exr", N, N, 3, rgb);
    auto t = make_texture({{"type", "bitmap"}, {"filename", "checker16.exr"}});
    EXPECT_FLOAT_EQ(t->eval(at(u, v)).g, 1.f);
    EXPECT_FLOAT_EQ(t->eval(at(u, v, 4.f / N, 0, 0, 0)).g, 0.5f);
    EXPECT_NEAR(t->eval(at(u, v, std::sqrt(2.f) / N, 0, 0, 0)).g, 0.75f, 1e-5f);
    EXPECT_NE(t->to_string().find("5 levels"), std::string::npos) << t->to_string();
}

// Issue 23: a bitmap's edge mode also reads as "wrap", the displacement's name; both at once is refused.
TEST(TextureBitmap, WrapIsAnAliasOfWrapMode) {
    const std::string file = std::string(MESO_SOURCE_DIR) + "/scenes/assets/sawtooth64.exr";
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", file}, {"wrap", "clamp"}, {"wrap_mode", "clamp"}}),
              "scene.json: textures.tex.wrap: give either \"wrap\" or \"wrap_mode\" (the same setting), not both");
    EXPECT_NE(texture_error({{"type", "bitmap"}, {"filename", file}, {"wrap", "tile"}}).find("textures.tex.wrap: expected"),
              std::string::npos);
    EXPECT_EQ(texture_error({{"type", "bitmap"}, {"filename", file}, {"wrap", "mirror"}}), "(no error)");
}
