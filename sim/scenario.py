"""Scenario files (``sim/scenarios/*.toml``): load and validate into a ``Scenario``.

A scenario names the corridor, the duration, the seed and the lighting, the background traffic
(density, speeds, vehicle mix, the fraction of drivers that yield to an EV with lights on, the
fractions with hazard flashers or a turn signal blinking, the buses with LED strips, stop-and-go waves), the EV
(start offset behind the AV, lane, speed, light bar switch-on time, pattern and frequency), static
hazards, the AV script, distractor vehicles (red cars, blue cars, red/white vans without lights,
cars that brake, buses with LED strips) and works vehicles with amber roof beacons (``[[works]]``). A bad
file fails with ``ScenarioError`` naming the file, the field and what was expected. See
``sim/scenarios/rellis_ev_yield.toml`` for a commented example.
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from protocol.corridor import DEFAULT_CORRIDOR, Corridor, CorridorError, load_corridor
from protocol.tomlfields import FieldReader

SCENARIO_DIR = Path(__file__).resolve().parent / "scenarios"
CORRIDOR_DIR = DEFAULT_CORRIDOR.parent
LIGHTINGS = ("day", "dusk", "night")
PATTERNS = ("alternating", "strobe")
DISTRACTOR_TYPES = ("red_car", "blue_car", "red_white_van", "brake_car", "white_van", "red_truck", "led_bus",
                    "chasing_led_bus")
WORKS_BODIES = ("van", "truck")
EV_BODIES = ("ambulance", "police")
TRAFFIC_MODELS = ("project", "sumo")
"""Who drives the traffic (``[scenario] traffic``, ``--traffic``): the simulator's own model or Eclipse SUMO."""
DEBRIS_KINDS = ("box", "rock", "barrel", "pallet", "pipe", "tyre")
"""Debris of the hazard report's simulation (rocks, wooden boxes, oil barrels, wooden pallets, sections of
pipe) and a lost tyre; the index is the debris' livery (``sim.render.renderer`` draws each kind)."""


class ScenarioError(ValueError):
    """A scenario file that cannot be used; the message says where and why."""


@dataclass(frozen=True)
class TrafficSpec:
    density_veh_per_km_lane: float = 12.0
    speed_mps: float = 12.0
    speed_spread_mps: float = 1.5
    spawn_s_min_m: float = 0.0
    spawn_s_max_m: float = 350.0
    yield_fraction: float = 0.6
    van_fraction: float = 0.15
    truck_fraction: float = 0.08
    bus_fraction: float = 0.04
    red_fraction: float = 0.1
    blue_fraction: float = 0.08
    hazard_flasher_fraction: float = 0.08
    """Background vehicles with amber hazard flashers blinking at their four corners (sim.lamps)."""
    turn_signal_fraction: float = 0.08
    """Background vehicles with one red rear turn signal blinking (US style)."""
    bus_led_fraction: float = 0.25
    """Background buses with an LED strip along the roof and destination boards (blue, a third white; sim.lamps)."""
    bus_led_chase_fraction: float = 0.5
    """... of which this share chase (a lit block runs along the strip); the others are steady."""
    stop_and_go_period_s: float = 0.0
    """Stop-and-go waves: every background driver slows hard for half of each period of a wave running upstream
    at ``sim.traffic.STOP_GO_WAVE_MPS`` (brake lights come on down the queue); 0: off, else 2-120 s."""
    flow_veh_per_h: float = 0.0
    """SUMO traffic: vehicles per hour entering at the corridor's start (0: density x speed, per lane)."""
    side_flow_route: tuple[str, ...] = ()
    """SUMO traffic: edges of a second flow (e.g. an on-ramp onto the corridor) ..."""
    side_flow_veh_per_h: float = 0.0
    """... and its vehicles per hour."""
    sumo_sublane: bool = False
    """SUMO traffic: the sublane model (drivers open a rescue lane between lanes for an EV; costs CPU)."""


@dataclass(frozen=True)
class AvSpec:
    vehicle_id: str = "av1"
    start_s_m: float = 100.0
    lane: int = 1
    speed_mps: float = 13.4


@dataclass(frozen=True)
class EvSpec:
    start_offset_m: float = -50.0
    """Start position along the road relative to the AV (negative = behind)."""
    lane: int = 1
    speed_mps: float = 19.0
    lights_on_at_s: float | None = 4.0
    """None: the light bar never switches on."""
    pattern: str = "alternating"
    frequency_hz: float = 2.0
    body: str = "ambulance"
    equipped: bool = False
    """The EV carries a V2X unit: it broadcasts CAMs with its light bar and siren state (sim/ev_radio.py)."""
    sumo_route: tuple[str, ...] = ()
    """SUMO traffic: the EV drives these edges of the network (e.g. from a side road onto the corridor),
    from ``sumo_depart_pos_m`` along the first, entering at ``depart_s``; empty: it starts on the corridor."""
    sumo_depart_pos_m: float = 0.0
    depart_s: float = 0.0


