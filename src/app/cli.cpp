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
        return app.exit(e);
    }
    try {
        for (auto &[sub, act] : actions)
            if (sub->parsed()) return act();
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
