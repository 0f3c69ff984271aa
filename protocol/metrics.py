"""Prometheus metrics of a service: ``--metrics-port PORT`` on iea-rsu, iea-ddm, iea-vehicle, iea-sim.

Off by default: until ``serve`` is called every hook below is a no-op (one ``is None`` test), so the
lockstep runner and the tests pay nothing. A service process serves one registry (``prometheus_client``)
at ``http://HOST:PORT/metrics``:

- ``iea_stage_latency_seconds{stage}``: histogram per processing stage, observed per frame or step
  (RSU: detect, track, classify, localize, hazard, publish; DDM: decision, step; vehicle: control; sim: step);
- ``iea_processed_fps{name}``: the rates of the service's own Health (``rates_hz``: frames, steps...);
- ``iea_messages_published_total{kind}``, ``iea_messages_received_total{kind}`` and
  ``iea_messages_dropped_total{kind, reason}`` (refused at decode: ``protocol.codec`` reasons);
- ``iea_rejected_inputs{reason}`` and ``iea_drops{name}``: the service's own Health counters;
- ``iea_commands_total{state}``: commands issued (DDM), acks by status (sent by a vehicle, received by
  the DDM);
- ``iea_link_up{peer}``: 1 while a peer's Health arrives (within ``LINK_STALE_S``), else 0;
  ``iea_health_status`` 0 ok, 1 degraded, 2 error.

The hooks are called by ``protocol.transport.Transport`` (publish / subscribe: every message of every
transport, whatever wraps it) and by the services' loops (``observe_stages``).
"""

from __future__ import annotations

import argparse
import threading
import time
from typing import Any

STAGE_BUCKETS_S = (0.0005, 0.001, 0.002, 0.005, 0.01, 0.02, 0.035, 0.05, 0.075, 0.1, 0.15, 0.25, 0.5, 1.0, 2.5)
LINK_STALE_S = 3.0
_STATUS = {"ok": 0, "degraded": 1, "error": 2}


class ServiceMetrics:
    """The metrics of one service and their HTTP endpoint (its own registry, not the global one)."""

    def __init__(self, role: str, node: str) -> None:
        from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram

        self.registry = r = CollectorRegistry()
        self.role, self.node = role, node
        r.register(_LinkRefresher(self))  # first: a scrape brings iea_link_up up to date before reading it
        Gauge("iea_service_info", "The service this endpoint belongs to", ["role", "node"], registry=r).labels(
            role, node).set(1)
        self.stage = Histogram("iea_stage_latency_seconds", "Processing time per stage, per frame or step",
                               ["stage"], buckets=STAGE_BUCKETS_S, registry=r)
        self.fps = Gauge("iea_processed_fps", "Processing rates of the service's Health (per second)", ["name"],
                         registry=r)
        self.published = Counter("iea_messages_published", "Messages published, by kind", ["kind"], registry=r)
        self.received = Counter("iea_messages_received", "Valid messages received, by kind", ["kind"], registry=r)
        self.dropped = Counter("iea_messages_dropped", "Messages refused at decode, by kind and reason",
                               ["kind", "reason"], registry=r)
        self.rejected = Gauge("iea_rejected_inputs", "Inputs refused at the boundary, by reason (service's Health)",
                              ["reason"], registry=r)
        self.drops = Gauge("iea_drops", "Drop counters of the service's Health", ["name"], registry=r)
        self.commands = Counter("iea_commands", "Commands issued and acks by status", ["state"], registry=r)
        self.link = Gauge("iea_link_up", "1 while the peer's Health arrives", ["peer"], registry=r)
        self.status = Gauge("iea_health_status", "The service's own status: 0 ok, 1 degraded, 2 error", registry=r)
        self._peers: dict[str, float] = {}
        self._commands_seen: set[str] = set()
        self._lock = threading.Lock()
        self.server: Any = None

    # ------------------------------------------------------------------ hooks
    def observe_stages(self, stage_s: dict[str, float]) -> None:
        for stage, seconds in stage_s.items():
            if seconds >= 0:
                self.stage.labels(stage).observe(seconds)

    def on_published(self, key: str, message: Any) -> None:
        kind = message.KIND
        self.published.labels(kind).inc()
        if kind == "Health":
            self.status.set(_STATUS.get(message.status.value, 2))
            for name, v in message.rates_hz.items():
                self.fps.labels(name).set(v)
            for reason, n in message.rejected.items():
                self.rejected.labels(reason).set(n)
            for name, n in message.drops.items():
                self.drops.labels(name).set(n)
        elif kind == "PathSwitchCommand":
            with self._lock:
                new = message.command_id not in self._commands_seen
                if new and len(self._commands_seen) < 100_000:
                    self._commands_seen.add(message.command_id)
            self.commands.labels("issued" if new else "retransmitted").inc()
        elif kind == "CommandAck":
            self.commands.labels(f"ack_{message.status.value}").inc()

    def on_received(self, key: str, message: Any) -> None:
        kind = message.KIND
        self.received.labels(kind).inc()
        if kind == "Health":
            peer = message.src if message.src else key
            with self._lock:
                if peer in self._peers or len(self._peers) < 1024:
                    self._peers[peer] = time.monotonic()
        elif kind == "CommandAck":
            self.commands.labels(f"ack_{message.status.value}_received").inc()

    def on_rejected(self, key: str, reason: str) -> None:
        kind = key.rsplit("/", 1)[-1] if isinstance(key, str) else "?"
        self.dropped.labels(kind, reason).inc()

    def refresh_links(self) -> None:
        now = time.monotonic()
        with self._lock:
            peers = dict(self._peers)
        for peer, t in peers.items():
            self.link.labels(peer).set(1 if now - t <= LINK_STALE_S else 0)

    # ------------------------------------------------------------------ endpoint
    def serve(self, port: int, host: str = "0.0.0.0") -> int:
        """Serve ``/metrics`` on ``host:port`` (0: any free port); returns the port."""
        from prometheus_client import start_http_server

        self.server, _thread = start_http_server(port, addr=host, registry=self.registry)
        return int(self.server.server_address[1])

    def close(self) -> None:
        if self.server is not None:
            self.server.shutdown()
            self.server.server_close()
            self.server = None


