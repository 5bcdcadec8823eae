// A material given on a command line (meso material, meso prefilter): an inline JSON object
// or the path of a JSON file.
#include <filesystem>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/input_file.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {

/// Builds the material from an inline JSON object or a JSON file.
std::shared_ptr<Material> load_material_arg(const std::string &arg, nlohmann::json &storage, std::string *base_dir) {
    auto ctx = std::make_shared<LoadContext>();
    size_t first = arg.find_first_not_of(" \t\r\n");
    bool is_inline = first != std::string::npos && (arg[first] == '{' || arg[first] == '[');
    std::string text;
    if (is_inline) {
        ctx->file = "<inline material>";
        text = arg;
    } else {
        namespace fs = std::filesystem;
        if (arg.empty()) throw MesoError("material: expected a JSON object or the path of a JSON file, got ''");
        text = read_input_file(arg, kMaxSceneFileBytes, "material file");
        ctx->file = arg;
        ctx->base_dir = fs::path(arg).parent_path().string();
    }
    try {
        storage = nlohmann::json::parse(text);
    } catch (const nlohmann::json::parse_error &e) {
        // e.what() is "[json.exception.parse_error.101] parse error at line 1, column 5: ..."
        std::string msg = e.what();
        size_t p = msg.find("] ");
        if (p != std::string::npos) msg = msg.substr(p + 2);
        throw MesoError(fmt::format("{}: invalid JSON: {}", ctx->file, msg));
    }
    if (!storage.is_object())
        throw MesoError(fmt::format("{}: expected a JSON object describing one material", ctx->file));
    Properties props(storage, "", ctx);
    if (base_dir) *base_dir = ctx->base_dir;
    if (!props.has("type")) throw MesoError(fmt::format("{}: type: missing required parameter (the material type)", ctx->file));
    return create_material(props);
}

}  // namespace meso
