"""The ``iea up`` topology in network namespaces: each role on its own host, joined to its router's host.

``Lab`` is ``deploy.up.Up`` (the same services, signing keys, run monitor and yield judge) with every service
started in its own namespace (``ip netns exec``) in client mode against the router's address on its own link,
as in the compose deployment, and the router (``iea router --listen tcp/0.0.0.0:7447``) in the router's
namespace. ``segments=2`` lays the corridor out as ``iea deploy mesh`` does (``deploy.mesh.mesh_layout``): a core
router with the DDM, the vehicle and the simulator, and a segment router per stretch of road with its RSUs,
linked to the core. The lab's own session (the monitor, the recorder of a fault row) stays in the caller's
namespace and joins the core over the monitor's link, which no fault touches.

``lab_guard`` turns SIGTERM into KeyboardInterrupt (SIGINT already is), so that a ``try/finally`` removes the
lab also when the run is stopped from outside.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import threading
from pathlib import Path

from deploy.host_tuning import HOST_SYSCTLS
from deploy.netlab.net import Net, cleanup_stale, require_lab, used_networks
from deploy.netlab.plan import (
    ZENOH_PORT,
    LabPlan,
    corridor_hosts,
    lab_plan,
    make_prefix,
    mesh_hosts,
    pick_monitor_slot,
)
from deploy.up import ROUTER, Up

LISTEN = f"tcp/0.0.0.0:{ZENOH_PORT}"


@contextlib.contextmanager
def lab_guard():
    """SIGTERM raises KeyboardInterrupt inside the block (SIGINT does by default), so ``finally`` clean-ups run
    when the run is stopped; the previous handlers come back after it. A no-op off the main thread."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def interrupt(signum, _frame):
        raise KeyboardInterrupt(f"signal {signum}")

    old = {s: signal.getsignal(s) for s in (signal.SIGINT, signal.SIGTERM)}
    signal.signal(signal.SIGINT, interrupt)
    signal.signal(signal.SIGTERM, interrupt)
    try:
        yield
    finally:
        for s, h in old.items():
            signal.signal(s, h)


def segment_router_config(core_endpoint: str) -> str:
    """A segment router's Zenoh config: listens on every address of its host, joins the core (waiting for it)."""
    return json.dumps({"mode": "router", "listen": {"endpoints": [LISTEN]},
                       "connect": {"endpoints": [core_endpoint], "timeout_ms": -1},
                       "scouting": {"multicast": {"enabled": False}}}, indent=2) + "\n"


def new_plan(hosts: dict[str, str], hubs: list[str], prefix: str | None = None) -> LabPlan:
    """A plan with a fresh prefix and a monitor link on a /30 no route here uses."""
    prefix = prefix or make_prefix(os.getpid())
    return lab_plan(prefix, hosts, hubs, monitor_slot=pick_monitor_slot(prefix, used_networks()))


class Lab(Up):
    """``Up`` across namespaces: ``start()`` makes the network then starts the services; ``stop()`` stops them
    and removes the network (namespaces, links, rules, processes)."""

    def __init__(self, *, segments: int = 0, prefix: str | None = None, sysctls: dict[str, str] | None = None,
                 **kw) -> None:
        """``segments``: segment routers (0: one router); ``sysctls``: kernel settings of every host
        (``deploy.netlab.net.Net``; None: a corridor host's, ``deploy.host_tuning.HOST_SYSCTLS``); the rest as
        ``Up``."""
        require_lab()
        cleanup_stale()  # what a crashed run left (labs of running processes are left alone)
        kw.setdefault("port", ZENOH_PORT)
        super().__init__(**kw)
        services = [s.name for s in self.specs]
        if segments:
            from deploy.mesh import mesh_layout

            hosts, hubs = mesh_hosts(mesh_layout(self.corridor, segments), services)
        else:
            hosts, hubs = corridor_hosts(services), ["router"]
        self.plan = new_plan(hosts, hubs, prefix)
        self.segments = list(hubs[1:])
        self.net = Net(self.plan, dict(HOST_SYSCTLS if sysctls is None else sysctls))
        self.endpoint = self.plan.endpoint("monitor")  # the lab's own session (Up.start's monitor) joins here
        for spec in self.specs:
            i = spec.args.index("--connect")
            spec.args[i + 1] = self.plan.endpoint(spec.name)
            self.group.launch[spec.name] = self.net.exec_prefix(spec.name)
        self.group.launch[ROUTER] = self.net.exec_prefix(hubs[0])
        for seg in self.segments:
            self.group.launch[f"router-{seg}"] = self.net.exec_prefix(seg)

    def _start_router(self, timeout_s: float = 20.0) -> None:
        """The (core) router in its namespace, then any segment router not running."""
        self._start_one(ROUTER, ["-m", "deploy", "router", "--listen", LISTEN, "--no-multicast"], timeout_s)
        for seg in self.segments:
            if not self.group.running(f"router-{seg}"):
                self._start_segment(seg, timeout_s)

    def _start_segment(self, seg: str, timeout_s: float = 20.0) -> None:
        cfg = self.run_dir / f"router-{seg}.json5"
        cfg.write_text(segment_router_config(self.plan.endpoint(seg)))
        self._start_one(f"router-{seg}", ["-m", "deploy", "router", "--config", str(cfg)], timeout_s)

    def _start_one(self, name: str, args: list[str], timeout_s: float) -> None:
        self.group.start(name, args)
        if not self.group.wait_for_log(name, "router ready", timeout_s):
            log = self.group.log_path(name).read_text(errors="replace")[-2000:]
            raise RuntimeError(f"router {name} did not start in its namespace:\n{log}")

    def start(self, settle_s: float = 2.0, monitor: bool = True, extra_subscribers: list | None = None) -> None:
        self.net.up()
        try:
            super().start(settle_s, monitor, extra_subscribers)
        except BaseException:
            self.stop()
            raise

    def stop(self) -> None:
        try:
            super().stop()
        finally:
            self.net.down()


def run_dir_for(root: Path | None, name: str) -> Path:
    import time
    import uuid

    return (root or Path("runs")) / f"netlab-{name}-{time.strftime('%H%M%S')}-{uuid.uuid4().hex[:4]}"
