#include "image/wrap_mode.h"
#include "core/properties.h"

namespace meso {

const char *wrap_mode_name(WrapMode mode) {
    switch (mode) {
        case WrapMode::Clamp: return "clamp";
        case WrapMode::Mirror: return "mirror";
        case WrapMode::Repeat:
        default: return "repeat";
    }
}

WrapMode parse_wrap_mode(const Properties &p, const std::string &key, WrapMode def) {
    return p.get_enum<WrapMode>(key, wrap_mode_name(def),
                                {{"repeat", WrapMode::Repeat}, {"clamp", WrapMode::Clamp}, {"mirror", WrapMode::Mirror}});
}

WrapMode parse_texture_wrap(const Properties &p) {
    if (p.has("wrap") && p.has("wrap_mode")) p.fail("wrap", "give either \"wrap\" or \"wrap_mode\" (the same setting), not both");
    return parse_wrap_mode(p, p.has("wrap") ? "wrap" : "wrap_mode");
}

}  // namespace meso
