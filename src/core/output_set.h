// The files of one command run: its inputs and its outputs, checked before any work and written
// all or nothing (README.md, "Outputs"). Every command that writes files uses it:
//
//   OutputSet out;
//   out.add_input(scene, "the scene file");
//   const std::string exr = out.add_output("-o", "out.exr");        // returns the staging path
//   const std::string rec = out.add_output("-o", "out.json", "out.exr", OutputKind::Record);
//   out.check();             // before any work: throws MesoError naming the option
//   ... write every output to its staging path ...
//   out.commit();            // renames them all into place
//
// check() refuses an output that resolves to an input (same canonical path or the same file),
// two outputs with one path, an output that is an existing directory (or, for a directory
// output, an existing file or a directory that is not a previous output), and an output whose
// directory is missing or not writable. Staging paths are hidden temporaries in the output's
// own directory (".NAME.meso-tmp-PID"), so the renames are atomic; until commit() the previous
// outputs are untouched, and the destructor deletes whatever was staged but not committed.
#pragma once
#include <string>
#include <vector>

namespace meso {

enum class OutputKind {
    File,       ///< any file
    Record,     ///< a JSON run record: an existing file there must be a meso record ("meso_version")
    Directory,  ///< a directory written whole (e.g. a prefiltered model); see add_output
};

class OutputSet {
public:
    OutputSet() = default;
    OutputSet(const OutputSet &) = delete;
    OutputSet &operator=(const OutputSet &) = delete;
    ~OutputSet();

    /// An input of the run; `what` names it in errors ("the scene file", "the reference").
    /// Empty paths are ignored.
    void add_input(const std::string &path, const std::string &what);
    /// An output `path` given (or implied) by `option` with the value `given` (default: path);
    /// returns the staging path to write it to. A Directory output may replace an existing
    /// directory only if it is empty or holds `marker` (a previous output of the same kind).
    std::string add_output(const std::string &option, const std::string &path, const std::string &given = "",
                           OutputKind kind = OutputKind::File, const std::string &marker = "");
    /// Throws MesoError "OPTION GIVEN: ..." for the first output that cannot be written safely.
    void check() const;
    /// Renames every staged output that was written into place (directories replace the old one).
    void commit();
    /// The staging path of `path` (as returned by add_output).
    const std::string &staged(const std::string &path) const;

private:
    struct Input {
        std::string path, what;
    };
    struct Output {
        std::string option, given, path, staging, marker;
        OutputKind kind;
    };
    void check_output(const Output &o) const;
    std::vector<Input> inputs_;
    std::vector<Output> outputs_;
};

/// True if `path` holds a JSON object with "meso_version" (a record meso wrote).
bool is_meso_record(const std::string &path);

}  // namespace meso
