// The plugin registry: every camera, integrator, sampler, shape, material, texture and
// light is created by its scene-file "type" name through here. Plugins register
// themselves with MESO_REGISTER_* in their own .cpp file; plugin sources are compiled as
// an OBJECT library, so the static registrars are never dropped by the linker.
// Adding a plugin = adding one file.
#pragma once
#include <functional>
#include <map>
#include <memory>
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>
#include "core/spectrum.h"

namespace meso {

class Properties;
class Material;
class Texture;
class Light;
class Integrator;
class Sampler;
class Camera;
class Shape;

template <typename T> using Factory = std::function<std::shared_ptr<T>(const Properties &)>;

template <typename T> struct PluginTable {
    std::map<std::string, Factory<T>> factories;
    std::map<std::string, std::string> docs;  ///< one-line description for `meso info`
};

struct Registry {
    PluginTable<Material> materials;
    PluginTable<Texture> textures;
    PluginTable<Light> lights;
    PluginTable<Integrator> integrators;
    PluginTable<Sampler> samplers;
    PluginTable<Camera> cameras;
    PluginTable<Shape> shapes;
};

Registry &registry();

/// Create a plugin of the kind T from props (dispatch on props.type()); errors name the
/// file, path and the known types. Calls check_unused() afterwards.
std::shared_ptr<Material> create_material(const Properties &props);
std::shared_ptr<Texture> create_texture(const Properties &props);
/// A constant texture (also what plain numbers and [r,g,b] arrays in a scene become); defined by
/// the texture layer (texture/constant.cpp).
std::shared_ptr<Texture> make_constant_texture(Spectrum value);
/// A material from a command-line argument: an inline JSON object or the path of a JSON file
/// (relative paths inside resolve against the file's directory, returned in *base_dir when
/// given). `storage` keeps the parsed JSON. Errors name the file or "<inline material>".
std::shared_ptr<Material> load_material_arg(const std::string &arg, nlohmann::json &storage,
                                            std::string *base_dir = nullptr);
std::shared_ptr<Light> create_light(const Properties &props);
std::shared_ptr<Integrator> create_integrator(const Properties &props);
std::shared_ptr<Sampler> create_sampler(const Properties &props);
std::shared_ptr<Camera> create_camera(const Properties &props);
std::shared_ptr<Shape> create_shape(const Properties &props);

template <typename T> struct Registrar {
    Registrar(PluginTable<T> &table, const char *name, const char *doc, Factory<T> f) {
        table.factories[name] = std::move(f);
        table.docs[name] = doc;
    }
};

#define MESO_CONCAT_(a, b) a##b
#define MESO_CONCAT(a, b) MESO_CONCAT_(a, b)
#define MESO_REGISTER_PLUGIN_(T, table, name, doc, ...) \
    static ::meso::Registrar<::meso::T> MESO_CONCAT(meso_registrar_, __LINE__)(::meso::registry().table, name, doc, __VA_ARGS__)
/// MESO_REGISTER_MATERIAL("diffuse", "Lambertian reflector", [](const Properties &p) {...});
#define MESO_REGISTER_MATERIAL(name, doc, ...) MESO_REGISTER_PLUGIN_(Material, materials, name, doc, __VA_ARGS__)
#define MESO_REGISTER_TEXTURE(name, doc, ...) MESO_REGISTER_PLUGIN_(Texture, textures, name, doc, __VA_ARGS__)
#define MESO_REGISTER_LIGHT(name, doc, ...) MESO_REGISTER_PLUGIN_(Light, lights, name, doc, __VA_ARGS__)
#define MESO_REGISTER_INTEGRATOR(name, doc, ...) MESO_REGISTER_PLUGIN_(Integrator, integrators, name, doc, __VA_ARGS__)
#define MESO_REGISTER_SAMPLER(name, doc, ...) MESO_REGISTER_PLUGIN_(Sampler, samplers, name, doc, __VA_ARGS__)
#define MESO_REGISTER_CAMERA(name, doc, ...) MESO_REGISTER_PLUGIN_(Camera, cameras, name, doc, __VA_ARGS__)
#define MESO_REGISTER_SHAPE(name, doc, ...) MESO_REGISTER_PLUGIN_(Shape, shapes, name, doc, __VA_ARGS__)

}  // namespace meso
