"""The ETSI ITS Release 2 ASN.1 (``asn1/release2/``, BSD-3-Clause, notice in its README.md) compiled for UPER.

Compiled once per process and cached on disk: parsing the 360 kB Common Data Dictionary takes seconds, so the
parsed modules are kept as JSON (never pickle: a cache file is data, not code) under
``$XDG_CACHE_HOME/iea-corridor/`` (``~/.cache`` by default; ``IEA_V2X_CACHE=off`` disables it), keyed by the
SHA-256 of the ASN.1 text after the fixes below and the asn1tools version.

Fixes applied to the text before parsing (asn1tools limitations, each checked to match exactly once):

1. ``WITH SUCCESSORS`` in IMPORTS does not parse in asn1tools; it only affects OID matching: dropped.
2. The CDD holds one Latin-1 byte in a comment: every file is read as Latin-1.
3. A value-union constraint (``TrafficParticipantType (unknown|passengerCar..tram|agricultural)``, CPM
   ``ObjectClass.vehicleSubClass``; ``VruSubProfileBicyclist (unavailable | ... | childrensbike)``, CAM) compiles
   to the range 0..0 (zero bits) without any error. X.691 10.3: the PER-visible constraint of a union of values is
   the range covering them: 0..14 and 0..10, written so.
4. ``SIZE(3..16,...)`` on a referenced SEQUENCE OF (``PolygonalShape.polygon``) is ignored and the referenced
   type's 1..16 kept: the SEQUENCE OF is written out in place with its own size.
5. A DEFAULT given by a value reference or an INTEGER's named number (DENM ``validityDuration DEFAULT
   defaultValidity``, ``AltitudeValue DEFAULT unavailable`` ...) is taken as the name's string: an absent field
   decodes to a string and fails the constraint check, and the default value itself is sent explicitly. Each is
   written as its number (600, 800001, 12800, 0, 0).
"""

from __future__ import annotations

import functools
import hashlib
import json
import os
import re
from importlib import resources
from pathlib import Path
from typing import Any

import asn1tools

RELEASE2_FILES = (
    "TS102894-2v241-CDD.asn",
    "TS103900v231-CAM.asn",
    "TS103831v231-DENM.asn",
    "TS103324v211/CPM-OriginatingStationContainers.asn",
    "TS103324v211/CPM-PDU-Descriptions.asn",
    "TS103324v211/CPM-PerceivedObjectContainer.asn",
    "TS103324v211/CPM-PerceptionRegionContainer.asn",
    "TS103324v211/CPM-SensorInformationContainer.asn",
)

# (file, text as published, text compiled): see the module docstring, fixes 3 and 4.
TEXT_FIXES: tuple[tuple[str, str, str], ...] = (
    ("TS102894-2v241-CDD.asn", "TrafficParticipantType (unknown|passengerCar..tram|agricultural)",
     "TrafficParticipantType (0..14)"),
    ("TS103900v231-CAM.asn", "VruSubProfileBicyclist (unavailable | bicyclist | e-scooter | pedelec | speed-pedelec "
     "| roadbike | childrensbike)", "VruSubProfileBicyclist (0..10)"),
    ("TS102894-2v241-CDD.asn", "polygon                SequenceOfCartesianPosition3d (SIZE(3..16,...))",
     "polygon                SEQUENCE (SIZE(3..16,...)) OF CartesianPosition3d"),
    ("TS103831v231-DENM.asn", "DeltaTimeSecond DEFAULT defaultValidity", "DeltaTimeSecond DEFAULT 600"),
    ("TS102894-2v241-CDD.asn", "altitude   AltitudeValue DEFAULT unavailable", "altitude   AltitudeValue DEFAULT 800001"),
    ("TS102894-2v241-CDD.asn", "deltaAltitude                 DeltaAltitude DEFAULT unavailable",
     "deltaAltitude                 DeltaAltitude DEFAULT 12800"),
    ("TS102894-2v241-CDD.asn", "laneType               LaneType DEFAULT traffic", "laneType               LaneType DEFAULT 0"),
    ("TS102894-2v241-CDD.asn", "direction              Direction DEFAULT sameDirection",
     "direction              Direction DEFAULT 0"),
)


class SchemaError(RuntimeError):
    """The vendored ASN.1 does not compile as expected (a changed file: the fixes no longer apply)."""


def _asn1_dir() -> Path:
    return Path(str(resources.files("protocol.v2x") / "asn1" / "release2"))


def fixed_sources() -> list[str]:
    """The vendored modules' text with the fixes applied, in RELEASE2_FILES order."""
    out = []
    for name in RELEASE2_FILES:
        text = (_asn1_dir() / name).read_text(encoding="latin-1")
        text = re.sub(r"\bWITH\s+SUCCESSORS\b", "", text)
        for file, old, new in TEXT_FIXES:
            if file != name:
                continue
            if text.count(old) != 1:
                raise SchemaError(f"{name}: expected {old!r} exactly once (found {text.count(old)}); "
                                  "the vendored ASN.1 changed: review protocol/v2x/schema.py TEXT_FIXES")
            text = text.replace(old, new)
        out.append(text)
    return out


def _cache_path(digest: str) -> Path | None:
    if os.environ.get("IEA_V2X_CACHE", "").lower() in ("off", "0", "no"):
        return None
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "iea-corridor" / f"etsi-r2-{digest[:24]}.v2.json"


_TUPLE = "__tuple__"


def _to_json(node: Any) -> Any:
    """The parsed modules as JSON data, tuples kept apart from lists (asn1tools' parser uses both)."""
    if isinstance(node, tuple):
        return {_TUPLE: [_to_json(v) for v in node]}
    if isinstance(node, list):
        return [_to_json(v) for v in node]
    if isinstance(node, dict):
        return {k: _to_json(v) for k, v in node.items()}
    return node


def _from_json(node: dict[str, Any]) -> Any:
    return tuple(node[_TUPLE]) if len(node) == 1 and _TUPLE in node else node


def _parsed(sources: list[str]) -> dict[str, Any]:
    digest = hashlib.sha256("\0".join([asn1tools.__version__, *sources]).encode("utf-8")).hexdigest()
    path = _cache_path(digest)
    if path is not None:
        try:
            return json.loads(path.read_text(encoding="utf-8"), object_hook=_from_json)
        except (OSError, ValueError):
            pass
    parsed = asn1tools.parse_string("\n".join(sources))
    if path is not None:
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp = path.with_suffix(f".{os.getpid()}.tmp")
            tmp.write_text(json.dumps(_to_json(parsed)), encoding="utf-8")
            tmp.replace(path)
        except OSError:
            pass  # a read-only home: compile each time
    return parsed


@functools.cache
def specification() -> asn1tools.compiler.Specification:
    """The Release 2 CAM, DENM, CPM and CDD modules compiled for UPER (once per process)."""
    return asn1tools.compile_dict(_parsed(fixed_sources()), "uper")
