// SHA-1 of bytes and of files: the provenance hash of a scene (EXR metadata, run records), so
// that `meso merge` can tell parts of one render from an image swapped in from another.
#pragma once
#include <string>

namespace meso {

/// Lower-case hex SHA-1 (FIPS 180-4) of `bytes`.
std::string sha1_hex(const std::string &bytes);

/// SHA-1 of a file's contents; throws MesoError("PATH: cannot read ...") on failure.
std::string file_sha1(const std::string &path);

}  // namespace meso
