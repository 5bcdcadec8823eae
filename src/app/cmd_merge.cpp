// `meso merge OUT.exr PART.exr... [--exposure S]`
//
// Joins the windows of one image rendered by `meso render --crop` (docs/cluster.md, "Very large
// images"). Each PART.exr comes with its record PART.json, which places it (crop, full_width,
// full_height; a record without "crop" is the whole image). The parts must come from the same
// render (full size, scene, defines, seed, spp, integrator, sampler) and tile the full image
// exactly: no two overlap, every pixel is in one. The pixels are copied unchanged, so the merge
// is bit-identical to a full render with the same seed and spp.
//
// Each part's EXR metadata (meso:scene_sha1, defines, seed, spp, crop, full_size, written by meso
// render) must agree with its record and with the other parts: an EXR swapped in from another
// render is refused, naming the file and the field.
//
// Writes OUT.exr (with the merged provenance), OUT.png and OUT.json, staged and renamed together
// (core/output_set.h); none may replace a part or its record. The record holds the fields common to
// all parts, "width"/"height" of the full image, "parts" (file, crop, wall_s, rays of each),
// rays, shadow_rays, nan_count, load_s, build_s and wall_s summed over the parts, "wall_s_max"
// (the slowest part), peak_rss_mb as the largest, and rays_per_s = rays / wall_s. Fields that
// differ between parts (threads, passes, ...) and the per-part error against a reference are
// left out. Any error leaves no output file.
#include <CLI/CLI.hpp>
#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <memory>
#include <nlohmann/json.hpp>
#include <string>
#include <vector>
#include "app/commands.h"
#include "core/distributed.h"
#include "core/error.h"
#include "core/output_set.h"
#include "core/text_file.h"
#include "image/image.h"

