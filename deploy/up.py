"""`iea up`: the docker-compose topology as local processes, for machines without Docker.

One Zenoh router (``iea router``, listening on loopback), then the vehicle, the DDM, one RSU per camera
of the corridor (``--source sim``) and the simulator, every service in client mode against that router
(``--connect tcp/127.0.0.1:PORT``). A service started while the router is down waits for it (Zenoh
``connect/timeout_ms: -1``), services that crash are restarted (``--restart on-failure``, as in the
compose file), and clients reconnect by themselves when the router comes back. Runs until Ctrl-C (or
``--duration-s``), printing a status line now and then; Ctrl-C stops the services, then the router.
The run folder (``runs/up-<time>/``) holds ``logs/<service>.log``, the vehicle's run and ``metrics.json``.

Signed by default: the DDM and every RSU sign with their own key and every service runs on a
corridor file trusting only those keys: an ``iea deploy keys`` bundle (``--keys DIR``), else throwaway
keys written to the run folder (``keys/``). ``--unsigned`` runs without signatures.

``--foxglove [PORT]`` also runs ``iea foxglove`` against the router: Foxglove or Lichtblick connect to
``ws://127.0.0.1:PORT`` (default 8765) and watch the corridor live.
"""

from __future__ import annotations

import argparse
import json
import logging
import socket
import sys
import time
import uuid
from pathlib import Path
from typing import Any

from deploy.procs import ROOT, ServiceGroup, ServiceSpec, corridor_services, start_when_rsus_up
from protocol.runtime import stop_on_ctrl_c
from scenario.monitor import RunMonitor, print_summary

ROUTER = "router"
FOXGLOVE = "foxglove"
CLIENT_CONFIG = "zenoh-client.json5"
CLIENT_CONFIG_TEXT = """// written by `iea up`: a service waits for its router instead of exiting when the router is not up
// (yet, or again); once connected, Zenoh clients reconnect by themselves after a router restart.
{ connect: { timeout_ms: -1 } }
"""


def fan_out(readers: list, key: str, message: Any) -> None:
    """Hand one decoded message to every reader in turn; a reader that raises is logged and the others still
    get the message (as separate subscriptions would)."""
    for read in readers:
        try:
            read(key, message)
        except Exception:
            logging.getLogger("iea.up").exception("reader %r of %s failed", read, key)


