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

EmbreeAccel::EmbreeAccel() {
    m_device = new_device();
    m_scene = new_scene(m_device);
}

EmbreeAccel::~EmbreeAccel() {
    if (m_scene) rtcReleaseScene(m_scene);
    for (LevelScene &l : m_levels) rtcReleaseScene(l.scene);
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

/// Commits `g`, attaches it to `scene` and records `shape` under its geomID in `table`.
static void attach(RTCScene scene, RTCGeometry g, const Shape *shape, std::vector<const Shape *> &table) {
    rtcCommitGeometry(g);
    unsigned id = rtcAttachGeometry(scene, g);
    rtcReleaseGeometry(g);
    if (id >= table.size()) table.resize(id + 1, nullptr);
    table[id] = shape;
}

void EmbreeAccel::add(const Shape *shape) {
    if (shape->alpha_mask && !rtcGetDeviceProperty(m_device, RTC_DEVICE_PROPERTY_FILTER_FUNCTION_SUPPORTED))
        throw MesoError(fmt::format("{}: this Embree build has no filter functions, which alpha masks need",
                                    shape->to_string()));
    if (shape->lod && !(shape->lod_level >= 0 && shape->lod_level < 32))
        throw MesoError(fmt::format("{}: LoD level {} outside 0..31", shape->to_string(), shape->lod_level));
    RTCGeometry g = shape->build_embree(m_device);
    if (shape->alpha_mask) {
        rtcSetGeometryUserData(g, const_cast<Shape *>(shape));
        rtcSetGeometryIntersectFilterFunction(g, alpha_mask_filter);
        rtcSetGeometryOccludedFilterFunction(g, alpha_mask_filter);
    }
    if (!shape->lod) {  // seen by every ray
        rtcSetGeometryMask(g, 0xFFFFFFFFu);
        attach(m_scene, g, shape, m_shapes);
        return;
    }
    // LoD level k of a chain is seen only by rays with mask bit k, its last level also by
    // rays of every higher level (a path at level 3 still sees a 2-level chain's coarsest
    // model). The geometry keeps the mask too: its level scene's instance has the same one.
    const int k = shape->lod_level;
    const uint32_t mask = k + 1 == shape->lod->chain.levels() ? ~(lod_ray_mask(k) - 1u) : lod_ray_mask(k);
    rtcSetGeometryMask(g, mask);
    auto level = std::find_if(m_levels.begin(), m_levels.end(), [&](const LevelScene &l) { return l.mask == mask; });
    if (level == m_levels.end()) level = m_levels.insert(m_levels.end(), LevelScene{mask, new_scene(m_device), {}});
    attach(level->scene, g, shape, level->shapes);
}

double EmbreeAccel::commit() {
    auto t0 = std::chrono::steady_clock::now();
    // Each level scene becomes one instance of the top scene (identity transform, the level's mask).
    static const float identity[12] = {1, 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0};  // 3x4 column major
    for (size_t i = 0; i < m_levels.size(); ++i) {
        rtcCommitScene(m_levels[i].scene);
        RTCGeometry inst = rtcNewGeometry(m_device, RTC_GEOMETRY_TYPE_INSTANCE);
        rtcSetGeometryInstancedScene(inst, m_levels[i].scene);
        rtcSetGeometryTimeStepCount(inst, 1);
        rtcSetGeometryTransform(inst, 0, RTC_FORMAT_FLOAT3X4_COLUMN_MAJOR, identity);
        rtcSetGeometryMask(inst, m_levels[i].mask);
        rtcCommitGeometry(inst);
        const unsigned id = rtcAttachGeometry(m_scene, inst);
        rtcReleaseGeometry(inst);
        if (id >= m_instance_level.size()) m_instance_level.resize(id + 1, -1);
        m_instance_level[id] = int(i);
    }
    rtcCommitScene(m_scene);
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

inline const Shape *EmbreeAccel::hit_shape(unsigned inst_id, unsigned geom_id) const {
    if (inst_id == RTC_INVALID_GEOMETRY_ID) return m_shapes[geom_id];
    return m_levels[size_t(m_instance_level[inst_id])].shapes[geom_id];
}

bool EmbreeAccel::intersect(const Ray &ray, SurfaceInteraction &si) const {
    RTCRayHit rh;
    if (!trace_closest(m_scene, ray, rh)) return false;
    PhaseScope phase(Phase::Interaction);
    hit_shape(rh.hit.instID[0], rh.hit.geomID)->fill_interaction(ray, rh.ray.tfar, rh.hit.primID, rh.hit.u, rh.hit.v, si);
    return true;
}

float EmbreeAccel::intersect_t(const Ray &ray) const {
    RTCRayHit rh;
    return trace_closest(m_scene, ray, rh) ? rh.ray.tfar : Infinity;
}

bool EmbreeAccel::occluded(const Ray &ray) const {
    RTCIntersectContext ctx;
    rtcInitIntersectContext(&ctx);
    RTCRay r;
    setup_ray(ray, r);
    PhaseScope phase(Phase::Trace);
    rtcOccluded1(m_scene, &ctx, &r);
    return r.tfar < 0.f;  // Embree sets tfar = -inf on a hit
}

void EmbreeAccel::bounds(Vec3 &lo, Vec3 &hi) const {
    RTCBounds b;
    rtcGetSceneBounds(m_scene, &b);
    lo = Vec3(b.lower_x, b.lower_y, b.lower_z);
    hi = Vec3(b.upper_x, b.upper_y, b.upper_z);
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
