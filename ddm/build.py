"""One DDM assembled in one place: the corridor, the decision settings, the command signer
and the alert verification from one :class:`DdmOptions`.

``iea-ddm run`` calls :func:`run_ddm`; anything that runs a DDM on another transport (a test on a
:class:`~protocol.loopback.LocalBus`, a bench) calls :func:`build_ddm` with its own transport and clock, so
the DDM it measures is the one a corridor runs. The in-process runners (lockstep, replay, fault injection)
hold a loaded corridor and construct :class:`~ddm.service.DdmService` directly, as :func:`build_ddm` does.
"""

from __future__ import annotations

import logging
import signal
import threading
from dataclasses import dataclass, field

from ddm.config import DdmConfig
from ddm.service import DdmService
from protocol.clock import Clock, WallClock
from protocol.corridor import Corridor, load_corridor
from protocol.keys import all_rsus_expr
from protocol.security import Signer, TrustList, load_signer
from protocol.transport import Transport
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

log = logging.getLogger("ddm")


@dataclass(frozen=True)
class DdmOptions:
    """One DDM process: its corridor, identity, decision settings and command key."""

    corridor_file: str | None = None
    """Corridor TOML (None: deploy/corridors/rellis.toml)."""
    corridor_id: str | None = None
    """Corridor id used in the key expressions (None: the file's)."""
    ddm_id: str = "ddm"
    config: DdmConfig = field(default_factory=DdmConfig)
    key: str | None = None
    """Ed25519 private key (PEM) that signs every command; None: unsigned."""
    key_id: str | None = None
    """Key id of ``key`` (None: the corridor trust entry holding its public key)."""
    verify_alerts: bool | None = None
    """Refuse unsigned EV/hazard alerts (None: when the corridor trusts RSU keys)."""
    catch_up: bool = True
    """Ask the RSUs for their active alerts at start (False: wait for the alerts' repeats; zenoh_bench's A/B)."""
    zenoh: ZenohSettings = field(default_factory=ZenohSettings)


def _log_signing(signer: Signer | None, trust: TrustList) -> None:
    """How commands leave, with the warning a misconfigured signer deserves (vehicles refuse its commands)."""
    if signer is not None:
        log.info("signing commands with key %r", signer.key_id)
        if signer.key_id not in trust.keys:
            log.warning("key %r is not in the corridor's trust list: vehicles will refuse its commands", signer.key_id)
    elif trust.has_role("ddm"):
        log.warning("the corridor trusts DDM keys but no --key was given: vehicles will refuse unsigned commands")
    else:
        log.warning("commands are NOT signed (no --key)")


def build_ddm(options: DdmOptions, transport: Transport, clock: Clock, corridor: Corridor | None = None
              ) -> DdmService:
    """The DDM of ``options`` on ``transport`` and ``clock``; ``corridor``: one already loaded (a runner's or a
    bench's, perhaps edited) instead of ``options.corridor_file``. Raises CorridorError (a ValueError) for a
    bad corridor file or id, ValueError / FileNotFoundError for a bad key, before anything is subscribed."""
    return _Checked.of(options, corridor).service(transport, clock)


@dataclass(frozen=True)
class _Checked:
    """The options read and checked: the corridor loaded, its id a valid key chunk, the key loaded."""

    options: DdmOptions
    corridor: Corridor
    signer: Signer | None

    @classmethod
    def of(cls, options: DdmOptions, corridor: Corridor | None = None) -> _Checked:
        if corridor is None:
            corridor = load_corridor(options.corridor_file)
        all_rsus_expr(options.corridor_id or corridor.corridor_id)  # an id that cannot be a key chunk fails here
        trust = TrustList.from_corridor(corridor)
        return cls(options, corridor, load_signer(options.key, options.key_id, trust) if options.key else None)

    def service(self, transport: Transport, clock: Clock) -> DdmService:
        o = self.options
        return DdmService(transport, clock, self.corridor, o.config, corridor_id=o.corridor_id, ddm_id=o.ddm_id,
                          signer=self.signer, verify_alerts=o.verify_alerts, catch_up=o.catch_up)


def run_ddm(options: DdmOptions, stop: threading.Event | None = None) -> int:
    """``iea-ddm run``: check the options (as :func:`build_ddm`, raising before the Zenoh session opens), then
    run the DDM over Zenoh until SIGINT/SIGTERM or ``stop`` is set; 0."""
    checked = _Checked.of(options)
    _log_signing(checked.signer, TrustList.from_corridor(checked.corridor))
    stop = stop or threading.Event()
    if threading.current_thread() is threading.main_thread():
        for sig in (signal.SIGINT, signal.SIGTERM):
            signal.signal(sig, lambda *_: stop.set())
    transport = ZenohTransport(options.zenoh)
    try:
        service = checked.service(transport, WallClock())
        try:
            service.run(stop)
        finally:
            service.close()
    finally:
        transport.close()
    return 0
