"""`iea status`: the whole corridor as one table, asked of Zenoh. The first thing an operator runs.

It asks, with one query each (answers within ``--timeout-s``; nothing waits for a 1 Hz beat):

- the liveliness tokens ``iea/{c}/alive/*/*``: who is up now;
- ``iea/{c}/**/health``: each service's latest Health (status, uptime, detail);
- ``iea/{c}/ddm/state`` and ``iea/{c}/rsu/*/state``: the DDM's picture and each RSU's tracks (JSON);
- ``iea/{c}/vehicle/*/state``: each vehicle's latest state (mode, speed, active command).

``gather`` is the shell (queries), ``rows`` / ``format_table`` are pure. Services named in the corridor
file that are not up are listed as ``missing``; exit status 1 when nothing answered at all.
"""

from __future__ import annotations

import argparse
import json
import sys
from dataclasses import dataclass, field
from typing import Any

from protocol import keys
from protocol.messages import Health, VehicleState

ROLES_ORDER = {"ddm": 0, "rsu": 1, "vehicle": 2, "sim": 3}


@dataclass
class CorridorStatus:
    """What the queries returned (``(role, id)`` keyed)."""

    alive: set[tuple[str, str]] = field(default_factory=set)
    health: dict[tuple[str, str], Health] = field(default_factory=dict)
    states: dict[tuple[str, str], dict[str, Any]] = field(default_factory=dict)
    vehicles: dict[str, VehicleState] = field(default_factory=dict)
    expected: set[tuple[str, str]] = field(default_factory=set)


def _node(parsed: keys.ParsedKey) -> tuple[str, str]:
    return (parsed.domain, parsed.node or parsed.domain)


def gather(transport, corridor_id: str, timeout_s: float = 1.0,
           expected: set[tuple[str, str]] | None = None) -> CorridorStatus:
    """Query presence, health and state of corridor ``corridor_id`` (any ``Transport``)."""
    st = CorridorStatus(expected=set(expected or ()))
    for key in transport.query_presence(keys.alive_expr(corridor_id), timeout_s):
        try:
            _, role, node = keys.parse_alive_key(key)
        except keys.KeyError_:
            continue
        st.alive.add((role, node))
    root = f"{keys.ROOT}/{corridor_id}"
    for key, msg in transport.query(f"{root}/**/health", timeout_s):
        st.health[_node(keys.parse_key(key))] = msg
    for key, msg in transport.query(keys.all_vehicles_expr(corridor_id, "state"), timeout_s):
        st.vehicles[keys.parse_key(key).node] = msg
    for expr in (keys.ddm_state_key(corridor_id), f"{root}/rsu/*/state"):
        for key, payload in transport.query_bytes(expr, timeout_s):
            parts = key.split("/")
            node = ("ddm", "ddm") if parts[2] == "ddm" else ("rsu", parts[3])
            try:
                st.states[node] = json.loads(payload)
            except ValueError:
                continue
    return st


def _detail(role: str, node: str, st: CorridorStatus) -> str:
    s = st.states.get((role, node)) or st.states.get((role, role)) or {}
    if role == "ddm" and s:
        evs = ", ".join(str(e.get("alert_id") or e.get("track_id")) for e in s.get("active_evs", [])) or "none"
        return (f"tracks {s.get('tracks_total')}, vehicles {len(s.get('vehicles', {}))}, "
                f"commands out {s.get('outstanding_commands')}, EVs {evs}, hazards {len(s.get('hazards', []))}, "
                f"stale RSUs {','.join(s.get('stale_rsus', [])) or 'none'}")
    if role == "rsu" and s:
        return (f"frames {s.get('frames')}, tracks {len(s.get('tracks', []))}, "
                f"EV alerts {','.join(s.get('ev_alerts_active', [])) or 'none'}, "
                f"hazards {','.join(s.get('hazards_active', [])) or 'none'}"
                + (f", stalled: {s.get('last_error')}" if s.get("stalled") else ""))
    if role == "vehicle" and node in st.vehicles:
        v = st.vehicles[node]
        return (f"{v.mode.value}, {v.speed_mps:.1f} m/s at ({v.pos_x_m:.0f}, {v.pos_y_m:.0f}) m, "
                f"command {v.active_command_id or 'none'}")
    h = st.health.get((role, node))
    return h.detail[:80] if h is not None else ""


