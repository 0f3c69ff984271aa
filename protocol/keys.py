"""Key expressions of the corridor (docs/architecture.md §Key expressions): the one place that knows the layout.

    iea/{c}/rsu/{rsu}/objects | ev | hazard | health
    iea/{c}/vehicle/{veh}/cmd | ack | state | health
    iea/{c}/ddm/health
    iea/{c}/sim/world | health
    iea/{c}/rsu/{rsu}/camera/jpeg   an RSU's annotated camera frames (foxglove.CompressedImage JSON)

Beside the published keys:

    iea/{c}/alive/{role}/{id}       liveliness token of every running service (role: rsu, ddm, vehicle, sim)
    iea/{c}/ddm/state               queryable: the DDM's picture as a JSON document
    iea/{c}/rsu/{rsu}/state         queryable: an RSU's tracks and configuration summary (JSON)

and every service answers queries on its published keys with the latest message (health, an RSU's
objects and active alerts, a vehicle's state).

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


PRESENCE_ROLES = ("rsu", "ddm", "vehicle", "sim")


def alive_key(corridor: str, role: str, node_id: str) -> str:
    """The liveliness token of one service: it exists exactly while the service's session is up."""
    if role not in PRESENCE_ROLES:
        raise KeyError_(f"unknown role {role!r} for a liveliness token; expected one of {PRESENCE_ROLES}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/alive/{role}/{_chunk(node_id, 'service id')}"


def alive_expr(corridor: str, role: str = "*") -> str:
    """Every liveliness token of ``role`` (``*``: of every role) in the corridor."""
    if role != "*" and role not in PRESENCE_ROLES:
        raise KeyError_(f"unknown role {role!r}; expected '*' or one of {PRESENCE_ROLES}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/alive/{role}/*"


def parse_alive_key(key: str) -> tuple[str, str, str]:
    """``(corridor, role, id)`` of a liveliness token key; ``KeyError_`` for anything else."""
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) != 5 or parts[0] != ROOT or parts[2] != "alive" or parts[3] not in PRESENCE_ROLES:
        raise KeyError_(f"key {key!r} is not a liveliness token iea/<corridor>/alive/<role>/<id>")
    return _chunk(parts[1], "corridor"), parts[3], _chunk(parts[4], "service id")


def ddm_state_key(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/ddm/state"


def rsu_state_key(corridor: str, rsu_id: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/{_chunk(rsu_id, 'rsu id')}/state"


def all_rsus_expr(corridor: str) -> str:
    """What the DDM subscribes to: every topic of every RSU of the corridor."""
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/*/*"


def rsu_topic_expr(corridor: str, topic: str) -> str:
    """One topic of every RSU (the DDM subscribes to the bulk ``objects`` apart from the alerts)."""
    if topic not in RSU_TOPICS:
        raise KeyError_(f"unknown RSU topic {topic!r}; expected one of {sorted(RSU_TOPICS)}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/*/{topic}"


def all_vehicles_expr(corridor: str, topic: str) -> str:
    if topic not in VEHICLE_TOPICS:
        raise KeyError_(f"unknown vehicle topic {topic!r}")
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/vehicle/*/{topic}"


def corridor_expr(corridor: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/**"


CAMERA_TOPIC = "camera/jpeg"
"""An RSU's annotated camera frames, as ``foxglove.CompressedImage`` JSON (``rsu.camera_feed``): two chunks
under the RSU, so the RSU's own ACL covers it and the DDM's ``rsu/*/*`` does not see it."""


def rsu_camera_key(corridor: str, rsu_id: str) -> str:
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/{_chunk(rsu_id, 'rsu id')}/{CAMERA_TOPIC}"


def camera_expr(corridor: str) -> str:
    """Every RSU's camera frames in the corridor."""
    return f"{ROOT}/{_chunk(corridor, 'corridor')}/rsu/*/{CAMERA_TOPIC}"


def parse_camera_key(key: str) -> tuple[str, str]:
    """``(corridor, rsu id)`` of an RSU camera key; ``KeyError_`` for anything else."""
    parts = key.split("/") if isinstance(key, str) else []
    if len(parts) != 6 or parts[0] != ROOT or parts[2] != "rsu" or "/".join(parts[4:]) != CAMERA_TOPIC:
        raise KeyError_(f"key {key!r} is not an RSU camera key iea/<corridor>/rsu/<rsu>/{CAMERA_TOPIC}")
    return _chunk(parts[1], "corridor"), _chunk(parts[3], "rsu id")


def is_camera_key(key: str) -> bool:
    try:
        parse_camera_key(key)
    except KeyError_:
        return False
    return True


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
