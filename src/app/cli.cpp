#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <cstdio>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/error.h"
#include "meso_version.h"

namespace meso {

std::vector<Subcommand> &subcommands() {
    static std::vector<Subcommand> cmds;
    return cmds;
}

/// A command-line error (unknown option, missing or malformed value, value out of range):
/// "meso: error: render: MESSAGE (see meso render --help)" on stderr and exit code 2.
static int usage_error(const CLI::App &app, const CLI::ParseError &e) {
    std::string cmd = "meso";
    const CLI::App *cur = &app;
    while (!cur->get_subcommands().empty()) {
        cur = cur->get_subcommands().back();
        cmd += " " + cur->get_name();
    }
    const std::string where = cmd.size() > 4 ? cmd.substr(5) + ": " : "";
    std::string msg = e.what();
    if (cur == &app && !app.remaining().empty() && app.remaining()[0].rfind("-", 0) != 0) {
        std::string names;
        for (const auto &c : subcommands()) names += std::string(names.empty() ? "" : ", ") + c.name;
        msg = fmt::format("unknown command '{}' (expected one of {})", app.remaining()[0], names);
    }
    std::fprintf(stderr, "meso: error: %s%s (see %s --help)\n", where.c_str(), msg.c_str(), cmd.c_str());
    return 2;
}

int run_cli(int argc, char **argv) {
    CLI::App app{"meso " MESO_VERSION " - a path tracer for sub-pixel surface detail (ground truth and prefiltered LoD)"};
    app.require_subcommand(1);
    app.set_version_flag("--version", MESO_VERSION);
    std::function<int()> action;
    std::vector<std::pair<CLI::App *, std::function<int()>>> actions;
    for (auto &c : subcommands()) {
        CLI::App *sub = app.add_subcommand(c.name, c.help);
        actions.emplace_back(sub, c.setup(*sub));
    }
    try {
        app.parse(argc, argv);
    } catch (const CLI::ParseError &e) {
        if (e.get_exit_code() == 0) return app.exit(e);  // --help, --version
        return usage_error(app, e);
    }
    try {
        for (auto &[sub, act] : actions)
            if (sub->parsed()) return act();
    } catch (const UsageError &e) {
        if (dist::size() > 1) dist::abort_all(e.what());
        std::fprintf(stderr, "meso: error: %s\n", e.what());
        return 2;
    } catch (const std::exception &e) {
        // Under MPI with several ranks the others may wait in a collective: end the whole job
        // (mpirun then exits non-zero; no output is written, rank 0 writes only after the reduce).
        if (dist::size() > 1) dist::abort_all(e.what());
        std::fprintf(stderr, "meso: error: %s\n", e.what());
        return 1;
    }
    return 0;
}

}  // namespace meso
