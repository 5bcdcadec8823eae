// `meso material`: inspect one material outside a scene.
//
//   meso material eval   MATERIAL --wo THETA,PHI --wi THETA,PHI
//        {"value":[r,g,b],"pdf":p}            value = f(wo, wi) |cos θi|
//   meso material albedo MATERIAL --wo THETA,PHI [--samples N] [--seed S]
//        {"albedo":[r,g,b],"stderr":[r,g,b]}  mean sample weight and its standard error
//   meso material chi2   MATERIAL --wo THETA,PHI [--samples N] [--seed S] [--res R] ...
//        {"p_value":p,"passed":bool,...}       χ² test of sample() against pdf(); exit 1 if failed
//
// MATERIAL is an inline JSON object ({"type": "conductor", "material": "Au", "alpha": 0.2})
// or the path of a JSON file holding one material object. Angles are in degrees in the
// local shading frame (θ from the normal, φ from the tangent s).
#include <CLI/CLI.hpp>
#include <cstdio>
#include <filesystem>
#include <fmt/format.h>
#include <fstream>
#include <limits>
#include <nlohmann/json.hpp>
#include <sstream>
#include "app/commands.h"
#include "core/error.h"
#include "bsdf/material.h"
#include "bsdf/chi2.h"
#include "core/properties.h"
#include "core/registry.h"

