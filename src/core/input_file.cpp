#include "core/input_file.h"
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <fmt/format.h>
#include "core/error.h"

namespace meso {

namespace fs = std::filesystem;

namespace {

const char *type_name(fs::file_type t) {
    switch (t) {
        case fs::file_type::character: return "a character device";
        case fs::file_type::block: return "a block device";
        case fs::file_type::fifo: return "a named pipe";
        case fs::file_type::socket: return "a socket";
        default: return "not a plain file";
    }
}

std::string bytes_text(uint64_t b) {
    if (b >= (uint64_t(1) << 30)) return fmt::format("{:.3g} GiB", double(b) / double(uint64_t(1) << 30));
    if (b >= (uint64_t(1) << 20)) return fmt::format("{:.3g} MiB", double(b) / double(uint64_t(1) << 20));
    return fmt::format("{} bytes", b);
}

}  // namespace

std::string input_file_problem(const std::string &path, uint64_t max_bytes, const char *kind) {
    std::error_code ec;
    const fs::file_status st = fs::status(path, ec);  // follows symbolic links
    if (st.type() == fs::file_type::not_found) return "file not found";
    if (ec) return ec.message();
    if (st.type() == fs::file_type::directory) return "it is a directory";
    if (st.type() != fs::file_type::regular) return fmt::format("it is {}, not a regular file", type_name(st.type()));
    const uintmax_t size = fs::file_size(path, ec);
    if (ec) return ec.message();
    if (uint64_t(size) > max_bytes)
        return fmt::format("it is {} bytes, more than the {} limit for {}s", uint64_t(size), bytes_text(max_bytes), kind);
    return "";
}

void check_input_file(const std::string &path, uint64_t max_bytes, const char *kind) {
    const std::string why = input_file_problem(path, max_bytes, kind);
    if (!why.empty()) throw MesoError(fmt::format("{}: cannot open the {} ({})", path, kind, why));
}

std::string read_input_file(const std::string &path, uint64_t max_bytes, const char *kind) {
    check_input_file(path, max_bytes, kind);
    std::ifstream f(path, std::ios::binary);
    if (!f) throw MesoError(fmt::format("{}: cannot open the {} ({})", path, kind, std::strerror(errno)));
    std::ostringstream ss;
    ss << f.rdbuf();
    if (f.bad()) throw MesoError(fmt::format("{}: cannot read the {} ({})", path, kind, std::strerror(errno)));
    return ss.str();
}

}  // namespace meso
