"""Namespaces, veth links and the faults on them (``ip``, ``iptables``, ``tc``): the lab's imperative shell.

``Net(plan).up()`` makes the plan's namespaces and links; ``down()`` removes every namespace, interface and
process of the plan's prefix (rules and queueing disciplines go with their namespace). ``cleanup_prefix``
does the same for any prefix, ``cleanup_stale`` for the labs of processes that no longer run (a crashed run).

Faults act on the host's end of a link (its namespace): ``drop`` (iptables ``statistic --mode random``: a
fraction of the packets each way; 1.0: the link cut, packets vanish as on a pulled cable or a radio out of
range), ``cap`` (a ``tbf`` token bucket on the host's egress: its uplink). The kernel here has no ``netem``:
added delay stays with the in-process ``DsrcLink`` model.
"""

from __future__ import annotations

import ipaddress
import json
import os
import shutil
import signal
import subprocess
import time
from dataclasses import dataclass, field

from deploy.netlab.plan import PREFIX_HEAD, LabPlan, Link, owner_pid

CAP_NET_ADMIN = 12
TOOLS = ("ip", "iptables", "tc")


class LabUnavailable(RuntimeError):
    """The lab cannot run here (no CAP_NET_ADMIN, a missing tool): the message says which and what to do."""


def has_net_admin(status_text: str | None = None) -> bool:
    """Whether this process holds CAP_NET_ADMIN (its effective capabilities, /proc/self/status ``CapEff``)."""
    if status_text is None:
        try:
            with open("/proc/self/status") as f:
                status_text = f.read()
        except OSError:
            return False
    for line in status_text.splitlines():
        if line.startswith("CapEff:"):
            return bool(int(line.split()[1], 16) >> CAP_NET_ADMIN & 1)
    return False


def unavailable_reason() -> str | None:
    """Why the lab cannot run here (None: it can): CAP_NET_ADMIN, then the tools."""
    if not has_net_admin():
        return ("the network lab needs CAP_NET_ADMIN (run as root, or in a container with "
                "--cap-add NET_ADMIN) to make network namespaces, veth links and iptables/tc rules")
    missing = [t for t in TOOLS if shutil.which(t) is None]
    if missing:
        return (f"the network lab needs {', '.join(missing)} (Debian: apt-get install iproute2 iptables)")
    return None


def require_lab() -> None:
    reason = unavailable_reason()
    if reason:
        raise LabUnavailable(reason)


def sh(*cmd: str, check: bool = True, timeout_s: float = 10.0) -> subprocess.CompletedProcess:
    """Run one command; a failure raises with the command and its error output."""
    p = subprocess.run(list(cmd), capture_output=True, text=True, timeout=timeout_s)
    if check and p.returncode != 0:
        raise RuntimeError(f"`{' '.join(cmd)}` failed ({p.returncode}): {p.stderr.strip() or p.stdout.strip()}")
    return p


def in_ns(ns: str | None, *cmd: str) -> list[str]:
    """``cmd`` run in namespace ``ns`` (None: here)."""
    return list(cmd) if ns is None else ["ip", "netns", "exec", ns, *cmd]


# ---------------------------------------------------------------------------------------------- inventory
def namespaces(prefix: str = PREFIX_HEAD) -> list[str]:
    out = sh("ip", "netns", "list", check=False).stdout
    return [line.split()[0] for line in out.splitlines() if line.split() and line.split()[0].startswith(prefix)]


def links(prefix: str = PREFIX_HEAD, ns: str | None = None) -> list[str]:
    """Interfaces starting with ``prefix`` in namespace ``ns`` (None: here)."""
    out = sh(*in_ns(ns, "ip", "-j", "link", "show"), check=False).stdout
    try:
        rows = json.loads(out or "[]")
    except json.JSONDecodeError:
        return []
    return [r["ifname"] for r in rows if r.get("ifname", "").startswith(prefix)]


def ns_pids(ns: str) -> list[int]:
    out = sh("ip", "netns", "pids", ns, check=False).stdout
    return [int(x) for x in out.split() if x.isdigit()]


