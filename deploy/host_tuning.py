"""The kernel settings of a corridor host: what the compose deployment and the network lab give every service.

The corridor's safety traffic travels as thin TCP streams (a command, its ack, an alert, a heartbeat: a few
packets in flight at a time, Zenoh's links being TCP). When a link drops out, Linux retransmits with an
exponentially backed-off timeout (RFC 6298 5.5: 0.2, 0.4, 0.8, 1.6 s ...), so after a 2 s outage the next
retransmission may come up to 1.6 s after the link is back: a DDM cut off for 2 s was heard again by the
vehicle only after 3.6 s, past its 3.5 s link watchdog (the network lab's "DDM host cut 2 s" row on default
kernels). ``net.ipv4.tcp_thin_linear_timeouts`` keeps the timeout linear for the first six retransmissions of
a stream with fewer than four packets in flight (Petlund et al., "Improving application layer latency for
reliable thin-stream game traffic", 2008; Linux ``Documentation/networking/ip-sysctl.rst``), which leaves bulk
streams alone. It is a per-network-namespace setting: a container (``sysctls:`` in compose) or a namespace
sets it for itself without touching the host's.
"""

from __future__ import annotations

HOST_SYSCTLS: dict[str, str] = {"net.ipv4.tcp_thin_linear_timeouts": "1"}
"""Kernel settings of every corridor host (each a per-namespace ``net.*`` key)."""
