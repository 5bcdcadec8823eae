// Mitsuba 3 XML scenes (issue 23 part 3): scenes/mitsuba/cbox.xml translates to exactly the
// hand-written scenes/mitsuba/cbox.json and renders the same image; errors name the file, the
// line and the element; $param defaults and -D, ref/id, include, twosided, rough defaults,
// transforms, cameras, emitters and textures translate as documented in docs/scene-format.md.
#include <gtest/gtest.h>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <nlohmann/json.hpp>
#include "cli_capture.h"
#include "core/error.h"
#include "render_test_util.h"
#include "scene/mitsuba_xml.h"
#include "scratch_dir.h"

using namespace meso;
using json = nlohmann::json;

namespace {

const std::string kCboxXml = std::string(MESO_SOURCE_DIR) + "/scenes/mitsuba/cbox.xml";
const std::string kCboxJson = std::string(MESO_SOURCE_DIR) + "/scenes/mitsuba/cbox.json";

/// Writes `body` inside <scene version="3.0.0"> (the opening tag on line 1) into the scratch dir.
std::string write_xml(const std::string &name, const std::string &body) {
    std::string p = test::scratch_dir("meso_mitsuba_xml") + "/" + name;
    std::filesystem::create_directories(std::filesystem::path(p).parent_path());
    std::ofstream(p) << "<scene version=\"3.0.0\">\n" << body << "</scene>\n";
    return p;
}

const char *const kSensor =
    "<sensor type=\"perspective\"><float name=\"fov\" value=\"45\"/>"
    "<film type=\"hdrfilm\"><integer name=\"width\" value=\"32\"/><integer name=\"height\" value=\"24\"/></film></sensor>\n";

json translate(const std::string &name, const std::string &body) { return mitsuba_xml_to_json(write_xml(name, body)); }

std::string error_of(const std::string &name, const std::string &body) {
    std::string p = write_xml(name, body);
    return test::meso_error_of([&] { mitsuba_xml_to_json(p); });
}

}  // namespace

TEST(MitsubaXml, CboxTranslatesToTheHandWrittenJson) {
    std::ifstream f(kCboxJson);
    std::stringstream ss;
    ss << f.rdbuf();
    json expected = json::parse(ss.str(), nullptr, true, /*ignore_comments=*/true);
    json got = mitsuba_xml_to_json(kCboxXml);
    EXPECT_EQ(got, expected) << "difference (JSON patch from the translation to cbox.json): "
                             << json::diff(got, expected).dump(1);
}

TEST(MitsubaXml, CboxRendersTheSameImageAsTheJson) {
    // Both through load_scene: the XML's $res and $spp by -D, the JSON's by JSON paths.
    auto a = load_scene(kCboxXml, {"res=24", "spp=2"});
    auto b = load_scene(kCboxJson, {"camera.width=24", "camera.height=24", "sampler.sample_count=2"});
    a->build();
    b->build();
    ASSERT_EQ(a->spp, 2);
    RenderResult ra = test::render_scene(*a, 2, 2, 11), rb = test::render_scene(*b, 2, 2, 11);
    ASSERT_EQ(ra.image.width, 24);
    ASSERT_EQ(ra.image.data.size(), rb.image.data.size());
    size_t differ = 0;
    for (size_t i = 0; i < ra.image.data.size(); ++i) differ += ra.image.data[i] != rb.image.data[i];
    EXPECT_EQ(differ, 0u) << "pixel values that differ";
    // Not a black image: the light and the walls are there.
    EXPECT_GT(test::pixel_stats(ra.image, 0).mean, 0.1);
    EXPECT_GT(test::pixel_stats(ra.image, 0).max, 5.0);
}

