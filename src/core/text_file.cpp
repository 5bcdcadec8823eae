#include "core/text_file.h"
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

void write_text_atomic(const std::string &path, const std::string &text) {
    const std::string tmp = path + ".tmp";
    bool ok;
    {
        std::ofstream f(tmp);
        ok = bool(f);
        if (ok) f << text;
        ok = ok && f.flush();
    }
    std::error_code ec;
    if (ok) std::filesystem::rename(tmp, path, ec);
    if (!ok || ec) {
        std::filesystem::remove(tmp, ec);
        throw MesoError(fmt::format("cannot write '{}'", path));
    }
}

}  // namespace meso