def free_port() -> int:
    """A TCP port on loopback nobody listens on now (for tests and parallel runs)."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class Up:
    """The corridor's processes around one router; ``start()``, ``restart_router()``, ``stop()``."""

    def __init__(self, *, corridor_file: str | None = None, corridor_id: str | None = None,
                 scenario: str = "rellis_ev_yield", duration_s: float | None = None, port: int = 7447,
                 run_dir: Path | None = None, detector: str = "project", rsu_ids: list[str] | None = None,
                 restart: str = "on-failure", annotate: bool = False, with_sim: bool = True,
                 vehicle_extra: list[str] | None = None, seed: int | None = None, peer: bool = False,
                 signed: bool = True, keys_dir: str | None = None, record: bool = False,
                 lighting: str | None = None, foxglove_port: int | None = None, v2x: bool = False,
                 traffic: str | None = None, ev_radio_loss: float | None = None) -> None:
        """``lighting``: day, dusk or night instead of the scenario's (the simulator's override).
        ``foxglove_port``: also run ``iea foxglove`` on that port (Foxglove / Lichtblick watch the corridor).
        ``v2x``: a V2X gateway per RSU, and (signed) a key for the scenario's EV radio in the trust list.
        ``ev_radio_loss``: the loss of an equipped EV's radio instead of the corridor's ``dsrc_loss``.
        ``signed`` (default): every service signs with its own key and trusts only the corridor's keys: those
        of ``keys_dir`` (an ``iea deploy keys`` bundle), else throwaway keys made in the run folder."""
        from deploy.signing import key_args, load_key_bundle, write_key_bundle
        from protocol.corridor import DEFAULT_CORRIDOR, load_corridor

        self.corridor = load_corridor(corridor_file)
        self.run_dir = Path(run_dir or ROOT / "runs" / f"up-{time.strftime('%Y%m%d-%H%M%S')}")
        self.signed = signed
        keys: dict[str, list[str]] = {}
        self.ev_key: Path | None = None
        """The EV radio's key (signed ``v2x`` runs; trusted by the run's corridor file), else None."""
        if signed:
            if keys_dir is not None:
                corridor_path, paths = load_key_bundle(keys_dir, self.corridor)
            else:
                corridor_path, paths = write_key_bundle(corridor_file or DEFAULT_CORRIDOR, self.run_dir / "keys",
                                                        key_id_suffix="up", overwrite=True,
                                                        note="throwaway keys of this run")
            keys = key_args(paths)
            if v2x:  # a copy of the corridor file in the run folder trusts the EV's key too (a bundle is not edited)
                copy = self.run_dir / "keys" / "corridor-v2x.toml"
                copy.parent.mkdir(parents=True, exist_ok=True)
                copy.write_text(Path(corridor_path).read_text())
                corridor_path = copy
                self.ev_key = add_ev_key(copy, self.run_dir / "keys")
                keys["ev"] = ["--ev-key", str(self.ev_key)]
            corridor_file = str(corridor_path)
            self.corridor = load_corridor(corridor_file)
        self.corridor_file = corridor_file
        self.corridor_id = corridor_id or f"{self.corridor.corridor_id}-{uuid.uuid4().hex[:6]}"
        self.port = port or free_port()
        self.endpoint = f"tcp/127.0.0.1:{self.port}"
        self.group = ServiceGroup(self.run_dir)
        self.peer = peer
        """Peer mode on loopback, no router (the `iea demo` topology): for comparisons."""
        zenoh = [] if peer else ["--connect", self.endpoint, "--zenoh-config", str(self.run_dir / CLIENT_CONFIG)]
        if corridor_file:
            zenoh = ["--corridor", corridor_file, *zenoh]
        self.service_args = zenoh
        """What every service of the run is given: the corridor file and the way to the router."""
        self.specs = corridor_services(self.corridor, self.corridor_id, scenario=scenario, duration_s=duration_s,
                                       run_dir=self.run_dir, detector=detector, zenoh_args=zenoh, rsu_ids=rsu_ids,
                                       annotate=annotate, vehicle_extra=vehicle_extra, seed=seed, keys=keys,
                                       lighting=lighting, v2x=v2x, traffic=traffic, ev_radio_loss=ev_radio_loss)
        if not with_sim:
            self.specs = [s for s in self.specs if s.name != "sim"]
        if foxglove_port is not None:  # publishes nothing: a Health-less watcher of the corridor
            self.specs.append(ServiceSpec(FOXGLOVE, ["-m", "deploy", "foxglove", "--port", str(foxglove_port),
                                                     "--corridor-id", self.corridor_id, *zenoh]))
        for s in self.specs:
            s.restart = restart if s.name != "sim" else "no"  # the simulator ends with its scenario
        if not peer:
            self.run_dir.mkdir(parents=True, exist_ok=True)
            (self.run_dir / CLIENT_CONFIG).write_text(CLIENT_CONFIG_TEXT)
        self.monitor = RunMonitor(self.corridor_id, road=self.corridor.road)
        self.health: dict[str, tuple[float, str]] = {}
        self.transport = None
        self.record = record
        """Record every key to ``<run folder>/run.mcap`` from the monitor's Zenoh session."""
        self.recorder = None
        self._ddm_poll = None

    def add_service(self, name: str, args: list[str], restart: str = "no") -> ServiceSpec:
        """One more process of the run (``args`` after the interpreter), given the run's corridor id, corridor file
        and router; started with the corridor's services, before the vehicle and the world. Call before ``start``."""
        spec = ServiceSpec(name, [*args, "--corridor-id", self.corridor_id, *self.service_args], restart)
        self.specs.append(spec)
        return spec

    # ------------------------------------------------------------------ lifecycle
    def _start_router(self, timeout_s: float = 20.0) -> None:
        self.group.start(ROUTER, ["-m", "deploy", "router", "--listen", self.endpoint, "--no-multicast"])
        if not self.group.wait_for_log(ROUTER, "router ready", timeout_s):
            log = self.group.log_path(ROUTER).read_text(errors="replace")[-2000:]
            raise RuntimeError(f"the router did not start on {self.endpoint}:\n{log}")

    def start(self, settle_s: float = 2.0, monitor: bool = True, extra_subscribers: list | None = None) -> None:
        """Router, then the services, then (after ``settle_s``) the simulator. ``extra_subscribers``:
        more ``callback(key, message)`` for every message of the corridor (the monitor's session)."""
        from protocol import keys
        from protocol.zenoh_transport import ZenohSettings, ZenohTransport

        if not self.peer:
            self._start_router()
        if monitor:
            settings = ZenohSettings() if self.peer else ZenohSettings(mode="client", connect=[self.endpoint])
            self.transport = ZenohTransport(settings)
            # one subscription, one decode per message, handed to every reader (a subscription per reader
            # would decode every snapshot and object list of the corridor once per reader)
            readers = [self.monitor.on_message, self._on_health, *(extra_subscribers or [])]
            self.transport.subscribe(keys.corridor_expr(self.corridor_id), lambda k, m: fan_out(readers, k, m))
            if self.record:
                from deploy.foxglove_scene import CorridorScene, DdmStatePoll
                from deploy.record import McapRecorder

                scene = CorridorScene(self.corridor)  # and the Foxglove scene, with the DDM's fused tracks
                self.recorder = McapRecorder(self.run_dir / "run.mcap", metadata={"corridor_id": self.corridor_id},
                                             derive=scene.feed)
                self._ddm_poll = DdmStatePoll(self.transport, self.corridor_id, scene).start()
                self.transport.subscribe_bytes(keys.corridor_expr(self.corridor_id), self.recorder.on_bytes)
        # the AV and the world start together once every RSU is up (its token), or the scenario would measure
        # the RSUs' start-up (7-9 s for four on a slow 2-core host) instead of the corridor
        start_when_rsus_up(self.group, self.specs, self.transport, self.corridor_id, settle_s=settle_s,
                           say=lambda line: print(f"[up] {line}", flush=True))

    def wait_for_scenario(self, timeout_s: float, settle_s: float = 0.5) -> bool:
        """Block until the simulator has played its scenario (its process ended) or ``timeout_s`` has passed, then
        ``settle_s`` for the last messages; whether the scenario ended in time."""
        deadline = time.monotonic() + timeout_s
        while self.group.running("sim") and time.monotonic() < deadline:
            time.sleep(0.2)
        ended = not self.group.running("sim")
        time.sleep(settle_s)
        return ended

    def restart_router(self, down_s: float = 0.5) -> None:
        """Stop the router, wait ``down_s``, start it again on the same endpoint."""
        self.group.stop(ROUTER)
        time.sleep(down_s)
        self.group.restarts[ROUTER] = self.group.restarts.get(ROUTER, 0) + 1
        self._start_router()

    def stop(self) -> None:
        """Services first (SIGINT, then SIGKILL), the router last."""
        if self._ddm_poll is not None:
            self._ddm_poll.close()
            self._ddm_poll = None
        if self.transport is not None:
            self.transport.close()
            self.transport = None
        if self.recorder is not None:
            self.recorder.close()
        self.group.stop_all(keep_last=0 if self.peer else 1)

    def __enter__(self) -> Up:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _on_health(self, key: str, msg: Any) -> None:
        if msg.KIND != "Health":
            return
        from protocol.keys import parse_key

        pk = parse_key(key)
        name = pk.node if pk.domain == "rsu" else ("vehicle" if pk.domain == "vehicle" else pk.domain)
        stale = f" stale={','.join(msg.stale)}" if msg.stale else ""
        self.health[name] = (time.time(), f"{msg.status.value}{stale}")

    def health_line(self) -> str:
        """Each service's last Health (1 Hz): status and how long ago; '?' when never heard."""
        now = time.time()
        parts = []
        for spec in self.specs:
            if spec.name == FOXGLOVE:
                continue
            h = self.health.get(spec.name)
            parts.append(f"{spec.name}:?" if h is None else f"{spec.name}:{h[1]}({now - h[0]:.0f}s)")
        return "health " + " ".join(parts)

    def status(self) -> str:
        parts = []
        for name in self.group.procs:
            code = self.group.exited().get(name)
            parts.append(name if code is None else f"{name}(exit {code})")
        return "up: " + " ".join(parts)

    def metrics(self) -> dict[str, Any]:
        m = self.monitor.metrics()  # m["yield"]: the one yield judge's verdict (scenario/outcome.py)
        m["restarts"] = dict(self.group.restarts)
        m["exit_codes"] = self.group.exited()
        return m