TEST(MitsubaXml, UnsupportedPluginsAndPropertiesNameTheElementAndLine) {
    std::string p = write_xml("bad_bsdf.xml", std::string(kSensor) + "\n<bsdf type=\"roughcoat\" id=\"c\"/>\n");
    EXPECT_EQ(test::meso_error_of([&] { mitsuba_xml_to_json(p); }),
              p + ": line 4: <bsdf type=\"roughcoat\" id=\"c\">: unsupported bsdf type 'roughcoat' (meso reads "
                  "\"diffuse\", \"conductor\", \"roughconductor\", \"plastic\", \"roughplastic\", \"dielectric\", "
                  "\"roughdielectric\", \"twosided\", \"normalmap\" or \"bumpmap\")");
    std::string prop = error_of("bad_prop.xml", std::string(kSensor) +
                                                   "<shape type=\"sphere\">\n  <bsdf type=\"diffuse\">\n"
                                                   "    <float name=\"roughness\" value=\"0.3\"/>\n  </bsdf>\n</shape>\n");
    EXPECT_NE(prop.find("bad_prop.xml: line 5: <float name=\"roughness\">: unsupported property 'roughness' of "
                        "<bsdf type=\"diffuse\"> (meso reads \"reflectance\")"),
              std::string::npos)
        << prop;
    EXPECT_NE(error_of("bad_shape.xml", std::string(kSensor) + "<shape type=\"serialized\"/>\n")
                  .find("bad_shape.xml: line 3: <shape type=\"serialized\">: unsupported shape type 'serialized'"),
              std::string::npos);
    EXPECT_NE(error_of("bad_elem.xml", std::string(kSensor) + "<medium type=\"homogeneous\" id=\"m\"/>\n")
                  .find("line 3: <medium type=\"homogeneous\" id=\"m\">: unsupported element"),
              std::string::npos);
    EXPECT_NE(error_of("bad_spec.xml", std::string(kSensor) +
                                           "<emitter type=\"constant\">\n<spectrum name=\"radiance\" value=\"400:1, 700:2\"/>"
                                           "</emitter>\n")
                  .find("line 4: <spectrum name=\"radiance\">: wavelength:value spectra are not supported"),
              std::string::npos);
    EXPECT_NE(error_of("bad_kind.xml", std::string(kSensor) +
                                           "<bsdf type=\"roughconductor\" id=\"r\">\n<texture name=\"alpha\" type=\"bitmap\">"
                                           "<string name=\"filename\" value=\"a.png\"/></texture></bsdf>\n")
                  .find("line 4: <texture type=\"bitmap\" name=\"alpha\">: property 'alpha' of <bsdf type=\"roughconductor\" "
                        "id=\"r\">: expected <float> or <integer>, got <texture>"),
              std::string::npos);
    // A parse error: pugixml's offset becomes a line.
    std::string broken = write_xml("broken.xml", std::string(kSensor) + "<shape type=\"sphere\">\n</shap>\n");
    EXPECT_EQ(test::meso_error_of([&] { mitsuba_xml_to_json(broken); }).rfind(broken + ": line 4: cannot parse XML", 0), 0u)
        << test::meso_error_of([&] { mitsuba_xml_to_json(broken); });
    // Through the loader and the command: the same message, non-zero exit.
    test::CliResult r = test::run_cli_captured({"render", p, "-o", test::scratch_dir("meso_mitsuba_xml") + "/bad.exr"});
    EXPECT_NE(r.code, 0);
    EXPECT_NE(r.err.find("line 4: <bsdf type=\"roughcoat\""), std::string::npos) << r.err;
}

