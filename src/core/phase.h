// Where the time of a render goes, by phase, from sampling (issue 22, `meso perf`).
//
// The hot code marks what it is doing with a PhaseScope: one store to a thread-local variable
// on entry and one on exit, nothing else (no clock reads), so the marks stay in the release
// build at no measurable cost. A PhaseSampler, while running, asks the kernel for a SIGPROF
// every millisecond of the process's CPU time (setitimer ITIMER_PROF: the signal goes to a
// thread that is running) and counts the phase that thread was in. The counts are
// proportional to CPU time per phase, with the binomial noise of a sample count.
#pragma once
#include <array>
#include <cstdint>

namespace meso {

enum class Phase : uint8_t {
    Other,        ///< everything unmarked (sampler, integrator bookkeeping, roulette ...)
    Camera,       ///< camera ray generation
    Trace,        ///< Embree traversal: closest hit and shadow (any-hit) rays
    Interaction,  ///< the hit record: SurfaceInteraction, shading frame, ray differentials
    Light,        ///< light selection, light sampling and light pdfs (MIS)
    Bsdf,         ///< material eval, pdf and sampling (their texture lookups included)
    Film,         ///< accumulating samples into the film
    Count
};
constexpr int kPhaseCount = int(Phase::Count);
const char *phase_name(Phase p);

namespace phase_detail {
/// `__thread`, not `thread_local`: a C++ `extern thread_local` may have a dynamic initialiser
/// in another file, so every access went through a TLS wrapper (a GOT load, a test and a
/// branch to a weak init function). `__thread` (GCC, Clang) guarantees static
/// initialisation: an access is one store through %fs, which keeps an unprofiled
/// PhaseScope at two stores.
extern __thread Phase current;
}

/// Marks the calling thread as being in `p` until the scope ends (nesting restores the outer phase).
class PhaseScope {
public:
    explicit PhaseScope(Phase p) noexcept : m_prev(phase_detail::current) { phase_detail::current = p; }
    ~PhaseScope() { phase_detail::current = m_prev; }
    PhaseScope(const PhaseScope &) = delete;
    PhaseScope &operator=(const PhaseScope &) = delete;

private:
    Phase m_prev;
};

/// Counts SIGPROF samples per phase between start() and stop(). One sampler at a time per
/// process (start() throws MesoError otherwise); the previous SIGPROF handler and timer are
/// restored by stop().
class PhaseSampler {
public:
    PhaseSampler() = default;
    ~PhaseSampler();
    void start(int hz = 1000);
    void stop();
    std::array<uint64_t, kPhaseCount> counts() const;
    uint64_t total() const;
};

}  // namespace meso