def add_ev_key(corridor_path: Path, key_dir: Path, ev_id: str = "ev1") -> Path:
    """A key for the EV's radio (``KEY_DIR/<ev>.pem``) and its ``[[trust]]`` entry (role ``ev``, the StationId of
    ``ev_id``) appended to the corridor file; returns the key's path."""
    from deploy.signing import write_new_key
    from protocol.security import TrustList, load_private_key
    from protocol.v2x.build import station_id

    path = Path(key_dir) / f"{ev_id}.pem"
    text = Path(corridor_path).read_text()
    if path.exists():
        path.unlink()
    path, entry = write_new_key(key_dir, f"{ev_id}-up", "ev")
    path = path.rename(Path(key_dir) / f"{ev_id}.pem")
    entry = entry.rsplit("\n", 1)[0] + f"\nstation_id = {station_id(ev_id)}"  # the scope: its StationId
    Path(corridor_path).write_text(text + "\n" + entry + "\n")
    from protocol.corridor import load_corridor

    assert TrustList.from_corridor(load_corridor(corridor_path)).key_id_of(load_private_key(path)) == f"{ev_id}-up"
    return path


def build_parser() -> argparse.ArgumentParser:
    from sim.cli import probability

    ap = argparse.ArgumentParser(prog="iea up", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corridor", default=None, help="corridor TOML file (default deploy/corridors/rellis.toml)")
    ap.add_argument("--corridor-id", default=None, help="corridor id in the keys (default: the file's id + a suffix)")
    ap.add_argument("--scenario", default="rellis_ev_yield", help="scenario the simulator runs (iea-sim list)")
    ap.add_argument("--lighting", choices=["day", "dusk", "night"], default=None,
                    help="the simulator's lighting instead of the scenario's (every camera renders in it)")
    ap.add_argument("--traffic", choices=["project", "sumo"], default=None,
                    help="who drives the simulator's traffic: its own model or Eclipse SUMO (default: the scenario's)")
    ap.add_argument("--no-sim", action="store_true", help="do not start the simulator (RSUs then wait for frames)")
    ap.add_argument("--rsus", type=int, default=None, metavar="N", help="start only the first N RSUs of the corridor")
    ap.add_argument("--port", type=int, default=7447, help="router port on 127.0.0.1 (0: any free port; default 7447)")
    ap.add_argument("--detector", default="project",
                    help="RSU detector: 'project' (models/iea_det_tiny.onnx, default), 'motion' (MOG2) or an ONNX path")
    ap.add_argument("--annotate", action="store_true", help="each RSU writes its annotated video to the run folder")
    ap.add_argument("--restart", choices=["no", "on-failure"], default="on-failure",
                    help="restart a service that exits with an error (default on-failure)")
    ap.add_argument("--duration-s", type=float, default=None,
                    help="stop everything after this many seconds (default: run until Ctrl-C)")
    ap.add_argument("--sim-duration-s", type=float, default=None,
                    help="scenario time the simulator runs (default: the scenario's duration)")
    ap.add_argument("--status-every-s", type=float, default=2.0, help="print a status line this often (0: never)")
    ap.add_argument("--runs", default=str(ROOT / "runs"), help="where run folders go")
    ap.add_argument("--keys", default=None, metavar="DIR",
                    help="sign with this `iea deploy keys --out DIR` bundle (default: throwaway keys in the run folder)")
    ap.add_argument("--unsigned", action="store_true",
                    help="no signatures: vehicles accept any command the router lets through (closed lab only)")
    ap.add_argument("--foxglove", type=int, nargs="?", const=8765, default=None, metavar="PORT",
                    help="also serve the corridor to Foxglove / Lichtblick (iea foxglove) on ws://127.0.0.1:PORT "
                         "(default port 8765); needs the foxglove extra")
    ap.add_argument("--v2x", action="store_true",
                    help="standard V2X: a gateway per RSU (CPM, DENM, the radio's CAMs to the DDM) and a key for an "
                         "equipped EV's radio")
    ap.add_argument("--ev-radio-loss", type=probability, default=None, metavar="P",
                    help="an equipped EV's radio loses each CAM with probability P in [0, 1] (default: the corridor's "
                         "dsrc_loss)")
    ap.add_argument("--no-record", action="store_true",
                    help="do not record (default: every key to <run folder>/run.mcap; `iea replay` it)")
    return ap


def main(argv: list[str] | None = None) -> int:
    stop_on_ctrl_c()  # SIGINT stops it even when started with SIGINT ignored (protocol.runtime)
    args = build_parser().parse_args(argv)
    from protocol.corridor import CorridorError, load_corridor

    try:
        corridor = load_corridor(args.corridor)
    except CorridorError as exc:
        print(f"iea up: {exc}", file=sys.stderr)
        return 2
    rsu_ids = None
    if args.rsus is not None:
        if not 1 <= args.rsus <= len(corridor.rsus):
            print(f"iea up: --rsus must be in 1..{len(corridor.rsus)}", file=sys.stderr)
            return 2
        rsu_ids = [r.rsu_id for r in corridor.rsus[:args.rsus]]
    if args.traffic == "sumo":
        from sim.sumo import sumo_missing

        if (why := sumo_missing()) is not None:
            print(f"iea up: --traffic sumo: {why}", file=sys.stderr)
            return 2
    run_dir = Path(args.runs) / f"up-{time.strftime('%Y%m%d-%H%M%S')}"
    try:
        up = Up(corridor_file=args.corridor, corridor_id=args.corridor_id, scenario=args.scenario,
                duration_s=args.sim_duration_s, port=args.port, run_dir=run_dir, detector=args.detector,
                rsu_ids=rsu_ids, restart=args.restart, annotate=args.annotate, with_sim=not args.no_sim,
                signed=not args.unsigned, keys_dir=args.keys, record=not args.no_record, lighting=args.lighting,
                foxglove_port=args.foxglove, v2x=args.v2x, traffic=args.traffic, ev_radio_loss=args.ev_radio_loss)
    except (FileNotFoundError, ValueError) as exc:
        print(f"iea up: {exc}", file=sys.stderr)
        return 2
    print("[up] " + (f"signed: every service signs with its own key; trust list in {up.corridor_file}" if up.signed
                     else "UNSIGNED (--unsigned): vehicles accept any command the router lets through"), flush=True)
    print(f"[up] corridor {up.corridor_id}: router {up.endpoint}, services "
          f"{', '.join(s.name for s in up.specs)}; logs in {up.run_dir / 'logs'}", flush=True)
    code = 0
    try:
        up.start()
        print(f"[up] {up.status()}  (Ctrl-C to stop)", flush=True)
        end = None if args.duration_s is None else time.monotonic() + args.duration_s
        next_status = time.monotonic()
        while end is None or time.monotonic() < end:
            time.sleep(0.5)
            for name in up.group.supervise():
                print(f"[up] {name} exited with an error; restarted (see its log)", flush=True)
            if args.status_every_s > 0 and time.monotonic() >= next_status:
                next_status = time.monotonic() + args.status_every_s
                print("  " + up.monitor.progress_line(), flush=True)
                print("    " + up.health_line(), flush=True)
    except KeyboardInterrupt:
        print("\n[up] interrupted: stopping the services, then the router", flush=True)
    except RuntimeError as exc:
        print(f"iea up: {exc}", file=sys.stderr)
        code = 1
    finally:
        up.stop()
    m = up.metrics()
    up.run_dir.mkdir(parents=True, exist_ok=True)
    (up.run_dir / "metrics.json").write_text(json.dumps(m, indent=2, default=str) + "\n")
    m["run_dir"] = str(up.run_dir)
    if m["events_since_lights_on_s"]:
        print_summary(m)
    print(f"[up] stopped; exit codes {m['exit_codes']}; run folder {up.run_dir}")
    return code


if __name__ == "__main__":
    raise SystemExit(main())
