"""`iea view [--port 8080]`: the corridor live in a browser, served by this process.

The process joins the corridor over Zenoh (peer on loopback, or ``--connect`` a router), subscribes to
every RSU topic, the vehicles' states, commands and acks and every service's Health, watches the
liveliness tokens, asks the corridor's latest state at start (queries on the published keys) and polls
the DDM's state queryable (``iea/{c}/ddm/state``) at 2 Hz for the fused tracks. ``deploy.view_model``
turns all that into one JSON picture; the page (``deploy/view/index.html``, the only asset: no CDN,
no internet) draws it on a canvas from a server-sent-events stream at ``--rate-hz`` (default 15).
The view only displays: it decodes strictly, verifies nothing and publishes nothing.

Endpoints: ``/`` the page, ``/api/plan`` the corridor plan, ``/api/state`` one picture, ``/events`` the
stream (SSE), ``/api/seen`` what the page reports it drew (POSTed by the page once a second: the test
and the bench read it).

Python's ``http.server`` (threaded) serves it: no web framework is installed here and SSE needs none.
"""

from __future__ import annotations

import argparse
import json
import logging
import signal
import sys
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path
from typing import Any

from deploy.view_model import CorridorPicture, corridor_plan
from protocol import keys
from protocol.runtime import stop_on_ctrl_c

log = logging.getLogger("deploy.view")
PAGE = Path(__file__).resolve().parent / "view" / "index.html"
MAX_REPORT_BYTES = 16 * 1024


class ViewServer:
    """The picture, its JSON frames at ``rate_hz`` and the HTTP server; ``start()`` / ``close()``."""

    def __init__(self, corridor: Any, corridor_id: str, *, host: str = "127.0.0.1", port: int = 8080,
                 rate_hz: float = 15.0) -> None:
        if not 1.0 <= rate_hz <= 60.0:
            raise ValueError(f"rate_hz must be in 1..60, got {rate_hz}")
        self.corridor_id = corridor_id
        self.plan = {**corridor_plan(corridor), "corridor_id": corridor_id}
        self.plan_json = json.dumps(self.plan, separators=(",", ":")).encode()
        self.picture = CorridorPicture(corridor_id)
        self.rate_hz = rate_hz
        self.seen: dict[str, dict[str, Any]] = {}
        """The pages' last reports of what they drew (``POST /api/seen``), by mode: ``live`` (the stream) or
        ``poll`` (``?poll``: plain requests, for screenshots)."""
        self._frame = (0.0, b"{}")
        self._frame_lock = threading.Lock()
        self._stop = threading.Event()
        self.frames_served = 0
        self.httpd = ThreadingHTTPServer((host, port), _handler(self))
        self.httpd.daemon_threads = True
        self.port = int(self.httpd.server_address[1])
        self.transport = None
        self._threads: list[threading.Thread] = []

    @property
    def url(self) -> str:
        return f"http://{self.httpd.server_address[0]}:{self.port}/"

    def frame(self) -> bytes:
        """The current picture as JSON, recomputed at most ``rate_hz`` times a second (shared by every client)."""
        now = time.monotonic()
        with self._frame_lock:
            if now - self._frame[0] >= 0.5 / self.rate_hz:
                snap = self.picture.snapshot(time.time())
                snap["server_time"] = round(time.time(), 3)
                self._frame = (now, json.dumps(snap, separators=(",", ":")).encode())
            return self._frame[1]

    # ------------------------------------------------------------------ Zenoh
    def connect(self, settings: Any) -> None:
        """Join the corridor: subscriptions, presence, the state at start, the DDM state poll."""
        from protocol.zenoh_transport import ZenohTransport

        t = self.transport = ZenohTransport(settings)
        c = self.corridor_id
        on = lambda k, m: self.picture.on_message(k, m, time.time())  # noqa: E731
        for topic in keys.RSU_TOPICS:
            t.subscribe(keys.rsu_topic_expr(c, topic), on)
        for topic in ("state", "cmd", "ack", "health"):
            t.subscribe(keys.all_vehicles_expr(c, topic), on)
        t.subscribe(keys.ddm_health_key(c), on)
        t.subscribe(keys.sim_health_key(c), on)
        t.subscribe_presence(keys.alive_expr(c), self.picture.on_presence)
        self._spawn(self._catch_up, "view catch-up")
        self._spawn(self._poll_ddm_state, "view ddm state")

    def _spawn(self, fn, name: str) -> None:
        th = threading.Thread(target=fn, name=name, daemon=True)
        th.start()
        self._threads.append(th)

    def _catch_up(self) -> None:
        c, t = self.corridor_id, self.transport
        for expr in (keys.all_rsus_expr(c), f"{keys.ROOT}/{c}/**/health", keys.all_vehicles_expr(c, "state")):
            try:
                for key, msg in t.query(expr, 1.0):
                    self.picture.on_message(key, msg, time.time())
            except Exception:  # the session closed under us, or a transient query error
                log.debug("catch-up query %s failed", expr, exc_info=True)

    def _poll_ddm_state(self) -> None:
        key = keys.ddm_state_key(self.corridor_id)
        while not self._stop.wait(0.5):
            try:
                for _k, payload in self.transport.query_bytes(key, 0.4):
                    self.picture.on_ddm_state(json.loads(payload))
            except Exception:
                log.debug("ddm state query failed", exc_info=True)

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> None:
        self._spawn(self.httpd.serve_forever, "view http")

    def wait(self) -> None:
        self._stop.wait()

    def close(self) -> None:
        self._stop.set()
        self.httpd.shutdown()
        self.httpd.server_close()
        if self.transport is not None:
            self.transport.close()
            self.transport = None


