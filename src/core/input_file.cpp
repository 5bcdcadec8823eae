#include "core/input_file.h"
#include <unistd.h>
#include <algorithm>
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

uint64_t physical_memory_bytes() {
    const long pages = sysconf(_SC_PHYS_PAGES), page = sysconf(_SC_PAGESIZE);
    return pages > 0 && page > 0 ? uint64_t(pages) * uint64_t(page) : 0;
}

std::string decoded_size_problem(uint64_t values, uint64_t stored_bytes_per_value, uint64_t file_bytes,
                                 uint64_t decoded_bytes) {
    if (values > kMaxImageValues) return fmt::format("{} values is more than the limit of 2^30", values);
    const uint64_t stored = values * std::max<uint64_t>(stored_bytes_per_value, 1);
    if (values > kFreeDecodedValues && stored / kMaxDecodeRatio > file_bytes)
        return fmt::format("it declares {} of pixel data in a file of {}, a ratio of {:.0f}:1 that no image codec "
                           "reaches (at most {}:1 is accepted): the file is corrupt or truncated",
                           bytes_text(stored), bytes_text(file_bytes), double(stored) / double(std::max<uint64_t>(file_bytes, 1)),
                           kMaxDecodeRatio);
    const uint64_t have = physical_memory_bytes();
    if (have > 0 && decoded_bytes > have)
        return fmt::format("decoding it needs {} of memory, more than this machine's {}", bytes_text(decoded_bytes),
                           bytes_text(have));
    return {};
}

}  // namespace meso
