// libmeso_oiio.so: OpenImageIO behind image/oiio_abi.h's C interface. Not part of meso_core
// (CMakeLists.txt builds it as a MODULE library); meso dlopen()s it on the first image in a
// format it does not read itself. It uses meso headers only (no meso library symbols).
#include <OpenImageIO/imageio.h>
#include <algorithm>
#include <cstdio>
#include <memory>
#include <string>
#include <utility>
#include <vector>
#include "image/image.h"
#include "image/oiio_abi.h"

struct MesoOiioFile {
    std::unique_ptr<OIIO::ImageInput> in;
    std::vector<std::pair<std::string, std::string>> strings;  ///< string attributes of the header
};

namespace {

void set_error(char *err, size_t errlen, std::string s, const char *fallback) {
    while (!s.empty() && (s.back() == '\n' || s.back() == ' ' || s.back() == '\r')) s.pop_back();
    std::replace(s.begin(), s.end(), '\n', ';');  // OIIO may accumulate several lines
    if (errlen) std::snprintf(err, errlen, "%s", s.empty() ? fallback : s.c_str());
}

meso::SampleType sample_type(const OIIO::TypeDesc &t) {
    switch (t.basetype) {
    case OIIO::TypeDesc::UINT8: return meso::SampleType::UInt8;
    case OIIO::TypeDesc::UINT16: return meso::SampleType::UInt16;
    case OIIO::TypeDesc::HALF: return meso::SampleType::Half;
    case OIIO::TypeDesc::FLOAT: return meso::SampleType::Float;
    case OIIO::TypeDesc::UINT32: return meso::SampleType::UInt32;
    default: return meso::SampleType::Other;
    }
}

MesoOiioFile *open_file(const char *path, MesoOiioInfo *info, char *err, size_t errlen) {
    try {
        OIIO::ImageSpec config;
        config.attribute("oiio:UnassociatedAlpha", 1);  // colour as stored, never premultiplied
        auto in = OIIO::ImageInput::open(path, &config);
        if (!in) {
            set_error(err, errlen, OIIO::geterror(), "unknown format");
            return nullptr;
        }
        const OIIO::ImageSpec &spec = in->spec();
        info->width = spec.width, info->height = spec.height, info->depth = spec.depth;
        info->channels = spec.nchannels;
        info->bytes_per_value = int(spec.format.size());
        info->sample_type = int(sample_type(spec.format));
        const std::string cs = spec.get_string_attribute("oiio:ColorSpace");
        info->says_linear = cs == "Linear" || cs == "linear" || cs == "lin_srgb" || cs == "scene_linear";
        info->alpha_channel = spec.alpha_channel;
        auto f = std::make_unique<MesoOiioFile>();
        for (const OIIO::ParamValue &p : spec.extra_attribs)
            if (p.type() == OIIO::TypeDesc::STRING) f->strings.emplace_back(p.name().string(), p.get_string());
        f->in = std::move(in);
        return f.release();
    } catch (const std::exception &e) {
        set_error(err, errlen, e.what(), "OpenImageIO failed");
        return nullptr;
    }
}

const char *channel_name(MesoOiioFile *f, int c) {
    const auto &names = f->in->spec().channelnames;
    return c >= 0 && size_t(c) < names.size() ? names[size_t(c)].c_str() : "";
}

int string_attribute(MesoOiioFile *f, int i, const char **name, const char **value) {
    if (i < 0 || size_t(i) >= f->strings.size()) return 0;
    *name = f->strings[size_t(i)].first.c_str();
    *value = f->strings[size_t(i)].second.c_str();
    return 1;
}

int read_float(MesoOiioFile *f, float *out, char *err, size_t errlen) {
    try {
        const int C = f->in->spec().nchannels;
        if (!f->in->read_image(0, 0, 0, C, OIIO::TypeDesc::FLOAT, out) || f->in->has_error()) {
            set_error(err, errlen, f->in->geterror(), "read failed");
            return 0;
        }
        return 1;
    } catch (const std::exception &e) {
        set_error(err, errlen, e.what(), "read failed");
        return 0;
    }
}

void close_file(MesoOiioFile *f) { delete f; }

}  // namespace

extern "C" __attribute__((visibility("default"))) const MesoOiioApi *meso_oiio_api(void) {
    static const MesoOiioApi api = {kMesoOiioAbiVersion, open_file, channel_name, string_attribute, read_float, close_file};
    return &api;
}
