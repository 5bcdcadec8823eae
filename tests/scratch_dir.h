// Per-process scratch directory for tests, removed at exit.
#pragma once
#include <unistd.h>
#include <filesystem>
#include <string>

namespace meso::test {

/// A fresh directory under the system temp dir named `<prefix>_<pid>`; removed at exit.
inline std::string scratch_dir(const std::string &prefix) {
    struct Dir {
        std::string path;
        ~Dir() {
            std::error_code ec;
            std::filesystem::remove_all(path, ec);
        }
    };
    static Dir dir{[&] {
        auto p = std::filesystem::temp_directory_path() / (prefix + "_" + std::to_string(::getpid()));
        std::filesystem::create_directories(p);
        return p.string();
    }()};
    return dir.path;
}

}  // namespace meso::test
