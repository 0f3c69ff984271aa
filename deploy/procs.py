"""Process management shared by `iea demo` and `iea up`: the corridor's services as child processes.

``ServiceGroup`` starts each service as ``python -m <pkg> ...`` in its own session (so a Ctrl-C in the
terminal reaches only the parent, which then stops the children in order), sends each one's output
to ``<run folder>/logs/<name>.log``, and stops them with SIGINT, then SIGKILL after a grace period.
It can kill, restart and supervise (restart on failure, like compose's ``restart: on-failure``).

``corridor_services`` is the topology both commands run: the vehicle, the DDM, one RSU per camera of
the corridor (``--source sim``) and the simulator, each given the same corridor id and Zenoh flags.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def child_env() -> dict[str, str]:
    """The environment of a service: this checkout first on PYTHONPATH, unbuffered output."""
    return dict(os.environ, PYTHONPATH=str(ROOT) + os.pathsep + os.environ.get("PYTHONPATH", ""),
                PYTHONUNBUFFERED="1")


@dataclass
class ServiceSpec:
    name: str
    args: list[str]
    """Arguments after the Python interpreter, e.g. ``["-m", "ddm", "run", ...]``."""
    restart: str = "no"
    """``no`` or ``on-failure`` (restarted when it exits with a non-zero code or a signal)."""


@dataclass
class ServiceGroup:
    """Named child processes with a log file each, stopped in reverse start order."""

    run_dir: Path
    env: dict[str, str] = field(default_factory=child_env)
    max_restarts: int = 5
    procs: dict[str, subprocess.Popen] = field(default_factory=dict)
    specs: dict[str, ServiceSpec] = field(default_factory=dict)
    restarts: dict[str, int] = field(default_factory=dict)
    log_start: dict[str, int] = field(default_factory=dict)
    """Size of each service's log when it was last started: what it wrote since begins there."""
    launch: dict[str, list[str]] = field(default_factory=dict)
    """Per service, a command its interpreter runs under (the network lab: ``ip netns exec NS``)."""

    def __post_init__(self) -> None:
        self.run_dir = Path(self.run_dir)
        (self.run_dir / "logs").mkdir(parents=True, exist_ok=True)

    def log_path(self, name: str) -> Path:
        return self.run_dir / "logs" / f"{name}.log"

    def start(self, name: str, args: list[str], restart: str = "no") -> subprocess.Popen:
        """Start (or start again) service ``name``; its log is appended to."""
        if restart not in ("no", "on-failure"):
            raise ValueError(f"restart must be 'no' or 'on-failure', got {restart!r}")
        old = self.procs.get(name)
        if old is not None and old.poll() is None:
            raise RuntimeError(f"service {name} is already running (pid {old.pid})")
        self.specs[name] = ServiceSpec(name, list(args), restart)
        with open(self.log_path(name), "a") as log:  # the child keeps its own descriptor
            self.log_start[name] = log.tell()
            proc = subprocess.Popen([*self.launch.get(name, []), sys.executable, *args], stdout=log, stderr=subprocess.STDOUT, env=self.env,
                                    cwd=ROOT, start_new_session=True)
        self.procs[name] = proc
        return proc

    def restart(self, name: str, timeout_s: float = 10.0) -> subprocess.Popen:
        """Stop ``name`` if it runs, then start it again with the same arguments."""
        self.stop(name, timeout_s)
        spec = self.specs[name]
        self.restarts[name] = self.restarts.get(name, 0) + 1
        return self.start(name, spec.args, spec.restart)

    def running(self, name: str) -> bool:
        p = self.procs.get(name)
        return p is not None and p.poll() is None

    def exited(self) -> dict[str, int]:
        """Services that have exited: name -> return code (negative: killed by that signal)."""
        return {n: p.returncode for n, p in self.procs.items() if p.poll() is not None}

    def kill(self, name: str) -> None:
        """SIGKILL the service's process group (a crash, for fault tests)."""
        p = self.procs[name]
        if p.poll() is None:
            _signal_group(p, signal.SIGKILL)
            p.wait(timeout=10)

    def stop(self, name: str, timeout_s: float = 10.0) -> int | None:
        """SIGINT, then SIGKILL after ``timeout_s``; returns the exit code."""
        p = self.procs.get(name)
        if p is None:
            return None
        return stop_process_group(p, signal.SIGINT, timeout_s)

    def stop_all(self, timeout_s: float = 10.0, keep_last: int = 0) -> None:
        """Stop every service: SIGINT to all (in reverse start order, the last ``keep_last`` - e.g. the
        router - after the others have exited), then SIGKILL what is left after ``timeout_s``."""
        names = list(self.procs)[::-1]
        last = names[:keep_last] if keep_last else []
        first = [n for n in names if n not in last]
        for group in (first, last):
            for n in group:
                p = self.procs[n]
                if p.poll() is None:
                    _signal_group(p, signal.SIGINT)
            deadline = time.monotonic() + timeout_s
            for n in group:
                p = self.procs[n]
                try:
                    p.wait(timeout=max(0.1, deadline - time.monotonic()))
                except subprocess.TimeoutExpired:
                    _signal_group(p, signal.SIGKILL)
                    p.wait(timeout=10)

    def supervise(self) -> list[str]:
        """Restart the services with ``restart=on-failure`` that exited with an error; returns their names."""
        out = []
        for name, code in self.exited().items():
            spec = self.specs[name]
            if spec.restart == "on-failure" and code != 0 and self.restarts.get(name, 0) < self.max_restarts:
                self.restarts[name] = self.restarts.get(name, 0) + 1
                self.start(name, spec.args, spec.restart)
                out.append(name)
        return out

    def wait_for_log(self, name: str, text: str, timeout_s: float) -> bool:
        """Poll ``name``'s log until what it wrote since its last start contains ``text`` (e.g. the router's
        "router ready"; a line from an earlier run in the same log does not count)."""
        deadline = time.monotonic() + timeout_s
        path = self.log_path(name)
        offset = self.log_start.get(name, 0)
        while time.monotonic() < deadline:
            if path.exists():
                with open(path, "rb") as f:
                    f.seek(offset)
                    if text in f.read().decode(errors="replace"):
                        return True
            if not self.running(name):
                return False
            time.sleep(0.05)
        return False

    def __enter__(self) -> ServiceGroup:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop_all()


