"""The address plan of a network lab. Pure.

A lab is a star (or a tree, for a mesh) of network namespaces: each *host* (a role: the DDM, an RSU, the
vehicle, the simulator) is one namespace joined to its *hub* (the namespace of the Zenoh router it talks to) by
one veth link, a /30 of its own (the hub's end ``.1``, the host's ``.2``). The host ``monitor`` stays in the
namespace of the process that runs the lab (where the bench and the tests listen); its link takes a /30 out of
``MONITOR_NET`` that no route there uses yet.

Every name a lab makes starts with its prefix, ``PREFIX_HEAD`` + the running process's id in base 36 + a
counter: parallel labs never collide, and leftovers of a crashed run name the process that made them
(``owner_pid``), so a clean-up removes only what a dead process left.
"""

from __future__ import annotations

import ipaddress
import itertools
from dataclasses import dataclass

PREFIX_HEAD = "nl"
"""Every namespace and interface of a lab starts with this."""
IFNAME_MAX = 15
"""Linux interface names: at most 15 characters (IFNAMSIZ - 1)."""
HOST_NET = ipaddress.ip_network("10.99.0.0/16")
"""The links between namespaces of one lab (/30 each); they live only inside the lab's namespaces."""
MONITOR_NET = ipaddress.ip_network("10.200.0.0/14")
"""The monitor's link (/30) out of the lab's own namespaces: the one address range the lab adds to its caller's."""
MONITOR = "monitor"
"""The host that stays in the caller's namespace (its processes: the bench, the tests)."""
ZENOH_PORT = 7447
_B36 = "0123456789abcdefghijklmnopqrstuvwxyz"
_counter = itertools.count()


def base36(n: int) -> str:
    if n < 0:
        raise ValueError(f"base36 of a negative number: {n}")
    out = ""
    while True:
        n, r = divmod(n, 36)
        out = _B36[r] + out
        if n == 0:
            return out


def make_prefix(pid: int, run: int | None = None) -> str:
    """``nl`` + pid in base 36 (5 digits: every Linux pid, at most 2^22) + a run counter digit."""
    if not 0 < pid < 36 ** 5:
        raise ValueError(f"pid {pid} out of range")
    run = next(_counter) if run is None else run
    return f"{PREFIX_HEAD}{base36(pid).rjust(5, '0')}{_B36[run % 36]}"


def owner_pid(name: str) -> int | None:
    """The pid that made a namespace or interface named by ``make_prefix`` (None: not a lab name)."""
    if not name.startswith(PREFIX_HEAD) or len(name) < len(PREFIX_HEAD) + 6:
        return None
    digits = name[len(PREFIX_HEAD):len(PREFIX_HEAD) + 5]
    if any(c not in _B36 for c in digits):
        return None
    return int(digits, 36)


@dataclass(frozen=True)
class Link:
    """One veth pair: ``host`` in namespace ``host_ns`` (None: the caller's), ``hub`` in ``hub_ns``."""

    host: str
    hub: str
    host_ns: str | None
    hub_ns: str
    host_if: str
    hub_if: str
    host_ip: str
    hub_ip: str
    prefixlen: int = 30


@dataclass(frozen=True)
class LabPlan:
    prefix: str
    hubs: tuple[str, ...]
    """Router namespaces, in start order (a mesh's core first)."""
    links: tuple[Link, ...]

    def ns(self, name: str) -> str | None:
        """The namespace of host or hub ``name`` (None: the monitor, in the caller's)."""
        if name == MONITOR:
            return None
        if name not in self.hubs and all(link.host != name for link in self.links):
            raise KeyError(f"no host or hub {name!r} in the lab (it has {', '.join(self.names())})")
        return f"{self.prefix}-{name}"

    def names(self) -> list[str]:
        """Hubs, then hosts (a mesh's segment router is both: once)."""
        return list(dict.fromkeys([*self.hubs, *(link.host for link in self.links)]))

    def namespaces(self) -> list[str]:
        """Every namespace the lab makes (hubs first)."""
        return [f"{self.prefix}-{n}" for n in self.names() if n != MONITOR]

    def link(self, host: str) -> Link:
        """The link of ``host`` to its hub (a hub that hangs off another hub: its uplink)."""
        for link in self.links:
            if link.host == host:
                return link
        raise KeyError(f"no link for host {host!r} (hosts: {', '.join(x.host for x in self.links)})")

    def endpoint(self, host: str, port: int = ZENOH_PORT) -> str:
        """Where ``host`` reaches its router: the hub's end of its link."""
        return f"tcp/{self.link(host).hub_ip}:{port}"

    def hosts_of(self, hub: str) -> list[str]:
        return [link.host for link in self.links if link.hub == hub]


