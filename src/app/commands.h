// The `meso` command line: one binary, subcommands render / compare / material / info /
// bench. Each subcommand lives in its own cmd_*.cpp and registers itself here.
#pragma once
#include <functional>
#include <string>
#include <vector>

namespace CLI { class App; }

namespace meso {

/// Runs the command line; returns the process exit code: 0 success, 1 an error, 2 a usage
/// error (unknown option, missing or malformed value, value out of range). Errors print one
/// line "meso: error: ..." to stderr.
int run_cli(int argc, char **argv);

/// A subcommand: `setup` adds options to its CLI::App and returns the action to run.
struct Subcommand {
    const char *name;
    const char *help;
    std::function<std::function<int()>(CLI::App &)> setup;
};
std::vector<Subcommand> &subcommands();

struct SubcommandRegistrar {
    explicit SubcommandRegistrar(Subcommand c) { subcommands().push_back(std::move(c)); }
};

}  // namespace meso
