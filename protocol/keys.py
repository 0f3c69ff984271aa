"""Key expressions of the corridor (DESIGN.md "Key expressions"): the one place that knows the layout.

    iea/{c}/rsu/{rsu}/objects | ev | hazard | health
    iea/{c}/vehicle/{veh}/cmd | ack | state | health
    iea/{c}/ddm/health
    iea/{c}/sim/world | health

Builders return concrete keys; ``parse_key`` turns a concrete key back into its parts and the
message type it carries; ``key_matches`` implements Zenoh's key-expression wildcards (``*`` one
chunk, ``**`` any number of chunks, ``$*`` inside a chunk) for the in-process bus.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import cache, lru_cache

from protocol.messages import (
    CommandAck,
    Envelope,
    EvAlert,
    HazardAlert,
    Health,
    ObjectList,
    PathSwitchCommand,
    VehicleState,
    WorldSnapshot,
)

ROOT = "iea"
_CHUNK = re.compile(r"^[A-Za-z0-9_.\-]+$")

RSU_TOPICS: dict[str, type[Envelope]] = {
    "objects": ObjectList,
    "ev": EvAlert,
    "hazard": HazardAlert,
    "health": Health,
}
VEHICLE_TOPICS: dict[str, type[Envelope]] = {
    "cmd": PathSwitchCommand,
    "ack": CommandAck,
    "state": VehicleState,
    "health": Health,
}
DDM_TOPICS: dict[str, type[Envelope]] = {"health": Health}
SIM_TOPICS: dict[str, type[Envelope]] = {"world": WorldSnapshot, "health": Health}


class KeyError_(ValueError):
    """A key that is not part of the corridor layout."""


def _chunk(value: str, what: str) -> str:
    if not isinstance(value, str) or not _CHUNK.match(value):
        raise KeyError_(f"{what} {value!r} is not a valid key chunk (letters, digits, '_', '-', '.')")
    return value


def rsu_key(corridor: str, rsu_id: str, topic: str) -> str:
    if topic not in RSU_TOPICS:
        raise KeyError_(f"unknown RSU topic {topic!r}; expected one of {sorted(RSU_TOPICS)}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/{_chunk(rsu_id, 'rsu id')}/{topic}"


def vehicle_key(corridor: str, vehicle_id: str, topic: str) -> str:
    if topic not in VEHICLE_TOPICS:
        raise KeyError_(f"unknown vehicle topic {topic!r}; expected one of {sorted(VEHICLE_TOPICS)}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/vehicle/{_chunk(vehicle_id, 'vehicle id')}/{topic}"


def ddm_health_key(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/ddm/health"


def sim_world_key(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/sim/world"


def sim_health_key(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/sim/health"


def all_rsus_expr(corridor: str) -> str:
    """What the DDM subscribes to: every topic of every RSU of the corridor."""
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/*/*"


def all_vehicles_expr(corridor: str, topic: str) -> str:
    if topic not in VEHICLE_TOPICS:
        raise KeyError_(f"unknown vehicle topic {topic!r}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/vehicle/*/{topic}"


def corridor_expr(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/**"


@dataclass(frozen=True, slots=True)
class ParsedKey:
    corridor: str
    domain: str  # "rsu" | "vehicle" | "ddm" | "sim"
    node: str | None  # rsu or vehicle id; None for ddm/sim
    topic: str
    message_type: type[Envelope]


@lru_cache(maxsize=4096)
def parse_key(key: str) -> ParsedKey:
    """Split a concrete key into its parts; raise ``KeyError_`` for anything outside the layout."""
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) < 4 or parts[0] != ROOT:
        raise KeyError_(f"key {key!r} is not under '{ROOT}/<corridor>/'")
    corridor, domain = parts[1], parts[2]
    _chunk(corridor, "corridor")
    if domain in ("rsu", "vehicle") and len(parts) == 5:
        node, topic = _chunk(parts[3], f"{domain} id"), parts[4]
        topics = RSU_TOPICS if domain == "rsu" else VEHICLE_TOPICS
        if topic in topics:
            return ParsedKey(corridor, domain, node, topic, topics[topic])
    elif domain in ("ddm", "sim") and len(parts) == 4:
        topics = DDM_TOPICS if domain == "ddm" else SIM_TOPICS
        if parts[3] in topics:
            return ParsedKey(corridor, domain, None, parts[3], topics[parts[3]])
    raise KeyError_(f"key {key!r} is not part of the corridor layout (see protocol/keys.py)")


def message_type_for_key(key: str) -> type[Envelope]:
    return parse_key(key).message_type


@lru_cache(maxsize=4096)
def _chunk_regex(pattern_chunk: str) -> re.Pattern[str]:
    return re.compile("^" + ".*".join(re.escape(p) for p in pattern_chunk.split("$*")) + "$")


def _chunk_matches(pattern: str, chunk: str) -> bool:
    if pattern == "*":
        return True
    if "$*" in pattern:
        return bool(_chunk_regex(pattern).match(chunk))
    return pattern == chunk


@lru_cache(maxsize=16384)
def key_matches(expr: str, key: str) -> bool:
    """True when concrete ``key`` is in the set defined by key expression ``expr`` (Zenoh rules)."""
    pat, ks = expr.split("/"), key.split("/")

    @cache
    def match(i: int, j: int) -> bool:
        if i == len(pat):
            return j == len(ks)
        if pat[i] == "**":
            return match(i + 1, j) or (j < len(ks) and match(i, j + 1))
        return j < len(ks) and _chunk_matches(pat[i], ks[j]) and match(i + 1, j + 1)

    return match(0, 0)
