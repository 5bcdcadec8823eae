// Shared by the meso microbenchmarks: the default flags (5 repetitions, randomly interleaved,
// aggregates only, 0.2 s minimum time; flags given on the command line come later and win) and
// a console reporter that also records every benchmark's median CPU time for the summary table.
#pragma once
#include <benchmark/benchmark.h>
#include <filesystem>
#include <functional>
#include <map>
#include <string>
#include <vector>

namespace meso::bench {

/// benchmark::Initialize with the defaults above; `own` takes the program's own flags (true:
/// consumed). False when a flag is unrecognised (reported).
inline bool initialize(int argc, char **argv, const std::function<bool(const std::string &)> &own) {
    // Static: benchmark keeps argv[0] for its "Running ..." line, printed after this returns.
    static std::vector<std::string> args;
    args = {argv[0], "--benchmark_repetitions=5", "--benchmark_enable_random_interleaving=true",
            "--benchmark_report_aggregates_only=true", "--benchmark_min_time=0.2"};
    for (int a = 1; a < argc; ++a)
        if (!own(argv[a])) args.push_back(argv[a]);
    static std::vector<char *> argp;
    argp.clear();
    for (std::string &s : args) argp.push_back(s.data());
    int n = int(argp.size());
    benchmark::Initialize(&n, argp.data());
    return !benchmark::ReportUnrecognizedArguments(n, argp.data());
}

/// Records the median CPU time of every benchmark (the single run without repetitions).
class MedianReporter : public benchmark::ConsoleReporter {
public:
    std::map<std::string, double> ns;
    void ReportRuns(const std::vector<Run> &runs) override {
        ConsoleReporter::ReportRuns(runs);
        for (const Run &r : runs) {
            const bool median = r.run_type == Run::RT_Aggregate && r.aggregate_name == "median";
            const bool single = r.run_type == Run::RT_Iteration && r.repetitions <= 1;
            if (median || single) ns[r.run_name.function_name] = r.GetAdjustedCPUTime();
        }
    }
};

/// Runs the registered benchmarks, prints `summary` of their medians and removes `scratch`.
inline int run(const std::function<void(const std::map<std::string, double> &)> &summary,
               const std::filesystem::path &scratch) {
    MedianReporter rep;
    benchmark::RunSpecifiedBenchmarks(&rep);
    summary(rep.ns);
    benchmark::Shutdown();
    std::error_code ec;
    std::filesystem::remove_all(scratch, ec);
    return 0;
}

}  // namespace meso::bench
