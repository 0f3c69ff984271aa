"""Fuzz targets of ``bench/fuzz_bench.py``, vehicle, simulator and RSU side: the
vehicle's ``_on_cmd`` (signature checking on; half the mutated commands re-signed with the trusted key
so they reach the command book), ``_on_rsu`` (RSU localisation) and DDM-health watchdog; the
simulator's ``_on_state``; the RSU side's ``SimCamera._on_snapshot`` + render.
"""


from __future__ import annotations

import dataclasses
import random

import msgpack

from bench.fuzz_targets import C, _BusTarget, _corridor, mutated_payload
from protocol import keys
from protocol.clock import SimClock
from protocol.codec import ProtocolError, decode, encode
from protocol.enums import Manoeuvre, Role
from protocol.examples import example_messages, object_list
from protocol.local_bus import LocalBus
from protocol.messages import Health, PathSwitchCommand


class VehicleTarget(_BusTarget):
    """A VehicleService (signatures on: the corridor trusts one DDM key) stepped 10 ms (one control
    step) every second input; a fresh car every 4,000 inputs (20 s: the 500 m corridor ends)."""

    key = ""

    def __init__(self, rng: random.Random, localisation: str = "gnss") -> None:
        from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

        from protocol.security import Signer, public_key_b64

        private = Ed25519PrivateKey.generate()
        self.signer = Signer("ddm-fuzz", private)
        self.corridor = dataclasses.replace(_corridor(), trust=(
            {"key_id": "ddm-fuzz", "role": "ddm", "public_key": public_key_b64(private.public_key())},))
        self.localisation = localisation
        self.retired: dict[str, int] = {}
        self._new_car()
        super().__init__(rng)

    def _new_car(self) -> None:
        from vehicle.service import VehicleService

        self.bus, self.clock = LocalBus(), SimClock(1000.0)
        self.svc = VehicleService(self.bus, self.clock, self.corridor, "av1", localisation=self.localisation)
        self.n_car = 0

    def after(self) -> None:
        self.n_car += 1
        if self.n_car % 2:
            return
        self.svc.step(self.clock.now())
        self.clock.advance(0.01)
        if self.n_car % 200 == 0:
            self.bus.publish(keys.ddm_health_key(C), Health(src="ddm", stamp=self.clock.now(), role=Role.DDM))
        if self.n_car >= 4000:
            for k, v in self.sizes().items():
                self.retired[k] = max(self.retired.get(k, 0), v)
            self.svc.close()
            self._new_car()

    def _keys(self) -> list[str]:
        return [self.key]

    def sizes(self) -> dict[str, int]:
        s = self.svc
        return {"inbox": len(s._inbox), "acks_sent": len(s.acks_sent), "book_decisions": len(s.sim.core.book._decisions),
                "replay_seen": len(s.gate.replay._seen), "replay_seq": len(s.gate.replay._newest_seq),
                "max_over_cars_book_decisions": self.retired.get("book_decisions", 0),
                "max_over_cars_replay_seen": self.retired.get("replay_seen", 0)}


class VehicleCmdTarget(VehicleTarget):
    name = "vehicle_on_cmd"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.vehicle_key(C, "av1", "cmd")
        super().__init__(rng)

    def _command(self, manoeuvre: Manoeuvre) -> PathSwitchCommand:
        """A command for where the car is now (paths re-planned every 20 inputs: 13 cm of driving each)."""
        self.seq = getattr(self, "seq", 0) + 1
        now = self.clock.now()
        cache = getattr(self, "_cache", {})
        base = cache.get(manoeuvre)
        if base is None or self.seq - base[0] >= 20:
            base = cache[manoeuvre] = (self.seq, self._plan(manoeuvre))
            self._cache = cache
        return base[1].model_copy(update={"command_id": f"ddm-av1-{self.seq}", "command_seq": self.seq, "stamp": now,
                                          "issued_at": now, "valid_until": now + 10.0})

    def _plan(self, manoeuvre: Manoeuvre) -> PathSwitchCommand:
        from vehicle.reference import lane_change_waypoints

        road = self.corridor.road
        t = self.svc.sim.truth
        s_car = road.to_frenet(t.x_m, t.y_m)[0]
        now = self.clock.now()
        if manoeuvre == Manoeuvre.RESUME:
            wp: list = []
            stop = None
        else:
            wp = [(float(x), float(y)) for x, y in lane_change_waypoints(road, s_car + 5.0, 1, 0, 40.0, 120.0, lead_m=8.0)]
            sx, sy, _ = road.pose_at(s_car + 90.0, road.lane_centre_offset_m(0))
            stop = (float(sx), float(sy))
        return PathSwitchCommand(
            src="ddm", stamp=now, command_id="ddm-av1-0", command_seq=0, vehicle_id="av1",
            manoeuvre=manoeuvre, reason="fuzz", target_lane=0, waypoints=wp,
            speed_profile_mps=[max(0.0, 13.4 - 0.1 * i) for i in range(len(wp))], target_speed_mps=13.4,
            stop_point=stop, issued_at=now, valid_until=now + 10.0)

    def seeds(self) -> list[bytes]:
        return [encode(self._command(m)) for m in (Manoeuvre.PULL_OVER, Manoeuvre.RESUME, Manoeuvre.STOP_IN_LANE)]

    def payload(self) -> bytes:
        r = self.rng
        if r.random() < 0.75:  # from a command made for where the car is now
            cmd = self._command(r.choice((Manoeuvre.PULL_OVER, Manoeuvre.PULL_OVER, Manoeuvre.RESUME,
                                          Manoeuvre.SLOW_IN_LANE, Manoeuvre.LANE_CHANGE)))
            tree = msgpack.unpackb(encode(cmd), raw=False)
            if r.random() < 0.85:
                tree = self.mutator.mutate_tree(tree)
            try:
                p = msgpack.packb(tree, use_bin_type=True)
            except (OverflowError, ValueError, TypeError):
                return encode(cmd)
            if r.random() < 0.5:  # signed after mutation: passes the gate, the command book must cope
                try:
                    m = decode(p, PathSwitchCommand)
                    p = encode(self.signer.sign_message(self.key, m.model_copy(update={"auth": None})))
                except ProtocolError:
                    pass
            return p
        return super().payload()


