#include "image/image_param.h"
#include <fmt/format.h>
#include "core/error.h"
#include "core/properties.h"

namespace meso {

Image read_image_param(const Properties &p, const std::string &key, const std::string &file, bool raw) {
    Image img;
    try {
        img = read_image(file, !raw);
    } catch (const MesoError &e) {
        p.fail(key, e.what());
    }
    if (img.width <= 0 || img.height <= 0 || img.channels <= 0 ||
        img.data.size() != size_t(img.width) * img.height * img.channels)
        p.fail(key, fmt::format("{}: empty or malformed image", file));
    return img;
}

}  // namespace meso
