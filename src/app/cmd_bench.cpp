// `meso bench SUITE|SCENE... [options]`: the equal-time benchmark suite (issue 8; paper 004
// Table 3-4). The orchestration (prefiltered models, cached references, equal-time renders of
// every method, report.md with tables and matplotlib figures, results.json) is the Python
// driver scripts/experiments/bench, which calls this binary for every render; this subcommand
// finds the driver and a Python with numpy and matplotlib, and runs it, passing every argument
// through (`meso bench --help` prints the driver's help).
//
// Nothing about the build machine is compiled in, so the binary can move:
//  * the driver: $MESO_BENCH_SCRIPT, else scripts/experiments/bench (or share/meso/scripts/
//    experiments/bench, an installed layout) in the binary's directory or any directory above it
//    (a build directory inside the source tree finds its tree);
//  * the interpreter: $MESO_PYTHON, else the first python3 on PATH that imports numpy and
//    matplotlib, else /usr/bin/python3 (Debian's, where scripts/setup installs both).
#include <CLI/CLI.hpp>
#include <unistd.h>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fmt/format.h>
#include <string>
#include <vector>
#include "app/commands.h"
#include "core/error.h"

namespace meso {
namespace {
namespace fs = std::filesystem;

fs::path self_exe() {
    std::error_code ec;
    fs::path p = fs::read_symlink("/proc/self/exe", ec);
    return ec ? fs::path() : p;
}

std::string find_driver(const fs::path &exe) {
    std::vector<fs::path> tried;
    if (const char *env = std::getenv("MESO_BENCH_SCRIPT")) tried.emplace_back(env);
    std::error_code ec;
    for (fs::path dir = exe.empty() ? fs::path() : fs::weakly_canonical(exe.parent_path(), ec); !dir.empty();
         dir = dir.parent_path()) {
        tried.push_back(dir / "scripts" / "experiments" / "bench");
        tried.push_back(dir / "share" / "meso" / "scripts" / "experiments" / "bench");
        if (dir == dir.root_path()) break;
    }
    for (const fs::path &p : tried)
        if (fs::is_regular_file(p, ec)) return fs::weakly_canonical(p, ec).string();
    throw MesoError(fmt::format("bench: cannot find the driver scripts/experiments/bench (looked in {} places above {}; "
                                "set MESO_BENCH_SCRIPT)",
                                tried.size(), exe.empty() ? std::string("?") : exe.parent_path().string()));
}

/// True when `python` runs and imports numpy and matplotlib.
bool python_has_modules(const std::string &python) {
    if (access(python.c_str(), X_OK) != 0) return false;
    const std::string cmd = "'" + python + "' -c 'import numpy, matplotlib' >/dev/null 2>&1";
    return std::system(cmd.c_str()) == 0;
}

std::string find_python() {
    if (const char *env = std::getenv("MESO_PYTHON")) {
        if (!python_has_modules(env))
            throw MesoError(fmt::format("bench: MESO_PYTHON={} cannot import numpy and matplotlib", env));
        return env;
    }
    if (const char *path = std::getenv("PATH")) {
        std::string dirs = path;
        for (size_t a = 0; a <= dirs.size();) {
            size_t b = dirs.find(':', a);
            if (b == std::string::npos) b = dirs.size();
            const std::string dir = dirs.substr(a, b - a);
            if (!dir.empty() && python_has_modules(dir + "/python3")) return dir + "/python3";
            a = b + 1;
        }
    }
    if (python_has_modules("/usr/bin/python3")) return "/usr/bin/python3";
    throw MesoError("bench: needs a python3 with numpy and matplotlib (Debian: apt install python3-numpy "
                    "python3-matplotlib; scripts/setup installs them; or set MESO_PYTHON)");
}

int run_bench(const std::vector<std::string> &args) {
    const fs::path exe = self_exe();
    const std::string driver = find_driver(exe);
    const std::string python = find_python();
    std::vector<std::string> argv_s = {python, driver, "--meso", exe.empty() ? std::string("meso") : exe.string()};
    argv_s.insert(argv_s.end(), args.begin(), args.end());
    std::vector<char *> argv;
    for (std::string &s : argv_s) argv.push_back(s.data());
    argv.push_back(nullptr);
    std::fflush(stdout);
    execv(python.c_str(), argv.data());
    throw MesoError(fmt::format("bench: cannot run {}: {}", python, std::strerror(errno)));
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
