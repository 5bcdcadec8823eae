// The C interface between meso_core and the OpenImageIO module (libmeso_oiio.so, built from
// image/oiio_module.cpp). meso reads EXR (OpenEXR) and PNG (libpng) itself; every other format
// (Radiance .hdr, PFM, JPEG, TIFF, ...) is read through this module, which image/oiio_loader.cpp
// dlopen()s on first use. Linking OpenImageIO into meso itself cost every run 0.2 s and 130 MB
// at start-up (its 37 dependent libraries' static initialisers and relocations), so only a run
// that reads such a file pays for it. Plain C types only: the module and meso need not agree on
// anything but this header. Bump kMesoOiioAbiVersion on any change.
#pragma once
#include <stddef.h>

extern "C" {

enum { kMesoOiioAbiVersion = 1 };

/// What the file declares, before any pixel is read.
struct MesoOiioInfo {
    int width, height, depth, channels;
    int bytes_per_value;  ///< the stored sample size (1 for 8-bit, 2 for 16-bit or half, 4 for float)
    int sample_type;      ///< meso::SampleType's value
    int says_linear;      ///< 1 when the file says its colour space is linear
    int alpha_channel;    ///< -1 when none
};

struct MesoOiioFile;  ///< one open image (opaque)

struct MesoOiioApi {
    int abi_version;  ///< kMesoOiioAbiVersion
    /// Opens `path` and fills `info`; null on failure with a one-line reason in err[errlen].
    MesoOiioFile *(*open)(const char *path, MesoOiioInfo *info, char *err, size_t errlen);
    /// Name of channel c (valid until close).
    const char *(*channel_name)(MesoOiioFile *file, int c);
    /// The i-th string attribute of the header: 1 and its name and value (valid until close),
    /// or 0 past the last one.
    int (*string_attribute)(MesoOiioFile *file, int i, const char **name, const char **value);
    /// All pixels as float, width * height * channels values (top row first, interleaved);
    /// 0 on failure with a one-line reason in err[errlen].
    int (*read_float)(MesoOiioFile *file, float *out, char *err, size_t errlen);
    void (*close)(MesoOiioFile *file);
};

/// The module's one exported symbol.
const MesoOiioApi *meso_oiio_api(void);
typedef const MesoOiioApi *(*MesoOiioApiFn)(void);
}
