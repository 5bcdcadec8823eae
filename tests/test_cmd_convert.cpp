// `meso convert`: EXR -> PFM keeps every float exactly (the format scripts read with numpy),
// PFM reads back through OpenImageIO, bad output formats are refused without writing.
#include <gtest/gtest.h>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include "cli_capture.h"
#include "image/image.h"
#include "scratch_dir.h"

using namespace meso;

TEST(CmdConvert, ExrToPfmIsExactAndBottomUp) {
    const std::string dir = test::scratch_dir("convert");
    Image img(5, 3, 3);
    for (size_t i = 0; i < img.data.size(); ++i) img.data[i] = 0.001f * float(i * i) - 0.3f;
    write_exr(dir + "/a.exr", img);
    auto r = test::run_cli_captured({"convert", dir + "/a.exr", dir + "/a.pfm"});
    ASSERT_EQ(r.code, 0) << r.err;
    std::ifstream f(dir + "/a.pfm", std::ios::binary);
    std::string kind, scale;
    int w = 0, h = 0;
    f >> kind >> w >> h >> scale;
    f.get();
    EXPECT_EQ(kind, "PF");
    EXPECT_EQ(w, 5);
    EXPECT_EQ(h, 3);
    EXPECT_EQ(scale, "-1.0");
    std::vector<float> px(size_t(w) * h * 3);
    f.read(reinterpret_cast<char *>(px.data()), std::streamsize(px.size() * sizeof(float)));
    ASSERT_TRUE(bool(f));
    for (int y = 0; y < h; ++y)
        for (int x = 0; x < w; ++x)
            for (int c = 0; c < 3; ++c)  // PFM rows run bottom to top
                EXPECT_EQ(px[(size_t(h - 1 - y) * w + x) * 3 + c], img.at(x, y, c));
    // And back through OpenImageIO.
    Image back = read_image(dir + "/a.pfm");
    ASSERT_EQ(back.width, 5);
    EXPECT_FLOAT_EQ(back.at(4, 2, 1), img.at(4, 2, 1));
}

TEST(CmdConvert, RefusesUnknownFormats) {
    const std::string dir = test::scratch_dir("convert_bad");
    Image img(2, 2, 3);
    write_exr(dir + "/a.exr", img);
    auto r = test::run_cli_captured({"convert", dir + "/a.exr", dir + "/a.bmpx"});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find("unsupported output format"), std::string::npos) << r.err;
    EXPECT_FALSE(std::filesystem::exists(dir + "/a.bmpx"));
    r = test::run_cli_captured({"convert", dir + "/missing.exr", dir + "/a.pfm"});
    EXPECT_NE(r.code, 0);
}
