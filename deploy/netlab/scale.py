"""The scale row: several corridors of a city across namespaces, each with its RSUs and its DDM.

Layout (as ``iea deploy mesh`` lays out one corridor, with a segment router per corridor): a core router;
per corridor a segment router on its own host hanging off the core, a host with the corridor's RSUs
(``bench/zenoh_corridor_stub.py``: each RSU's object lists at 15 Hz of synthetic traffic with an EV approaching
the AV, an EvAlert at 2 Hz, Health at 1 Hz, and one AV's state at 15 Hz) on the segment router, and a host with
the corridor's DDM (``ddm run``) on the core, so every object list crosses a segment router and the core.

Measured over a window once every DDM is heard: per DDM, its decision latency (alert -> command published,
p50/p99 of its Health's ``latency_ms``) and its loop step; per router, the CPU it used (``/proc/PID/stat``
utime + stime, in cores) and the bytes per second through its links (counted at its ends of the veths).
"""

from __future__ import annotations

import os
import re
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from deploy.netlab.lab import LISTEN, lab_guard, new_plan, run_dir_for, segment_router_config
from deploy.netlab.net import Net, require_lab
from deploy.netlab.plan import MONITOR
from deploy.procs import ROOT, ServiceGroup

STUB = ROOT / "bench" / "zenoh_corridor_stub.py"
RSU_SPACING_M = 50.0


