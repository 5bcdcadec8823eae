// Shared by the meso microbenchmarks: a console reporter that also records the median CPU time
// of every benchmark (or its single run, without repetitions) for a summary table at the end.
#pragma once
#include <benchmark/benchmark.h>
#include <map>
#include <string>
#include <vector>

namespace meso::bench {

class MedianReporter : public benchmark::ConsoleReporter {
public:
    std::map<std::string, double> ns;  ///< benchmark name -> median CPU ns
    void ReportRuns(const std::vector<Run> &runs) override {
        ConsoleReporter::ReportRuns(runs);
        for (const Run &r : runs) {
            const bool median = r.run_type == Run::RT_Aggregate && r.aggregate_name == "median";
            const bool single = r.run_type == Run::RT_Iteration && r.repetitions <= 1;
            if (median || single) ns[r.run_name.function_name] = r.GetAdjustedCPUTime();
        }
    }
};

}  // namespace meso::bench