class _LinkRefresher:
    """A collector with no metrics of its own: brings ``iea_link_up`` up to date at every scrape."""

    def __init__(self, metrics: ServiceMetrics) -> None:
        self.metrics = metrics

    def collect(self):
        if hasattr(self.metrics, "link"):  # (the registry also calls this once at registration)
            self.metrics.refresh_links()
        return iter(())


_active: ServiceMetrics | None = None


def active() -> ServiceMetrics | None:
    return _active


def serve(role: str, node: str, port: int, host: str = "0.0.0.0") -> ServiceMetrics:
    """Start this process's metrics endpoint; the hooks report to it from now on."""
    global _active
    m = ServiceMetrics(role, node)
    m.serve(port, host)
    _active = m
    return m


def stop() -> None:
    global _active
    m, _active = _active, None
    if m is not None:
        m.close()


def observe_stages(stage_s: dict[str, float]) -> None:
    if _active is not None:
        _active.observe_stages(stage_s)


def on_published(key: str, message: Any) -> None:
    if _active is not None:
        _active.on_published(key, message)


def on_received(key: str, message: Any) -> None:
    if _active is not None:
        _active.on_received(key, message)


def on_rejected(key: str, reason: str) -> None:
    if _active is not None:
        _active.on_rejected(key, reason)


def add_arguments(ap: argparse.ArgumentParser) -> None:
    g = ap.add_argument_group("metrics (Prometheus)")
    g.add_argument("--metrics-port", type=int, default=None, metavar="PORT",
                   help="serve Prometheus metrics on http://HOST:PORT/metrics (default: off)")
    g.add_argument("--metrics-host", default="0.0.0.0", help="address of the metrics endpoint (default 0.0.0.0)")


def serve_from_args(args: argparse.Namespace, role: str, node: str) -> ServiceMetrics | None:
    """``serve`` when ``--metrics-port`` was given (a port in use raises OSError naming it)."""
    port = getattr(args, "metrics_port", None)
    if port is None:
        return None
    if not 0 <= port <= 65535:
        raise ValueError(f"--metrics-port must be in 0..65535, got {port}")
    try:
        return serve(role, node, port, getattr(args, "metrics_host", "0.0.0.0"))
    except OSError as exc:
        raise ValueError(f"--metrics-port {port}: cannot serve metrics there ({exc})") from None
