// Checks on the files a run reads (scene JSON, glTF and its buffers, images, height maps,
// material files) before any byte is read: each must be a regular file (a device, FIFO or
// folder could block forever or be endless, e.g. /dev/zero) no larger than its kind's limit.
#pragma once
#include <cstdint>
#include <string>

namespace meso {

/// Size limits of input files (README.md, "Limits").
inline constexpr uint64_t kMaxSceneFileBytes = uint64_t(256) << 20;  ///< scene / material JSON: 256 MiB
inline constexpr uint64_t kMaxMeshFileBytes = uint64_t(4) << 30;     ///< .gltf, .glb and their buffers: 4 GiB
inline constexpr uint64_t kMaxImageFileBytes = uint64_t(4) << 30;    ///< images and maps: 4 GiB
/// Decoded images: at most 2^30 channel values (e.g. 16384 x 16384 RGBA, 32768 x 32768 grey).
inline constexpr uint64_t kMaxImageValues = uint64_t(1) << 30;

/// Empty when `path` is a regular file of at most `max_bytes`; otherwise why not: "file not
/// found", "it is a directory", "it is a character device, not a regular file" or "it is
/// 5000000000 bytes, more than the 4 GiB limit for KINDs" (KIND: "scene file", "image", ...).
std::string input_file_problem(const std::string &path, uint64_t max_bytes, const char *kind);

/// Throws MesoError "PATH: cannot open the KIND (PROBLEM)" when input_file_problem finds one.
void check_input_file(const std::string &path, uint64_t max_bytes, const char *kind);

/// check_input_file, then the whole file.
std::string read_input_file(const std::string &path, uint64_t max_bytes, const char *kind);

}  // namespace meso