TEST(MitsubaXml, ParametersDefaultsAndOverrides) {
    std::string body = "<default name=\"spp\" value=\"3\"/>\n<default name=\"w\" value=\"40\"/>\n"
                       "<sensor type=\"perspective\"><film type=\"hdrfilm\"><integer name=\"width\" value=\"$w\"/></film>"
                       "<sampler type=\"stratified\"><integer name=\"sample_count\" value=\"$spp\"/></sampler></sensor>\n";
    std::string p = write_xml("params.xml", body);
    json d = mitsuba_xml_to_json(p);
    EXPECT_EQ(d["sampler"], json({{"type", "sobol"}, {"sample_count", 3}}));
    EXPECT_EQ(d["camera"]["width"], 40);
    EXPECT_EQ(d["camera"]["height"], 576);  // Mitsuba's hdrfilm default
    // -D name=value sets $name; JSON-path overrides stay for the loader.
    std::vector<std::string> o = {"spp=5", "camera.height=10", "integrator={\"type\":\"direct\"}"};
    d = mitsuba_xml_to_json(p, &o);
    EXPECT_EQ(d["sampler"]["sample_count"], 5);
    EXPECT_EQ(o, (std::vector<std::string>{"camera.height=10", "integrator={\"type\":\"direct\"}"}));
    auto s = load_scene(p, {"spp=7", "camera.height=10"});
    EXPECT_EQ(s->spp, 7);
    // cbox.xml uses $integrator: -D integrator=direct is its parameter there.
    std::vector<std::string> oi = {"integrator=direct"};
    EXPECT_EQ(mitsuba_xml_to_json(kCboxXml, &oi)["integrator"], json({{"type", "direct"}}));
    EXPECT_TRUE(oi.empty());
    EXPECT_NE(error_of("direct.xml", "<default name=\"integrator\" value=\"direct\"/>\n<integrator type=\"$integrator\">"
                                     "<integer name=\"depth\" value=\"3\"/></integrator>\n" + std::string(kSensor))
                  .find("line 3: <integer name=\"depth\">: unsupported property 'depth' of <integrator type=\"$integrator\">"),
              std::string::npos);
    // An unknown -D name and an undefined $name are errors.
    std::vector<std::string> typo = {"sp=5"};
    EXPECT_EQ(test::meso_error_of([&] { mitsuba_xml_to_json(p, &typo); }), "-D sp=5: " + p + " has no parameter '$sp'");
    EXPECT_NE(error_of("undef.xml", std::string(kSensor) + "<integrator type=\"path\">\n<integer name=\"max_depth\" value=\"$depth\"/>"
                                                           "</integrator>\n")
                  .find("line 4: <integer name=\"max_depth\">: undefined parameter '$depth'"),
              std::string::npos);
}

TEST(MitsubaXml, RefsIdsIncludesAndMaterials) {
    write_xml("sub/materials.xml",
              "<texture type=\"bitmap\" id=\"wood\"><string name=\"filename\" value=\"wood.png\"/></texture>\n"
              "<bsdf type=\"twosided\" id=\"floor\"><bsdf type=\"roughplastic\"><ref name=\"diffuse_reflectance\" id=\"wood\"/>"
              "</bsdf></bsdf>\n");
    json d = translate("refs.xml", std::string(kSensor) +
                                       "<include filename=\"sub/materials.xml\"/>\n"
                                       "<texture type=\"checkerboard\" id=\"checks\"><rgb name=\"color0\" value=\"0.1\"/>"
                                       "<transform name=\"to_uv\"><scale value=\"4\"/></transform></texture>\n"
                                       "<bsdf type=\"diffuse\" id=\"d\"><ref name=\"reflectance\" id=\"checks\"/></bsdf>\n"
                                       "<bsdf type=\"roughconductor\" id=\"gold\"><string name=\"material\" value=\"Au\"/></bsdf>\n"
                                       "<shape type=\"disk\"><ref id=\"floor\"/></shape>\n"
                                       "<shape type=\"cube\"><ref id=\"d\"/></shape>\n"
                                       "<shape type=\"obj\"><string name=\"filename\" value=\"m.obj\"/>"
                                       "<bsdf type=\"dielectric\"><string name=\"int_ior\" value=\"water\"/></bsdf></shape>\n");
    EXPECT_EQ(d["textures"]["wood"], json({{"type", "bitmap"}, {"filename", "sub/wood.png"}, {"filter_type", "bilinear"}}));
    EXPECT_EQ(d["textures"]["checks"], json({{"type", "checkerboard"}, {"color0", 0.1}, {"scale", 8.0}}));
    EXPECT_EQ(d["materials"]["floor"], json({{"type", "plastic"}, {"diffuse_reflectance", "wood"}, {"distribution", "beckmann"},
                                             {"alpha", 0.1}}));
    EXPECT_EQ(d["materials"]["d"], json({{"type", "diffuse"}, {"reflectance", "checks"}}));
    EXPECT_EQ(d["materials"]["gold"], json({{"type", "conductor"}, {"material", "Au"}, {"distribution", "beckmann"}, {"alpha", 0.1}}));
    EXPECT_EQ(d["shapes"][0]["material"], "floor");
    EXPECT_EQ(d["shapes"][1]["material"], "d");
    EXPECT_EQ(d["shapes"][2], json({{"type", "obj"}, {"filename", "m.obj"}, {"flip_tex_coords", true},
                                    {"material", {{"type", "dielectric"}, {"int_ior", "water"}}}}));
    EXPECT_NE(error_of("badref.xml", std::string(kSensor) + "<shape type=\"cube\">\n<ref id=\"nope\"/></shape>\n")
                  .find("line 4: <ref id=\"nope\">: no bsdf with id 'nope' before this line"),
              std::string::npos);
    EXPECT_NE(error_of("loop.xml", std::string(kSensor) + "<include filename=\"loop.xml\"/>\n").find("the file includes itself"),
              std::string::npos);
}

