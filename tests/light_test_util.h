// Test helpers shared by the light tests (test_lights.cpp, test_area_light.cpp,
// test_light_sampling.cpp): a light from JSON, triangle-mesh and sphere shapes that carry only
// what area lights use, mean and standard error, a float image writer.
#pragma once
#include <gtest/gtest.h>
#include <OpenImageIO/imageio.h>
#include <algorithm>
#include <cmath>
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/properties.h"
#include "core/registry.h"
#include "geometry/shape.h"
#include "image/image.h"
#include "lights/light.h"
#include "sampling/warp.h"

namespace meso::test {

using json = nlohmann::json;

inline std::shared_ptr<Light> make_light(const json &j, std::shared_ptr<LoadContext> ctx = nullptr) {
    if (!ctx) ctx = std::make_shared<LoadContext>();
    return create_light(Properties(j, "lights[0]", ctx));
}

/// The message of the error that building the light throws, or "(no error)".
inline std::string light_error(const json &j, std::shared_ptr<LoadContext> ctx = nullptr) {
    try {
        make_light(j, ctx);
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

/// Test-only triangle-mesh shape (only what area lights use).
class TestMeshShape final : public Shape {
public:
    explicit TestMeshShape(TriangleMesh m) : m_mesh(std::move(m)) {}
    RTCGeometry build_embree(RTCDevice) const override { return nullptr; }
    void fill_interaction(const Ray &, float, uint32_t, float, float, SurfaceInteraction &) const override {}
    float surface_area() const override {
        double a = 0;
        for (size_t t = 0; t < m_mesh.triangle_count(); ++t) a += tri_area(t);
        return float(a);
    }
    PositionSample sample_area(float, Vec2) const override { return {}; }  // not used for meshes
    size_t primitive_count() const override { return m_mesh.triangle_count(); }
    size_t memory_bytes() const override { return 0; }
    std::string to_string() const override { return "test mesh"; }
    const TriangleMesh *mesh() const override { return &m_mesh; }
    Vec3 vertex(size_t t, int k) const { return m_mesh.positions[m_mesh.indices[3 * t + k]]; }
    double tri_area(size_t t) const { return 0.5 * length(cross(vertex(t, 1) - vertex(t, 0), vertex(t, 2) - vertex(t, 0))); }
    Vec3 normal(size_t t) const { return normalize(cross(vertex(t, 1) - vertex(t, 0), vertex(t, 2) - vertex(t, 0))); }

private:
    TriangleMesh m_mesh;
};

/// Test-only analytic sphere (uniform area sampling, no mesh).
class TestSphereShape final : public Shape {
public:
    TestSphereShape(Vec3 c, float r) : m_c(c), m_r(r) {}
    RTCGeometry build_embree(RTCDevice) const override { return nullptr; }
    void fill_interaction(const Ray &, float, uint32_t, float, float, SurfaceInteraction &) const override {}
    float surface_area() const override { return 4.f * Pi * m_r * m_r; }
    PositionSample sample_area(float, Vec2 u) const override {
        PositionSample ps;
        ps.n = square_to_uniform_sphere(u);
        ps.p = m_c + ps.n * m_r;
        ps.pdf_area = 1.f / surface_area();
        return ps;
    }
    size_t primitive_count() const override { return 1; }
    size_t memory_bytes() const override { return 0; }
    std::string to_string() const override { return "test sphere"; }

private:
    Vec3 m_c;
    float m_r;
};

inline TriangleMesh make_mesh(const std::vector<Vec3> &pos, const std::vector<uint32_t> &idx) {
    TriangleMesh m;
    m.positions = pos;
    m.indices = idx;
    return m;
}


struct MeanStd {
    double mean, stderr_;
};
inline MeanStd mean_std(double sum, double sum2, long n) {
    double m = sum / n;
    double var = std::max(0.0, sum2 / n - m * m);
    return {m, std::sqrt(var / n)};
}

inline void write_float_image(const std::string &path, const Image &img) {
    auto out = OIIO::ImageOutput::create(path);
    ASSERT_TRUE(out) << OIIO::geterror();
    OIIO::ImageSpec spec(img.width, img.height, img.channels, OIIO::TypeDesc::FLOAT);
    ASSERT_TRUE(out->open(path, spec));
    ASSERT_TRUE(out->write_image(OIIO::TypeDesc::FLOAT, img.data.data()));
    out->close();
}

}  // namespace meso::test
