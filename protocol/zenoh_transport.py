"""Zenoh transport (eclipse-zenoh 1.x) behind the ``protocol.transport.Transport`` interface.

``ZenohSettings`` says how a service joins (peer on loopback by default, client of routers with
``--connect``); ``ZenohTransport`` maps the interface onto a session: publishers declared once per key
with their kind's QoS (``protocol.qos``), subscribers (bulk kinds through a ring channel drained by a
worker thread), liveliness tokens and subscribers, queryables and ``session.get``. Only this module
imports zenoh: ``protocol.transport`` holds the interface, ``LocalBus`` and ``DsrcLink``.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from protocol.keys import key_matches
from protocol.qos import QosClass, is_bulk_expr, is_command_expr, is_control_expr, qos_for_key
from protocol.transport import BytesCallback, PresenceCallback, QueryHandler, Subscription, Transport

log = logging.getLogger("protocol.transport")

ENV_MODE = "IEA_ZENOH_MODE"
ENV_CONNECT = "IEA_ZENOH_CONNECT"
ENV_LISTEN = "IEA_ZENOH_LISTEN"
ENV_CONFIG = "IEA_ZENOH_CONFIG"


@dataclass
class ZenohSettings:
    """How a service joins Zenoh. Precedence: CLI flags > environment > config file > defaults."""

    mode: str = "peer"
    connect: list[str] = field(default_factory=list)
    listen: list[str] = field(default_factory=list)
    config_file: str | None = None
    multicast_interface: str = "lo"
    """Scouting stays on loopback unless told otherwise (peer mode, no router needed)."""

    def __post_init__(self) -> None:
        if self.mode not in ("peer", "client", "router"):
            raise ValueError(f"zenoh mode must be peer, client or router, got {self.mode!r}")
        for ep in [*self.connect, *self.listen]:
            if "/" not in ep:
                raise ValueError(f"zenoh endpoint {ep!r} must look like tcp/127.0.0.1:7447")
        if self.mode == "client" and not self.connect:
            raise ValueError("zenoh client mode needs --connect tcp/HOST:PORT (a router to join)")

    @staticmethod
    def add_arguments(parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("transport (Zenoh)")
        g.add_argument("--connect", action="append", metavar="ENDPOINT", default=None,
                       help="join a Zenoh router, e.g. tcp/127.0.0.1:7447 (repeatable; implies --mode client "
                            f"unless --mode is given). Env: {ENV_CONNECT} (comma-separated)")
        g.add_argument("--listen", action="append", metavar="ENDPOINT", default=None,
                       help=f"also listen on this endpoint (repeatable). Env: {ENV_LISTEN}")
        g.add_argument("--mode", choices=["peer", "client"], default=None,
                       help=f"Zenoh session mode (default: peer on loopback, client with --connect). Env: {ENV_MODE}")
        g.add_argument("--zenoh-config", metavar="FILE", default=None,
                       help=f"a Zenoh JSON5 config file applied before the flags. Env: {ENV_CONFIG}")

    @classmethod
    def from_args(cls, args: argparse.Namespace, env: dict[str, str] | None = None) -> ZenohSettings:
        env = dict(os.environ) if env is None else env
        split = lambda v: [x.strip() for x in v.split(",") if x.strip()]  # noqa: E731
        connect = args.connect if args.connect else split(env.get(ENV_CONNECT, ""))
        listen = args.listen if args.listen else split(env.get(ENV_LISTEN, ""))
        mode = args.mode or env.get(ENV_MODE) or ("client" if connect else "peer")
        config_file = args.zenoh_config or env.get(ENV_CONFIG) or None
        if config_file and not os.path.isfile(config_file):
            raise ValueError(f"zenoh config file {config_file!r} does not exist")
        return cls(mode=mode, connect=connect, listen=listen, config_file=config_file)

    def to_config(self) -> Any:
        import zenoh

        conf = zenoh.Config.from_file(self.config_file) if self.config_file else zenoh.Config()
        conf.insert_json5("mode", json.dumps(self.mode))
        if self.connect:
            conf.insert_json5("connect/endpoints", json.dumps(self.connect))
        if self.listen:
            conf.insert_json5("listen/endpoints", json.dumps(self.listen))
        elif self.mode == "peer" and not self.config_file:
            conf.insert_json5("listen/endpoints", json.dumps(["tcp/127.0.0.1:0"]))
        if self.mode == "peer" and not self.config_file and self.multicast_interface:
            conf.insert_json5("scouting/multicast/interface", json.dumps(self.multicast_interface))
        return conf


BULK_THREAD_NICE = 19
"""Niceness of the thread that decodes bulk samples (object lists, snapshots, video)."""
BULK_SWITCH_INTERVAL_S = 0.0001
"""The interpreter's GIL switch interval in a process with a bulk subscription: a command callback waiting
for the GIL while the bulk thread decodes waits at most this long (plus the C call in progress). Python's
default is 5 ms. ``bench/zenoh_bench.py --modes prio --flood-only`` on a 2-core AMD EPYC, command
p99 under the flood with 1 ms 4.96-5.68 ms in 5 runs, 0.2 ms 3.87-5.02 in 5, 0.1 ms 3.42-5.00 in 4."""


class ZenohTransport(Transport):
    """eclipse-zenoh 1.x session. Publishers are declared once per key with their kind's QoS
    (``protocol.qos``: priority, congestion control, express; ``qos`` overrides the table)."""

    def __init__(self, settings: ZenohSettings | None = None, *,
                 qos: Callable[[str], QosClass] = qos_for_key, bulk_queue: int = 16,
                 stream_connection: bool = False, command_connections: int = 1) -> None:
        super().__init__()
        import zenoh

        self._zenoh = zenoh
        self.settings = settings or ZenohSettings()
        self.qos = qos
        self.bulk_queue = bulk_queue
        """Samples kept per bulk subscription (0: deliver bulk on the network thread, as other kinds)."""
        self.stream_connection = stream_connection
        """Commands, acks and beats (``protocol.qos.CONTROL_TOPICS``) alone on the main Zenoh session; every
        other publisher and subscription (state, object lists, alerts) on another Zenoh session, its own
        connection to the router. On a lossy link TCP delivers a connection's bytes in order and at 50 % loss
        carries a few kB/s: a command or an ack queued behind other kinds' bytes waits for every retransmission of
        theirs; on a connection of its own it waits only for its own. Liveliness and queries stay on the main."""
        if command_connections < 1:
            raise ValueError(f"command_connections must be >= 1, got {command_connections}")
        self.command_connections = command_connections
        """Commands and acks (``protocol.qos.COMMAND_TOPICS``) published and subscribed on this many sessions, each its
        own connection: a copy is late only when every connection is stalled at once (path diversity, as a radio
        repeats a frame on several channels). Receivers see duplicates; commands and acks are idempotent."""
        self.session = zenoh.open(self.settings.to_config())
        self._stream_session: Any = None
        self._command_sessions: list[Any] = []
        self._publishers: dict[str, Any] = {}
        self._copy_publishers: dict[str, list[Any]] = {}
        self._subs: list[Any] = []
        self._drains: list[threading.Thread] = []
        self._lock = threading.Lock()
        self._sessions_lock = threading.Lock()
        """Guards opening the stream and extra command sessions (``_lock`` may be held while one is opened)."""
        self._closed = False

    def publish_bytes(self, key: str, payload: bytes) -> None:
        self._publisher(key).put(payload)
        for pub in self._copies(key):
            pub.put(payload)

    def _copies(self, key: str) -> list[Any]:
        """The publishers of ``key`` on the extra command sessions (none unless ``command_connections`` > 1)."""
        if not self._extra_sessions_carry(key):
            return []
        copies = self._copy_publishers.get(key)
        if copies is None:
            with self._lock:
                copies = [self._declare_publisher(sess, key) for sess in self._extra_command_sessions()]
                self._copy_publishers[key] = copies
        return copies

    def _extra_sessions_carry(self, key_expr: str) -> bool:
        return self.command_connections > 1 and is_command_expr(key_expr)

    def _extra_command_sessions(self) -> list[Any]:
        with self._sessions_lock:
            while len(self._command_sessions) < self.command_connections - 1:
                self._command_sessions.append(self._zenoh.open(self.settings.to_config()))
            return list(self._command_sessions)

    def wait_for_subscribers(self, key: str, timeout_s: float) -> bool:
        """Poll the key's publisher's matching status (zenoh ``Publisher.matching_status``) until a remote
        subscriber is known: a peer that publishes right after opening its session may not have heard the
        others' subscriptions yet, and a put with no matching subscriber goes nowhere."""
        pub = self._publisher(key)
        deadline = time.monotonic() + max(0.0, timeout_s)
        while not pub.matching_status.matching:
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.01)
        return True

    def _publisher(self, key: str) -> Any:
        pub = self._publishers.get(key)
        if pub is None:
            with self._lock:
                pub = self._publishers.get(key)
                if pub is None:
                    pub = self._declare_publisher(self._session_for(key), key)
                    self._publishers[key] = pub
        return pub

    def _declare_publisher(self, session: Any, key: str) -> Any:
        """A publisher of ``key`` on ``session`` with its kind's QoS."""
        q = self.qos(key)
        return session.declare_publisher(key, congestion_control=getattr(self._zenoh.CongestionControl, q.congestion),
                                         priority=getattr(self._zenoh.Priority, q.priority), express=q.express)

    def subscribe_bytes(self, key_expr: str, callback: BytesCallback) -> Subscription:
        def on_sample(sample: Any) -> None:
            try:
                callback(str(sample.key_expr), sample.payload.to_bytes())
            except Exception:  # never raise into zenoh's thread
                log.exception("subscriber callback on %s failed", key_expr)

        if self.bulk_queue > 0 and is_bulk_expr(key_expr):
            return self._subscribe_bulk(key_expr, callback)
        main = self._declared(self._session_for(key_expr).declare_subscriber(key_expr, on_sample))
        if not self._extra_sessions_carry(key_expr):
            return main
        copies = [self._declared(sess.declare_subscriber(key_expr, on_sample))
                  for sess in self._extra_command_sessions()]

        def close() -> None:
            for sub in (main, *copies):
                sub.close()

        return Subscription(close)

    def _subscribe_bulk(self, key_expr: str, callback: BytesCallback) -> Subscription:
        """A ring channel (zenoh drops the oldest sample when full, without the GIL) drained by a worker."""
        sub = self._session_for(key_expr).declare_subscriber(key_expr, self._zenoh.handlers.RingChannel(self.bulk_queue))
        # a decode in the worker holds the GIL; let the network thread's callbacks in every BULK_SWITCH_INTERVAL_S
        sys.setswitchinterval(min(sys.getswitchinterval(), BULK_SWITCH_INTERVAL_S))

        def drain() -> None:
            try:  # bulk decoding yields the CPU to the threads that carry commands and alerts (Linux: per thread)
                os.setpriority(os.PRIO_PROCESS, threading.get_native_id(), BULK_THREAD_NICE)
            except (AttributeError, OSError):
                pass
            while True:
                try:
                    sample = sub.handler.recv()
                except Exception:  # undeclared, or the session closed
                    return
                try:
                    callback(str(sample.key_expr), sample.payload.to_bytes())
                except Exception:
                    log.exception("bulk subscriber callback on %s failed", key_expr)
                time.sleep(0)  # hand the GIL over between samples: a waiting command callback runs now

        worker = threading.Thread(target=drain, name=f"bulk {key_expr}", daemon=True)
        worker.start()
        self._drains = [t for t in self._drains if t.is_alive()] + [worker]  # those of closed subscriptions ended
        return self._declared(sub)

    def _session_for(self, key_expr: str) -> Any:
        if not self.stream_connection or is_control_expr(key_expr):
            return self.session
        with self._sessions_lock:
            if self._stream_session is None:
                self._stream_session = self._zenoh.open(self.settings.to_config())
            return self._stream_session

    def _declared(self, entity: Any) -> Subscription:
        """Keep ``entity`` (subscriber, token, queryable) until closed here or with the session."""
        with self._lock:
            self._subs.append(entity)

        def close() -> None:
            with self._lock:
                if entity in self._subs:
                    self._subs.remove(entity)
            try:
                entity.undeclare()
            except Exception:  # session may already be closed
                pass

        return Subscription(close)

    def declare_token(self, key: str) -> Subscription:
        return self._declared(self.session.liveliness().declare_token(key))

    def subscribe_presence(self, key_expr: str, callback: PresenceCallback, *, history: bool = True) -> Subscription:
        put = self._zenoh.SampleKind.PUT

        def on_sample(sample: Any) -> None:
            try:
                callback(str(sample.key_expr), sample.kind == put)
            except Exception:  # never raise into zenoh's thread
                log.exception("presence callback on %s failed", key_expr)

        return self._declared(self.session.liveliness().declare_subscriber(key_expr, on_sample, history=history))

    def query_presence(self, key_expr: str, timeout_s: float = 1.0) -> list[str]:
        replies = self.session.liveliness().get(key_expr, timeout=timeout_s)
        return sorted({str(r.ok.key_expr) for r in replies if r.ok is not None})

    def declare_queryable(self, key_expr: str, handler: QueryHandler) -> Subscription:
        def on_query(query: Any) -> None:
            try:
                expr = str(query.key_expr)
                for key, payload in handler(expr):
                    if key_matches(expr, key):  # zenoh refuses replies outside the query's key expression
                        query.reply(key, payload, express=True)  # (a reply's priority is the query's)
            except Exception:
                log.exception("queryable %s failed", key_expr)
            finally:
                query.drop()  # finalise: the querier stops waiting for this queryable

        return self._declared(self.session.declare_queryable(key_expr, on_query))

    def query_bytes(self, key_expr: str, timeout_s: float = 1.0) -> list[tuple[str, bytes]]:
        z = self._zenoh
        out = []
        replies = self.session.get(key_expr, target=z.QueryTarget.ALL, consolidation=z.ConsolidationMode.NONE,
                                   timeout=timeout_s, priority=z.Priority.INTERACTIVE_HIGH, express=True)
        for reply in replies:  # ends when every matching queryable has answered, or at the timeout
            sample = reply.ok
            if sample is not None:
                out.append((str(sample.key_expr), sample.payload.to_bytes()))
        return out

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        for sub in list(self._subs):
            try:
                sub.undeclare()
            except Exception:
                pass
        self._subs.clear()
        for pub in [*self._publishers.values(), *(p for ps in self._copy_publishers.values() for p in ps)]:
            try:
                pub.undeclare()
            except Exception:
                pass
        self._publishers.clear()
        self._copy_publishers.clear()
        for extra in [self._stream_session, *self._command_sessions]:
            if extra is not None:
                extra.close()
        self.session.close()
        # a drain thread still waiting in recv() when the interpreter finalises would re-take the GIL there and
        # be ended by pthread_exit inside zenoh's Rust frames, which abort the process ("FATAL: exception not
        # rethrown", exit -6): the channels are closed now, so each thread returns; wait for it.
        for worker in self._drains:
            if worker is not threading.current_thread():
                worker.join(timeout=2.0)
        self._drains.clear()
