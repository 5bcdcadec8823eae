// Parsing of "to_world" objects in scene files.
#pragma once
#include "core/transform.h"

namespace meso {
class Properties;

/// Reads an optional "to_world" child of `p`:
///   {"matrix": [16 numbers, row-major]}  or any of
///   {"scale": s | [sx,sy,sz], "rotate": {"axis": [x,y,z], "angle": deg} | [ {...}, ... ],
///    "translate": [x,y,z], "look_at": {"origin":[..], "target":[..], "up":[..]}}
/// applied in the order scale, rotate(s), translate (then look_at, if given, replaces all).
/// Returns identity when the key is absent.
Transform parse_transform(const Properties &p, const char *key = "to_world");
}  // namespace meso