def wait_until(pred, timeout_s: float, poll_s: float = 0.05) -> bool:
    """Poll ``pred`` every ``poll_s`` until it is true or ``timeout_s`` has passed; its last answer."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if pred():
            return True
        time.sleep(poll_s)
    return bool(pred())


def _signal_group(p: subprocess.Popen, sig: int) -> None:
    try:
        os.killpg(p.pid, sig)
    except ProcessLookupError:
        pass


def stop_process(p: subprocess.Popen, sig: int = signal.SIGTERM, timeout_s: float = 10.0, *,
                 group: bool = False) -> int | None:
    """Stop a process: ``sig`` (to its process group with ``group``: one started with ``start_new_session``,
    its children included), then SIGKILL after ``timeout_s``; its exit code. The one teardown of the runners,
    benches and tests that start services."""
    def send(s: int) -> None:
        if group:
            _signal_group(p, s)
        else:
            p.send_signal(s)

    if p.poll() is None:
        send(sig)
        try:
            p.wait(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            send(signal.SIGKILL)
            p.wait(timeout=10)
    return p.returncode


def stop_process_group(p: subprocess.Popen, sig: int = signal.SIGINT, timeout_s: float = 10.0) -> int | None:
    """Stop a process started in its own session (``start_new_session``) and its children: ``sig`` to its group,
    then SIGKILL after ``timeout_s``; its exit code."""
    return stop_process(p, sig, timeout_s, group=True)


SIM_WAIT_FOR_AV_S = 30.0
"""How long the simulator holds the world for the vehicle process's first state."""
SIM_WAIT_FOR_RSUS_S = 60.0
"""At most this long the vehicle and the world wait for the RSUs' liveliness tokens (four RSUs loading their
models at once on a slow 2-core host took 7-9 s; a world started before them lit the EV's lamps unwatched)."""


def start_when_rsus_up(group: ServiceGroup, specs: list[ServiceSpec], transport, corridor_id: str,
                       settle_s: float = 2.0, timeout_s: float = SIM_WAIT_FOR_RSUS_S,
                       say=print) -> list[str] | None:
    """Start ``specs`` in order, the vehicle and the simulator last and together: first every other service,
    then (``transport``: a session on the corridor) wait until each started RSU has its liveliness token, at
    most ``timeout_s``, and ``settle_s`` for discovery; returns the RSUs that never came up (None: no
    presence to wait on, ``settle_s`` only)."""
    from protocol import presence

    last = [s for s in specs if s.name in ("vehicle", "sim")]
    first = [s for s in specs if s not in last]
    for spec in first:
        group.start(spec.name, spec.args, spec.restart)
    rsus = [s.name for s in first if "--rsu" in s.args]
    missing = None
    if rsus and transport is not None:
        t0 = time.monotonic()
        missing = presence.wait_for_tokens(transport, corridor_id, "rsu", rsus, timeout_s)
        if missing:
            say(f"RSU(s) {', '.join(missing)} not up after {timeout_s:.0f} s: starting the world without them")
        elif missing is not None:
            say(f"every RSU up after {time.monotonic() - t0:.1f} s ({', '.join(rsus)})")
    time.sleep(settle_s)  # every client joins the router before the AV and the world start
    for spec in last:
        group.start(spec.name, spec.args, spec.restart)
    return missing


def detector_args(detector: str) -> list[str]:
    """iea-rsu options for a detector name: ``project`` (the project's ONNX model, models/), ``motion``
    (MOG2), or the path of an ONNX model."""
    if detector == "motion":
        return ["--detector", "motion"]
    from rsu.detect import PROJECT_MODEL

    model = PROJECT_MODEL if detector == "project" else Path(detector)
    if not model.is_file():
        raise FileNotFoundError(f"detector model {model} not found (use --detector motion, or train it: make models)")
    return ["--detector", "onnx", "--model", str(model)]


