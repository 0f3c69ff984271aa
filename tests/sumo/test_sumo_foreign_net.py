"""A SUMO network the project did not make: the on-ramp sample that ships with eclipse-sumo. A corridor is written
on it (RSUs placed along an edge), and an EV scenario runs on it end to end: SUMO traffic, the RSUs' cameras
rendering it, detection, the EvAlert, the DDM's command to the AV."""

from __future__ import annotations

from pathlib import Path

import pytest

pytestmark = pytest.mark.usefixtures("need_sumo")

SCENARIO = """
[scenario]
name = "ramp_ev"
corridor = "{corridor}"
duration_s = {duration_s}
seed = 3
traffic = "sumo"

[traffic]
density_veh_per_km_lane = 6.0
speed_mps = 12.0
spawn_s_min_m = 0.0
spawn_s_max_m = 300.0

[av]
id = "av1"
start_s_m = 100.0
lane = 1
speed_mps = 13.4

[ev]
start_offset_m = -45.0
lane = 1
speed_mps = 19.0
lights_on_at_s = 1.0
"""


@pytest.fixture(scope="module")
def ramp_net() -> Path:
    import sumo

    net = Path(sumo.SUMO_HOME) / "tools" / "game" / "ramp" / "ramp.net.xml"
    if not net.is_file():
        pytest.skip(f"{net}: the eclipse-sumo package ships no ramp sample here")
    return net


def test_corridor_on_a_foreign_network_has_its_road(ramp_net, tmp_path):
    from protocol.corridor import load_corridor
    from sim.sumo.corridor import sumo_section, write_corridor
    from sim.sumo.network import read_net

    path = write_corridor(ramp_net, ["gneE8", "gneE11"], [("rsu1", "gneE11", 20.0, 4.5)], tmp_path / "ramp.toml",
                          corridor_id="ramp")
    corridor = load_corridor(path)
    net = read_net(ramp_net)
    assert corridor.road.lanes == 2 and corridor.road.lane_width_m == pytest.approx(net.getEdge("gneE11").getLane(0).getWidth())
    assert corridor.road.length_m == pytest.approx(net.getEdge("gneE8").getLength() + net.getEdge("gneE11").getLength(),
                                                   abs=15.0)
    # the curb line is lane 0's right edge: lane 0's centre line lies half a lane to its left
    x, y = net.getEdge("gneE11").getLane(0).getShape()[1]
    s, d = corridor.road.to_frenet(x, y)
    assert d == pytest.approx(corridor.road.lane_width_m / 2, abs=0.05)
    assert len(corridor.rsu("rsu1").calibration) > 50
    section = sumo_section(corridor)
    assert section.route == ("gneE8", "gneE11") and section.net == ramp_net.resolve()
    # a road edited away from its network (moved 3 m) is refused
    bad = path.with_name("bad.toml")
    y0 = corridor.road.start_y_m
    bad.write_text(path.read_text().replace(f"start_y_m = {round(y0, 6)!r}", f"start_y_m = {y0 + 3.0!r}", 1))
    assert load_corridor(bad).road.start_y_m == pytest.approx(y0 + 3.0)
    with pytest.raises(ValueError, match="python -m sim.sumo.corridor"):
        sumo_section(load_corridor(bad))


@pytest.mark.slow
def test_ev_scenario_end_to_end_on_a_foreign_network(ramp_net, tmp_path):
    from scenario.lockstep import CorridorLockstep, LockstepConfig
    from sim.scenario import load_scenario
    from sim.sumo.corridor import write_corridor

    corridor = write_corridor(ramp_net, ["gneE11"], [("rsu1", "gneE11", 10.0, 4.5), ("rsu2", "gneE11", 70.0, 4.5)],
                              tmp_path / "ramp.toml", corridor_id="ramp", av_start_s_m=100.0, av_lane=1)
    (tmp_path / "ramp_ev.toml").write_text(SCENARIO.format(corridor=corridor, duration_s=9.0))
    sc = load_scenario(tmp_path / "ramp_ev.toml")
    runner = CorridorLockstep(LockstepConfig(warmup_s=2.0), scenario=sc)
    m = runner.run()
    assert m["traffic"] == "sumo" and not m["collision"]
    assert m["first_alert_rsu"] in ("rsu1", "rsu2")  # the cameras saw SUMO's EV with its lights on
    assert m["commands"] and m["commands"][0]["manoeuvre"] != "resume"  # and the DDM told the AV to make way
