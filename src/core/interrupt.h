// SIGINT / SIGTERM handling for long commands (render, prefilter, genmap). In graceful mode the
// first signal only raises a flag that the work polls (`meso render` finishes its pass and writes
// what it has, exit 130); the next signal, or the first in immediate mode, deletes the registered
// temporaries and ends the process at once with exit code 130. Nothing is renamed into place by
// the handler, so the previous outputs stay untouched.
#pragma once
#include <string>

namespace meso {

enum class InterruptMode { Graceful, Immediate };

/// Exit code of an interrupted command (128 + SIGINT, as shells report it).
constexpr int kInterruptedExitCode = 130;

/// Installs the handler for SIGINT and SIGTERM and clears the flag.
void install_interrupt_handler(InterruptMode mode);

/// True once a first signal arrived in graceful mode (async-signal-safe flag).
bool interrupt_requested();

/// Files (or directories, removed if empty) the handler deletes before ending the process:
/// staged outputs not yet renamed into place. At most 64 at a time; more are not tracked.
void register_temporary(const std::string &path);
void unregister_temporary(const std::string &path);

}  // namespace meso