def rows(st: CorridorStatus) -> list[list[str]]:
    """One row per service seen or expected: SERVICE, UP, STATUS, UPTIME, DETAIL (pure)."""
    nodes = st.alive | set(st.health) | st.expected
    out = []
    for role, node in sorted(nodes, key=lambda n: (ROLES_ORDER.get(n[0], 9), n[1])):
        h = st.health.get((role, node))
        up = "yes" if (role, node) in st.alive else ("missing" if (role, node) in st.expected else "no")
        out.append([f"{role}/{node}" if node != role else role, up, h.status.value if h else "-",
                    f"{h.uptime_s:.0f} s" if h else "-", _detail(role, node, st)])
    return out


def format_table(table: list[list[str]]) -> str:
    head = ["SERVICE", "UP", "STATUS", "UPTIME", "DETAIL"]
    widths = [max(len(r[i]) for r in [head, *table]) for i in range(4)]
    fmt = lambda r: "  ".join(c.ljust(w) for c, w in zip(r[:4], widths, strict=True)) + "  " + r[4]  # noqa: E731
    return "\n".join([fmt(head), *(fmt(r) for r in table)])


def expected_services(corridor) -> set[tuple[str, str]]:
    return ({("ddm", "ddm")} | {("rsu", r.rsu_id) for r in corridor.rsus}
            | {("vehicle", v.vehicle_id) for v in corridor.vehicles})


def health_key(corridor_id: str, role: str, node: str | None = None) -> str:
    """The Health key of one service: ``rsu`` and ``vehicle`` need their id (ValueError without it)."""
    if role in ("rsu", "vehicle") and not node:
        raise ValueError(f"{role} needs its id")
    return {"rsu": lambda: keys.rsu_key(corridor_id, node, "health"),
            "vehicle": lambda: keys.vehicle_key(corridor_id, node, "health"),
            "ddm": lambda: keys.ddm_health_key(corridor_id), "sim": lambda: keys.sim_health_key(corridor_id)}[role]()


def check_health(settings, key: str, timeout_s: float) -> int:
    """``iea health``: wait up to ``timeout_s`` for a Health on ``key`` and print it; 0 for ok or degraded, 1 for
    error or none (the docker-compose health check)."""
    import threading

    from protocol.zenoh_transport import ZenohTransport

    got: list[Health] = []
    done = threading.Event()
    transport = ZenohTransport(settings)
    try:
        transport.subscribe(key, lambda _k, m: (got.append(m), done.set()))
        done.wait(timeout_s)
    finally:
        transport.close()
    if not got:
        print(f"no Health on {key} within {timeout_s:g} s", file=sys.stderr)
        return 1
    h = got[-1]
    print(f"{key}: {h.status.value} (uptime {h.uptime_s:.0f} s) {h.detail}")
    return 0 if h.status.value in ("ok", "degraded") else 1


def main(argv: list[str] | None = None) -> int:
    from protocol.corridor import DEFAULT_CORRIDOR, CorridorError, load_corridor
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    ap = argparse.ArgumentParser(prog="iea status", description="Print every service of a running corridor as one "
                                 "table: liveliness token (UP), latest Health (STATUS, UPTIME) and state (DDM picture, "
                                 "RSU tracks and alerts, vehicle mode and command). Exit 1 when nothing answered.")
    ap.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (its services are expected)")
    ap.add_argument("--corridor-id", default=None, help="corridor id in the keys (default: the file's id; `iea up` "
                    "prints the one it uses)")
    ap.add_argument("--timeout-s", type=float, default=1.0, help="how long each query may take (default 1)")
    ap.add_argument("--json", action="store_true", help="print the gathered status as JSON instead of a table")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    try:
        corridor = load_corridor(args.corridor)
        cid = args.corridor_id or corridor.corridor_id
        keys.alive_expr(cid)
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError) as exc:
        print(f"iea status: {exc}", file=sys.stderr)
        return 2
    transport = ZenohTransport(settings)
    try:
        st = gather(transport, cid, args.timeout_s, expected_services(corridor))
    finally:
        transport.close()
    table = rows(st)
    if args.json:
        print(json.dumps({"corridor_id": cid, "services": [dict(zip(["service", "up", "status", "uptime", "detail"],
                                                                      r, strict=True)) for r in table],
                          "ddm_state": st.states.get(("ddm", "ddm"))}, default=str))
    else:
        print(f"corridor {cid}: {len(st.alive)} services up")
        print(format_table(table))
    return 0 if st.alive or st.health else 1
