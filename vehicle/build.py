"""One vehicle process assembled in one place: the corridor with the car's start, the
command gate, the controller's fail-safe, the localisation, from one :class:`VehicleOptions`.

``iea-vehicle run`` calls :func:`run_vehicle`; a test or bench running the car on another transport and clock
calls :func:`build_vehicle`. The in-process runners (lockstep corridor, fault injection) hold a loaded
corridor and construct :class:`~vehicle.service.VehicleService` directly.
"""

from __future__ import annotations

import dataclasses
import logging
import signal
from collections.abc import Callable
from dataclasses import dataclass, field

from protocol.clock import Clock, WallClock
from protocol.corridor import Corridor, load_corridor
from protocol.security import TrustList
from protocol.transport import Transport
from protocol.zenoh_transport import ZenohSettings, ZenohTransport
from vehicle.commands import CommandGate
from vehicle.core import CoreConfig
from vehicle.failsafe import FailsafeConfig
from vehicle.localisation import FixSourceConfig
from vehicle.service import VehicleService

log = logging.getLogger("iea-vehicle")

Attachment = Callable[[VehicleService, Transport], None]
"""An on-board component attached to a built vehicle service before it runs (e.g. a study's learned steering); it
may subscribe on the transport and add subscriptions to the service, which closes them with itself."""


@dataclass(frozen=True)
class VehicleOptions:
    """One vehicle process. None for the start, lane and speed: the corridor file's entry for the vehicle."""

    corridor_file: str | None = None
    corridor_id: str | None = None
    vehicle_id: str = "av1"
    start_s_m: float | None = None
    start_lane: int | None = None
    cruise_speed_mps: float | None = None
    localisation: str = "gnss"
    """``gnss``, ``rsu`` or ``both`` (vehicle.service)."""
    gnss_sigma_m: float = 0.2
    gnss_rate_hz: float = 10.0
    gnss_latency_s: float = 0.1
    link_timeout_s: float = 3.5
    localisation_stale_s: float = 1.0
    seed: int = 0
    record: bool = False
    require_signed: bool | None = None
    """Refuse unsigned commands (None: when the corridor trusts DDM keys)."""
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)


def vehicle_corridor(options: VehicleOptions) -> Corridor:
    """The corridor with the options' id and this vehicle's start, lane and speed. Raises CorridorError
    (a ValueError) for a bad file or value, KeyError for a vehicle the corridor lacks."""
    corridor = load_corridor(options.corridor_file)
    if options.corridor_id:
        corridor = dataclasses.replace(corridor, corridor_id=options.corridor_id)
    vc = corridor.vehicle(options.vehicle_id)
    return corridor.with_vehicle(
        options.vehicle_id, start_s_m=vc.start_s_m if options.start_s_m is None else options.start_s_m,
        start_lane=vc.start_lane if options.start_lane is None else options.start_lane,
        cruise_speed_mps=vc.cruise_speed_mps if options.cruise_speed_mps is None else options.cruise_speed_mps)


def command_gate(options: VehicleOptions, corridor: Corridor) -> CommandGate:
    """The command authentication of the corridor's trust list; ValueError when ``require_signed`` is asked
    of a corridor that trusts no DDM key."""
    gate = CommandGate.from_trust(TrustList.from_corridor(corridor), options.require_signed)
    if options.require_signed and not gate.active:
        raise ValueError("--require-signed needs [[trust]] entries with role = 'ddm' in the corridor file")
    return gate


def build_vehicle(options: VehicleOptions, transport: Transport, clock: Clock,
                  attach: Attachment | None = None) -> VehicleService:
    """The vehicle service of ``options`` on ``transport`` and ``clock``, with ``attach`` attached. Raises before
    anything is subscribed for bad options."""
    corridor = vehicle_corridor(options)
    return _service(options, corridor, command_gate(options, corridor), transport, clock, attach)


def _service(options: VehicleOptions, corridor: Corridor, gate: CommandGate, transport: Transport,
             clock: Clock, attach: Attachment | None) -> VehicleService:
    config = CoreConfig(failsafe=FailsafeConfig(link_timeout_s=options.link_timeout_s,
                                                localisation_stale_s=options.localisation_stale_s))
    fix = FixSourceConfig("gnss", options.gnss_sigma_m, options.gnss_rate_hz, options.gnss_latency_s)
    service = VehicleService(transport, clock, corridor, options.vehicle_id, config=config,
                             localisation=options.localisation, fix_source=fix, seed=options.seed,
                             record=options.record, gate=gate)
    if attach is not None:
        try:
            attach(service, transport)
        except BaseException:
            service.close()
            raise
    return service


def run_vehicle(options: VehicleOptions, duration_s: float | None = None, record_dir: str | None = None,
                attach: Attachment | None = None) -> int:
    """``iea-vehicle run``: check the options (raising before the Zenoh session opens), run the car over Zenoh
    in real time until SIGTERM / Ctrl-C or ``duration_s``, write the run to ``record_dir`` when given; 0."""
    corridor = vehicle_corridor(options)
    gate = command_gate(options, corridor)
    # commands, acks and beats alone on one connection, its state, the alerts and object lists on another, and
    # commands and acks on a second connection as well: a lossy radio's retransmissions of the rest never hold a
    # command or an ack back, and one stalled connection does not hold it either (protocol.zenoh_transport)
    client = options.zenoh.mode == "client"
    transport = ZenohTransport(options.zenoh, stream_connection=client, command_connections=2 if client else 1)
    try:
        service = _service(options, corridor, gate, transport, WallClock(), attach)
    except BaseException:
        transport.close()
        raise
    if gate.active:
        log.info("commands verified against %d trusted key(s); unsigned commands %s",
                 len(TrustList.from_corridor(corridor).keys), "refused" if gate.require_signed else "accepted")
    else:
        log.warning("no DDM key in the corridor's trust list: commands are NOT authenticated")
    signal.signal(signal.SIGTERM, lambda *_: service.stop())
    log.info("vehicle %s on corridor %s: publishing %s", options.vehicle_id, corridor.corridor_id, service.state_key)
    try:
        service.run(duration_s)
    except KeyboardInterrupt:
        pass
    finally:
        service.close()
        transport.close()
        if record_dir and service.record is not None:
            from vehicle.record import write_run
            write_run(record_dir, service.record)
    return 0
