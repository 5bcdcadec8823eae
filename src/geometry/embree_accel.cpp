#include "geometry/embree_accel.h"
#include "core/phase.h"
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <fmt/format.h>
#include "core/error.h"
#include "geometry/shape.h"
#include "geometry/lod.h"

namespace meso {

static void embree_error(void *, RTCError code, const char *str) {
    std::fprintf(stderr, "meso: embree error %d: %s\n", int(code), str ? str : "");
}

static RTCDevice new_device() {
    RTCDevice d = rtcNewDevice("verbose=0");
    if (!d) throw MesoError(fmt::format("cannot create the Embree device (error {})", int(rtcGetDeviceError(nullptr))));
    rtcSetDeviceErrorFunction(d, embree_error, nullptr);
    return d;
}

/// A new scene with the flags and build quality of every meso scene.
static RTCScene new_scene(RTCDevice device) {
    RTCScene s = rtcNewScene(device);
    rtcSetSceneFlags(s, RTC_SCENE_FLAG_ROBUST);
    rtcSetSceneBuildQuality(s, RTC_BUILD_QUALITY_HIGH);
    return s;
}

EmbreeAccel::EmbreeAccel() { m_device = new_device(); }

EmbreeAccel::~EmbreeAccel() {
    for (auto &[shape, g] : m_pending) rtcReleaseGeometry(g);
    for (RTCScene s : m_scenes) rtcReleaseScene(s);
    if (m_shared) rtcReleaseScene(m_shared);
    if (m_device) rtcReleaseDevice(m_device);
}

/// Intersection and occlusion filter of shapes with an alpha mask: a candidate hit where the
/// mask cuts the surface out is rejected (valid = 0), so Embree goes on to the next surface
/// along the ray. Shapes without a mask get no filter and pay nothing.
static void alpha_mask_filter(const RTCFilterFunctionNArguments *args) {
    const Shape *shape = static_cast<const Shape *>(args->geometryUserPtr);
    for (unsigned i = 0; i < args->N; ++i) {
        if (args->valid[i] != -1) continue;
        const uint32_t prim = RTCHitN_primID(args->hit, args->N, i);
        if (shape->cut_out(prim, RTCHitN_u(args->hit, args->N, i), RTCHitN_v(args->hit, args->N, i)))
            args->valid[i] = 0;
    }
}

/// Attaches `g` to `scene` and records `shape` under its geomID in `table`.
static void attach(RTCScene scene, RTCGeometry g, const Shape *shape, std::vector<const Shape *> &table) {
    const unsigned id = rtcAttachGeometry(scene, g);
    if (id >= table.size()) table.resize(id + 1, nullptr);
    table[id] = shape;
}

void EmbreeAccel::add(const Shape *shape) {
    if (shape->alpha_mask && !rtcGetDeviceProperty(m_device, RTC_DEVICE_PROPERTY_FILTER_FUNCTION_SUPPORTED))
        throw MesoError(fmt::format("{}: this Embree build has no filter functions, which alpha masks need",
                                    shape->to_string()));
    if (shape->lod && !(shape->lod_level >= 0 && shape->lod_level < shape->lod->chain.levels() && shape->lod_level < 32))
        throw MesoError(fmt::format("{}: LoD level {} outside its chain (at most 32 levels)", shape->to_string(),
                                    shape->lod_level));
    RTCGeometry g = shape->build_embree(m_device);
    if (shape->alpha_mask) {
        rtcSetGeometryUserData(g, const_cast<Shape *>(shape));
        rtcSetGeometryIntersectFilterFunction(g, alpha_mask_filter);
        rtcSetGeometryOccludedFilterFunction(g, alpha_mask_filter);
    }
    // Level k of a chain answers to mask bit k, its last level to bits k..31 (a path at level 3
    // still sees a 2-level chain's coarsest model); other shapes to every bit.
    uint32_t mask = 0xFFFFFFFFu;
    if (shape->lod) {
        const int k = shape->lod_level;
        mask = k + 1 == shape->lod->chain.levels() ? ~(lod_ray_mask(k) - 1u) : lod_ray_mask(k);
    }
    rtcSetGeometryMask(g, mask);
    rtcCommitGeometry(g);
    m_pending.emplace_back(shape, g);
}

void EmbreeAccel::build_level_scenes(int levels) {
    size_t lod_prims = 0, other_prims = 0;
    for (const auto &[shape, g] : m_pending) (shape->lod ? lod_prims : other_prims) += shape->primitive_count();
    // Shapes without LoD in every level scene, or (when they outnumber the levels) instanced.
    RTCGeometry shared = nullptr;
    if (other_prims > lod_prims) {
        m_shared = new_scene(m_device);
        for (const auto &[shape, g] : m_pending)
            if (!shape->lod) attach(m_shared, g, shape, m_shared_shapes);
        rtcCommitScene(m_shared);
        static const float identity[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};  // 3x4 column major
        shared = rtcNewGeometry(m_device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(shared, m_shared);
        rtcSetGeometryTimeStepCount(shared, 1);
        rtcSetGeometryTransform(shared, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, identity);
        rtcCommitGeometry(shared);
    }
    for (int k = 0; k < levels; ++k) {
        RTCScene scene = m_scenes.emplace_back(new_scene(m_device));
        ShapeTable &table = m_shapes.emplace_back();
        for (const auto &[shape, g] : m_pending) {
            const bool seen = shape->lod ? std::min(k, shape->lod->chain.levels() - 1) == shape->lod_level : !shared;
            if (seen) attach(scene, g, shape, table);
        }
        if (shared) attach(scene, shared, nullptr, table);
        rtcCommitScene(scene);
    }
    if (shared) rtcReleaseGeometry(shared);
}

double EmbreeAccel::commit() {
    auto t0 = std::chrono::steady_clock::now();
    int levels = 0;  // the longest chain
    for (const auto &[shape, g] : m_pending)
        if (shape->lod) levels = std::max(levels, shape->lod->chain.levels());
    if (levels == 0) {  // no LoD: one scene, as if there were no levels at all
        RTCScene scene = m_scenes.emplace_back(new_scene(m_device));
        ShapeTable &table = m_shapes.emplace_back();
        for (const auto &[shape, g] : m_pending) attach(scene, g, shape, table);
        rtcCommitScene(scene);
    } else {
        build_level_scenes(levels);
    }
    for (auto &[shape, g] : m_pending) rtcReleaseGeometry(g);  // the scenes hold them
    m_pending.clear();
    RTCError err = rtcGetDeviceError(m_device);
    if (err != RTC_ERROR_NONE) throw MesoError(fmt::format("Embree failed to build the scene (error {})", int(err)));
    return std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
}

static void setup_ray(const Ray &ray, RTCRay &r) {
    r.org_x = ray.o.x;
    r.org_y = ray.o.y;
    r.org_z = ray.o.z;
    r.dir_x = ray.d.x;
    r.dir_y = ray.d.y;
    r.dir_z = ray.d.z;
    r.tnear = ray.tmin;
    r.tfar = ray.tmax;
    r.mask = ray.mask;
    r.time = 0.f;
    r.flags = 0;
    r.id = 0;
}

/// Closest-hit query; returns false on a miss.
static bool trace_closest(RTCScene scene, const Ray &ray, RTCRayHit &rh) {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    setup_ray(ray, rh.ray);
    rh.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rh.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
    {
        PhaseScope phase(Phase::Trace);
        rtcIntersect1(scene, &ctx, &rh);
    }
    return rh.hit.geomID != RTC_INVALID_GEOMETRY_ID;
}

inline RTCScene EmbreeAccel::scene_for(uint32_t mask, const ShapeTable *&shapes) const {
    // The lowest set bit is the ray's level; past the longest chain, its last level. (A mask
    // of 0 sees nothing in Embree, whatever the scene.)
    size_t k = mask ? size_t(__builtin_ctz(mask)) : 0;
    if (k >= m_scenes.size()) k = m_scenes.size() - 1;
    shapes = &m_shapes[k];
    return m_scenes[k];
}

inline const Shape *EmbreeAccel::hit_shape(const ShapeTable &shapes, unsigned inst_id, unsigned geom_id) const {
    return inst_id == RTC_INVALID_GEOMETRY_ID ? shapes[geom_id] : m_shared_shapes[geom_id];
}

bool EmbreeAccel::intersect(const Ray &ray, SurfaceInteraction &si) const {
    RTCRayHit rh;
    const ShapeTable *shapes;
    if (!trace_closest(scene_for(ray.mask, shapes), ray, rh)) return false;
    PhaseScope phase(Phase::Interaction);
    hit_shape(*shapes, rh.hit.instID[0], rh.hit.geomID)
        ->fill_interaction(ray, rh.ray.tfar, rh.hit.primID, rh.hit.u, rh.hit.v, si);
    return true;
}

float EmbreeAccel::intersect_t(const Ray &ray) const {
    RTCRayHit rh;
    const ShapeTable *shapes;
    return trace_closest(scene_for(ray.mask, shapes), ray, rh) ? rh.ray.tfar : Infinity;
}

bool EmbreeAccel::occluded(const Ray &ray) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay r;
    setup_ray(ray, r);
    const ShapeTable *shapes;
    RTCScene scene = scene_for(ray.mask, shapes);
    PhaseScope phase(Phase::Trace);
    rtcOccluded1(scene, &ctx, &r);
    return r.tfar < 0.f;  // Embree sets tfar = -inf on a hit
}

void EmbreeAccel::bounds(Vec3 &lo, Vec3 &hi) const {
    // The union over the level scenes (coarser levels may reach where the original does not).
    lo = Vec3(Infinity, Infinity, Infinity);
    hi = -lo;
    for (RTCScene scene : m_scenes) {
        RTCBounds b;
        rtcGetSceneBounds(scene, &b);
        lo = Vec3(std::min(lo.x, b.lower_x), std::min(lo.y, b.lower_y), std::min(lo.z, b.lower_z));
        hi = Vec3(std::max(hi.x, b.upper_x), std::max(hi.y, b.upper_y), std::max(hi.z, b.upper_z));
    }
}

std::string EmbreeAccel::version_string() {
    RTCDevice d = new_device();
    long ver = rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_VERSION);
    std::string isa;
    // Embree 3 exposes the compiled ISAs through its config string only; report what the
    // device has enabled via the native-ray-packet properties.
    bool r4 = rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY4_SUPPORTED);
    bool r8 = rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY8_SUPPORTED);
    bool r16 = rtcGetDeviceProperty(d, RTC_DEVICE_PROPERTY_NATIVE_RAY16_SUPPORTED);
    isa = r16 ? "AVX-512 (16-wide)" : r8 ? "AVX/AVX2 (8-wide)" : r4 ? "SSE (4-wide)" : "scalar";
    rtcReleaseDevice(d);
    return fmt::format("Embree {}.{}.{}, ISA {}", ver / 10000, (ver / 100) % 100, ver % 100, isa);
}

}  // namespace meso