namespace meso {
namespace {

using ojson = nlohmann::ordered_json;

/// "THETA,PHI" (or "THETA", φ = 0) in degrees -> local direction.
Vec3 parse_direction(const std::string &opt, const std::string &s) {
    std::string t = s;
    for (char &c : t)
        if (c == ',') c = ' ';
    std::istringstream in(t);
    double theta, phi = 0.0;
    std::string rest;
    if (!(in >> theta) || (!(in >> phi) && !in.eof()) || (in >> rest) || !std::isfinite(theta) || !std::isfinite(phi))
        throw MesoError(fmt::format("{}: expected THETA,PHI in degrees, got '{}'", opt, s));
    if (theta < 0.0 || theta > 180.0) throw MesoError(fmt::format("{}: THETA must be in [0, 180] degrees, got {}", opt, theta));
    double th = theta * 3.14159265358979323846 / 180.0, ph = phi * 3.14159265358979323846 / 180.0;
    // exact 90/180 degrees: keep z exactly 0 / -1 so that "grazing" really is grazing
    double z = theta == 90.0 ? 0.0 : (theta == 180.0 ? -1.0 : std::cos(th));
    double st = (theta == 180.0 || theta == 0.0) ? 0.0 : std::sin(th);
    return Vec3(float(st * std::cos(ph)), float(st * std::sin(ph)), float(z));
}

ojson rgb(const Spectrum &s) { return ojson::array({double(s.r), double(s.g), double(s.b)}); }

void print_json(const ojson &j) {
    std::string s = j.dump();
    std::fwrite(s.data(), 1, s.size(), stdout);
    std::fputc('\n', stdout);
    std::fflush(stdout);
}

struct Options {
    std::string material, wo = "0,0", wi = "0,0";
    // Signed, so that "-5" is an error rather than a huge unsigned count; 0: the default.
    int64_t samples = 0, seed = 0;
    int res = 16, tests = 1, sub = 16;
    double alpha = 0.01;
};

SubcommandRegistrar reg({"material", "Evaluate, integrate or χ²-test one material (eval | albedo | chi2)", [](CLI::App &app) {
    auto o = std::make_shared<Options>();
    app.require_subcommand(1);
    const char *mat_help = "material: inline JSON object or path of a JSON file with one material object";
    const char *dir_help = "direction THETA,PHI in degrees (local frame, theta from the normal)";

    CLI::App *eval = app.add_subcommand("eval", "print {\"value\":[r,g,b],\"pdf\":p}; value = f(wo,wi)|cos theta_i|");
    eval->add_option("MATERIAL", o->material, mat_help)->required();
    eval->add_option("--wo", o->wo, dir_help)->required();
    eval->add_option("--wi", o->wi, dir_help)->required();

    CLI::App *albedo = app.add_subcommand("albedo", "print {\"albedo\":[r,g,b],\"stderr\":[r,g,b]} from the material's sampler");
    albedo->add_option("MATERIAL", o->material, mat_help)->required();
    albedo->add_option("--wo", o->wo, dir_help)->required();
    const auto count = CLI::Range(int64_t(1), std::numeric_limits<int64_t>::max());
    const auto seed = CLI::Range(int64_t(0), std::numeric_limits<int64_t>::max());
    albedo->add_option("--samples", o->samples, "number of samples, > 0 (default 100000)")->check(count);
    albedo->add_option("--seed", o->seed, "random seed, >= 0 (default 0)")->check(seed);

    CLI::App *chi2 = app.add_subcommand("chi2", "chi^2 test of sample() against pdf(); prints {\"p_value\":p,\"passed\":bool,...}, exit 1 if it fails");
    chi2->add_option("MATERIAL", o->material, mat_help)->required();
    chi2->add_option("--wo", o->wo, dir_help)->required();
    chi2->add_option("--samples", o->samples, "number of samples, > 0 (default 1000000)")->check(count);
    chi2->add_option("--seed", o->seed, "random seed, >= 0 (default 0)")->check(seed);
    chi2->add_option("--res", o->res, "cos(theta) bins per hemisphere; phi gets twice as many (default 16)")->check(CLI::Range(2, 512));
    chi2->add_option("--sub", o->sub, "Simpson intervals per cell and axis for integrating the pdf (default 16)")->check(CLI::Range(2, 256));
    chi2->add_option("--alpha", o->alpha, "significance level of the family of tests (default 0.01)")->check(CLI::Range(1e-12, 0.5));
    chi2->add_option("--tests", o->tests, "number of tests in the family, for the Sidak correction (default 1)")->check(CLI::PositiveNumber);

    return std::function<int()>([o, eval, albedo, chi2]() -> int {
        nlohmann::json storage;
        auto mat = load_material_arg(o->material, storage);
        ShadingContext ctx;
        Vec3 wo = parse_direction("--wo", o->wo);
        if (eval->parsed()) {
            Vec3 wi = parse_direction("--wi", o->wi);
            Spectrum v = mat->eval(ctx, wo, wi);
            float p = mat->pdf(ctx, wo, wi);
            ojson j;
            j["value"] = rgb(v);
            j["pdf"] = double(p);
            print_json(j);
            return 0;
        }
        if (albedo->parsed()) {
            uint64_t n = o->samples ? uint64_t(o->samples) : 100000;
            AlbedoEstimate a = estimate_albedo(*mat, ctx, wo, n, uint64_t(o->seed));
            ojson j;
            j["albedo"] = rgb(a.mean);
            j["stderr"] = rgb(a.stderr_);
            print_json(j);
            return 0;
        }
        Chi2Options co;
        co.samples = o->samples ? uint64_t(o->samples) : 1000000;
        co.seed = uint64_t(o->seed);
        co.res = o->res;
        co.sub = o->sub;
        co.alpha = o->alpha;
        co.test_count = o->tests;
        co.name = "material";
        Chi2Result r = chi2_material_test(*mat, ctx, wo, co);
        ojson j;
        j["p_value"] = r.p_value;
        j["passed"] = r.passed;
        j["chi2_passed"] = r.chi2_passed;
        j["chi2"] = r.chi2;
        j["dof"] = r.dof;
        j["significance"] = r.significance;
        j["samples"] = r.samples;
        j["smooth"] = r.smooth;
        j["delta"] = r.delta;
        j["failed"] = r.failed;
        j["invalid"] = r.invalid;
        j["weight_mismatch"] = r.weight_mismatch;
        j["pdf_mismatch"] = r.pdf_mismatch;
        j["pdf_integral"] = r.pdf_integral;
        j["domain"] = r.sphere ? "sphere" : "hemisphere";
        if (!r.message.empty()) j["message"] = r.message;
        if (!r.dump_path.empty()) j["dump"] = r.dump_path;
        print_json(j);
        return r.passed ? 0 : 1;
    });
}});

}  // namespace
}  // namespace meso
