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

// 600 ms of CPU in Light, then 200 ms in Other. The profiling timer fires at most once per
// kernel tick (100-1000 Hz: CONFIG_HZ), so 80 to 800 samples; the bounds are 4 binomial standard
// errors of the shares at the count seen, plus 0.03 for the ticks split at the phase change
// and the spin loops' own set-up. SIGPROF counts this
// process's CPU time only, so a loaded machine gives fewer samples, not other phases.
TEST(Phase, SamplerAttributesCpuTimeToThePhase) {
    PhaseSampler ps;
    ps.start(1000);
    {
        PhaseScope light(Phase::Light);
        spin(600);
    }
    spin(200);
    ps.stop();
    const auto c = ps.counts();
    const double n = double(ps.total());
    ASSERT_GE(n, 50.0);
    const double light = double(c[size_t(Phase::Light)]) / n, other = double(c[size_t(Phase::Other)]) / n;
    const double tol = 4.0 * std::sqrt(0.75 * 0.25 / n) + 0.03;
    EXPECT_NEAR(light, 0.75, tol) << n << " samples";
    EXPECT_NEAR(other, 0.25, tol) << n << " samples";
    EXPECT_EQ(c[size_t(Phase::Trace)] + c[size_t(Phase::Bsdf)] + c[size_t(Phase::Camera)], 0u);
    // One sampler at a time.
    ps.start(1000);
    PhaseSampler second;
    EXPECT_THROW(second.start(1000), std::exception);
    ps.stop();
}
