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

/// A decoded image may be at most this many times larger than its file once it is over
/// kFreeDecodedValues values. No image codec gets near: zlib (PNG, EXR ZIP) stops at 1032:1,
/// RLE at 64:1, PIZ's Huffman run codes at about 400:1. A small file declaring a huge size is
/// corrupt or truncated and is refused before the pixels are allocated (fuzz/, issue 24: a
/// 1349-byte EXR declaring 16777023 x 64 pixels made the reader allocate 4 GB).
inline constexpr uint64_t kMaxDecodeRatio = 4096;
inline constexpr uint64_t kFreeDecodedValues = uint64_t(1) << 24;

/// Physical memory of the machine in bytes (sysconf); 0 when unknown.
uint64_t physical_memory_bytes();

/// Empty when an image of `values` channel values, stored at `stored_bytes_per_value` in a
/// file of `file_bytes`, may be decoded into `decoded_bytes` of memory; otherwise why not
/// (over kMaxImageValues, a decode ratio no codec reaches, or more than the machine's memory).
std::string decoded_size_problem(uint64_t values, uint64_t stored_bytes_per_value, uint64_t file_bytes,
                                 uint64_t decoded_bytes);

/// Empty when `path` is a regular file of at most `max_bytes`; otherwise why not: "file not
/// found", "it is a directory", "it is a character device, not a regular file" or "it is
/// 5000000000 bytes, more than the 4 GiB limit for KINDs" (KIND: "scene file", "image", ...).
std::string input_file_problem(const std::string &path, uint64_t max_bytes, const char *kind);

/// Throws MesoError "PATH: cannot open the KIND (PROBLEM)" when input_file_problem finds one.
void check_input_file(const std::string &path, uint64_t max_bytes, const char *kind);

/// check_input_file, then the whole file.
std::string read_input_file(const std::string &path, uint64_t max_bytes, const char *kind);

}  // namespace meso
