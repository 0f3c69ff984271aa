"""Corridor files: the default loads, geometry is exact, bad files say where and why."""

from __future__ import annotations

import math

import numpy as np
import pytest

from protocol.corridor import CorridorError, load_corridor, parse_corridor
from protocol.road import Road, Segment


def test_default_corridor_is_the_rellis_test():
    c = load_corridor()
    assert c.corridor_id == "rellis"
    assert [r.rsu_id for r in c.rsus] == ["rsu1", "rsu2", "rsu3", "rsu4"]
    assert c.rsu_index("rsu3") == 2 and c.rsu("rsu3") is c.rsus[2]
    with pytest.raises(KeyError, match="has no RSU 'rsu9'; it has"):
        c.rsu_index("rsu9")
    xs = [r.camera.x_m for r in c.rsus]
    assert np.allclose(np.diff(xs), 50.0)
    assert all(r.camera.height_m == pytest.approx(10.7) for r in c.rsus)
    assert c.road.lanes == 2 and c.road.segments[0].kind == "straight"
    assert all(len(r.calibration) > 50 for r in c.rsus)
    assert c.vehicle("av1").cruise_speed_mps == pytest.approx(13.4)
    lat, lon = c.to_latlon(0.0, 0.0)
    assert (lat, lon) == pytest.approx((c.origin_lat_deg, c.origin_lon_deg), abs=1e-12)
    assert 30.5 < lat < 30.8 and -96.6 < lon < -96.3  # near the RELLIS campus
    x, y = c.from_latlon(*c.to_latlon(123.4, -56.7))
    assert (x, y) == pytest.approx((123.4, -56.7), abs=1e-6)


def test_camera_looks_at_the_road():
    c = load_corridor()
    cam = c.rsus[0].camera
    r = cam.rotation_world_to_camera
    assert np.allclose(r @ r.T, np.eye(3), atol=1e-12)
    # road points 25 m and 110 m ahead project inside the image, the far one higher up
    near = cam.projection_matrix @ np.array([cam.x_m + 25.0, 3.7, 0.0, 1.0])
    far = cam.projection_matrix @ np.array([cam.x_m + 110.0, 3.7, 0.0, 1.0])
    (un, vn), (uf, vf) = near[:2] / near[2], far[:2] / far[2]
    assert 0 < un < cam.width_px and 0 < uf < cam.width_px
    assert 0 < vf < vn < cam.height_px


def test_curved_road_geometry_is_exact():
    road = Road(0.0, 0.0, 0.0, (Segment("straight", 50.0), Segment("arc", 100.0, 200.0)), lanes=2)
    x, y, h = road.pose_at(150.0)
    theta = 100.0 / 200.0
    assert (x, y, h) == pytest.approx((50.0 + 200.0 * math.sin(theta), 200.0 * (1 - math.cos(theta)), theta), abs=1e-9)
    for s, d in [(10.0, 1.0), (80.0, 5.0), (140.0, -1.5), (120.0, 2.2)]:
        px, py, _ = road.pose_at(s, d)
        s2, d2 = road.to_frenet(px, py)
        assert (s2, d2) == pytest.approx((s, d), abs=2e-3)
    assert road.lane_of_offset(1.0) == 0 and road.lane_of_offset(5.0) == 1
    assert road.lane_of_offset(-0.5) is None and road.lane_of_offset(7.5) is None
    assert road.curvature_at(100.0) == pytest.approx(1 / 200.0)


def _base() -> dict:
    return {
        "corridor": {"id": "c1", "origin_lat_deg": 30.6, "origin_lon_deg": -96.4},
        "road": {"segments": [{"kind": "straight", "length_m": 100.0}]},
        "rsu": [{"id": "r1", "x_m": 0.0, "y_m": -4.0,
                 "camera": {"yaw_rad": 0.1, "pitch_rad": 0.2, "fx_px": 1000.0}}],
    }