def leftovers(prefix: str) -> dict[str, list]:
    """What a lab of ``prefix`` left: its namespaces, its interfaces here, the processes in its namespaces
    (the rules and queueing disciplines live in the namespaces)."""
    nss = namespaces(prefix)
    return {"namespaces": nss, "links": links(prefix), "processes": [p for ns in nss for p in ns_pids(ns)]}


def used_networks() -> list[ipaddress.IPv4Network]:
    """The IPv4 networks routed here (the monitor link must not overlap them)."""
    out = sh("ip", "-4", "-j", "route", "show", "table", "all", check=False).stdout
    nets = []
    for r in json.loads(out or "[]"):
        dst = r.get("dst", "")
        if dst in ("default", "") or r.get("type") in ("broadcast",):
            continue
        try:
            nets.append(ipaddress.ip_network(dst if "/" in dst else f"{dst}/32", strict=False))
        except ValueError:
            continue
    return [n for n in nets if n.prefixlen > 0]


# ---------------------------------------------------------------------------------------------- clean-up
def cleanup_prefix(prefix: str, term_wait_s: float = 3.0) -> dict[str, list]:
    """Remove every namespace and interface whose name starts with ``prefix``, after stopping the processes
    in those namespaces (SIGTERM, then SIGKILL after ``term_wait_s``); returns what was there."""
    found = leftovers(prefix)
    pids = found["processes"]
    for sig, wait in ((signal.SIGTERM, term_wait_s), (signal.SIGKILL, 2.0)):
        alive = [p for p in pids if _alive(p)]
        for p in alive:
            try:
                os.kill(p, sig)
            except ProcessLookupError:
                pass
        deadline = time.monotonic() + wait
        while alive and time.monotonic() < deadline:
            alive = [p for p in alive if _alive(p)]
            time.sleep(0.05)
    for ns in found["namespaces"]:
        sh("ip", "netns", "del", ns, check=False)
    for ifname in links(prefix):  # the veth ends here go with their peer's namespace; anything else left
        sh("ip", "link", "del", ifname, check=False)
    return found


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # a zombie child of ours has exited: reap it
        done, _ = os.waitpid(pid, os.WNOHANG)
        return done == 0
    except ChildProcessError:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(") ", 1)[-1][:1] != "Z"


def cleanup_stale() -> list[str]:
    """Remove the labs whose making process no longer runs (a run killed before its clean-up); returns their
    prefixes. Labs of running processes (parallel runs) are left alone."""
    names = set(namespaces()) | set(links())
    stale = sorted({n[:len(PREFIX_HEAD) + 6] for n in names
                    if (pid := owner_pid(n)) is not None and not os.path.exists(f"/proc/{pid}")})
    for prefix in stale:
        cleanup_prefix(prefix)
    return stale


