// Progress reporting on stderr: a bar with ETA on a terminal, plain periodic lines otherwise.
#pragma once
#include <string>

namespace meso {

class Progress {
public:
    /// `total` in `unit`s (spp or seconds); disabled when `enabled` is false.
    Progress(bool enabled, double total, std::string unit);
    /// `done` of total, `elapsed` seconds, `extra` shown after the bar.
    void update(double done, double elapsed, const std::string &extra);
    void finish(double elapsed);

private:
    bool m_enabled, m_tty;
    double m_total, m_last_print = -1e9;
    std::string m_unit;
};

}  // namespace meso