@pytest.mark.parametrize("mutate,fragment", [
    (lambda d: d.pop("corridor"), "field 'corridor': expected a table (missing)"),
    (lambda d: d["corridor"].update(origin_lat_deg=123.0), "field 'corridor.origin_lat_deg': expected a number in [-90.0, 90.0]"),
    (lambda d: d["corridor"].update(id="bad id"), "field 'corridor.id'"),
    (lambda d: d["road"]["segments"][0].update(kind="spiral"), "field 'road.segments[0].kind': expected one of"),
    (lambda d: d["road"]["segments"].append({"kind": "arc", "length_m": 10.0}), "road.segments[1].radius_m"),
    (lambda d: d["road"]["segments"][0].update(length_m=-5), "expected a number > 0"),
    (lambda d: d["rsu"][0]["camera"].pop("fx_px"), "field 'rsu[0].camera.fx_px': expected a number (missing)"),
    (lambda d: d["rsu"][0]["camera"].update(width_px="wide"), "rsu[0].camera.width_px"),
    (lambda d: d["rsu"].append(dict(d["rsu"][0])), "unique RSU ids"),
    (lambda d: d["rsu"][0].update(calibration=[[1, 2, 3]]), "rsu[0].calibration[0]"),
    (lambda d: d["road"].update(lanes=0), "field 'road.lanes'"),
])
def test_bad_files_say_file_field_and_expectation(mutate, fragment):
    data = _base()
    mutate(data)
    with pytest.raises(CorridorError) as info:
        parse_corridor(data, "my.toml")
    assert str(info.value).startswith("my.toml: ")
    assert fragment in str(info.value)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(CorridorError, match="not found"):
        load_corridor(tmp_path / "nope.toml")
    bad = tmp_path / "bad.toml"
    bad.write_text("[corridor\nid=1")
    with pytest.raises(CorridorError, match="bad.toml: not valid TOML"):
        load_corridor(bad)


def test_minimal_file_gets_sensible_defaults():
    c = parse_corridor(_base(), "x.toml")
    cam = c.rsus[0].camera
    assert (cam.width_px, cam.height_px, cam.cx_px, cam.cy_px, cam.fy_px) == (1280, 720, 640.0, 360.0, 1000.0)
    assert c.road.lane_width_m == 3.7 and c.transport.dsrc_range_m == 300.0


def test_frenet_and_pose_fast_paths_match_the_full_search_on_curved_roads():
    """``Road.to_frenet`` looks only at the two pieces meeting at the nearest sample (k-d tree) and ``pose_at``
    of one point runs on plain floats: both give what the vectorised full search over every piece gives."""
    import numpy as np

    from protocol.road import Road, Segment

    road = Road(10.0, -3.0, 0.3, (Segment("straight", 100.0), Segment("arc", 150.0, 60.0),
                                   Segment("straight", 50.0), Segment("arc", 200.0, -100.0)))
    rng = np.random.default_rng(1)
    s = rng.uniform(-20.0, road.length_m + 20.0, 500)
    d = rng.uniform(-15.0, 20.0, 500)
    x, y, h = road.pose_at(s, d)
    for k in range(0, 500, 25):
        assert road.pose_at(float(s[k]), float(d[k])) == pytest.approx((x[k], y[k], h[k]), abs=1e-9)
    x = x + rng.normal(0.0, 2.0, 500)
    got_s, got_d = road.to_frenet(x, y)
    # brute force: project every point onto every piece of the sampled line, then the same refinement
    _, xs, ys, _ = road._samples
    ax, ay, bx, by = xs[:-1], ys[:-1], np.diff(xs), np.diff(ys)
    t = np.clip(((x[:, None] - ax) * bx + (y[:, None] - ay) * by) / (bx * bx + by * by), 0.0, 1.0)
    i = np.argmin((x[:, None] - ax - t * bx) ** 2 + (y[:, None] - ay - t * by) ** 2, axis=1)
    s0 = road._samples[0][i] + t[np.arange(500), i] * road.sample_step_m
    for k in range(500):
        sk = float(s0[k])
        for _ in range(2):
            rx, ry, rh = road.pose_at(sk)
            sk = min(max(sk + (x[k] - rx) * np.cos(rh) + (y[k] - ry) * np.sin(rh), 0.0), road.length_m)
        assert got_s[k] == pytest.approx(sk, abs=1e-6)
    assert road.to_frenet(float(x[3]), float(y[3])) == pytest.approx((got_s[3], got_d[3]))


def test_prepare_builds_what_the_first_road_query_would():
    """``Road.prepare`` (a service's start-up) leaves nothing for the first ``to_frenet`` to build."""
    road = Road(0.0, 0.0, 0.0, (Segment("straight", 50.0), Segment("arc", 40.0, 60.0)))
    assert "_sample_tree" not in road.__dict__
    assert road.prepare() is road
    assert {"_samples", "_sample_tree", "_pieces", "_samples_list"} <= set(road.__dict__)
    s, d = road.to_frenet(30.0, 1.5)
    assert float(s) == pytest.approx(30.0) and float(d) == pytest.approx(1.5)