class VehicleRsuTarget(VehicleTarget):
    name = "vehicle_on_rsu"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.rsu_key(C, "rsu1", "objects")
        super().__init__(rng, localisation="both")

    def seeds(self) -> list[bytes]:
        return [encode(object_list(n, 1000.0)) for n in (1, 3, 12)]

    def payload(self) -> bytes:
        if self.rng.random() < 0.5:  # an object list that holds the car itself (RSU fix)
            t = self.svc.sim.truth
            ol = object_list(2, self.clock.now())
            o = ol.objects[0]
            ol = ol.model_copy(update={"objects": [dataclasses.replace(o, pos_x_m=t.x_m + self.rng.gauss(0, 1),
                                                                       pos_y_m=t.y_m + self.rng.gauss(0, 1)),
                                                   ol.objects[1]],
                                       "measurement_time": self.clock.now() - self.rng.uniform(-0.5, 2.0)})
            return mutated_payload(self.mutator, self.rng, ol, 0.7)
        return super().payload()

    def _odd_keys(self) -> list[str]:
        return [keys.rsu_key(C, "rsu2", "ev"), keys.rsu_key(C, "rsu3", "health"), f"iea/{C}/rsu/rsu1/bogus"]


class VehicleDdmHealthTarget(VehicleTarget):
    name = "vehicle_on_ddm_health"

    def __init__(self, rng: random.Random) -> None:
        self.key = keys.ddm_health_key(C)
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=1000.0) if k == self.key]


# -- simulator and RSU side
class SimStateTarget(_BusTarget):
    name = "sim_on_state"

    def __init__(self, rng: random.Random) -> None:
        from sim.scenario import load_scenario
        from sim.service import SimService

        self.bus, self.clock = LocalBus(), SimClock(10.0)
        self.scenario = load_scenario("rellis_ev_yield")
        self.svc = SimService(self.scenario, self.bus, self.clock, corridor_id=C, seed=1)
        self.rejections_before = 0
        self.n = 0
        super().__init__(rng)

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=10.0) if k.endswith("/state")]

    def _keys(self) -> list[str]:
        return [keys.vehicle_key(C, "av1", "state")]

    def _odd_keys(self) -> list[str]:
        return [keys.vehicle_key(C, "ghost", "state")]

    def feed(self, payload: bytes) -> bool:
        before = self.svc.rejected["unknown_vehicle"]
        got = super().feed(payload)
        return got and self.svc.rejected["unknown_vehicle"] == before

    def after(self) -> None:
        self.n += 1
        if self.n % 10 == 0:
            self.clock.advance(0.05)
            self.svc.step_once()
        if self.n % 20000 == 0:  # the scenario is finite: start it again
            from sim.world import World
            self.svc.world = World(self.scenario, seed=1)

    def sizes(self) -> dict[str, int]:
        return {"pending_states": len(self.svc._pending_states), "last_state": len(self.svc._last_state),
                "actors": len(self.svc.world.snapshot(0.0).actors)}


class RsuSnapshotTarget(_BusTarget):
    """The RSU's only peer input (``--source sim``): world snapshots, rendered every 200th input."""

    name = "rsu_sim_camera"

    def __init__(self, rng: random.Random) -> None:
        from sim.camera_source import SimCamera

        self.bus = LocalBus()
        self.camera = SimCamera(_corridor(), "rsu1", transport=self.bus, seed=0)
        self.n = 0
        super().__init__(rng)
        for seed in self.mutator.seeds:  # warm the renderer's caches before memory is measured
            self.camera.render(decode(seed))

    def seeds(self) -> list[bytes]:
        return [encode(m) for k, m in example_messages(C, stamp=1.0) if k.endswith("/world")]

    def _keys(self) -> list[str]:
        return [keys.sim_world_key(C)]

    def after(self) -> None:
        self.n += 1
        held = self.camera.newest_held
        if self.n % 200 == 0 and held is not None:
            self.camera.render(held)

    def sizes(self) -> dict[str, int]:
        return {"snapshots_held": self.camera.frames_held}
