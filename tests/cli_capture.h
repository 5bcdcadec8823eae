// Helpers for tests of the command line and of error messages: run `meso ARGS...`
// in-process through meso::run_cli with stdout and stderr captured, and turn the
// MesoError a call throws into its message.
#pragma once
#include <gtest/gtest.h>
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
