// Reading an image named by a scene parameter, with errors located at that parameter.
#pragma once
#include <string>
#include "image/image.h"

namespace meso {

class Properties;

/// read_image(file, !raw) for the file named by p[key] (already resolved by the caller with
/// p.get_file(key)); read failures and empty or malformed images fail at `key`.
Image read_image_param(const Properties &p, const std::string &key, const std::string &file, bool raw);

}  // namespace meso
