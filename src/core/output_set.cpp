#include "core/output_set.h"
#include <unistd.h>
#include <filesystem>
#include <fstream>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"
#include "core/interrupt.h"

namespace meso {

namespace fs = std::filesystem;

namespace {

/// The same file: equal canonical paths, or (both existing) the same inode.
bool same_file(const std::string &a, const std::string &b) {
    std::error_code e1, e2;
    const fs::path ca = fs::weakly_canonical(fs::absolute(a), e1), cb = fs::weakly_canonical(fs::absolute(b), e2);
    if (!e1 && !e2 && ca == cb) return true;
    std::error_code ec;
    return fs::exists(a, ec) && fs::exists(b, ec) && fs::equivalent(a, b, ec) && !ec;
}

std::string dir_of(const std::string &path) {
    const fs::path d = fs::path(path).parent_path();
    return d.empty() ? std::string(".") : d.string();
}

}  // namespace

bool is_meso_record(const std::string &path) {
    std::error_code ec;
    if (!fs::is_regular_file(path, ec) || fs::file_size(path, ec) > (64u << 20)) return false;
    std::ifstream f(path);
    const nlohmann::json j = nlohmann::json::parse(f, nullptr, false);
    return j.is_object() && j.contains("meso_version");
}

OutputSet::~OutputSet() {
    std::error_code ec;
    for (const Output &o : outputs_) {
        fs::remove_all(o.staging, ec);
        unregister_temporary(o.staging);
    }
}

void OutputSet::add_input(const std::string &path, const std::string &what) {
    if (!path.empty()) inputs_.push_back({path, what});
}

std::string OutputSet::add_output(const std::string &option, const std::string &path, const std::string &given,
                                  OutputKind kind, const std::string &marker) {
    const fs::path p(path);
    const std::string staging =
        (fs::path(dir_of(path)) / fmt::format(".{}.meso-tmp-{}", p.filename().string(), long(::getpid()))).string();
    outputs_.push_back({option, given.empty() ? path : given, path, staging, marker, kind});
    register_temporary(staging);
    return staging;
}

const std::string &OutputSet::staged(const std::string &path) const {
    for (const Output &o : outputs_)
        if (o.path == path) return o.staging;
    throw MesoError(fmt::format("internal: '{}' is not a declared output", path));
}

void OutputSet::check_output(const Output &o) const {
    const std::string where = fmt::format("{} {}", o.option, o.given);
    auto fail = [&](const std::string &why) { throw MesoError(fmt::format("{}: {}", where, why)); };
    if (fs::path(o.path).filename().empty()) fail("expected a file name, not a directory");
    for (const Input &in : inputs_)
        if (same_file(o.path, in.path))
            fail(o.path == o.given || same_file(o.given, in.path)
                     ? fmt::format("would overwrite the input {} ({})", in.path, in.what)
                     : fmt::format("the output {} would overwrite the input {} ({})", o.path, in.path, in.what));
    std::error_code ec;
    const bool exists = fs::exists(o.path, ec), is_dir = fs::is_directory(o.path, ec);
    if (o.kind == OutputKind::Directory) {
        if (exists && !is_dir) fail(fmt::format("{} exists and is not a directory", o.path));
        if (is_dir && !fs::is_empty(o.path, ec) && (o.marker.empty() || !fs::exists(fs::path(o.path) / o.marker, ec)))
            fail(fmt::format("{} is a directory that is neither empty nor a previous output (it has no {}); "
                             "refusing to replace it",
                             o.path, o.marker));
    } else {
        if (is_dir) fail(fmt::format("{} is a directory", o.path));
        if (o.kind == OutputKind::Record && exists && !is_meso_record(o.path))
            fail(fmt::format("would overwrite {}, which is not a meso record (a scene or other data?); choose "
                             "another output name",
                             o.path));
    }
    const std::string dir = dir_of(o.path);
    // A model directory's missing parents are created (as `meso prefilter -o a/b/model` always did).
    if (o.kind == OutputKind::Directory && !fs::exists(dir, ec)) fs::create_directories(dir, ec);
    if (!fs::is_directory(dir, ec)) fail(fmt::format("directory '{}' does not exist", dir));
    if (::access(dir.c_str(), W_OK | X_OK) != 0) fail(fmt::format("directory '{}' is not writable", dir));
}

void OutputSet::check() const {
    for (size_t i = 0; i < outputs_.size(); ++i) {
        check_output(outputs_[i]);
        for (size_t j = 0; j < i; ++j)
            if (same_file(outputs_[i].path, outputs_[j].path))
                throw MesoError(fmt::format("{} {}: {} is also written by {} {}", outputs_[i].option, outputs_[i].given,
                                            outputs_[i].path, outputs_[j].option, outputs_[j].given));
    }
}

void OutputSet::commit() {
    for (const Output &o : outputs_) {
        std::error_code ec;
        if (!fs::exists(o.staging, ec)) continue;  // an optional output that was not written
        if (o.kind == OutputKind::Directory && fs::exists(o.path, ec)) {
            // A directory cannot be renamed over a non-empty one: move the old one aside first.
            const std::string old = o.staging + "-old";
            fs::rename(o.path, old, ec);
            if (!ec) fs::rename(o.staging, o.path, ec);
            if (ec) throw MesoError(fmt::format("{} {}: cannot replace {}: {}", o.option, o.given, o.path, ec.message()));
            fs::remove_all(old, ec);
        } else {
            fs::rename(o.staging, o.path, ec);
            if (ec) throw MesoError(fmt::format("{} {}: cannot write {}: {}", o.option, o.given, o.path, ec.message()));
        }
        unregister_temporary(o.staging);
    }
}

}  // namespace meso
