#include "core/interrupt.h"
#include <unistd.h>
#include <atomic>
#include <csignal>
#include <cstring>

namespace meso {

namespace {

constexpr int kSlots = 64, kPathMax = 4096;
char g_paths[kSlots][kPathMax];
std::atomic<int> g_used[kSlots];
volatile std::sig_atomic_t g_signals = 0;
volatile std::sig_atomic_t g_graceful = 1;

void say(const char *s) {
    ssize_t n = ::write(STDERR_FILENO, s, std::strlen(s));
    (void)n;
}

extern "C" void on_signal(int) {
    g_signals = g_signals + 1;
    if (g_graceful && g_signals == 1) {
        say("\nmeso: interrupted: finishing the current pass, then writing what is done (interrupt again to abort)\n");
        return;
    }
    for (int i = 0; i < kSlots; ++i)
        if (g_used[i].load(std::memory_order_acquire) == 1) {
            ::unlink(g_paths[i]);
            ::rmdir(g_paths[i]);
        }
    say("\nmeso: aborted: no output written\n");
    ::_exit(kInterruptedExitCode);
}

}  // namespace

void install_interrupt_handler(InterruptMode mode) {
    g_signals = 0;
    g_graceful = mode == InterruptMode::Graceful;
    struct sigaction sa;
    std::memset(&sa, 0, sizeof(sa));
    sa.sa_handler = on_signal;
    sigemptyset(&sa.sa_mask);
    sa.sa_flags = SA_RESTART;
    sigaction(SIGINT, &sa, nullptr);
    sigaction(SIGTERM, &sa, nullptr);
}

bool interrupt_requested() { return g_signals > 0; }

void register_temporary(const std::string &path) {
    if (path.size() >= size_t(kPathMax)) return;
    for (int i = 0; i < kSlots; ++i) {
        int expected = 0;
        if (g_used[i].compare_exchange_strong(expected, 2)) {  // 2: claimed, path being copied
            std::memcpy(g_paths[i], path.c_str(), path.size() + 1);
            g_used[i].store(1, std::memory_order_release);
            return;
        }
    }
}

void unregister_temporary(const std::string &path) {
    for (int i = 0; i < kSlots; ++i)
        if (g_used[i].load(std::memory_order_acquire) == 1 && path == g_paths[i]) {
            g_used[i].store(0, std::memory_order_release);
            return;
        }
}

}  // namespace meso
