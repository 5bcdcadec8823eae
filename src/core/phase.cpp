#include "core/phase.h"
#include <signal.h>
#include <sys/time.h>
#include <atomic>
#include <cstring>
#include "core/error.h"

namespace meso {

namespace phase_detail {
__thread Phase current = Phase::Other;
}

namespace {
std::array<std::atomic<uint64_t>, kPhaseCount> g_counts;
std::atomic<bool> g_running{false};
struct sigaction g_old_action;
struct itimerval g_old_timer;

void on_sigprof(int) {
    const int p = int(phase_detail::current);  // initial-exec TLS: async-signal-safe
    g_counts[size_t(p < kPhaseCount ? p : 0)].fetch_add(1, std::memory_order_relaxed);
}
}  // namespace

const char *phase_name(Phase p) {
    switch (p) {
        case Phase::Camera: return "camera";
        case Phase::Trace: return "trace";
        case Phase::Interaction: return "interaction";
        case Phase::Light: return "light sampling";
        case Phase::Bsdf: return "BSDF";
        case Phase::Film: return "film";
        default: return "other";
    }
}

PhaseSampler::~PhaseSampler() {
    if (g_running.load()) stop();
}

void PhaseSampler::start(int hz) {
    if (g_running.exchange(true)) throw MesoError("phase sampler: already running");
    for (auto &c : g_counts) c.store(0);
    struct sigaction sa;
    std::memset(&sa, 0, sizeof sa);
    sa.sa_handler = on_sigprof;
    sa.sa_flags = SA_RESTART;
    sigemptyset(&sa.sa_mask);
    sigaction(SIGPROF, &sa, &g_old_action);
    const long us = 1000000L / (hz > 0 ? hz : 1000);
    struct itimerval t;
    t.it_interval.tv_sec = us / 1000000L;
    t.it_interval.tv_usec = us % 1000000L;
    t.it_value = t.it_interval;
    setitimer(ITIMER_PROF, &t, &g_old_timer);
}

void PhaseSampler::stop() {
    if (!g_running.load()) return;
    setitimer(ITIMER_PROF, &g_old_timer, nullptr);
    sigaction(SIGPROF, &g_old_action, nullptr);
    g_running.store(false);
}

std::array<uint64_t, kPhaseCount> PhaseSampler::counts() const {
    std::array<uint64_t, kPhaseCount> out{};
    for (int i = 0; i < kPhaseCount; ++i) out[size_t(i)] = g_counts[size_t(i)].load();
    return out;
}

uint64_t PhaseSampler::total() const {
    uint64_t s = 0;
    for (uint64_t c : counts()) s += c;
    return s;
}

}  // namespace meso
