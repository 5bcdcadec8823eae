#include "filter/ramp_parse.h"
#include <cmath>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "image/image.h"
#include "core/properties.h"
#include "image/image_param.h"

namespace meso {

namespace {

Ramp parse_stops(const Properties &p, const std::string &key, const nlohmann::json &j, int channels) {
    if (!j.is_array() || j.empty())
        p.fail(key, fmt::format("expected a non-empty array of [x, value] stops, got {}", json_type_name(j)));
    std::vector<double> xs, vs;
    for (size_t i = 0; i < j.size(); ++i) {
        const auto &s = j[i];
        const std::string where = fmt::format("stop {}", i);
        if (!s.is_array() || s.size() != 2 || !s[0].is_number())
            p.fail(key, fmt::format("{}: expected [x, value] with a number x", where));
        const double x = s[0].get<double>();
        if (!std::isfinite(x)) p.fail(key, fmt::format("{}: x must be finite", where));
        if (!xs.empty() && !(x > xs.back()))
            p.fail(key, fmt::format("{}: x = {} must be greater than the previous stop's {}", where, x, xs.back()));
        xs.push_back(x);
        const auto &v = s[1];
        if (v.is_number()) {
            for (int c = 0; c < channels; ++c) vs.push_back(v.get<double>());
        } else if (v.is_array() && int(v.size()) == channels) {
            for (int c = 0; c < channels; ++c) {
                if (!v[c].is_number()) p.fail(key, fmt::format("{}: value {} is not a number", where, c));
                vs.push_back(v[c].get<double>());
            }
        } else {
            p.fail(key, fmt::format("{}: expected a number or an array of {} numbers as the value", where, channels));
        }
        for (int c = 0; c < channels; ++c)
            if (!std::isfinite(vs[vs.size() - channels + c])) p.fail(key, fmt::format("{}: values must be finite", where));
    }
    return Ramp(std::move(xs), std::move(vs), channels);
}

Ramp parse_image(const Properties &p, const std::string &key, int channels) {
    const Properties c = p.child(key);
    const std::string file = c.get_file("filename");
    const std::vector<float> range = c.get_floats("range");
    if (range.size() != 2 || !std::isfinite(range[0]) || !std::isfinite(range[1]) || !(range[1] > range[0]))
        c.fail("range", "expected [min, max] with min < max");
    const bool raw = c.get_bool("raw", false);
    c.check_unused("colour map image");
    const Image img = read_image_param(c, "filename", file, raw);
    const int row = img.height / 2;
    std::vector<double> xs, vs;
    for (int i = 0; i < img.width; ++i) {
        xs.push_back(range[0] + (i + 0.5) / img.width * (double(range[1]) - range[0]));
        const Spectrum s = img.rgb(i, row);
        if (channels == 1) vs.push_back(s.average());
        else for (int k = 0; k < channels; ++k) vs.push_back(s[k % 3]);
    }
    return Ramp(std::move(xs), std::move(vs), channels);
}

}  // namespace

Ramp parse_ramp(const Properties &p, const std::string &key, int channels) {
    const nlohmann::json &j = p.raw(key);
    if (j.is_object()) return parse_image(p, key, channels);
    return parse_stops(p, key, j, channels);
}

}  // namespace meso
