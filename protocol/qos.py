"""Quality of service per message kind (docs/architecture.md §Presence and QoS): priority, congestion control
and express, decided by the key's topic alone (pure, no Zenoh import).

Zenoh keeps one transmission queue per priority and serves the higher ones first, so a command never
waits behind a queued world snapshot. A ``BLOCK`` message holds its priority's queue until there is room
(up to ``wait_before_close``), which stalls any ``DROP`` message queued at the same priority (upstream
eclipse-zenoh/zenoh#2584): the blocking kinds therefore own priorities no dropping kind uses.

| kind (topic)              | priority          | congestion | express | why                                     |
|---------------------------|-------------------|------------|---------|-----------------------------------------|
| ``cmd``, ``ack``          | REAL_TIME         | BLOCK      | yes     | safety: never dropped, never batched    |
| ``ev``, ``hazard``        | INTERACTIVE_HIGH  | BLOCK      | yes     | alerts: never dropped                   |
| ``health``                | INTERACTIVE_LOW   | DROP       | yes     | 1 Hz beats; the next one replaces it    |
| vehicle ``state``         | DATA_HIGH         | DROP       | yes     | 20 Hz pose; the newest wins             |
| ``objects``               | DATA              | DROP       | no      | bulk at 10-15 Hz, batched               |
| ``world`` (sim), video    | BACKGROUND        | DROP       | no      | bulk, first to go under congestion      |

REAL_TIME is the highest priority an application may use (zenoh's priority 0, ``Control``, is its own).
``QosClass`` names are Zenoh's ``Priority`` / ``CongestionControl`` member names, so the Zenoh
transport maps them with ``getattr``; ``LocalBus`` delivers synchronously and ignores them.
"""

from __future__ import annotations

from dataclasses import dataclass

PRIORITIES = ("REAL_TIME", "INTERACTIVE_HIGH", "INTERACTIVE_LOW", "DATA_HIGH", "DATA", "DATA_LOW", "BACKGROUND")
"""Zenoh's application priorities, highest first."""


@dataclass(frozen=True, slots=True)
class QosClass:
    priority: str
    congestion: str  # "BLOCK" | "DROP"
    express: bool

    def __post_init__(self) -> None:
        if self.priority not in PRIORITIES:
            raise ValueError(f"priority must be one of {PRIORITIES}, got {self.priority!r}")
        if self.congestion not in ("BLOCK", "DROP"):
            raise ValueError(f"congestion must be BLOCK or DROP, got {self.congestion!r}")


COMMAND = QosClass("REAL_TIME", "BLOCK", True)
ALERT = QosClass("INTERACTIVE_HIGH", "BLOCK", True)
HEALTH = QosClass("INTERACTIVE_LOW", "DROP", True)
STATE = QosClass("DATA_HIGH", "DROP", True)
OBJECTS = QosClass("DATA", "DROP", False)
BULK = QosClass("BACKGROUND", "DROP", False)
FLAT = QosClass("DATA", "DROP", True)
"""Every kind the same way (no per-kind QoS): the bench's "no priorities" case."""

BY_TOPIC: dict[str, QosClass] = {
    "cmd": COMMAND, "ack": COMMAND,
    "ev": ALERT, "hazard": ALERT,
    "health": HEALTH,
    "state": STATE,
    "objects": OBJECTS,
    "world": BULK, "video": BULK,
}


ROUTER_NETWORK_QOS: list[dict] = [{
    "id": "forwarding_never_blocks", "messages": ["put"], "flows": ["egress"],
    "key_exprs": [f"**/{topic}" for topic, q in BY_TOPIC.items() if q.congestion == "BLOCK"],
    "overwrite": {"congestion_control": "drop"}}]
"""A router's ``qos/network`` (every router config of the project carries it): the router never blocks on what
it forwards of the ``BLOCK`` kinds. Such a message queued for a host whose link has stalled would hold up the
task that reads its publisher's link, and with it everything that publisher sends to every other host (a DDM cut
off for 2 s silenced the vehicle's state to the simulator for a second). Forwarded, they are dropped instead when
the stalled host's queue is full, and the application repeats them: commands until acknowledged, an ack with
every repeat, alerts refreshed at 2 Hz. A publisher's own session still blocks: nothing is dropped at its source."""


def qos_for_key(key: str) -> QosClass:
    """The QoS of a concrete key by its last chunk (its topic); unknown topics travel as ``OBJECTS``."""
    return BY_TOPIC.get(key.rsplit("/", 1)[-1], OBJECTS)


def qos_lossless(key: str) -> QosClass:
    """The kind's priority with ``BLOCK`` and express: for a publisher that must lose nothing and batch
    nothing (``iea replay`` at any speed, whose last batch would otherwise still be queued at close)."""
    return QosClass(qos_for_key(key).priority, "BLOCK", True)


COMMAND_TOPICS = ("cmd", "ack")
"""A command and its acknowledgement: idempotent, so they may travel as several copies."""
CONTROL_TOPICS = (*COMMAND_TOPICS, "health")
"""A vehicle's control loop with the DDM: commands, acks and the 1 Hz beats."""


def is_command_expr(key_expr: str) -> bool:
    return key_expr.rsplit("/", 1)[-1] in COMMAND_TOPICS


def is_control_expr(key_expr: str) -> bool:
    """True for the keys of ``CONTROL_TOPICS``. Everything else (state, object lists, alerts, world, video) a
    vehicle can take over a connection of its own."""
    return key_expr.rsplit("/", 1)[-1] in CONTROL_TOPICS


def is_bulk_expr(key_expr: str) -> bool:
    """True when every key of ``key_expr`` is a bulk kind (its last chunk ``objects``, ``world``, ``video``):
    such subscriptions are delivered off the network thread through a bounded ring that keeps the newest
    samples (``ZenohTransport``), so decoding bulk never holds up a command behind it."""
    return BY_TOPIC.get(key_expr.rsplit("/", 1)[-1]) in (OBJECTS, BULK)


def check_separation(table: dict[str, QosClass] = BY_TOPIC) -> None:
    """Raise if a priority carries both BLOCK and DROP kinds (the head-of-line case of the module doc)."""
    modes: dict[str, set[str]] = {}
    for q in table.values():
        modes.setdefault(q.priority, set()).add(q.congestion)
    mixed = sorted(p for p, m in modes.items() if len(m) > 1)
    if mixed:
        raise ValueError(f"priorities {mixed} mix BLOCK and DROP kinds: give the blocking kinds their own priority")


check_separation()
