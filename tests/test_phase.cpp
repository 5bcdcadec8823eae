// The phase marks of `meso perf` (core/phase.h): PhaseScope nests and restores, and a running
// PhaseSampler attributes the CPU time of a marked busy loop to its phase.
#include <gtest/gtest.h>
#include <chrono>
#include <cmath>
#include <thread>
#include "core/phase.h"

using namespace meso;

namespace {

/// Spins for `ms` milliseconds of this thread's CPU time (SIGPROF counts process CPU time).
double spin(int ms) {
    const std::clock_t end = std::clock() + std::clock_t(double(ms) * CLOCKS_PER_SEC / 1000.0);
    volatile double x = 1.0;
    while (std::clock() < end)
        for (int i = 0; i < 1000; ++i) x = std::sqrt(x + 1.0);
    return x;
}

}  // namespace

TEST(Phase, ScopesNestAndRestore) {
    EXPECT_EQ(phase_detail::current, Phase::Other);
    {
        PhaseScope a(Phase::Light);
        EXPECT_EQ(phase_detail::current, Phase::Light);
        {
            PhaseScope b(Phase::Bsdf);
            EXPECT_EQ(phase_detail::current, Phase::Bsdf);
        }
        EXPECT_EQ(phase_detail::current, Phase::Light);
    }
    EXPECT_EQ(phase_detail::current, Phase::Other);
    // Per thread: another thread starts in Other whatever this one is in.
    PhaseScope c(Phase::Trace);
    Phase seen = Phase::Count;
    std::thread([&] { seen = phase_detail::current; }).join();
    EXPECT_EQ(seen, Phase::Other);
}

// 300 ms of CPU in Light, then 100 ms in Other: at 1 kHz about 300 and 100 samples. The bounds
// allow for the timer's granularity and for other work on the machine (SIGPROF counts this
// process's CPU time only, so a loaded machine gives fewer samples, not other phases).
TEST(Phase, SamplerAttributesCpuTimeToThePhase) {
    PhaseSampler ps;
    ps.start(1000);
    {
        PhaseScope light(Phase::Light);
        spin(300);
    }
    spin(100);
    ps.stop();
    const auto c = ps.counts();
    const double n = double(ps.total());
    ASSERT_GT(n, 100.0);
    const double light = double(c[size_t(Phase::Light)]) / n, other = double(c[size_t(Phase::Other)]) / n;
    EXPECT_NEAR(light, 0.75, 0.12) << n << " samples";
    EXPECT_NEAR(other, 0.25, 0.12) << n << " samples";
    EXPECT_EQ(c[size_t(Phase::Trace)] + c[size_t(Phase::Bsdf)] + c[size_t(Phase::Camera)], 0u);
    // One sampler at a time.
    ps.start(1000);
    PhaseSampler second;
    EXPECT_THROW(second.start(1000), std::exception);
    ps.stop();
}
