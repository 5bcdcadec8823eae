// Error reporting. Everything a user can get wrong raises MesoError with a message of the
// form "file: json.path: what was expected"; the command line prints it on one line and
// exits non-zero. Nothing is written after an error.
#pragma once
#include <stdexcept>
#include <string>

namespace meso {

class MesoError : public std::runtime_error {
public:
    explicit MesoError(const std::string &msg) : std::runtime_error(msg) {}
};

/// A command-line error (an option's value out of range, options that do not go together): the
/// command line prints it like any MesoError but exits with 2, as for CLI11's parse errors.
class UsageError : public MesoError {
public:
    explicit UsageError(const std::string &msg) : MesoError(msg) {}
};

/// Builds "file: path: message", leaving out empty parts.
std::string located_message(const std::string &file, const std::string &path, const std::string &msg);

[[noreturn]] void throw_located(const std::string &file, const std::string &path, const std::string &msg);

}  // namespace meso