# ---------------------------------------------------------------------------------------------- the network
@dataclass
class Net:
    """The namespaces and links of ``plan``; ``up()`` then ``down()`` (idempotent; also as a context)."""

    plan: LabPlan
    sysctls: dict[str, str] = field(default_factory=dict)
    """Kernel settings of every namespace of the lab (``net.ipv4.*`` is per namespace), e.g.
    ``net.ipv4.tcp_thin_linear_timeouts=1``: what its hosts' kernels would be tuned to."""
    made: bool = False
    rules: dict[str, list[list[str]]] = field(default_factory=dict)
    """Per namespace, the iptables rules in force (to take them out one by one)."""

    def up(self) -> Net:
        require_lab()
        self.made = True  # from the first namespace on, down() has something to remove
        try:
            for ns in self.plan.namespaces():
                sh("ip", "netns", "add", ns)
                sh("ip", "-n", ns, "link", "set", "lo", "up")
                for key, value in self.sysctls.items():
                    sh("ip", "netns", "exec", ns, "sysctl", "-q", "-w", f"{key}={value}")
            for link in self.plan.links:
                self._link(link)
        except BaseException:
            self.down()
            raise
        return self

    def _link(self, link: Link) -> None:
        sh("ip", "link", "add", link.host_if, "type", "veth", "peer", "name", link.hub_if)
        sh("ip", "link", "set", link.hub_if, "netns", link.hub_ns)
        if link.host_ns is not None:
            sh("ip", "link", "set", link.host_if, "netns", link.host_ns)
        for ns, ifname, ip in ((link.host_ns, link.host_if, link.host_ip), (link.hub_ns, link.hub_if, link.hub_ip)):
            sh(*in_ns(ns, "ip", "addr", "add", f"{ip}/{link.prefixlen}", "dev", ifname))
            sh(*in_ns(ns, "ip", "link", "set", ifname, "up"))

    def down(self) -> dict[str, list]:
        if not self.made:
            return {}
        self.made = False
        self.rules.clear()
        return cleanup_prefix(self.plan.prefix)

    def __enter__(self) -> Net:
        return self.up()

    def __exit__(self, *exc: object) -> None:
        self.down()

    def exec_prefix(self, name: str) -> list[str]:
        """The command prefix that runs a program on host (or hub) ``name``."""
        return in_ns(self.plan.ns(name))

    # ------------------------------------------------------------------------------------------ faults
    def _iptables(self, ns: str | None, op: str, spec: list[str]) -> None:
        if ns is None:
            raise ValueError("the lab puts no rule in its caller's namespace (the monitor's link is never faulted)")
        sh("ip", "netns", "exec", ns, "iptables", "-w", op, *spec)

    def drop(self, host: str, fraction: float, hub_side: bool = False) -> None:
        """Drop ``fraction`` of the packets each way on ``host``'s link (1.0: cut). ``hub_side``: at the hub's
        end (a host whose own namespace must stay untouched)."""
        if not 0.0 < fraction <= 1.0:
            raise ValueError(f"drop fraction must be in (0, 1], got {fraction}")
        link = self.plan.link(host)
        ns, ifname = (link.hub_ns, link.hub_if) if hub_side else (link.host_ns, link.host_if)
        match = [] if fraction >= 1.0 else ["-m", "statistic", "--mode", "random", "--probability", f"{fraction:.4f}"]
        for chain, flag in (("INPUT", "-i"), ("OUTPUT", "-o")):
            spec = [chain, flag, ifname, *match, "-j", "DROP"]
            self._iptables(ns, "-I", spec)
            self.rules.setdefault(ns, []).append(spec)

    def cut_hub(self, hub: str) -> None:
        """Cut every link of ``hub`` to its hosts (the monitor's excepted: it keeps watching)."""
        for link in self.plan.links:
            if link.hub == hub and link.host_ns is not None:
                self.drop(link.host, 1.0, hub_side=True)
        for link in self.plan.links:  # a hub's own uplink (a segment router to the core)
            if link.host == hub:
                self.drop(hub, 1.0)

    def restore(self) -> None:
        """Take out every drop rule in force."""
        for ns, specs in list(self.rules.items()):
            for spec in specs:
                self._iptables(ns, "-D", spec)
        self.rules.clear()

    def cap(self, host: str, rate_bit_s: float, queue_latency_s: float = 0.2) -> None:
        """A token bucket (tbf) of ``rate_bit_s`` on ``host``'s egress (its uplink to the hub)."""
        if rate_bit_s <= 0:
            raise ValueError(f"rate must be positive, got {rate_bit_s}")
        link = self.plan.link(host)
        burst_b = max(3200, int(rate_bit_s / 8 * 0.02))  # 20 ms of the rate, at least two full frames
        sh(*in_ns(link.host_ns, "tc", "qdisc", "replace", "dev", link.host_if, "root", "tbf", "rate",
                  f"{int(rate_bit_s)}bit", "burst", str(burst_b), "latency", f"{int(queue_latency_s * 1000)}ms"))

    def uncap(self, host: str) -> None:
        link = self.plan.link(host)
        sh(*in_ns(link.host_ns, "tc", "qdisc", "del", "dev", link.host_if, "root"), check=False)

    def link_bytes(self, host: str, hub_side: bool = True) -> tuple[int, int]:
        """(rx, tx) bytes of ``host``'s link, counted at the hub's end (what its router received and sent)."""
        link = self.plan.link(host)
        ns, ifname = (link.hub_ns, link.hub_if) if hub_side else (link.host_ns, link.host_if)
        rows = json.loads(sh(*in_ns(ns, "ip", "-s", "-j", "link", "show", "dev", ifname)).stdout)
        st = rows[0]["stats64"]
        return int(st["rx"]["bytes"]), int(st["tx"]["bytes"])
