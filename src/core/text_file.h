// Writing small text files (JSON records, manifests) so that an error or an interrupted run
// never leaves a partial file: a temporary file beside the target, renamed into place.
#pragma once
#include <string>

namespace meso {

/// Writes `text` to `path` atomically (PATH.tmp, then rename). Throws MesoError("cannot write
/// 'PATH'") on failure and leaves neither file behind.
void write_text_atomic(const std::string &path, const std::string &text);

}  // namespace meso
