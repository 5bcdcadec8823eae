// Prefiltered LoD model: tables, lookups, directory I/O (see model.h for the layout).
#include "prefilter/model.h"
#include "core/text_file.h"
#include <tbb/parallel_for.h>
#include <algorithm>
#include <cmath>
#include <smmintrin.h>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include "core/error.h"
#include "core/float_trig.h"
#include "core/math.h"
#include "core/properties.h"
#include "sampling/warp.h"

namespace fs = std::filesystem;

namespace meso::prefilter {

Vec2 concentric_disk_to_square(Vec2 d) {
    const double x = d.x, y = d.y;
    const double r = std::sqrt(x * x + y * y);
    if (!(r > 0)) return Vec2(0.5f, 0.5f);
    // Inverse of the forward map: |ox| > |oy| sector: r = ox, θ = π/4 oy/ox; else r = oy,
    // θ = π/2 - π/4 ox/oy (with the sign of r carrying the half plane).
    double phi = std::atan2(y, x);  // (-π, π]
    if (phi < -Pi / 4) phi += 2 * Pi;  // [-π/4, 7π/4)
    double ox, oy;
    if (phi < Pi / 4) {  // right sector: ox = r
        ox = r;
        oy = r * phi / (Pi / 4);
    } else if (phi < 3 * Pi / 4) {  // top: oy = r, θ = π/2 - π/4 ox/oy
        oy = r;
        ox = r * (Pi / 2 - phi) / (Pi / 4);
    } else if (phi < 5 * Pi / 4) {  // left: ox = -r, θ = π + π/4 oy/ox... forward gives θ = π/4 oy/ox with r < 0
        ox = -r;
        oy = -r * (phi - Pi) / (Pi / 4);
    } else {  // bottom: oy = -r
        oy = -r;
        ox = -r * (3 * Pi / 2 - phi) / (Pi / 4);
    }
    auto c = [](double v) { return float(std::clamp(0.5 * (v + 1.0), 0.0, 1.0)); };
    return Vec2(c(ox), c(oy));
}

Vec2 hemisphere_to_square(Vec3 w) {
    const double l = std::sqrt(double(w.x) * w.x + double(w.y) * w.y + double(w.z) * w.z);
    if (!(l > 0) || !std::isfinite(l)) return Vec2(0.5f, 0.5f);
    const double x = w.x / l, y = w.y / l, z = std::abs(double(w.z) / l);
    const double s = std::sqrt(x * x + y * y);
    if (!(s > 0)) return Vec2(0.5f, 0.5f);
    const double rho = std::atan2(s, z) / (Pi / 2);  // θ / 90°: equidistant in the polar angle
    return concentric_disk_to_square(Vec2(float(rho * x / s), float(rho * y / s)));
}

Vec3 square_to_hemisphere(Vec2 u) {
    // The disk point d at radius rho = max(|2u - 1|) (the concentric map's radius) goes to
    // theta = rho pi / 2 along d / |d|. cos theta = sin x and sin theta = cos x with
    // x = (1 - rho) pi / 2: the polynomial sine keeps its relative accuracy at grazing angles
    // (x -> 0), so z > 0 inside the square (the prefilter makes 225 of these a line).
    const float rho = std::min(1.f, std::max(std::abs(2.f * u.x - 1.f), std::abs(2.f * u.y - 1.f)));
    if (!(rho > 0.f)) return Vec3(0.f, 0.f, 1.f);
    const Vec2 d = square_to_uniform_disk_concentric(u);
    const float len2 = d.x * d.x + d.y * d.y;
    if (!(len2 > 0.f)) return Vec3(0.f, 0.f, 1.f);
    float z, st;
    sincos_half_pi((1.f - rho) * PiOver2, z, st);
    const float k = st / std::sqrt(len2);
    // On the square's border (rho = 1) z is cos(pi / 2) as the map in double gives it, not 0: a
    // direction of the grid stays above the horizon.
    return Vec3(k * d.x, k * d.y, std::max(z, 6.123234e-17f));
}

void square_to_hemisphere_grid(int N, float sa, float sb, Vec3 *out) {
    // square_to_hemisphere and square_to_uniform_disk_concentric in four SSE lanes, every
    // operation in the scalar code's order and the same polynomials (sincos_quarter and
    // sincos_half_pi on __m128): no FMA below x86-64-v3, so each lane rounds as the scalar map
    // does (tested bit for bit).
    const int B = N * N;
    const float fN = float(N);
    const __m128 one = _mm_set1_ps(1.f), two = _mm_set1_ps(2.f), zero = _mm_setzero_ps();
    const __m128 abs_mask = _mm_castsi128_ps(_mm_set1_epi32(0x7fffffff));
    auto mul = [](__m128 a, __m128 b) { return _mm_mul_ps(a, b); };
    auto add = [](__m128 a, __m128 b) { return _mm_add_ps(a, b); };
    auto c = [](float v) { return _mm_set1_ps(v); };
    int b = 0;
    for (; b + 4 <= B; b += 4) {
        alignas(16) float ux[4], uy[4];
        for (int l = 0; l < 4; ++l)
            ux[l] = (float((b + l) % N) + sa) / fN, uy[l] = (float((b + l) / N) + sb) / fN;
        const __m128 ox = _mm_sub_ps(mul(two, _mm_load_ps(ux)), one), oy = _mm_sub_ps(mul(two, _mm_load_ps(uy)), one);
        const __m128 ax = _mm_and_ps(ox, abs_mask), ay = _mm_and_ps(oy, abs_mask);
        const __m128 rho = _mm_min_ps(one, _mm_max_ps(ay, ax));  // std::min(1, std::max(|ox|, |oy|))
        // The concentric disk point d.
        const __m128 x_major = _mm_cmpgt_ps(ax, ay);
        const __m128 r = _mm_blendv_ps(oy, ox, x_major), other = _mm_blendv_ps(ox, oy, x_major);
        const __m128 q = _mm_and_ps(_mm_div_ps(other, r), _mm_cmpneq_ps(r, zero));
        __m128 sq, cq;
        sincos_quarter(mul(c(PiOver4), q), sq, cq);
        const __m128 pa = mul(r, cq), pb = mul(r, sq);
        const __m128 dx = _mm_blendv_ps(pb, pa, x_major), dy = _mm_blendv_ps(pa, pb, x_major);
        const __m128 len2 = add(mul(dx, dx), mul(dy, dy));
        // θ = ρ π / 2: cos θ = sin t, sin θ = cos t with t = (1 - ρ) π / 2 (sincos_half_pi).
        __m128 cz, st;
        sincos_half_pi(mul(_mm_sub_ps(one, rho), c(PiOver2)), cz, st);
        const __m128 k = _mm_div_ps(st, _mm_sqrt_ps(len2));
        // The centre (ρ = 0, or a zero disk point): straight up.
        const __m128 up = _mm_and_ps(_mm_cmpgt_ps(rho, zero), _mm_cmpgt_ps(len2, zero));
        alignas(16) float wx[4], wy[4], wz[4];
        _mm_store_ps(wx, _mm_and_ps(mul(k, dx), up));
        _mm_store_ps(wy, _mm_and_ps(mul(k, dy), up));
        _mm_store_ps(wz, _mm_blendv_ps(one, _mm_max_ps(cz, c(6.123234e-17f)), up));
        for (int l = 0; l < 4; ++l) out[b + l] = Vec3(wx[l], wy[l], wz[l]);
    }
    for (; b < B; ++b) out[b] = square_to_hemisphere(Vec2((float(b % N) + sa) / fN, (float(b / N) + sb) / fN));
}

Spectrum ScalingTables::S_bin(int bi, int bo) const {
    const int ix = bi % N, iy = bi / N, ox = bo % N, oy = bo / N;
    return S.rgb(ox * N + ix, oy * N + iy);
}

void ScalingTables::set_S_bin(int bi, int bo, Spectrum s) {
    const int ix = bi % N, iy = bi / N, ox = bo % N, oy = bo / N;
    S.set_rgb(ox * N + ix, oy * N + iy, s);
}

Image lobes_to_image(const std::vector<PatchNdf> &ndf, int width, int height, int lobes) {
    if (ndf.size() != size_t(width) * size_t(height))
        throw MesoError(fmt::format("lobes image: {} patches for a {}x{} grid", ndf.size(), width, height));
    Image img(width, height, 5 * lobes + 1);
    for (int j = 0; j < height; ++j)
        for (int i = 0; i < width; ++i) {
            const PatchNdf &p = ndf[size_t(j) * width + i];
            for (int k = 0; k < lobes; ++k) {
                float *c = &img.at(i, j, 5 * k);
                if (size_t(k) < p.lobes.size()) {
                    const VmfLobe &l = p.lobes[size_t(k)];
                    c[0] = l.mu.x, c[1] = l.mu.y, c[2] = l.mu.z, c[3] = l.kappa, c[4] = l.weight;
                } else {
                    c[0] = 0, c[1] = 0, c[2] = 1, c[3] = 0, c[4] = 0;  // an empty lobe
                }
            }
            img.at(i, j, 5 * lobes) = float(p.amplitude);
        }
    return img;
}

std::vector<PatchNdf> lobes_from_image(const Image &img, int lobes, const std::string &where) {
    if (lobes < 1 || img.channels != 5 * lobes + 1)
        throw MesoError(fmt::format("{}: expected {} channels (5 per lobe for {} lobes + amplitude), got {}", where,
                                    5 * lobes + 1, lobes, img.channels));
    std::vector<PatchNdf> out(size_t(img.width) * img.height);
    for (int j = 0; j < img.height; ++j)
        for (int i = 0; i < img.width; ++i) {
            PatchNdf &p = out[size_t(j) * img.width + i];
            for (int k = 0; k < lobes; ++k) {
                const float *c = &img.data[(size_t(j) * img.width + i) * img.channels + 5 * k];
                for (int q = 0; q < 5; ++q)
                    if (!std::isfinite(c[q]))
                        throw MesoError(fmt::format("{}: pixel ({}, {}) lobe {}: non-finite value", where, i, j, k));
                if (!(c[4] > 0.f)) continue;  // empty lobe
                VmfLobe l;
                l.mu = Vec3(c[0], c[1], c[2]);
                l.kappa = c[3];
                l.weight = c[4];
                if (!(length(l.mu) > 0.f) || l.kappa < 0.f)
                    throw MesoError(fmt::format("{}: pixel ({}, {}) lobe {}: zero direction or negative kappa", where,
                                                i, j, k));
                l.mu = normalize(l.mu);
                p.lobes.push_back(l);
            }
            p.amplitude = img.at(i, j, 5 * lobes);
            if (p.lobes.empty() || !(p.amplitude > 0.0) || !std::isfinite(p.amplitude))
                throw MesoError(fmt::format("{}: pixel ({}, {}): no lobe or amplitude {} (expected > 0)", where, i, j,
                                            p.amplitude));
        }
    return out;
}

std::string resolve_model_dir(const Properties &p, const std::string &key) {
    fs::path dir(p.get_string(key));
    if (dir.is_relative() && !p.context().base_dir.empty()) dir = fs::path(p.context().base_dir) / dir;
    std::error_code ec;
    if (!fs::is_directory(dir, ec))
        p.fail(key, fmt::format("model directory not found: '{}' (make one with `meso prefilter`)", dir.string()));
    const fs::path canon = fs::weakly_canonical(dir, ec);
    return ec ? dir.string() : canon.string();
}

namespace {

const nlohmann::json &need(const nlohmann::json &j, const char *key, const std::string &where) {
    auto it = j.find(key);
    if (it == j.end()) throw MesoError(fmt::format("{}: missing key '{}'", where, key));
    return *it;
}

Image read_checked(const fs::path &p, int w, int h, int c, const std::string &what) {
    if (!fs::exists(p)) throw MesoError(fmt::format("{}: {} is missing", p.string(), what));
    Image img = read_image(p.string());
    if (img.width != w || img.height != h || img.channels < c)
        throw MesoError(fmt::format("{}: {} must be {}x{} with {} channels, got {}x{} with {}", p.string(), what, w,
                                    h, c, img.width, img.height, img.channels));
    if (img.channels != c) {  // keep the first c channels
        Image o(w, h, c);
        for (int y = 0; y < h; ++y)
            for (int x = 0; x < w; ++x)
                for (int k = 0; k < c; ++k) o.at(x, y, k) = img.at(x, y, k);
        img = std::move(o);
    }
    for (float v : img.data)
        if (!std::isfinite(v) || v < 0.f) throw MesoError(fmt::format("{}: {} holds a negative or non-finite value", p.string(), what));
    return img;
}

/// parameters.`key`, one of two values: `now` (what meso prefilter writes) or `before` (the
/// default: models made before the key existed keep shading the way their tables were fitted).
/// True for `before`; anything else is an error naming the key and both values.
bool fitted_before(const nlohmann::json &par, const char *key, const char *now, const char *before,
                   const std::string &where) {
    const std::string v = par.value(key, std::string(before));
    if (v != now && v != before)
        throw MesoError(fmt::format("{}: parameters.{}: expected \"{}\" or \"{}\", got \"{}\"", where, key, now, before, v));
    return v == before;
}

}  // namespace

PrefilteredModel PrefilteredModel::load(const std::string &dir) {
    PrefilteredModel m;
    m.dir = dir;
    const fs::path mf = fs::path(dir) / "manifest.json";
    std::ifstream in(mf);
    if (!in) throw MesoError(fmt::format("{}: cannot open the model's manifest (is '{}' a `meso prefilter` output?)", mf.string(), dir));
    try {
        in >> m.manifest;
    } catch (const std::exception &e) {
        throw MesoError(fmt::format("{}: invalid JSON: {}", mf.string(), e.what()));
    }
    const std::string where = mf.string();
    const auto &j = m.manifest;
    if (need(j, "format", where) != "meso-prefiltered-model")
        throw MesoError(fmt::format("{}: 'format' must be \"meso-prefiltered-model\"", where));
    const auto &in_j = need(j, "input", where);
    m.map_width = need(in_j, "map_width", where + " input").get<int>();
    m.map_height = need(in_j, "map_height", where + " input").get<int>();
    m.height_scale = need(in_j, "height_scale", where + " input").get<double>();
    m.tile_size = need(in_j, "tile_size", where + " input").get<double>();
    m.base = need(in_j, "base", where + " input");
    if (in_j.contains("map_samples")) {
        const auto &ms = in_j["map_samples"];
        if (!ms.is_array() || ms.size() != size_t(kMapFingerprintSize))
            throw MesoError(fmt::format("{}: input.map_samples: expected {} numbers", where, kMapFingerprintSize));
        for (const auto &x : ms) {
            if (!x.is_number()) throw MesoError(fmt::format("{}: input.map_samples: expected numbers", where));
            m.map_samples.push_back(x.get<double>());
        }
    }
    const std::string wrap = in_j.value("wrap", std::string("repeat"));
    if (wrap != "repeat" && wrap != "clamp" && wrap != "mirror")
        throw MesoError(fmt::format("{}: input.wrap: expected \"repeat\", \"clamp\" or \"mirror\", got \"{}\"", where, wrap));
    m.wrap = wrap == "clamp" ? WrapMode::Clamp : wrap == "mirror" ? WrapMode::Mirror : WrapMode::Repeat;
    const auto &par = need(j, "parameters", where);
    m.lobes = need(par, "lobes", where + " parameters").get<int>();
    m.quadrature.polar = par.value("quadrature_polar", 4);
    m.quadrature.azimuth = par.value("quadrature_azimuth", 6);
    m.quadrature.projected_area = par.value("flow_projected_area", false);
    // parameters.flow (absent in models made before --flow lobes: eq5 or visible as above).
    const std::string flow = par.value("flow", flow_name(m.quadrature));
    if (flow != "eq5" && flow != "visible" && flow != "lobes")
        throw MesoError(fmt::format("{}: parameters.flow: expected \"eq5\", \"visible\" or \"lobes\", got \"{}\"",
                                    where, flow));
    m.quadrature.lobes = flow == "lobes";
    m.quadrature.projected_area = flow == "visible";
    // Form choices recorded by later versions (fitted_before: absent in older models).
    // albedo: the lobes form's diffuse base reflectance averaged over the patch (before: at the point).
    m.quadrature.point_albedo = fitted_before(par, "albedo", "patch_mean", "point", where);
    // lambert_view: the visible form of the Lambertian lobes' view weight.
    m.quadrature.cap_mass_lambert = fitted_before(par, "lambert_view", "visible", "cap_mass", where);
    // microfacet_view: microfacet lobes weighted by their visible share (before: by area).
    m.quadrature.area_microfacet = fitted_before(par, "microfacet_view", "visible", "area", where);
    // quadrature_weights: eq5 / visible nodes weighted by their share of the facing nodes' weight.
    m.quadrature.absolute_weights = fitted_before(par, "quadrature_weights", "share", "absolute", where);
    if (m.map_width < 1 || m.map_height < 1 || !(m.tile_size > 0) || m.lobes < 1 || m.lobes > 64)
        throw MesoError(fmt::format("{}: invalid map size, tile_size or lobes", where));
    for (const auto &lj : need(j, "levels", where)) {
        PrefilteredLevel L;
        L.factor = need(lj, "factor", where + " levels[]").get<int>();
        const std::string lw = fmt::format("{} level x{}", where, L.factor);
        if (L.factor < 1 || m.map_width % L.factor || m.map_height % L.factor)
            throw MesoError(fmt::format("{}: factor must divide the map size {}x{}", lw, m.map_width, m.map_height));
        const int w = m.map_width / L.factor, h = m.map_height / L.factor;
        const fs::path ldir = fs::path(dir) / need(lj, "dir", lw).get<std::string>();
        L.h_low = read_height_map((ldir / "h_low.exr").string());
        if (L.h_low.width != w || L.h_low.height != h)
            throw MesoError(fmt::format("{}: h_low.exr must be {}x{}", (ldir / "h_low.exr").string(), w, h));
        Image lobes = read_image((ldir / "lobes.exr").string());
        if (lobes.width != w || lobes.height != h)
            throw MesoError(fmt::format("{}: lobes.exr must be {}x{}", (ldir / "lobes.exr").string(), w, h));
        L.ndf = lobes_from_image(lobes, m.lobes, (ldir / "lobes.exr").string());
        const int M = need(par, "M", where).get<int>(), N = need(par, "N", where).get<int>();
        auto load_tables = [&](const char *t, const char *s, ScalingTables &tab) {
            tab.M = M, tab.N = N;
            tab.T = read_checked(ldir / t, M, M, 3, "T");
            tab.S = read_checked(ldir / s, N * N, N * N, 3, "S");
        };
        load_tables("T.exr", "S.exr", L.single);
        if (lj.value("interreflections", false)) load_tables("T_ir.exr", "S_ir.exr", L.ir);
        L.stats = lj;
        m.levels.push_back(std::move(L));
    }
    if (m.levels.empty()) throw MesoError(fmt::format("{}: 'levels' is empty", where));
    return m;
}

void PrefilteredModel::save(const std::string &out) const {
    fs::create_directories(out);
    nlohmann::json j = manifest;
    j["format"] = "meso-prefiltered-model";
    nlohmann::json levels_j = nlohmann::json::array();
    for (const PrefilteredLevel &L : levels) {
        const std::string sub = fmt::format("level_{}", L.factor);
        const fs::path ldir = fs::path(out) / sub;
        fs::create_directories(ldir);
        write_height_map((ldir / "h_low.exr").string(), L.h_low);
        write_exr((ldir / "lobes.exr").string(), lobes_to_image(L.ndf, L.width(), L.height(), lobes));
        write_exr((ldir / "T.exr").string(), L.single.T);
        write_exr((ldir / "S.exr").string(), L.single.S);
        if (!L.ir.empty()) {
            write_exr((ldir / "T_ir.exr").string(), L.ir.T);
            write_exr((ldir / "S_ir.exr").string(), L.ir.S);
        }
        nlohmann::json lj = L.stats.is_object() ? L.stats : nlohmann::json::object();
        lj["factor"] = L.factor;
        lj["dir"] = sub;
        lj["size"] = {L.width(), L.height()};
        lj["interreflections"] = !L.ir.empty();
        levels_j.push_back(lj);
    }
    j["levels"] = levels_j;
    // The manifest last, atomically: a directory without it is not a model.
    write_text_atomic((fs::path(out) / "manifest.json").string(), j.dump(2) + "\n");
}

std::shared_ptr<Material> create_model_base(const PrefilteredModel &model, const std::string &dir) {
    if (!model.base.is_object())
        throw MesoError(fmt::format("{}: input.base: expected a material object, got {}",
                                    (fs::path(dir) / "manifest.json").string(), json_type_name(model.base)));
    auto ctx = std::make_shared<LoadContext>();
    ctx->file = (fs::path(dir) / "manifest.json").string();
    ctx->base_dir = dir;
    const auto &in = model.manifest.find("input");
    if (in != model.manifest.end() && in->is_object()) {
        const auto bd = in->find("base_dir");
        std::error_code ec;
        if (bd != in->end() && bd->is_string() && fs::is_directory(bd->get<std::string>(), ec))
            ctx->base_dir = bd->get<std::string>();
    }
    return create_material(Properties(model.base, "input.base", ctx));
}

std::vector<std::pair<int, int>> map_fingerprint_vertices(int w, int h) {
    // R2 sequence (Roberts 2018, the plastic constant): well spread for any w x h.
    const double g = 1.32471795724474602596, a1 = 1.0 / g, a2 = 1.0 / (g * g);
    std::vector<std::pair<int, int>> v;
    for (int k = 0; k < kMapFingerprintSize; ++k) {
        const double x = std::fmod(0.5 + a1 * (k + 1), 1.0), y = std::fmod(0.5 + a2 * (k + 1), 1.0);
        v.push_back({std::min(w - 1, int(x * w)), std::min(h - 1, int(y * h))});
    }
    return v;
}

const PrefilteredLevel *PrefilteredModel::level_for_factor(int factor) const {
    for (const auto &L : levels)
        if (L.factor == factor) return &L;
    return nullptr;
}

std::string PrefilteredModel::factor_list() const {
    std::string have;
    for (const PrefilteredLevel &L : levels) have += (have.empty() ? "" : ", ") + std::to_string(L.factor);
    return have;
}

// ---------------------------------------------------------------------------------------

std::string flow_name(const QuadratureOptions &q) { return q.lobes ? "lobes" : q.projected_area ? "visible" : "eq5"; }

SvMultiLobe::SvMultiLobe(std::shared_ptr<const Material> base, const std::vector<PatchNdf> &ndf, int width,
                         int height, const QuadratureOptions &q, const nlohmann::json &base_json,
                         const std::string &base_where)
    : m_base(std::move(base)), m_w(width), m_h(height) {
    if (width < 1 || height < 1 || ndf.size() != size_t(width) * size_t(height))
        throw MesoError(fmt::format("multi-lobe SVBRDF: {} patch NDFs for a {}x{} grid", ndf.size(), width, height));
    if (q.lobes) {
        m_lobe_form = std::make_unique<SvLobeBrdf>(make_lobe_base(m_base, base_json, base_where), ndf, width, height,
                                                   !q.point_albedo, !q.cap_mass_lambert, !q.area_microfacet);
        return;
    }
    m_patches.resize(ndf.size());
    tbb::parallel_for(size_t(0), ndf.size(), [&](size_t k) {
        m_patches[k] = std::make_unique<MultiLobeBrdf>(m_base, ndf[k], q);
    });
}

const MultiLobeBrdf &SvMultiLobe::patch(Vec2 uv) const {
    const double u = double(uv.x) - std::floor(double(uv.x)), v = double(uv.y) - std::floor(double(uv.y));
    const int i = std::clamp(int(u * m_w), 0, m_w - 1), j = std::clamp(int(v * m_h), 0, m_h - 1);
    return *m_patches[size_t(j) * m_w + i];
}

Spectrum SvMultiLobe::eval(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    return m_lobe_form ? m_lobe_form->eval(ctx, wo, wi) : patch(ctx.uv).eval(ctx, wo, wi);
}
float SvMultiLobe::pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi) const {
    return m_lobe_form ? m_lobe_form->pdf(ctx, wo, wi) : patch(ctx.uv).pdf(ctx, wo, wi);
}
Spectrum SvMultiLobe::eval_pdf(const ShadingContext &ctx, const Vec3 &wo, const Vec3 &wi, float *pdf) const {
    return m_lobe_form ? m_lobe_form->eval_pdf(ctx, wo, wi, pdf) : patch(ctx.uv).eval_pdf(ctx, wo, wi, pdf);
}
bool SvMultiLobe::sample(const ShadingContext &ctx, const Vec3 &wo, float u_lobe, Vec2 u, BSDFSample &out) const {
    return m_lobe_form ? m_lobe_form->sample(ctx, wo, u_lobe, u, out) : patch(ctx.uv).sample(ctx, wo, u_lobe, u, out);
}
uint32_t SvMultiLobe::flags() const { return m_lobe_form ? m_lobe_form->flags() : m_patches.front()->flags(); }
Spectrum SvMultiLobe::albedo_hint(const ShadingContext &ctx) const {
    return m_lobe_form ? m_lobe_form->albedo_hint(ctx) : patch(ctx.uv).albedo_hint(ctx);
}
std::string SvMultiLobe::to_string() const {
    return fmt::format("SvMultiLobe[{}x{} patches, flow {}, base {}]", m_w, m_h,
                       m_lobe_form ? "lobes" : "quadrature", m_base->to_string());
}
size_t SvMultiLobe::memory_bytes() const {
    if (m_lobe_form) return m_lobe_form->memory_bytes();
    size_t b = 0;
    for (const auto &p : m_patches) b += sizeof(MultiLobeBrdf) + p->node_bytes();
    return b;
}

}  // namespace meso::prefilter