def corridor_services(corridor, corridor_id: str, *, scenario: str, duration_s: float | None, run_dir: Path,
                      detector: str = "project", zenoh_args: list[str] | None = None,
                      rsu_ids: list[str] | None = None, annotate: bool = True,
                      vehicle_extra: list[str] | None = None, seed: int | None = None,
                      keys: dict[str, list[str]] | None = None, lighting: str | None = None,
                      v2x: bool = False, traffic: str | None = None,
                      ev_radio_loss: float | None = None) -> list[ServiceSpec]:
    """The corridor topology in start order: DDM, RSUs, then the vehicle and the simulator (start these two
    together, last: the AV is where the scenario puts it when the world starts).

    ``duration_s`` bounds the simulator (and the vehicle, 4 s later); None: they run until stopped.
    ``seed`` overrides the scenario's seed and seeds the vehicle's sensors and the cameras' noise.
    ``lighting`` (day, dusk, night) overrides the scenario's: the simulator's world snapshots carry it, so every RSU
    renders its camera in it.
    ``keys``: per service extra arguments (signing keys: ``--key PATH``; ``ev``: the simulator's ``--ev-key``).
    ``v2x``: a V2X gateway per RSU (``rsu.v2x_gateway``, service ``<rsu>-v2x``, signing with the RSU's key).
    ``traffic``: ``project`` or ``sumo`` instead of the scenario's (who drives the simulator's traffic).
    ``ev_radio_loss``: an equipped EV's radio loss instead of the corridor's ``dsrc_loss`` (the simulator's).
    """
    from sim.scenario import LIGHTINGS, load_scenario

    if lighting is not None and lighting not in LIGHTINGS:
        raise ValueError(f"lighting must be one of {', '.join(LIGHTINGS)}, got {lighting!r}")
    if ev_radio_loss is not None and not 0.0 <= ev_radio_loss <= 1.0:
        raise ValueError(f"ev_radio_loss must be a probability in [0, 1], got {ev_radio_loss}")
    keys = keys or {}
    z = list(zenoh_args or [])
    common = ["--corridor-id", corridor_id]
    rsus = [r.rsu_id for r in corridor.rsus] if rsu_ids is None else list(rsu_ids)
    vehicle = ["-m", "vehicle", "run", *common, "--record", str(Path(run_dir) / "vehicle")]
    av = load_scenario(scenario, corridor).av
    if av is not None:  # the vehicle process starts where the scenario puts the AV (as the lockstep runner does)
        vehicle += ["--vehicle", av.vehicle_id, "--start-s", str(av.start_s_m), "--start-lane", str(av.lane),
                    "--speed", str(av.speed_mps)]
    if duration_s is not None:
        vehicle += ["--duration", str(duration_s + 4)]
    if seed is not None:
        vehicle += ["--seed", str(seed)]
    out = [ServiceSpec("ddm", ["-m", "ddm", "run", *common, *keys.get("ddm", []), *z])]
    for rsu in rsus:
        corridor.rsu(rsu)  # unknown ids fail here, naming the corridor's RSUs
        # Every RSU shares this host's cores: one thread each, or their thread pools spin against each other.
        args = ["-m", "rsu", "--rsu", rsu, "--source", "sim", "--threads", "1", *common, *keys.get(rsu, []),
                *detector_args(detector)]
        if annotate:
            args += ["--annotate", str(Path(run_dir) / f"{rsu}.mp4")]
        if seed is not None:
            args += ["--sim-seed", str(seed)]
        out.append(ServiceSpec(rsu, [*args, *z]))
        if v2x:
            out.append(ServiceSpec(f"{rsu}-v2x", ["-m", "rsu.v2x_gateway", "--rsu-id", rsu, *common,
                                                  *keys.get(rsu, []), *z]))
    out.append(ServiceSpec("vehicle", [*vehicle, *(vehicle_extra or []), *z]))
    sim = ["-m", "sim", "run", scenario, *common, *keys.get("ev", [])]
    if av is not None:  # the world starts when the vehicle process is up and driving, not before
        sim += ["--wait-for-av", str(SIM_WAIT_FOR_AV_S)]
    elif rsus:  # no vehicle process: the world waits for the RSUs itself (with one, the vehicle and the world
        # start together once the RSUs are up: ``start_when_rsus_up``)
        sim += ["--wait-for-rsus", ",".join(rsus), "--wait-timeout", str(SIM_WAIT_FOR_RSUS_S)]
    if duration_s is not None:
        sim += ["--duration", str(duration_s)]
    if seed is not None:
        sim += ["--seed", str(seed)]
    if lighting is not None:
        sim += ["--lighting", lighting]
    if traffic is not None:
        sim += ["--traffic", traffic]
    if ev_radio_loss is not None:
        sim += ["--ev-radio-loss", repr(float(ev_radio_loss))]
    out.append(ServiceSpec("sim", [*sim, *z]))
    return out