def _handler(view: ViewServer) -> type[BaseHTTPRequestHandler]:
    class Handler(BaseHTTPRequestHandler):
        server_version = "iea-view"
        protocol_version = "HTTP/1.1"

        def log_message(self, fmt: str, *args: Any) -> None:
            log.debug("%s " + fmt, self.address_string(), *args)

        def _send(self, body: bytes, ctype: str, code: int = 200) -> None:
            self.send_response(code)
            self.send_header("Content-Type", ctype)
            self.send_header("Content-Length", str(len(body)))
            self.send_header("Cache-Control", "no-store")
            self.end_headers()
            self.wfile.write(body)

        def do_GET(self) -> None:  # noqa: N802 (http.server's name)
            path = self.path.split("?", 1)[0]
            if path in ("/", "/index.html"):
                self._send(PAGE.read_bytes(), "text/html; charset=utf-8")
            elif path == "/api/plan":
                self._send(view.plan_json, "application/json")
            elif path == "/api/state":
                self._send(view.frame(), "application/json")
            elif path == "/api/seen":
                mode = "poll" if "mode=poll" in self.path else "live"
                self._send(json.dumps(view.seen.get(mode, {})).encode(), "application/json")
            elif path == "/events":
                self._stream()
            else:
                self._send(b"not found", "text/plain", 404)

        def do_POST(self) -> None:  # noqa: N802
            if self.path != "/api/seen":
                self._send(b"not found", "text/plain", 404)
                return
            n = int(self.headers.get("Content-Length") or 0)
            if not 0 < n <= MAX_REPORT_BYTES:
                self._send(b"report must be 1..16384 bytes of JSON", "text/plain", 413)
                return
            try:
                report = json.loads(self.rfile.read(n))
            except ValueError:
                self._send(b"report is not JSON", "text/plain", 400)
                return
            if isinstance(report, dict) and report.get("mode") in ("live", "poll"):
                view.seen[report["mode"]] = {**report, "received": time.time()}
            self._send(b"{}", "application/json")

        def _stream(self) -> None:
            self.send_response(200)
            self.send_header("Content-Type", "text/event-stream")
            self.send_header("Cache-Control", "no-store")
            self.send_header("Connection", "keep-alive")
            self.end_headers()
            period = 1.0 / view.rate_hz
            next_t = time.monotonic()
            try:
                while not view._stop.is_set():
                    self.wfile.write(b"data: " + view.frame() + b"\n\n")
                    self.wfile.flush()
                    view.frames_served += 1
                    next_t += period
                    delay = next_t - time.monotonic()
                    if delay < 0:
                        next_t, delay = time.monotonic(), 0.0
                    view._stop.wait(delay)
            except (BrokenPipeError, ConnectionResetError, OSError):
                pass  # the page went away
            self.close_connection = True

    return Handler


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    from protocol.corridor import CorridorError, load_corridor
    from protocol.zenoh_transport import ZenohSettings

    ap = argparse.ArgumentParser(prog="iea view", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--port", type=int, default=8080, help="HTTP port (default 8080; 0: any free port)")
    ap.add_argument("--host", default="127.0.0.1", help="address to serve on (default 127.0.0.1: this machine only)")
    ap.add_argument("--corridor", default=None, help="corridor file (the plan, and its id names the keys)")
    ap.add_argument("--corridor-id", default=None, help="corridor id in the keys (e.g. the one `iea up` printed)")
    ap.add_argument("--rate-hz", type=float, default=15.0, help="page updates per second (default 15)")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        corridor = load_corridor(args.corridor)
        settings = ZenohSettings.from_args(args)
        view = ViewServer(corridor, args.corridor_id or corridor.corridor_id, host=args.host, port=args.port,
                          rate_hz=args.rate_hz)
    except (CorridorError, ValueError, OSError) as exc:
        print(f"iea view: {exc}", file=sys.stderr)
        return 2
    signal.signal(signal.SIGTERM, lambda *_: view._stop.set())
    view.connect(settings)
    view.start()
    print(f"[view] corridor {view.corridor_id}: open {view.url} (Ctrl-C to stop)", flush=True)
    try:
        view.wait()
    except KeyboardInterrupt:
        pass
    finally:
        view.close()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