TEST(MitsubaXml, TransformsCamerasAndEmitters) {
    json d = translate("xf.xml",
                       "<sensor type=\"perspective\"><float name=\"fov\" value=\"30\"/>"
                       "<string name=\"fov_axis\" value=\"diagonal\"/><float name=\"near_clip\" value=\"0.1\"/>\n"
                       "<transform name=\"to_world\"><rotate y=\"1\" angle=\"90\"/><translate x=\"1\" y=\"2\" z=\"3\"/></transform>"
                       "<film type=\"hdrfilm\"><integer name=\"width\" value=\"400\"/><integer name=\"height\" value=\"300\"/>"
                       "<rfilter type=\"gaussian\"/></film></sensor>\n"
                       "<shape type=\"rectangle\"><transform name=\"to_world\"><translate x=\"1\"/><scale value=\"2\"/></transform>"
                       "<emitter type=\"area\"><rgb name=\"radiance\" value=\"5\"/></emitter></shape>\n"
                       "<emitter type=\"spot\"><transform name=\"to_world\"><lookat origin=\"0, 5, 0\" target=\"0, 0, 0\" "
                       "up=\"0, 0, 1\"/></transform><float name=\"cutoff_angle\" value=\"30\"/></emitter>\n"
                       "<emitter type=\"directional\"><vector name=\"direction\" x=\"0\" y=\"-1\" z=\"0\"/>"
                       "<rgb name=\"irradiance\" value=\"1, 2, 3\"/></emitter>\n"
                       "<emitter type=\"point\"><point name=\"position\" value=\"1, 1, 1\"/></emitter>\n");
    const json &cam = d["camera"];
    // diagonal 30 degrees on a 4:3 film: the x field of view is 2 atan(tan(15 deg) * 4/5).
    EXPECT_NEAR(cam["fov"].get<double>(), 2 * std::atan(std::tan(15 * M_PI / 180) * 0.8) * 180 / M_PI, 1e-9);
    EXPECT_EQ(cam["fov_axis"], "x");
    EXPECT_EQ(cam["origin"], json::array({1, 2, 3}));
    // +z rotated 90 degrees about y is +x.
    EXPECT_NEAR(cam["target"][0].get<double>(), 2, 1e-6);
    EXPECT_NEAR(cam["target"][2].get<double>(), 3, 1e-6);
    EXPECT_NEAR(cam["up"][1].get<double>(), 1, 1e-6);
    // translate then scale is not meso's scale → rotate → translate order: a matrix.
    EXPECT_EQ(d["shapes"][0]["to_world"], json({{"matrix", {2, 0, 0, 2, 0, 2, 0, 0, 0, 0, 2, 0, 0, 0, 0, 1}}}));
    EXPECT_EQ(d["shapes"][0]["emitter"], json({{"type", "area"}, {"radiance", 5.0}}));
    EXPECT_EQ(d["lights"][0], json({{"type", "spot"}, {"position", {0, 5, 0}}, {"target", {0, 0, 0}}, {"cutoff_angle", 30.0}}));
    EXPECT_EQ(d["lights"][1], json({{"type", "directional"}, {"direction", {0, -1, 0}}, {"irradiance", {1, 2, 3}}}));
    EXPECT_EQ(d["lights"][2], json({{"type", "point"}, {"position", {1, 1, 1}}}));
    // The translation loads (every value is one meso's plugins accept).
    auto s = load_scene(write_xml("xf2.xml", "<sensor type=\"perspective\"/>\n<emitter type=\"constant\"/>\n"
                                             "<shape type=\"sphere\"><point name=\"center\" value=\"0, 0, 5\"/></shape>\n"),
                        {});
    EXPECT_EQ(s->shapes.size(), 1u);
    // A mirrored camera and a sheared sphere are refused.
    EXPECT_NE(error_of("mirror.xml", "<sensor type=\"perspective\"><transform name=\"to_world\">\n<scale x=\"-1\"/>"
                                     "<lookat origin=\"0,0,4\" target=\"0,0,0\"/></transform></sensor>\n")
                  .find("a mirroring camera transform"),
              std::string::npos);
    EXPECT_NE(error_of("shear.xml", std::string(kSensor) + "<shape type=\"sphere\"><transform name=\"to_world\">"
                                                           "<scale x=\"1\" y=\"2\"/></transform></shape>\n")
                  .find("line 3: <transform name=\"to_world\">: a sphere's to_world must be a similarity"),
              std::string::npos);
}

