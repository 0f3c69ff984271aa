"""The pure fusion of an EV's CAM with the camera tracks: gates, probability of association, evidence."""

from __future__ import annotations

import math

import numpy as np

from ddm.v2x_fusion import CameraTracks, CameraView, CamObservation, V2xFusion, V2xFusionConfig, associate

CFG = V2xFusionConfig()


def cam(x: float, y: float, *, heading: float = 0.0, speed: float = 20.0, t: float = 10.0, sigma: float = 1.0,
        station: int = 7) -> CamObservation:
    return CamObservation(station, t, x, y, heading, speed, sigma, True)


def tracks(*rows: tuple[float, float, float, float]) -> CameraTracks:
    a = np.array(rows, dtype=float).reshape(-1, 4)
    n = len(a)
    return CameraTracks(np.arange(1, n + 1), a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.full(n, 0.25), np.full(n, 10.0))


VIEW = CameraView("rsu1", 0.0, -4.5, 0.18, 0.52, 85.0, 10.0)


def test_the_nearest_compatible_track_is_associated_with_high_probability():
    a = associate(cam(50.0, 5.5), tracks((50.5, 5.4, 20.0, 0.0), (58.0, 1.8, 20.0, 0.0)), CFG)
    assert a.track_id == 1 and a.probability > 0.9 and a.candidates == 1


def test_gates_refuse_a_track_going_the_other_way_or_at_another_speed():
    assert associate(cam(50.0, 5.5), tracks((50.5, 5.4, -20.0, 0.0)), CFG).track_id is None  # heading
    assert associate(cam(50.0, 5.5), tracks((50.5, 5.4, 5.0, 0.0)), CFG).track_id is None  # speed
    assert associate(cam(50.0, 5.5), tracks((70.0, 5.5, 20.0, 0.0)), CFG).track_id is None  # position


def test_the_cam_is_predicted_to_the_tracks_time():
    t = tracks((60.0, 5.5, 20.0, 0.0))  # the track at t = 10.0 s, the CAM half a second earlier, 10 m behind
    assert associate(cam(50.0, 5.5, t=9.5), t, CFG).track_id == 1


def test_two_cars_side_by_side_share_the_probability():
    a = associate(cam(50.0, 3.7), tracks((50.0, 1.85, 20.0, 0.0), (50.0, 5.55, 20.0, 0.0)), CFG)
    assert a.candidates == 2 and 0.3 < a.probability < 0.6


def test_probability_is_calibrated_on_random_scenes():
    """Scenes drawn as the model assumes: the EV seen by the cameras with ``p_detect``, other cars scattered over
    the road at ``clutter_density_pm2``; CAM and tracks with their stated noise. Among the associations made, the
    mean probability in each bin matches the fraction that are right (within 0.08)."""
    rng = np.random.default_rng(3)
    cfg = V2xFusionConfig(p_detect=0.9, clutter_density_pm2=5e-3)
    length_m, width_m = 80.0, 8.0
    bins: dict[int, list[tuple[float, bool]]] = {}
    for _ in range(2500):
        ev = (rng.uniform(10.0, length_m - 10.0), rng.uniform(1.0, width_m - 1.0))
        others = rng.uniform((0.0, 0.0), (length_m, width_m), size=(rng.poisson(cfg.clutter_density_pm2 * length_m
                                                                                 * width_m), 2))
        rows = [(x, y, 20.0, 0.0) for x, y in others]
        if rng.random() < cfg.p_detect:
            rows.append((ev[0] + rng.normal(0, 0.5), ev[1] + rng.normal(0, 0.5), 20.0, 0.0))  # the EV: last track
        if not rows:
            continue
        obs = cam(ev[0] + rng.normal(0, 1.0), ev[1] + rng.normal(0, 1.0), sigma=1.0)
        a = associate(obs, tracks(*rows), cfg)
        if a.track_id is None:
            continue
        right = a.track_id == len(rows) and len(rows) == len(others) + 1
        bins.setdefault(min(int(a.probability * 5), 4), []).append((a.probability, right))
    assert sum(len(v) for v in bins.values()) > 1500
    for k, pts in bins.items():
        if len(pts) < 40:
            continue
        mean_p = sum(p for p, _ in pts) / len(pts)
        freq = sum(r for _, r in pts) / len(pts)
        assert abs(mean_p - freq) < 0.08, (k, mean_p, freq, len(pts))


def settled(f: V2xFusion, x: float, y: float, tracks_at, views_at, t_end: float, *, station: int = 7,
            speed: float = 20.0, n: int = 6):
    """``n`` CAMs of one station at 10 Hz driving along x, ending at (x, y) at ``t_end``; the last assessment."""
    out = None
    for k in range(n):
        t = t_end - 0.1 * (n - 1 - k)
        xk = x - speed * (t_end - t)
        out = f.assess(cam(xk, y, t=t, speed=speed, station=station), tracks_at(t, xk), views_at(t), t)
    return out


def fresh_view(t: float) -> list[CameraView]:
    return [CameraView("rsu1", 0.0, -4.5, 0.18, 0.52, 85.0, t - 0.05)]  # reporting all along


