// Helpers for tests of the command line and of error messages: run `meso ARGS...`
// in-process through meso::run_cli with stdout and stderr captured, and turn the
// MesoError a call throws into its message.
#pragma once
#include <gtest/gtest.h>
#include <sys/wait.h>
#include <cstdio>
#include <functional>
#include <string>
#include <vector>
#include "app/commands.h"
#include "core/error.h"

namespace meso::test {

struct CliResult {
    int code;
    std::string out, err;
};

/// Runs `meso args...` in-process; returns the exit code and what it printed.
inline CliResult run_cli_captured(std::vector<std::string> args) {
    args.insert(args.begin(), "meso");
    std::vector<char *> argv;
    for (auto &a : args) argv.push_back(a.data());
    testing::internal::CaptureStdout();
    testing::internal::CaptureStderr();
    int code = meso::run_cli(int(argv.size()), argv.data());
    std::fflush(stdout);
    std::fflush(stderr);
    CliResult r{code, testing::internal::GetCapturedStdout(), testing::internal::GetCapturedStderr()};
    return r;
}

/// Runs the meso binary (MESO_BINARY) through the shell as `meso ARGS 2>&1`, in directory `cwd` if
/// given; `out` holds stdout and stderr together. For what must run in its own process (signals,
/// the current directory, the real exit code).
inline CliResult run_binary(const std::string &args, const std::string &cwd = "") {
    const std::string cmd = (cwd.empty() ? std::string() : "cd '" + cwd + "' && ") + MESO_BINARY + " " + args + " 2>&1";
    CliResult r{0, "", ""};
    FILE *p = popen(cmd.c_str(), "r");
    char buf[4096];
    while (size_t n = fread(buf, 1, sizeof(buf), p)) r.out.append(buf, n);
    const int st = pclose(p);
    r.code = WIFEXITED(st) ? WEXITSTATUS(st) : -1;
    return r;
}

/// The message of the MesoError that f throws, or "(no error)".
inline std::string meso_error_of(const std::function<void()> &f) {
    try {
        f();
    } catch (const MesoError &e) {
        return e.what();
    }
    return "(no error)";
}

}  // namespace meso::test