@dataclass(frozen=True)
class HazardSpec:
    s_m: float
    lane: int
    length_m: float = 0.8
    width_m: float = 0.7
    height_m: float = 0.35
    offset_m: float = 0.0
    kind: str = "box"
    appear_s: float = 0.0
    """Sim time the object lands on the road (0: there from the start; later: it falls off a vehicle)."""
    remove_s: float | None = None
    """Sim time it is cleared from the road (None: it stays)."""


@dataclass(frozen=True)
class DistractorSpec:
    kind: str
    s_m: float
    lane: int
    speed_mps: float = 11.0
    brake_period_s: float = 0.0
    """brake_car: the driver brakes for half of every period (brake lights flash on and off)."""


@dataclass(frozen=True)
class WorksSpec:
    """A works vehicle with an amber beacon flashing on its roof (sim.lamps): parked (speed 0; e.g. on the
    shoulder with ``offset_m``) or driving slowly in its lane."""

    s_m: float
    lane: int = 0
    offset_m: float = 0.0
    """From the lane centre, -4..4 m (negative: to the right; about -2.6 puts it on the shoulder of lane 0)."""
    speed_mps: float = 0.0
    body: str = "van"
    beacon_hz: float = 2.5
    """1.5-4 Hz."""
    hazard_flashers: bool = False


@dataclass(frozen=True)
class Scenario:
    name: str
    corridor: Corridor
    duration_s: float
    seed: int
    lighting: str
    traffic: TrafficSpec
    av: AvSpec | None
    ev: EvSpec | None
    hazards: tuple[HazardSpec, ...] = ()
    distractors: tuple[DistractorSpec, ...] = ()
    works: tuple[WorksSpec, ...] = ()
    description: str = ""
    source: str = ""
    extra: dict[str, Any] = field(default_factory=dict)
    traffic_model: str = "project"
    """Who drives the traffic: ``project`` (``sim.traffic``) or ``sumo`` (``sim.sumo``)."""

    def with_overrides(self, *, seed: int | None = None, lighting: str | None = None,
                       traffic: str | None = None) -> Scenario:
        from dataclasses import replace

        if lighting is not None and lighting not in LIGHTINGS:
            raise ScenarioError(f"lighting must be one of {LIGHTINGS}, got {lighting!r}")
        if traffic is not None and traffic not in TRAFFIC_MODELS:
            raise ScenarioError(f"traffic must be one of {TRAFFIC_MODELS}, got {traffic!r}")
        return replace(self, seed=self.seed if seed is None else seed,
                       lighting=self.lighting if lighting is None else lighting,
                       traffic_model=self.traffic_model if traffic is None else traffic)


def resolve_scenario_path(name_or_path: str | Path) -> Path:
    """A scenario name (``rellis_ev_yield``) or a path to a TOML file."""
    p = Path(name_or_path)
    if p.suffix == ".toml" or p.exists():
        return p
    return SCENARIO_DIR / f"{name_or_path}.toml"


def list_scenarios() -> list[str]:
    return sorted(p.stem for p in SCENARIO_DIR.glob("*.toml"))


def _resolve_corridor(value: str, scenario_path: Path) -> Path:
    if "/" not in value and not value.endswith(".toml"):
        return CORRIDOR_DIR / f"{value}.toml"
    p = Path(value)
    if not p.is_absolute():
        beside = scenario_path.parent / p
        p = beside if beside.exists() else Path.cwd() / p
    return p


def load_scenario(name_or_path: str | Path, corridor: Corridor | None = None) -> Scenario:
    """Load a scenario by name or path; ``corridor`` overrides the file's corridor."""
    path = resolve_scenario_path(name_or_path)
    if not path.is_file():
        raise ScenarioError(f"{path}: scenario not found; known scenarios: {list_scenarios()}")
    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as exc:
        raise ScenarioError(f"{path}: not valid TOML: {exc}") from None
    return parse_scenario(data, str(path), corridor)


def _flag(r: FieldReader, key: str) -> bool:
    v = r.data.get(key, False)
    if not isinstance(v, bool):
        raise r.fail(key, "true or false", v)
    return v