def no_tracks(_t: float, _x: float) -> CameraTracks:
    return CameraTracks.empty()


def test_evidence_vision_v2x_cam_alone_and_contradicted():
    f = V2xFusion()

    def car_under_cam(t: float, x: float) -> CameraTracks:
        return CameraTracks(np.array([1]), np.array([x + 0.3]), np.array([5.5]), np.array([20.0]), np.array([0.0]),
                            np.array([0.25]), np.array([t]))

    seen = settled(f, 40.0, 5.5, car_under_cam, fresh_view, 10.0)
    assert seen.evidence == "vision+v2x" and seen.believed
    behind = settled(f, -150.0, 5.5, no_tracks, fresh_view, 10.0, station=8)  # beyond the last camera
    assert behind.evidence == "v2x" and behind.believed
    empty_view = settled(f, 40.0, 5.5, no_tracks, fresh_view, 10.0, station=9)
    assert empty_view.evidence == "contradicted" and not empty_view.believed and empty_view.seen_by == "rsu1"
    stale = settled(f, 40.0, 5.5, no_tracks, lambda t: [CameraView("rsu1", 0.0, -4.5, 0.18, 0.52, 85.0, t - 3.0)],
                    10.0, station=10)  # a camera that stopped reporting sees nothing
    assert stale.evidence == "v2x"


def test_a_station_is_believed_only_once_its_cams_agree():
    f = V2xFusion()
    first = [f.assess(cam(-150.0 + 2.0 * k, 5.5, t=10.0 + 0.1 * k), CameraTracks.empty(), [], 10.0 + 0.1 * k)
             for k in range(6)]
    assert [a.evidence for a in first] == ["unconfirmed"] * 4 + ["v2x"] * 2


def test_claims_that_hop_about_or_stand_still_while_driving_are_never_believed():
    f = V2xFusion()
    hops = [(60.0, 1.85), (80.0, 5.55), (60.0, 5.55), (110.0, 1.85)]
    out = [f.assess(cam(*hops[k % 4], t=10.0 + 0.1 * k, station=3), CameraTracks.empty(), [], 10.0 + 0.1 * k).evidence
           for k in range(30)]
    assert set(out) == {"unconfirmed"}
    still = [f.assess(cam(60.0, 1.85, t=10.0 + 0.1 * k, speed=18.0, station=4), CameraTracks.empty(), [],
                      10.0 + 0.1 * k).evidence for k in range(30)]
    assert "v2x" not in still


def test_a_believed_ev_entering_a_view_keeps_its_belief_while_the_camera_starts_its_track():
    f = V2xFusion()
    assert settled(f, -20.0, 5.5, no_tracks, fresh_view, 10.0, n=6).believed
    for k in range(1, 6):  # 0.5 s more: into the view, no camera track yet
        t = 10.0 + 0.1 * k
        assert f.assess(cam(-20.0 + 20.0 * 0.1 * k, 5.5, t=t), CameraTracks.empty(), fresh_view(t), t).believed
    later = [f.assess(cam(-20.0 + 2.0 * k, 5.5, t=10.0 + 0.1 * k), CameraTracks.empty(),
                      fresh_view(10.0 + 0.1 * k), 10.0 + 0.1 * k) for k in range(6, 40)]
    assert later[13].believed  # x = 18 m: the view starts at about 20 m
    assert later[-1].evidence == "contradicted"  # in view since x = 20 m, still no track 1 s on: not believed


def test_view_geometry():
    assert VIEW.sees(40.0, 5.5, 10.0, CFG)
    assert not VIEW.sees(-40.0, 5.5, 10.0, CFG)  # behind the camera
    assert not VIEW.sees(100.0, 5.5, 10.0, CFG)  # beyond its range
    assert VIEW.sees(40.0, 5.5, 11.5, CFG)  # a camera that stutters keeps its say
    assert not VIEW.sees(40.0, 5.5, 12.5, CFG)  # its last report is too old
    assert math.isclose(CFG.gate_d2, 13.8155, rel_tol=1e-4)


def test_a_claim_driven_through_traffic_is_ambiguous_not_believed():
    """A stolen key's claim that overtakes the cars in a camera's view rides on each for a few CAMs: never one
    track steadily, so it is not believed by itself."""
    f = V2xFusion()
    out = []
    for k in range(25):  # in the camera's view, at 18 m/s past cars at 14 m/s spaced 12 m apart
        t = 10.0 + 0.1 * k
        x = 30.0 + 18.0 * (t - 10.0)
        cars = np.array([30.0 + 14.0 * (t - 10.0) + 12.0 * i for i in range(-2, 6)])
        tracks = CameraTracks(np.arange(len(cars)) + 1, cars, np.full(len(cars), 5.5),
                              np.full(len(cars), 14.0), np.zeros(len(cars)), np.full(len(cars), 0.25),
                              np.full(len(cars), t))
        out.append(f.assess(cam(x, 5.5, t=t, speed=18.0, station=5), tracks, fresh_view(t), t))
    assert not any(a.believed for a in out), [a.evidence for a in out]
    assert {"ambiguous", "contradicted"} & {a.evidence for a in out}
