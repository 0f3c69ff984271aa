"""The scale row's corridor files: the RELLIS corridor's RSUs repeated along a longer road (pure)."""

from __future__ import annotations

from deploy.netlab.scale import corridor_text
from protocol.corridor import DEFAULT_CORRIDOR, load_corridor


def test_eight_rsus_along_the_road_under_the_given_id(tmp_path):
    path = tmp_path / "c.toml"
    path.write_text(corridor_text(DEFAULT_CORRIDOR.read_text(), "city1x", 8))
    c = load_corridor(str(path))
    assert c.corridor_id == "city1x"
    assert [r.rsu_id for r in c.rsus] == [f"rsu{k}" for k in range(1, 9)]
    xs = [r.camera.x_m for r in c.rsus]
    assert xs == sorted(xs) and len(set(xs)) == 8 and xs[4] - xs[0] == 200.0
    base = load_corridor()
    assert c.road.length_m >= base.road.length_m + 200.0
