// `meso info`: version, Embree version/ISA, threads, and the compiled-in plugins.
#include <CLI/CLI.hpp>
#include <cstdio>
#include <tbb/info.h>
#include "app/commands.h"
#include "core/distributed.h"
#include "geometry/embree_accel.h"
#include "meso_version.h"
#include "core/registry.h"

namespace meso {
namespace {

template <typename T> void list(const char *kind, const PluginTable<T> &t) {
    std::printf("%s:\n", kind);
    for (auto &[name, doc] : t.docs) std::printf("  %-14s %s\n", name.c_str(), doc.c_str());
}

int run_info() {
    std::printf("meso %s\n", MESO_VERSION);
    std::printf("%s\n", EmbreeAccel::version_string().c_str());
    std::printf("distribution: %s\n", dist::describe().c_str());
    std::printf("threads available: %d\n", tbb::info::default_concurrency());
    const Registry &r = registry();
    list("cameras", r.cameras);
    list("integrators", r.integrators);
    list("samplers", r.samplers);
    list("shapes", r.shapes);
    list("materials", r.materials);
    list("textures", r.textures);
    list("lights", r.lights);
    return 0;
}

SubcommandRegistrar reg({"info", "Print version, Embree ISA and the compiled-in plugins", [](CLI::App &) {
    return [] { return run_info(); };
}});

}  // namespace
}  // namespace meso
