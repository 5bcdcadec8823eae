#include "core/error.h"

namespace meso {

std::string located_message(const std::string &file, const std::string &path, const std::string &msg) {
    std::string out;
    if (!file.empty()) out += file + ": ";
    if (!path.empty()) out += path + ": ";
    return out + msg;
}

void throw_located(const std::string &file, const std::string &path, const std::string &msg) {
    throw MesoError(located_message(file, path, msg));
}

}  // namespace meso