TEST(MitsubaXml, NormalAndBumpMapsAndObjTexCoords) {
    json d = translate("maps.xml", std::string(kSensor) +
                                       "<bsdf type=\"normalmap\" id=\"n\"><texture name=\"normalmap\" type=\"bitmap\">"
                                       "<boolean name=\"raw\" value=\"true\"/><string name=\"filename\" value=\"n.png\"/></texture>"
                                       "<bsdf type=\"roughplastic\"><float name=\"alpha\" value=\"0.2\"/></bsdf></bsdf>\n"
                                       "<bsdf type=\"bumpmap\" id=\"b\"><texture type=\"bitmap\"><boolean name=\"raw\" value=\"true\"/>"
                                       "<string name=\"filename\" value=\"h.png\"/></texture><float name=\"scale\" value=\"0.01\"/>"
                                       "<bsdf type=\"diffuse\"/></bsdf>\n");
    EXPECT_EQ(d["materials"]["n"], json({{"type", "normalmap"}, {"normals", "n.png"},
                                         {"bsdf", {{"type", "plastic"}, {"alpha", 0.2}, {"distribution", "beckmann"}}}}));
    EXPECT_EQ(d["materials"]["b"], json({{"type", "normalmap"}, {"heightmap", {{"map", "h.png"}, {"scale", 0.01}}},
                                         {"bsdf", {{"type", "diffuse"}}}}));
    // flip_tex_coords (Mitsuba's OBJ default) reaches the obj shape, which accepts it.
    std::string dir = test::scratch_dir("meso_mitsuba_xml");
    std::ofstream(dir + "/quad.obj") << "v 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvt 0 1\nf 1/1 2/2 3/3 4/4\n";
    auto s = load_scene(write_xml("objscene.xml", std::string(kSensor) + "<shape type=\"obj\"><string name=\"filename\" "
                                                                          "value=\"quad.obj\"/></shape>\n"),
                        {});
    EXPECT_EQ(s->shapes.size(), 1u);
}