def corridor_text(base_text: str, corridor_id: str, n_rsus: int) -> str:
    """A corridor file of ``n_rsus`` RSUs: the base file's RSUs, repeated further along the road (ids
    ``rsu<k>``, each copy's mast ``RSU_SPACING_M`` x its count further on), under ``corridor_id``. Pure."""
    head, *blocks = re.split(r"(?m)^(?=\[\[rsu\]\])", base_text)
    if not blocks:
        raise ValueError("the base corridor has no [[rsu]] table to repeat")
    base_n = len(blocks)
    head = re.sub(r'(?m)^id = ".*"$', f'id = "{corridor_id}"', head, count=1)
    m = re.search(r"(?m)^length_m = ([0-9.]+)", head)
    if m:  # the road long enough for the last mast's view
        need = float(m.group(1)) + RSU_SPACING_M * max(0, n_rsus - base_n)
        head = head[:m.start(1)] + f"{need:.1f}" + head[m.end(1):]
    out = []
    for k in range(n_rsus):
        block = blocks[k % base_n]
        shift = RSU_SPACING_M * base_n * (k // base_n)
        block = re.sub(r'(?m)^id = "rsu\d+"$', f'id = "rsu{k + 1}"', block, count=1)
        block = re.sub(r"(?m)^x_m = ([-0-9.]+)", lambda mm, s=shift: f"x_m = {float(mm.group(1)) + s}", block,
                       count=1)
        out.append(block)
    return head + "".join(out)


def _cpu_s(pid: int) -> float:
    with open(f"/proc/{pid}/stat") as f:
        fields = f.read().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def run_scale(n_corridors: int = 3, n_rsus: int = 8, window_s: float = 20.0, rate_hz: float = 15.0,
              run_root: Path | None = None, warmup_timeout_s: float = 60.0) -> dict[str, Any]:
    """The scale row's figures (see the module's docstring); the lab is removed before it returns."""
    require_lab()
    with lab_guard():
        return _run_scale(n_corridors, n_rsus, window_s, rate_hz, run_root, warmup_timeout_s)


def _run_scale(n_corridors: int, n_rsus: int, window_s: float, rate_hz: float, run_root: Path | None,
               warmup_timeout_s: float) -> dict[str, Any]:
    from protocol.corridor import DEFAULT_CORRIDOR
    from protocol.keys import ddm_health_key
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    run_dir = run_dir_for(run_root, "scale")
    run_dir.mkdir(parents=True, exist_ok=True)
    tag = uuid.uuid4().hex[:6]
    corridors = [f"city{i + 1}{tag}" for i in range(n_corridors)]
    segs = [f"c{i + 1}" for i in range(n_corridors)]
    hosts: dict[str, str] = {}
    for seg in segs:
        hosts[seg] = "core"
        hosts[f"{seg}-rsus"] = seg
        hosts[f"{seg}-ddm"] = "core"
    plan = new_plan(hosts, ["core", *segs])
    net = Net(plan)
    group = ServiceGroup(run_dir)
    files = {}
    base = DEFAULT_CORRIDOR.read_text()
    for cid in corridors:
        files[cid] = run_dir / f"{cid}.toml"
        files[cid].write_text(corridor_text(base, cid, n_rsus))
    health: dict[str, list[tuple[float, dict[str, float], dict[str, float]]]] = {c: [] for c in corridors}
    transport = None
    try:
        net.up()
        group.launch["router"] = net.exec_prefix("core")
        group.start("router", ["-m", "deploy", "router", "--listen", LISTEN, "--no-multicast"])
        routers = {"core": "router"}
        for seg in segs:
            cfg = run_dir / f"router-{seg}.json5"
            cfg.write_text(segment_router_config(plan.endpoint(seg)))
            group.launch[f"router-{seg}"] = net.exec_prefix(seg)
            group.start(f"router-{seg}", ["-m", "deploy", "router", "--config", str(cfg)])
            routers[seg] = f"router-{seg}"
        for name in routers.values():
            if not group.wait_for_log(name, "router ready", 30.0):
                raise RuntimeError(f"{name} did not start: {group.log_path(name).read_text()[-1500:]}")
        transport = ZenohTransport(ZenohSettings(mode="client", connect=[plan.endpoint(MONITOR)]))
        for cid in corridors:
            transport.subscribe(ddm_health_key(cid), lambda _k, m, c=cid: health[c].append(
                (time.time(), dict(m.latency_ms), dict(m.rates_hz))))
        duration = warmup_timeout_s + window_s + 30.0
        for seg, cid in zip(segs, corridors, strict=True):
            group.launch[f"{seg}-ddm"] = net.exec_prefix(f"{seg}-ddm")
            group.start(f"{seg}-ddm", ["-m", "ddm", "run", "--corridor", str(files[cid]), "--corridor-id", cid,
                                       "--connect", plan.endpoint(f"{seg}-ddm")])
            group.launch[f"{seg}-rsus"] = net.exec_prefix(f"{seg}-rsus")
            group.start(f"{seg}-rsus", [str(STUB), "--corridor", str(files[cid]), "--corridor-id", cid, "--connect",
                                        plan.endpoint(f"{seg}-rsus"), "--duration-s", str(duration),
                                        "--rate-hz", str(rate_hz)])
        deadline = time.monotonic() + warmup_timeout_s
        while time.monotonic() < deadline and not all(len(h) >= 3 for h in health.values()):
            time.sleep(0.2)
        missing = [c for c, h in health.items() if len(h) < 3]
        if missing:
            raise RuntimeError(f"DDM(s) of {missing} not heard within {warmup_timeout_s:.0f} s; logs in {run_dir}")
        pids = {r: group.procs[name].pid for r, name in routers.items()}
        hub_links = {r: [link.host for link in plan.links if link.hub == r] for r in routers}
        cpu0 = {r: _cpu_s(p) for r, p in pids.items()}
        bytes0 = {r: sum(sum(net.link_bytes(h)) for h in hub_links[r]) for r in routers}
        t0 = time.time()
        time.sleep(window_s)
        span = time.time() - t0
        cpu = {r: round((_cpu_s(p) - cpu0[r]) / span, 3) for r, p in pids.items()}
        bps = {r: round((sum(sum(net.link_bytes(h)) for h in hub_links[r]) - bytes0[r]) / span) for r in routers}
        exited = {n: c for n, c in group.exited().items()}
    finally:
        if transport is not None:
            transport.close()
        group.stop_all(timeout_s=5.0)
        net.down()
    ddms = {}
    for cid, rows in health.items():
        window = [r for r in rows if t0 <= r[0] <= t0 + span]
        last = window[-1] if window else (rows[-1] if rows else None)
        steps = [r[1].get("step") for r in window if r[1].get("step") is not None]
        ddms[cid] = {
            "decision_p50_ms": None if last is None else _r(last[1].get("decision_p50")),
            "decision_p99_ms": None if last is None else _r(last[1].get("decision_p99")),
            "step_ms_max": _r(max(steps)) if steps else None,
            "health_periods": len(window),
        }
    return {"corridors": n_corridors, "rsus_per_corridor": n_rsus, "rate_hz": rate_hz, "window_s": round(span, 1),
            "object_lists_per_s_offered": round(n_corridors * n_rsus * rate_hz, 1),
            "ddm": ddms, "router_cpu_cores": cpu, "router_bytes_per_s": bps, "exited_early": exited,
            "run_dir": str(run_dir), "python": sys.executable}


def _r(x: float | None) -> float | None:
    return None if x is None else round(float(x), 2)