namespace meso {
namespace {

namespace fs = std::filesystem;
using nlohmann::json;

struct MergeArgs {
    std::string output;
    std::vector<std::string> parts;
    float exposure = 0.f;
};

struct Part {
    std::string exr;
    json rec;
    ImageMetadata meta;  ///< the EXR's own provenance (meso:scene_sha1, seed, spp, crop, full_size)
    int full_w = 0, full_h = 0;
    std::array<int, 4> crop{};  ///< x0, y0, x1, y1
};

/// The keys on which all parts must agree (besides the full size).
constexpr const char *kSameRender[] = {"scene", "scene_sha1", "defines", "seed", "spp", "integrator", "sampler"};
/// Summed over the parts in the merged record.
constexpr const char *kSummed[] = {"wall_s", "rays", "shadow_rays", "nan_count", "load_s", "build_s"};
/// A part's error against its reference: meaningless for the whole image.
constexpr const char *kPerPart[] = {"reference", "mse", "relmse", "rmse", "psnr", "mean_luminance_ratio"};

std::string crop_str(const std::array<int, 4> &c) { return fmt::format("[{}, {}, {}, {}]", c[0], c[1], c[2], c[3]); }

int int_field(const json &j, const char *key, const std::string &json_path) {
    if (!j.is_number_integer()) throw MesoError(fmt::format("{}: \"{}\" must be an integer", json_path, key));
    return j.get<int>();
}

Part read_part(const std::string &exr) {
    Part p;
    p.exr = exr;
    fs::path js = fs::path(exr).replace_extension(".json");
    if (fs::path(exr).extension() != ".exr") throw MesoError(fmt::format("{}: a part must be an .exr written by meso render", exr));
    if (!fs::exists(exr)) throw MesoError(fmt::format("{}: no such part", exr));
    std::ifstream f(js);
    if (!f) throw MesoError(fmt::format("{}: missing record {} (written beside each part by meso render --crop)", exr, js.string()));
    try {
        p.rec = json::parse(f);
    } catch (const json::exception &e) {
        throw MesoError(fmt::format("{}: not a valid JSON record: {}", js.string(), e.what()));
    }
    if (!p.rec.is_object()) throw MesoError(fmt::format("{}: not a meso render record", js.string()));
    for (const char *k : {"width", "height"})
        if (!p.rec.contains(k)) throw MesoError(fmt::format("{}: missing \"{}\" (not a meso render record?)", js.string(), k));
    const std::string jp = js.string();
    if (p.rec.contains("crop")) {
        const json &c = p.rec["crop"];
        if (!c.is_array() || c.size() != 4) throw MesoError(fmt::format("{}: \"crop\" must be [x0, y0, x1, y1]", jp));
        for (int i = 0; i < 4; ++i) p.crop[i] = int_field(c[i], "crop", jp);
        if (!p.rec.contains("full_width") || !p.rec.contains("full_height"))
            throw MesoError(fmt::format("{}: a record with \"crop\" needs \"full_width\" and \"full_height\"", jp));
        p.full_w = int_field(p.rec["full_width"], "full_width", jp);
        p.full_h = int_field(p.rec["full_height"], "full_height", jp);
    } else {
        p.full_w = int_field(p.rec["width"], "width", jp);
        p.full_h = int_field(p.rec["height"], "height", jp);
        p.crop = {0, 0, p.full_w, p.full_h};
    }
    p.meta = read_image_metadata(exr);
    const auto &c = p.crop;
    if (!(0 <= c[0] && c[0] < c[2] && c[2] <= p.full_w && 0 <= c[1] && c[1] < c[3] && c[3] <= p.full_h))
        throw MesoError(fmt::format("{}: crop {} is not a window of the {}x{} image", jp, crop_str(c), p.full_w, p.full_h));
    return p;
}

std::string meta_value(const Part &p, const std::string &key) {
    for (const auto &[k, v] : p.meta)
        if (k == key) return v;
    throw MesoError(fmt::format("{}: the EXR has no meso:{} metadata (not written by meso render, or an image swapped "
                                "in from elsewhere)",
                                p.exr, key));
}

/// The EXR's own metadata must say what its record says: an image swapped in beside another
/// render's record is refused, naming the field.
void check_metadata(const Part &p) {
    const std::string js = fs::path(p.exr).replace_extension(".json").string();
    const std::pair<std::string, std::string> expected[] = {
        {"crop", fmt::format("{},{},{},{}", p.crop[0], p.crop[1], p.crop[2], p.crop[3])},
        {"full_size", fmt::format("{}x{}", p.full_w, p.full_h)},
        {"seed", p.rec.value("seed", json()).dump()},
        {"spp", p.rec.value("spp", json()).dump()},
        {"scene_sha1", p.rec.value("scene_sha1", std::string())},
        {"defines", p.rec.value("defines", json()).dump()}};
    for (const auto &[key, want] : expected) {
        const std::string got = meta_value(p, key);
        if (got != want)
            throw MesoError(fmt::format("{}: the EXR's metadata says {} = {} but its record {} says {} (an image "
                                        "swapped in from another render?)",
                                        p.exr, key, got, js, want));
    }
}

/// Each EXR's metadata against its record and against the first part's EXR.
void check_part_metadata(const Part &p, const Part &first) {
    check_metadata(p);
    for (const char *k : {"scene_sha1", "defines", "seed", "spp", "full_size"})
        if (meta_value(p, k) != meta_value(first, k))
            throw MesoError(fmt::format("{}: the EXR's metadata says {} = {} but {} has {} (the parts must come "
                                        "from one render)",
                                        p.exr, k, meta_value(p, k), first.exr, meta_value(first, k)));
}

/// Throws unless the parts come from the same render, do not overlap and cover the image.
void check_parts(const std::vector<Part> &parts) {
    const Part &a = parts[0];
    for (const Part &p : parts) {
        if (p.full_w != a.full_w || p.full_h != a.full_h)
            throw MesoError(fmt::format("{}: the full image is {}x{} but {} has {}x{} (the parts must come from one render)",
                                        p.exr, p.full_w, p.full_h, a.exr, a.full_w, a.full_h));
        for (const char *k : kSameRender) {
            json va = a.rec.value(k, json()), vp = p.rec.value(k, json());
            if (va != vp)
                throw MesoError(fmt::format("{}: \"{}\" is {} but {} has {} (the parts must come from one render)", p.exr, k,
                                            vp.dump(), a.exr, va.dump()));
        }
    }
    for (size_t i = 0; i < parts.size(); ++i)
        for (size_t j = i + 1; j < parts.size(); ++j) {
            const auto &c = parts[i].crop, &d = parts[j].crop;
            const int x0 = std::max(c[0], d[0]), y0 = std::max(c[1], d[1]);
            if (x0 < std::min(c[2], d[2]) && y0 < std::min(c[3], d[3]))
                throw MesoError(fmt::format("parts {} {} and {} {} overlap (both hold pixel ({}, {}))", parts[i].exr,
                                            crop_str(c), parts[j].exr, crop_str(d), x0, y0));
        }
    // Disjoint windows inside the image cover it exactly when their areas add up to it.
    long long area = 0;
    for (const Part &p : parts) area += (long long)(p.crop[2] - p.crop[0]) * (p.crop[3] - p.crop[1]);
    if (area == (long long)a.full_w * a.full_h) return;
    for (int y = 0; y < a.full_h; ++y) {  // the first pixel (row by row) in no part
        std::vector<std::pair<int, int>> spans;
        for (const Part &p : parts)
            if (p.crop[1] <= y && y < p.crop[3]) spans.emplace_back(p.crop[0], p.crop[2]);
        std::sort(spans.begin(), spans.end());
        int x = 0;
        for (auto [s0, s1] : spans) {
            if (s0 > x) break;
            x = s1;
        }
        if (x < a.full_w)
            throw MesoError(fmt::format("the parts do not cover the {}x{} image: pixel ({}, {}) is in none of them",
                                        a.full_w, a.full_h, x, y));
    }
}

/// The merged record: the parts' common fields, sums, the full size and the list of parts.
json merged_record(const std::vector<Part> &parts) {
    json rec = json::object();
    for (auto it = parts[0].rec.begin(); it != parts[0].rec.end(); ++it) {
        bool common = std::all_of(parts.begin(), parts.end(),
                                  [&](const Part &p) { return p.rec.contains(it.key()) && p.rec[it.key()] == it.value(); });
        if (common) rec[it.key()] = it.value();
    }
    for (const char *k : {"crop", "full_width", "full_height"}) rec.erase(k);
    for (const char *k : kPerPart) rec.erase(k);
    rec["width"] = parts[0].full_w;
    rec["height"] = parts[0].full_h;
    for (const char *k : kSummed) {
        if (!std::all_of(parts.begin(), parts.end(), [&](const Part &p) { return p.rec.contains(k); })) continue;
        bool integer = true, non_negative = true;
        double sum = 0;
        long long isum = 0;
        for (const Part &p : parts) {
            const json &v = p.rec[k];
            if (!v.is_number()) throw MesoError(fmt::format("{}: \"{}\" must be a number", p.exr, k));
            integer = integer && v.is_number_integer();
            non_negative = non_negative && v.is_number_unsigned();
            sum += v.get<double>();
            if (v.is_number_integer()) isum += v.get<long long>();
        }
        if (integer && non_negative) rec[k] = (unsigned long long)isum;  // as meso render writes counters
        else if (integer) rec[k] = isum;
        else rec[k] = sum;
    }
    double wall_max = 0, rss_max = 0;
    json list = json::array();
    for (const Part &p : parts) {
        wall_max = std::max(wall_max, p.rec.value("wall_s", 0.0));
        rss_max = std::max(rss_max, p.rec.value("peak_rss_mb", 0.0));
        list.push_back({{"file", p.exr}, {"crop", p.crop}, {"wall_s", p.rec.value("wall_s", json())},
                        {"rays", p.rec.value("rays", json())}});
    }
    rec["wall_s_max"] = wall_max;
    if (std::all_of(parts.begin(), parts.end(), [](const Part &p) { return p.rec.contains("peak_rss_mb"); }))
        rec["peak_rss_mb"] = rss_max;
    if (rec.contains("rays") && rec.contains("wall_s")) {
        double w = rec["wall_s"].get<double>();
        rec["rays_per_s"] = w > 0 ? rec["rays"].get<double>() / w : 0.0;
    }
    rec["parts"] = list;
    return rec;
}

int run_merge(const MergeArgs &a) {
    if (dist::rank() != 0) return 0;  // nothing to distribute: under mpirun only rank 0 merges
    // The outputs are checked before anything is read: none may replace a part or its record.
    if (!std::isfinite(a.exposure)) throw UsageError(fmt::format("--exposure {}: expected a finite number of stops", a.exposure));
    fs::path out = a.output;
    if (out.extension() != ".exr") throw MesoError(fmt::format("{}: the output must be an .exr file", a.output));
    fs::path png = out, js = out;
    png.replace_extension(".png");
    js.replace_extension(".json");
    OutputSet set;
    for (const std::string &p : a.parts) {
        set.add_input(p, "a part");
        set.add_input(fs::path(p).replace_extension(".json").string(), "a part's record");
    }
    const std::string exr_tmp = set.add_output("output", out.string()), png_tmp = set.add_output("output", png.string(), a.output);
    const std::string js_tmp = set.add_output("output", js.string(), a.output, OutputKind::Record);
    set.check();

    std::vector<Part> parts;
    for (const std::string &p : a.parts) parts.push_back(read_part(p));
    check_parts(parts);
    json rec = merged_record(parts);

    const int W = parts[0].full_w, H = parts[0].full_h;
    Image merged(W, H, 3);
    for (const Part &p : parts) {
        Image img = read_image(p.exr);
        const int w = p.crop[2] - p.crop[0], h = p.crop[3] - p.crop[1];
        if (img.width != w || img.height != h)
            throw MesoError(fmt::format("{}: the image is {}x{} but its record's crop {} is {}x{}", p.exr, img.width,
                                        img.height, crop_str(p.crop), w, h));
        if (img.channels != 3) throw MesoError(fmt::format("{}: expected an RGB image, found {} channels", p.exr, img.channels));
        check_part_metadata(p, parts[0]);
        for (int y = 0; y < h; ++y)
            std::copy_n(&img.at(0, y, 0), size_t(w) * 3, &merged.at(p.crop[0], p.crop[1] + y, 0));
    }

    // All or nothing: staged, then renamed together (a failure leaves the previous files).
    write_exr(exr_tmp, merged,
              {{"version", meta_value(parts[0], "version")}, {"scene_sha1", meta_value(parts[0], "scene_sha1")},
               {"defines", meta_value(parts[0], "defines")}, {"seed", meta_value(parts[0], "seed")},
               {"spp", meta_value(parts[0], "spp")}, {"crop", fmt::format("0,0,{},{}", W, H)},
               {"full_size", meta_value(parts[0], "full_size")}});
    write_png(png_tmp, merged, a.exposure);
    write_text_atomic(js_tmp, rec.dump(2) + "\n");
    set.commit();
    std::printf("wrote %s, %s, %s\n", out.string().c_str(), png.string().c_str(), js.string().c_str());
    std::printf("%dx%d from %zu parts, %s spp\n", W, H, parts.size(), rec.value("spp", json()).dump().c_str());
    return 0;
}

SubcommandRegistrar reg_merge{{"merge", "Join the windows of an image rendered with `meso render --crop` into one",
                               [](CLI::App &app) -> std::function<int()> {
                                   auto a = std::make_shared<MergeArgs>();
                                   app.add_option("output", a->output, "merged EXR (PNG and JSON are written beside it)")
                                       ->required();
                                   app.add_option("parts", a->parts,
                                                  "the parts' EXRs, each with its record PART.json beside it")
                                       ->required();
                                   app.add_option("--exposure", a->exposure, "exposure in stops for the PNG");
                                   return [a] { return run_merge(*a); };
                               }}};

}  // namespace
}  // namespace meso
