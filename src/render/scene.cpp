#include "render/scene.h"
#include <fmt/format.h>
#include "geometry/embree_accel.h"
#include "geometry/shape.h"
#include "bsdf/material.h"
#include "sampling/distribution.h"
#include "render/renderer.h"

namespace meso {

Scene::Scene() = default;
Scene::~Scene() = default;

void Scene::build() {
    m_accel = std::make_unique<EmbreeAccel>();
    for (auto &s : shapes) m_accel->add(s.get());
    m_accel->commit();
    m_accel->bounds(m_bmin, m_bmax);
    materials_read_footprints = has_lod_shapes = false;
    for (auto &s : shapes) {
        materials_read_footprints |= s->material && s->material->uses_footprint();
        has_lod_shapes |= s->lod != nullptr;
    }
    if (shapes.empty() || !is_finite(m_bmin) || !is_finite(m_bmax) || m_bmin.x > m_bmax.x) {
        m_bmin = Vec3(-1, -1, -1);
        m_bmax = Vec3(1, 1, 1);
    }
    Vec3 center = (m_bmin + m_bmax) * 0.5f;
    float radius = std::max(1e-3f, length(m_bmax - m_bmin) * 0.5f);
    infinite_lights.clear();
    std::vector<float> power;
    for (auto &l : lights) {
        l->preprocess(center, radius);
        if (l->is_infinite()) infinite_lights.push_back(l.get());
        float p = l->power();
        power.push_back(std::isfinite(p) && p > 0.f ? p : 0.f);
    }
    m_light_distr = std::make_unique<Distribution1D>(power);
    m_light_pmf.clear();
    for (size_t i = 0; i < lights.size(); ++i) m_light_pmf[lights[i].get()] = m_light_distr->pmf(i);
}

bool Scene::intersect(const Ray &ray, SurfaceInteraction &si) const { return m_accel->intersect(ray, si); }
bool Scene::occluded(const Ray &ray) const { return m_accel->occluded(ray); }
float Scene::intersect_t(const Ray &ray) const { return m_accel->intersect_t(ray); }

const Light *Scene::sample_light(float u, float &pmf) const {
    if (lights.empty()) {
        pmf = 0.f;
        return nullptr;
    }
    size_t i = m_light_distr->sample_discrete(u, &pmf);
    return lights[i].get();
}

float Scene::light_pmf(const Light *light) const {
    auto it = m_light_pmf.find(light);
    return it == m_light_pmf.end() ? 0.f : it->second;
}

std::vector<std::string> Scene::plan() const {
    std::vector<std::string> out;
    size_t total = 0;
    out.push_back(fmt::format("camera: {}", camera ? camera->to_string() : "none"));
    out.push_back(fmt::format("integrator: {}", integrator ? integrator->to_string() : "none"));
    out.push_back(fmt::format("sampler: {} x {} spp", sampler ? sampler->name() : "none", spp));
    size_t prims = 0;
    for (size_t i = 0; i < shapes.size(); ++i) {
        size_t b = shapes[i]->memory_bytes();
        total += b;
        prims += shapes[i]->primitive_count();
        out.push_back(fmt::format("shape {}: {}; material {}{}; {:.2f} MB", i, shapes[i]->to_string(),
                                  shapes[i]->material ? shapes[i]->material->to_string() : "none",
                                  shapes[i]->emitter ? "; area emitter" : "", b / 1048576.0));
    }
    for (size_t i = 0; i < lights.size(); ++i) out.push_back(fmt::format("light {}: {}", i, lights[i]->to_string()));
    if (camera) {
        size_t film = film_bytes(camera->width(), camera->height());
        total += film;
        out.push_back(fmt::format("film: {}x{}, {:.2f} MB", camera->width(), camera->height(), film / 1048576.0));
    }
    out.push_back(fmt::format("total: {} primitives, about {:.2f} MB (+ textures and light tables listed above)", prims,
                              total / 1048576.0));
    return out;
}

}  // namespace meso
