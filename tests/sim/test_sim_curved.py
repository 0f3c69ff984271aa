"""A corridor with a curve: vehicles follow the arc and the renderer draws the bend."""

import math

import numpy as np

from protocol.corridor import parse_corridor
from sim.render.renderer import Renderer
from sim.scenario import parse_scenario
from sim.world import World

CURVED = {
    "corridor": {"id": "bend", "origin_lat_deg": 30.0, "origin_lon_deg": -96.0},
    "road": {"lanes": 2, "segments": [{"kind": "straight", "length_m": 60.0},
                                      {"kind": "arc", "length_m": 120.0, "radius_m": 150.0},
                                      {"kind": "straight", "length_m": 100.0}]},
    "rsu": [{"id": "cam", "x_m": 0.0, "y_m": -4.5,
             "camera": {"height_m": 10.7, "yaw_rad": 0.25, "pitch_rad": 0.23, "fx_px": 1100.0}}],
}


def test_vehicles_follow_the_arc_and_the_bend_is_rendered():
    corridor = parse_corridor(CURVED, "bend.toml")
    sc = parse_scenario({"scenario": {"name": "bend", "duration_s": 20.0, "seed": 1},
                         "av": {"start_s_m": 40.0, "lane": 0, "speed_mps": 12.0},
                         "traffic": {"density_veh_per_km_lane": 0.0}}, "bend.toml", corridor)
    w = World(sc)
    w.run_until(8.0)
    av = next(a for a in w.snapshot().actors if a.actor_id == "av1")
    s, d = corridor.road.to_frenet(av.pos_x_m, av.pos_y_m)
    assert 120.0 < s < 145.0 and abs(d - corridor.road.lane_centre_offset_m(0)) < 0.1
    _, _, heading = corridor.road.pose_at(s, d)
    assert heading > 0.3 and abs(av.heading_rad - heading) < 0.05  # turned left with the road
    r = Renderer(corridor.rsu("cam").camera, corridor.road, noise=False, exposure=False)
    bg = r.background("day")
    # the road (grey, low saturation) bends: its centre column moves left from near rows to far rows
    import cv2

    hsv = cv2.cvtColor(bg, cv2.COLOR_BGR2HSV)
    road = (hsv[..., 1] < 40) & (hsv[..., 2] > 60) & (hsv[..., 2] < 200)
    horizon = int(r.cam.horizon_v_px())
    rows = [horizon + 55, horizon + 150, 700]
    centres = [float(np.mean(np.flatnonzero(road[v]))) for v in rows]
    assert all(math.isfinite(c) for c in centres)
    assert centres[0] < centres[1] - 100  # far road well to the left: the bend
    labels = r.labels(w.snapshot())
    assert [lb.actor_id for lb in labels] == ["av1"]
