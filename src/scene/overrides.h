// `-D key=value` overrides of a scene file, applied to the parsed JSON before anything
// is built, so every parameter of every plugin can be changed from the command line.
//
//   key   = segment ('.' segment)*      segment = name ('[' index ']')*
//   value = any JSON text (number, true/false, null, [array], {object}, "string");
//           if it does not parse as JSON it is taken as a plain string.
//
// Missing object keys are created (as objects along the way); array indices must exist.
// Errors are MesoError "-D <key>: <what went wrong>".
#pragma once
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>

namespace meso {

/// Applies one "a.b[2].c=value" assignment to `root` (an object).
void apply_override(nlohmann::json &root, const std::string &assignment);

/// Applies them in order (later ones win).
void apply_overrides(nlohmann::json &root, const std::vector<std::string> &assignments);

}  // namespace meso