def parse_scenario(data: dict[str, Any], source: str = "<scenario>", corridor: Corridor | None = None) -> Scenario:
    top = FieldReader(source, data, error=ScenarioError)
    top.check_keys({"scenario", "traffic", "av", "ev", "hazard", "distractor", "works"})
    sc = top.optional_table("scenario")
    if sc is None:
        raise top.fail("scenario", "a [scenario] table (missing)")
    sc.check_keys({"name", "description", "corridor", "duration_s", "seed", "lighting", "traffic"})
    name = sc.text("name")
    if not all(c.isalnum() or c in "_-." for c in name):
        raise sc.fail("name", "an id of letters, digits, '_', '-', '.'", name)
    if corridor is None:
        try:
            corridor = load_corridor(_resolve_corridor(sc.text("corridor", "rellis"), Path(source)))
        except CorridorError as exc:
            raise ScenarioError(f"{source}: field 'scenario.corridor': {exc}") from None
    road = corridor.road
    lanes = road.lanes

    def lane_of(r: FieldReader, key: str, default: int) -> int:
        return r.integer(key, default, lo=0, hi=lanes - 1)

    traffic = TrafficSpec()
    tr = top.optional_table("traffic")
    if tr is not None:
        tr.check_keys(set(TrafficSpec.__dataclass_fields__))
        d = TrafficSpec()
        traffic = TrafficSpec(
            density_veh_per_km_lane=tr.num("density_veh_per_km_lane", d.density_veh_per_km_lane, 0.0, 120.0),
            speed_mps=tr.num("speed_mps", d.speed_mps, 0.0, 40.0),
            speed_spread_mps=tr.num("speed_spread_mps", d.speed_spread_mps, 0.0, 10.0),
            spawn_s_min_m=tr.num("spawn_s_min_m", d.spawn_s_min_m, 0.0, road.length_m),
            spawn_s_max_m=tr.num("spawn_s_max_m", min(d.spawn_s_max_m, road.length_m), 0.0, road.length_m),
            yield_fraction=tr.num("yield_fraction", d.yield_fraction, 0.0, 1.0),
            van_fraction=tr.num("van_fraction", d.van_fraction, 0.0, 1.0),
            truck_fraction=tr.num("truck_fraction", d.truck_fraction, 0.0, 1.0),
            bus_fraction=tr.num("bus_fraction", d.bus_fraction, 0.0, 1.0),
            red_fraction=tr.num("red_fraction", d.red_fraction, 0.0, 1.0),
            blue_fraction=tr.num("blue_fraction", d.blue_fraction, 0.0, 1.0),
            hazard_flasher_fraction=tr.num("hazard_flasher_fraction", d.hazard_flasher_fraction, 0.0, 1.0),
            turn_signal_fraction=tr.num("turn_signal_fraction", d.turn_signal_fraction, 0.0, 1.0),
            bus_led_fraction=tr.num("bus_led_fraction", d.bus_led_fraction, 0.0, 1.0),
            bus_led_chase_fraction=tr.num("bus_led_chase_fraction", d.bus_led_chase_fraction, 0.0, 1.0),
            stop_and_go_period_s=tr.num("stop_and_go_period_s", 0.0, 0.0, 120.0),
            flow_veh_per_h=tr.num("flow_veh_per_h", 0.0, 0.0, 20000.0),
            side_flow_route=tuple(tr.str_list("side_flow_route")) if tr.has("side_flow_route") else (),
            side_flow_veh_per_h=tr.num("side_flow_veh_per_h", 0.0, 0.0, 20000.0),
            sumo_sublane=_flag(tr, "sumo_sublane"),
        )
        if traffic.spawn_s_max_m < traffic.spawn_s_min_m:
            raise tr.fail("spawn_s_max_m", f"a value >= spawn_s_min_m ({traffic.spawn_s_min_m})",
                          traffic.spawn_s_max_m)
        if traffic.van_fraction + traffic.truck_fraction + traffic.bus_fraction > 1.0:
            raise tr.fail("van_fraction", "van + truck + bus fractions <= 1")
        if traffic.hazard_flasher_fraction + traffic.turn_signal_fraction > 1.0:
            raise tr.fail("turn_signal_fraction", "hazard_flasher_fraction + turn_signal_fraction <= 1")
        if 0.0 < traffic.stop_and_go_period_s < 2.0:
            raise tr.fail("stop_and_go_period_s", "0 (off) or 2..120 s", traffic.stop_and_go_period_s)

    av = None
    avr = top.optional_table("av")
    if avr is not None:
        avr.check_keys({"id", "start_s_m", "lane", "speed_mps"})
        av = AvSpec(vehicle_id=avr.text("id", "av1"), start_s_m=avr.num("start_s_m", 100.0, 0.0, road.length_m),
                    lane=lane_of(avr, "lane", min(1, lanes - 1)), speed_mps=avr.num("speed_mps", 13.4, 0.0, 40.0))

    ev = None
    evr = top.optional_table("ev")
    if evr is not None:
        evr.check_keys({"start_offset_m", "start_s_m", "lane", "speed_mps", "lights_on_at_s", "pattern",
                        "frequency_hz", "body", "equipped", "sumo_route", "sumo_depart_pos_m",
                        "depart_s"})
        equipped = evr.data.get("equipped", False)
        if not isinstance(equipped, bool):
            raise evr.fail("equipped", "true or false", equipped)
        if "start_s_m" in evr.data:
            offset = evr.num("start_s_m", 0.0, 0.0, road.length_m) - (av.start_s_m if av else 0.0)
        else:
            offset = evr.num("start_offset_m", -50.0, -road.length_m, road.length_m)
        lights = evr.num("lights_on_at_s", -1.0, -1.0, 1e6)
        ev = EvSpec(start_offset_m=offset, lane=lane_of(evr, "lane", min(1, lanes - 1)),
                    speed_mps=evr.num("speed_mps", 19.0, 0.0, 45.0),
                    lights_on_at_s=None if lights < 0 else lights,
                    pattern=evr.text("pattern", "alternating", PATTERNS),
                    frequency_hz=evr.num("frequency_hz", 2.0, 1.0, 4.0),
                    body=evr.text("body", "ambulance", EV_BODIES), equipped=equipped,
                    sumo_route=tuple(evr.str_list("sumo_route")) if evr.has("sumo_route") else (),
                    sumo_depart_pos_m=evr.num("sumo_depart_pos_m", 0.0, 0.0, 1e5),
                    depart_s=evr.num("depart_s", 0.0, 0.0, 3600.0))

    hazards = []
    for hr in top.tables("hazard", required=False):
        hr.check_keys(set(HazardSpec.__dataclass_fields__))
        hazards.append(HazardSpec(s_m=hr.num("s_m", None, 0.0, road.length_m), lane=lane_of(hr, "lane", 0),
                                  length_m=hr.num("length_m", 0.8, 0.1, 5.0), width_m=hr.num("width_m", 0.7, 0.1, 3.0),
                                  height_m=hr.num("height_m", 0.35, 0.05, 2.0),
                                  offset_m=hr.num("offset_m", 0.0, -4.0, 4.0),
                                  kind=hr.text("kind", "box", DEBRIS_KINDS),
                                  appear_s=hr.num("appear_s", 0.0, 0.0, 3600.0),
                                  remove_s=(None if "remove_s" not in hr.data else hr.num("remove_s", None, 0.0, 3600.0))))
        if hazards[-1].remove_s is not None and hazards[-1].remove_s <= hazards[-1].appear_s:
            raise hr.fail("remove_s", f"a time later than appear_s ({hazards[-1].appear_s})", hazards[-1].remove_s)
    distractors = []
    for dr in top.tables("distractor", required=False):
        dr.check_keys(set(DistractorSpec.__dataclass_fields__))
        distractors.append(DistractorSpec(kind=dr.text("kind", None, DISTRACTOR_TYPES),
                                          s_m=dr.num("s_m", None, 0.0, road.length_m), lane=lane_of(dr, "lane", 0),
                                          speed_mps=dr.num("speed_mps", 11.0, 0.0, 40.0),
                                          brake_period_s=dr.num("brake_period_s", 0.0, 0.0, 60.0)))
    works = []
    for wr in top.tables("works", required=False):
        wr.check_keys(set(WorksSpec.__dataclass_fields__))
        works.append(WorksSpec(s_m=wr.num("s_m", None, 0.0, road.length_m), lane=lane_of(wr, "lane", 0),
                               offset_m=wr.num("offset_m", 0.0, -4.0, 4.0),
                               speed_mps=wr.num("speed_mps", 0.0, 0.0, 30.0),
                               body=wr.text("body", "van", WORKS_BODIES),
                               beacon_hz=wr.num("beacon_hz", 2.5, 1.5, 4.0),
                               hazard_flashers=_flag(wr, "hazard_flashers")))
    return Scenario(
        name=name, corridor=corridor, duration_s=sc.num("duration_s", 30.0, 0.1, 3600.0),
        seed=sc.integer("seed", 0), lighting=sc.text("lighting", "day", LIGHTINGS), traffic=traffic, av=av, ev=ev,
        hazards=tuple(hazards), distractors=tuple(distractors), works=tuple(works),
        description=sc.data.get("description", ""),
        source=source, traffic_model=sc.text("traffic", "project", TRAFFIC_MODELS),
    )