def lab_plan(prefix: str, hosts: dict[str, str], hubs: list[str], monitor_slot: int = 0,
             monitor_hub: str | None = None) -> LabPlan:
    """The plan for ``hosts`` (host -> its hub; a hub may itself be a host of another hub: a mesh's segment
    router hangs off the core) with ``hubs`` (router namespaces, core first) and the monitor's link on the
    first hub (or ``monitor_hub``) in /30 number ``monitor_slot`` of ``MONITOR_NET``."""
    if not hubs:
        raise ValueError("a lab needs at least one hub (router namespace)")
    if len(set(hubs)) != len(hubs):
        raise ValueError(f"hub names repeat: {hubs}")
    for host, hub in hosts.items():
        if hub not in hubs:
            raise ValueError(f"host {host!r} joins hub {hub!r}, which is not one of {hubs}")
        if host == MONITOR:
            raise ValueError(f"{MONITOR!r} is the caller's own host: it is added by the plan")
        if host == hub:
            raise ValueError(f"host {host!r} cannot be its own hub")
    n_links = len(hosts) + 1
    if n_links > HOST_NET.num_addresses // 4:
        raise ValueError(f"{n_links} links do not fit in {HOST_NET}")
    slots = MONITOR_NET.num_addresses // 4
    if not 0 <= monitor_slot < slots:
        raise ValueError(f"monitor_slot must be in 0..{slots - 1}, got {monitor_slot}")
    links = []
    for i, (host, hub) in enumerate(hosts.items()):
        base = HOST_NET.network_address + 4 * (i + 1)
        links.append(_link(prefix, i + 1, host, hub, f"{prefix}-{host}", f"{prefix}-{hub}", base))
    mbase = MONITOR_NET.network_address + 4 * monitor_slot
    mhub = monitor_hub or hubs[0]
    links.append(_link(prefix, 0, MONITOR, mhub, None, f"{prefix}-{mhub}", mbase))
    return LabPlan(prefix, tuple(hubs), tuple(links))


def _link(prefix: str, i: int, host: str, hub: str, host_ns: str | None, hub_ns: str,
          base: ipaddress.IPv4Address) -> Link:
    host_if, hub_if = f"{prefix}{i}h", f"{prefix}{i}r"
    if len(host_if) > IFNAME_MAX:
        raise ValueError(f"interface name {host_if!r} longer than {IFNAME_MAX} characters")
    return Link(host, hub, host_ns, hub_ns, host_if, hub_if, str(base + 2), str(base + 1))


def monitor_slot_free(slot: int, used: list[ipaddress.IPv4Network]) -> bool:
    """Whether /30 number ``slot`` of ``MONITOR_NET`` overlaps none of ``used`` (the caller's routes)."""
    net = ipaddress.ip_network(f"{MONITOR_NET.network_address + 4 * slot}/30")
    return not any(net.overlaps(u) for u in used)


def pick_monitor_slot(prefix: str, used: list[ipaddress.IPv4Network]) -> int:
    """A /30 of ``MONITOR_NET`` free in the caller's routes, starting from one derived from the prefix (so
    parallel labs start apart)."""
    slots = MONITOR_NET.num_addresses // 4
    start = int.from_bytes(prefix.encode(), "big") % slots
    for k in range(slots):
        slot = (start + k) % slots
        if monitor_slot_free(slot, used):
            return slot
    raise RuntimeError(f"no free /30 left in {MONITOR_NET} for the lab's monitor link")


def corridor_hosts(services: list[str], hub: str = "router") -> dict[str, str]:
    """The ``iea up`` topology: every service its own host on one router."""
    return {s: hub for s in services}


def mesh_hosts(layout: dict[str, str], services: list[str]) -> tuple[dict[str, str], list[str]]:
    """The two-level mesh (``deploy.mesh.mesh_layout``: service -> ``core`` / ``segN``): the core and each
    segment router their own hub, each segment router a host of the core; a service not in the layout (the
    simulator, the vehicle under its process name) joins the core."""
    segs = sorted({r for r in layout.values() if r != "core"})
    hosts: dict[str, str] = {s: "core" for s in segs}
    for s in services:
        hosts[s] = layout.get(s, "core")
    return hosts, ["core", *segs]
