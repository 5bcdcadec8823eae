#include "core/progress.h"
#include <unistd.h>
#include <cstdio>
#include <fmt/format.h>

namespace meso {

Progress::Progress(bool enabled, double total, std::string unit)
    : m_enabled(enabled), m_tty(isatty(fileno(stderr))), m_total(total), m_unit(std::move(unit)) {}

static std::string format_time(double s) {
    if (s < 60) return fmt::format("{:.1f}s", s);
    if (s < 3600) return fmt::format("{}m{:02d}s", int(s / 60), int(s) % 60);
    return fmt::format("{}h{:02d}m", int(s / 3600), int(s / 60) % 60);
}

void Progress::update(double done, double elapsed, const std::string &extra) {
    if (!m_enabled || m_total <= 0) return;
    double frac = std::min(1.0, done / m_total);
    double eta = frac > 0 ? elapsed * (1 - frac) / frac : 0;
    if (m_tty) {
        if (elapsed - m_last_print < 0.1 && frac < 1.0) return;
        const int width = 30;
        int filled = int(frac * width);
        std::string bar(filled, '#');
        bar += std::string(width - filled, ' ');
        std::fprintf(stderr, "\r[%s] %5.1f%%  %s elapsed, ETA %s  %s   ", bar.c_str(), frac * 100,
                     format_time(elapsed).c_str(), format_time(eta).c_str(), extra.c_str());
        std::fflush(stderr);
    } else {
        if (elapsed - m_last_print < 5.0 && frac < 1.0) return;  // plain lines every 5 s
        std::fprintf(stderr, "meso: %5.1f%% (%s) elapsed %s, ETA %s\n", frac * 100, extra.c_str(),
                     format_time(elapsed).c_str(), format_time(eta).c_str());
    }
    m_last_print = elapsed;
}

void Progress::finish(double elapsed) {
    if (!m_enabled) return;
    if (m_tty) std::fprintf(stderr, "\n");
    std::fprintf(stderr, "meso: done in %s\n", format_time(elapsed).c_str());
}

}  // namespace meso
