// `meso bench SUITE|SCENE... [options]`: the equal-time benchmark suite (issue 8; paper 004
// Table 3-4). The orchestration (prefiltered models, cached references, equal-time renders of
// every method, report.md with tables and matplotlib figures, results.json) is the Python
// driver scripts/bench, which calls this binary for every render; this subcommand finds the
// driver and runs it with Debian's /usr/bin/python3 (numpy, matplotlib), passing every
// argument through (`meso bench --help` prints the driver's help).
//
// The driver is looked up in: $MESO_BENCH_SCRIPT, <dir of this binary>/../scripts/bench (a build
// directory inside the source tree), the source tree this binary was built from.
#include <CLI/CLI.hpp>
#include <unistd.h>
#include <cerrno>
#include <cstring>
#include <filesystem>
#include <fmt/format.h>
#include <string>
#include <vector>
#include "app/commands.h"
#include "core/error.h"

#ifndef MESO_SOURCE_DIR
#define MESO_SOURCE_DIR ""
#endif

namespace meso {
namespace {
namespace fs = std::filesystem;

constexpr const char *kPython = "/usr/bin/python3";

fs::path self_exe() {
    std::error_code ec;
    fs::path p = fs::read_symlink("/proc/self/exe", ec);
    return ec ? fs::path() : p;
}

std::string find_driver(const fs::path &exe) {
    std::vector<fs::path> tried;
    if (const char *env = std::getenv("MESO_BENCH_SCRIPT")) tried.emplace_back(env);
    if (!exe.empty()) tried.push_back(exe.parent_path() / ".." / "scripts" / "bench");
    if (std::string(MESO_SOURCE_DIR).size()) tried.push_back(fs::path(MESO_SOURCE_DIR) / "scripts" / "bench");
    std::string list;
    for (const fs::path &p : tried) {
        std::error_code ec;
        if (fs::is_regular_file(p, ec)) return fs::weakly_canonical(p, ec).string();
        list += (list.empty() ? "" : ", ") + p.string();
    }
    throw MesoError(fmt::format("bench: cannot find the driver scripts/bench (looked in: {}; set MESO_BENCH_SCRIPT)",
                                list.empty() ? "nowhere" : list));
}

int run_bench(const std::vector<std::string> &args) {
    const fs::path exe = self_exe();
    const std::string driver = find_driver(exe);
    if (access(kPython, X_OK) != 0)
        throw MesoError(fmt::format("bench: needs {} with numpy and matplotlib (Debian: apt install python3-numpy "
                                    "python3-matplotlib; scripts/setup installs them)",
                                    kPython));
    std::vector<std::string> argv_s = {"python3", driver, "--meso", exe.empty() ? std::string("meso") : exe.string()};
    argv_s.insert(argv_s.end(), args.begin(), args.end());
    std::vector<char *> argv;
    for (std::string &s : argv_s) argv.push_back(s.data());
    argv.push_back(nullptr);
    std::fflush(stdout);
    execv(kPython, argv.data());
    throw MesoError(fmt::format("bench: cannot run {}: {}", kPython, std::strerror(errno)));
}

SubcommandRegistrar reg({"bench",
                         "Equal-time benchmark: every LoD method against the original, error vs time, report "
                         "(meso bench --help)",
                         [](CLI::App &app) {
                             app.prefix_command();
                             app.set_help_flag();  // --help goes to the driver
                             return [&app] { return run_bench(app.remaining()); };
                         }});

}  // namespace
}  // namespace meso
