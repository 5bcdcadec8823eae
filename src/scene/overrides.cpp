#include "scene/overrides.h"
#include <cctype>
#include <fmt/format.h>
#include <nlohmann/json.hpp>
#include "core/error.h"

namespace meso {

using json = nlohmann::json;

namespace {

/// One step of an override path: an object key or an array index.
struct Step {
    bool is_index = false;
    std::string key;
    size_t index = 0;
    std::string prefix;  ///< the path up to and including this step (for messages)
};

[[noreturn]] void fail(const std::string &key, const std::string &msg) {
    throw MesoError(fmt::format("-D {}: {}", key, msg));
}

std::vector<Step> parse_key(const std::string &key) {
    if (key.empty()) fail(key, "empty key (expected -D path.to.key=value)");
    std::vector<Step> steps;
    size_t i = 0, n = key.size();
    std::string prefix;
    bool expect_name = true;  // at the start and after a '.'
    while (i < n) {
        if (key[i] == '[') {
            if (expect_name && steps.empty()) fail(key, "expected a key name before '['");
            if (expect_name) fail(key, "empty key name before '['");
            size_t close = key.find(']', i);
            if (close == std::string::npos) fail(key, "missing ']'");
            std::string digits = key.substr(i + 1, close - i - 1);
            if (digits.empty() || digits.size() > 9)
                fail(key, fmt::format("expected an array index in [], got '[{}]'", digits));
            for (char c : digits)
                if (!std::isdigit(static_cast<unsigned char>(c)))
                    fail(key, fmt::format("expected an array index in [], got '[{}]'", digits));
            Step s;
            s.is_index = true;
            s.index = std::stoul(digits);
            prefix += key.substr(i, close - i + 1);
            s.prefix = prefix;
            steps.push_back(s);
            i = close + 1;
            if (i < n && key[i] != '.' && key[i] != '[') fail(key, "expected '.' or '[' after ']'");
            if (i < n && key[i] == '.') {
                ++i;
                expect_name = true;
                if (i == n) fail(key, "empty key name at the end");
                prefix += ".";
            }
            continue;
        }
        size_t end = key.find_first_of(".[", i);
        if (end == std::string::npos) end = n;
        std::string name = key.substr(i, end - i);
        if (name.empty()) fail(key, "empty key name");
        if (name.find(']') != std::string::npos) fail(key, "unexpected ']'");
        Step s;
        s.key = name;
        prefix += name;
        s.prefix = prefix;
        steps.push_back(s);
        expect_name = false;
        i = end;
        if (i < n && key[i] == '.') {
            ++i;
            if (i == n) fail(key, "empty key name at the end");
            expect_name = true;
            prefix += ".";
        }
    }
    return steps;
}

const char *kind_of(const json &j) {
    switch (j.type()) {
        case json::value_t::object: return "an object";
        case json::value_t::array: return "an array";
        case json::value_t::string: return "a string";
        case json::value_t::boolean: return "a boolean";
        case json::value_t::null: return "null";
        default: return "a number";
    }
}

}  // namespace

void apply_override(json &root, const std::string &assignment) {
    size_t eq = assignment.find('=');
    if (eq == std::string::npos) fail(assignment, "expected key=value");
    std::string key = assignment.substr(0, eq);
    std::string text = assignment.substr(eq + 1);
    std::vector<Step> steps = parse_key(key);

    // Anything that parses as JSON is JSON (numbers, arrays, objects, true/false, "strings");
    // everything else (plain words, file names) is a string.
    json value = json::parse(text, nullptr, /*allow_exceptions=*/false);
    if (value.is_discarded()) value = text;

    json *cur = &root;
    std::string parent = "the scene";
    for (const Step &s : steps) {
        if (s.is_index) {
            if (!cur->is_array())
                fail(key, fmt::format("cannot index {}: it is {}, not an array", parent, kind_of(*cur)));
            if (s.index >= cur->size())
                fail(key, fmt::format("index {} out of range ({} has {} element{})", s.index, parent, cur->size(),
                                      cur->size() == 1 ? "" : "s"));
            cur = &(*cur)[s.index];
        } else {
            if (cur->is_null()) *cur = json::object();  // created along the way
            if (!cur->is_object())
                fail(key, fmt::format("cannot set '{}': {} is {}, not an object", s.key, parent, kind_of(*cur)));
            cur = &(*cur)[s.key];
        }
        parent = s.prefix;
    }
    *cur = std::move(value);
}

void apply_overrides(json &root, const std::vector<std::string> &assignments) {
    for (const auto &a : assignments) apply_override(root, a);
}

}  // namespace meso
