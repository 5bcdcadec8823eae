// Mitsuba 3 XML scenes: the common subset of Mitsuba 3's scene format, translated (through
// pugixml) into a meso scene JSON document that then goes through the same plugin registry,
// -D overrides and errors as a hand-written scene (as glTF files do, scene/gltf.h).
//
// Read: sensor `perspective` (+ film `hdrfilm`, sampler `independent` / `stratified`),
// integrator `path` / `direct`, shapes `obj`, `ply`, `rectangle`, `cube`, `sphere`, `disk`,
// bsdfs `diffuse`, `conductor`, `roughconductor`, `plastic`, `roughplastic`, `dielectric`,
// `roughdielectric`, `twosided`, `normalmap`, `bumpmap`, emitters `area`, `point`, `spot`,
// `constant`, `envmap`, `directional`, textures `bitmap`, `checkerboard`; `ref`/`id`,
// `default`/`$param`, `include`. docs/scene-format.md ("Mitsuba 3 XML scenes") has the table.
// Anything else (an unknown plugin, property or element) is an error naming the file, the
// line and the element; properties meso has no use for (near_clip, rfilter, ...) are
// dropped with a note on stderr.
#pragma once
#include <string>
#include <vector>
#include <nlohmann/json_fwd.hpp>

namespace meso {

/// Translates a Mitsuba 3 XML file into a meso scene JSON object. When `overrides` is given,
/// every `name=value` in it whose name is a bare identifier sets the XML parameter `$name` (as
/// `mitsuba -D name=value`) and is removed from the list; one that the file never uses is an
/// error, unless it is a meso top-level key (camera, integrator, ...): that one stays in the list
/// as a JSON override. File names in the result are relative to the XML file's directory.
nlohmann::json mitsuba_xml_to_json(const std::string &path, std::vector<std::string> *overrides = nullptr);

/// True for paths ending in .xml (case-insensitive).
bool is_mitsuba_xml_path(const std::string &path);

}  // namespace meso
