"""The lockstep corridor (``scenario.lockstep``) with V2X: the equipped EV's radio, each RSU's V2X gateway, keys.

``V2xLockstep(config, v2x=V2xSetup(...))`` adds to the lockstep run:

- keys: an Ed25519 key per RSU (role ``rsu``) and one for the EV (role ``ev``, scoped to its StationId), made for
  the run and put in the corridor's trust list (the DDM verifies every relay; camera alerts travel on the wired
  bus unsigned as in the plain runner);
- the EV's radio (``sim.ev_radio.EvRadio``, when the scenario says ``equipped``): CAMs at 10 Hz through a
  ``DsrcLink`` from the EV's true position to the RSU masts (the corridor's DSRC latency, jitter and range; loss
  ``radio_loss``);
- a gateway per RSU (``rsu.v2x_gateway``): CPMs, DENMs, and what its radio hears passed on signed;
- an attacker (``attack``: ``scenario.v2x_attack.Attacker``), for the security figures: ``forged`` (lights-on
  CAMs for the EV's StationId signed with a key of the EV's key id that is not the trusted one), ``replayed``
  (the EV's own genuinely signed lights-on CAMs played back ``replay_delay_s`` late) or ``contradicted``
  (validly signed lights-on CAMs, as from a stolen key, of an EV driving at 18 m/s through the cameras' clear
  views where no car is), published straight on the bus (no radio model: every CAM reaches every gateway).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from protocol.radio import ChannelModel, DsrcLink
from protocol.security import Signer, public_key_b64
from protocol.v2x.build import station_id
from rsu.v2x_gateway import V2xGateway
from scenario.lockstep import CorridorLockstep, LockstepConfig, _Task
from scenario.v2x_attack import ATTACKS, REPLAY_DELAY_S, Attacker
from sim.ev_radio import EvRadio
from sim.scenario import load_scenario

EV_ACTOR_ID = "ev1"
RADIO_STEP_S = 0.005


@dataclass(frozen=True)
class V2xSetup:
    radio_loss: float | None = None
    """Loss of the EV's radio (None: the corridor's ``dsrc_loss``)."""
    equipped: bool | None = None
    """Override the scenario's ``[ev] equipped`` (None: as the scenario says)."""
    attack: str | None = None
    replay_delay_s: float = REPLAY_DELAY_S
    radio_seed: int = 0


def _signer(key_id: str) -> Signer:
    return Signer(key_id, Ed25519PrivateKey.generate())


class V2xLockstep(CorridorLockstep):
    def __init__(self, config: LockstepConfig | None = None, *, v2x: V2xSetup | None = None) -> None:
        cfg = config or LockstepConfig()
        self.v2x = setup = v2x or V2xSetup()
        if setup.attack is not None and setup.attack not in ATTACKS:
            raise ValueError(f"attack {setup.attack!r}: expected one of {ATTACKS}")
        sc = load_scenario(cfg.scenario)
        if cfg.seed is not None:
            sc = sc.with_overrides(seed=cfg.seed)
        if sc.ev is not None and setup.equipped is not None:
            sc = replace(sc, ev=replace(sc.ev, equipped=setup.equipped))
        self.rsu_signers = {r.rsu_id: _signer(f"{r.rsu_id}-key") for r in sc.corridor.rsus}
        self.ev_signer = _signer("ev-key")
        self.ev_station = station_id(EV_ACTOR_ID)
        trust = tuple(sc.corridor.trust) + tuple(
            {"key_id": s.key_id, "role": "rsu", "rsu_id": rid, "public_key": public_key_b64(s.private_key.public_key())}
            for rid, s in self.rsu_signers.items()) + (
            {"key_id": "ev-key", "role": "ev", "station_id": self.ev_station,
             "public_key": public_key_b64(self.ev_signer.private_key.public_key())},)
        sc = replace(sc, corridor=replace(sc.corridor, trust=trust))
        super().__init__(cfg, scenario=sc)
        t = self.corridor.transport
        loss = t.dsrc_loss if setup.radio_loss is None else setup.radio_loss
        self.radio_model = ChannelModel(latency_s=t.dsrc_latency_s, jitter_s=t.dsrc_jitter_s, loss=loss,
                                        range_m=t.dsrc_range_m)
        self.radio: EvRadio | None = None
        self.radio_link: DsrcLink | None = None
        masts = [r.position for r in self.corridor.rsus]
        if sc.ev is not None and sc.ev.equipped:
            self.radio_link = DsrcLink(self.bus, self.radio_model, seed=setup.radio_seed, clock=self.clock,
                                       directions=("tx",), position=lambda: self.radio.position, peers=masts,
                                       threaded=False)
            self.radio = EvRadio(self.radio_link, self.corridor, self.corridor_id, signer=self.ev_signer,
                                 clock=self.clock.now, seed=setup.radio_seed, ev_ids=(EV_ACTOR_ID,)).start()
        self.gateways = [V2xGateway(self.bus, self.corridor, self.corridor_id, r.rsu_id, clock=self.clock.now,
                                    signer=self.rsu_signers[r.rsu_id]).start() for r in self.corridor.rsus]
        self.attacker = None if not setup.attack else Attacker(
            setup.attack, self.corridor, self.corridor_id, self.ev_signer, ev_id=EV_ACTOR_ID,
            replay_delay_s=setup.replay_delay_s)
        # the radio delivers (DSRC latency 3 +- 1 ms) every 5 ms of simulated time, not at every millisecond
        self._tasks.append(_Task("v2x-radio", RADIO_STEP_S, self._radio_step, start_s=RADIO_STEP_S))

    def start_ddm(self) -> None:
        """As the plain runner, camera alerts accepted unsigned on the wired bus; V2X relays always verified."""
        from ddm.build import DdmOptions, build_ddm

        self.kill_ddm()
        self.ddm = build_ddm(DdmOptions(config=self.config.ddm_config, verify_alerts=False), self.bus, self.clock,
                             self.corridor)
        self._tasks.append(_Task("ddm", 1.0 / self.config.ddm_config.rate_hz, self._ddm_step, start_s=self.clock.now()))

    def _radio_step(self, now: float) -> None:
        if self.radio_link is not None:
            self.radio_link.deliver_due(now)
        if self.attacker is not None and self._snapshot is not None:
            out = self.attacker.step(now, self._snapshot)
            if out is not None:
                self.bus.publish_bytes(*out)

    def finish(self) -> dict[str, Any]:
        m = super().finish()
        v2x = getattr(self.ddm, "v2x", None)
        m["v2x"] = {
            "equipped": self.radio is not None,
            "cams_sent": 0 if self.radio is None else self.radio.sent,
            "radio": {} if self.radio_link is None else {d: dict(c) for d, c in self.radio_link.counts.items()},
            "relayed": sum(g.counts["rx"] for g in self.gateways),
            "cpm": sum(g.counts["cpm"] for g in self.gateways),
            "denm": sum(g.counts["denm"] for g in self.gateways),
            "ddm": {} if v2x is None else dict(v2x.counts),
            "ddm_rejected": {k: v for k, v in (self.ddm.rejected.items() if self.ddm else ()) if k.startswith("v2x")},
            "attack": self.v2x.attack,
            "attack_sent": 0 if self.attacker is None else self.attacker.sent,
        }
        return m
