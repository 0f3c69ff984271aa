"""Static-object hazard detection (rsu/hazard.py): life cycle, localisation, what is not a hazard."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from protocol.corridor import load_corridor
from protocol.enums import HazardState
from rsu.hazard import HazardConfig, HazardDetector, road_mask
from rsu.localize import Localizer

RSU = "rsu3"


@pytest.fixture(scope="module")
def scene():
    corridor = load_corridor()
    rsu = corridor.rsu(RSU)
    cam = rsu.camera
    h, w = cam.height_px, cam.width_px
    rng = np.random.default_rng(0)
    # a textured grey "road" image (static background)
    base = np.clip(110 + rng.normal(0, 6, (h, w, 1)), 0, 255).astype(np.uint8).repeat(3, axis=2)
    loc = Localizer(corridor, rsu)
    return corridor, rsu, base, loc


def project(rsu, x, y, z=0.0):
    cam = rsu.camera
    pc = cam.rotation_world_to_camera @ (np.array([x, y, z]) - cam.centre_world)
    uv = cam.intrinsic_matrix @ pc
    return uv[:2] / uv[2]


def patch_box(rsu, x, y, length=1.0, width=0.8, height=0.5):
    """Image box of an object standing at (x, y) (corners of its 3-D box)."""
    pts = [project(rsu, x + dx, y + dy, z) for dx in (-length / 2, length / 2) for dy in (-width / 2, width / 2)
           for z in (0.0, height)]
    pts = np.array(pts)
    return pts[:, 0].min(), pts[:, 1].min(), pts[:, 0].max(), pts[:, 1].max()


_NOISE: list[np.ndarray] = []


def frame_with(base, boxes, colour=(40, 90, 200), noise=None):
    """The background with filled boxes; ``noise`` (a Generator) adds sensor noise (+-2 levels, one of 4
    precomputed fields picked at random)."""
    img = base.copy()
    for b in boxes:
        x1, y1, x2, y2 = (int(round(v)) for v in b)
        img[y1:y2, x1:x2] = colour
    if noise is not None:
        if not _NOISE:
            g = np.random.default_rng(99)
            _NOISE.extend(g.integers(0, 5, base.shape, dtype=np.uint8) for _ in range(4))
        n = _NOISE[int(noise.integers(4))]
        img = cv2.subtract(cv2.add(img, n), 2)
    return img


def detector(corridor, rsu, loc, base, **cfg):
    d = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(**cfg), camera=rsu.camera)
    d.prime(base)
    return d


def run(det, frames, t0=0.0, dt=1 / 15, tracks=None):
    events = []
    for k, img in enumerate(frames):
        ids, boxes = tracks(k) if tracks else ((), ())
        events += [(t0 + k * dt, e) for e in det.update(img, t0 + k * dt, ids, boxes)]
    return events


FAST = dict(on_s=0.4, off_s=2 / 15, evidence_max_s=1.0, decay=3.0, clear_after_s=0.3, persist_period_s=0.5)
"""A quicker life cycle than the defaults (keeps the tests short); the logic is the same."""


def test_debris_appears_persists_and_clears(scene):
    corridor, rsu, base, loc = scene
    det = detector(corridor, rsu, loc, base, **FAST)
    x = 125.0  # 25 m ahead of rsu3, lane 1 centre
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    box = patch_box(rsu, x, y)
    rng = np.random.default_rng(1)
    present = [frame_with(base, [box], noise=rng) for _ in range(45)]
    gone = [frame_with(base, [], noise=rng) for _ in range(20)]
    events = run(det, present + gone)
    states = [e.state for _, e in events]
    assert states[0] == HazardState.APPEAR
    t_appear, first = events[0]
    # the short-term background needs ~0.5 s to take the object in, then on_s (0.4 s); looked at twice a second
    # (every eighth frame: 8/15 s apart)
    assert 6 / 15 - 1e-6 <= t_appear <= 16 / 15 + 1e-6
    assert first.lane == 1
    # the ground contact of the object's near face: within its length of the true centre, laterally within 0.5 m
    assert abs(first.x_m - x) < 1.0 and abs(first.y_m - y) < 0.5
    assert 0.3 < first.width_m < 1.6
    persists = [t for t, e in events if e.state == HazardState.PERSIST]
    # every persist_period_s (0.5 s) on the frames looked at (every eighth frame): 8/15 s apart
    assert len(persists) >= 2 and np.allclose(np.diff(persists), 8 / 15, atol=0.07)
    clears = [t for t, e in events if e.state == HazardState.CLEAR]
    assert len(clears) == 1 and 3.0 - 1e-6 <= clears[0] <= 3.0 + 1.0  # removed at 3 s: evidence decays, 0.3 s
    assert {e.hazard_id for _, e in events} == {first.hazard_id}


def test_looks_at_3_frames_a_second_with_the_same_timing_as_every_frame(scene):
    """The detector passes over frames sooner than 1 / rate_hz after the last it looked at; evidence and
    learning rates count seconds, so the object appears and clears at about the same times as at 15 fps."""
    corridor, rsu, base, loc = scene
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    box = patch_box(rsu, 125.0, y)
    rng = np.random.default_rng(11)
    frames = [frame_with(base, [box], noise=rng) for _ in range(45)] + [frame_with(base, [], noise=rng)
                                                                        for _ in range(30)]
    times = {}
    for rate in (0.0, 3.0):
        det = detector(corridor, rsu, loc, base, rate_hz=rate, **FAST)
        events = run(det, frames)
        times[rate] = {e.state: t for t, e in reversed(events)}  # first of each state
        assert det.stats.frames == (75 if rate == 0 else 15)
    # appear within one look; clear within two (at 3 Hz one look takes the evidence past the hysteresis)
    assert abs(times[3.0][HazardState.APPEAR] - times[0.0][HazardState.APPEAR]) <= 1 / 3 + 1e-6, times
    assert abs(times[3.0][HazardState.CLEAR] - times[0.0][HazardState.CLEAR]) <= 2 / 3 + 1e-6, times


def test_a_corridors_rsus_look_in_turn(scene):
    """RSU k of the corridor first looks k / 4 of a period after its first frame, then once a period, so
    four RSUs on one machine do not all look (~10 ms of CPU each) at the same frames."""
    corridor, rsu, base, loc = scene
    from rsu.build import PipelineConfig, build_hazards

    looks = {}
    for r in corridor.rsus:
        det = build_hazards(PipelineConfig(hazards=True), corridor, r.rsu_id, Localizer(corridor, r))
        seen = []
        for k in range(30):  # 2 s at 15 fps, from t = 100 s
            before = det.stats.frames
            det.update(base, 100.0 + k / 15)
            if det.stats.frames > before:
                seen.append(k)
        looks[r.rsu_id] = seen
    assert [v[0] for v in looks.values()] == [0, 2, 4, 6]  # 0, 1/8, 1/4, 3/8 s: the first frame at or after
    for seen in looks.values():
        assert np.diff(seen).tolist() == [8] * (len(seen) - 1)  # then every 0.5 s (the next frame: 8 frames)
    with pytest.raises(ValueError, match="phase_s"):
        HazardConfig(phase_s=-1.0)


def test_moving_and_tracked_vehicles_are_not_hazards(scene):
    corridor, rsu, base, loc = scene
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(0))[1])
    rng = np.random.default_rng(2)
    # a car drives from 20 m to 40 m ahead at 10 m/s, stops there (a queue) and stays: tracked while moving
    xs = [120.0 + min(10.0 * k / 15, 20.0) for k in range(54)]  # stopped for 1.6 s (the detector looks at 2 Hz)
    boxes = [patch_box(rsu, x, y, 4.5, 1.8, 1.5) for x in xs]
    frames = [frame_with(base, [b], colour=(200, 200, 200), noise=rng) for b in boxes]
    det = detector(corridor, rsu, loc, base, **FAST)
    assert run(det, frames, tracks=lambda k: ([7], [boxes[k]])) == []
    # the detector then loses the stopped car (a background model absorbs it): its region stays parked
    more = [frame_with(base, [boxes[-1]], colour=(200, 200, 200), noise=rng) for _ in range(15)]
    assert run(det, more, t0=54 / 15) == []
    # control: the same pixels without the track are reported (so the masking is what kept them out)
    det2 = detector(corridor, rsu, loc, base, **FAST)
    events = run(det2, frames)
    assert any(e.state == HazardState.APPEAR for _, e in events)


def test_untracked_static_object_on_the_shoulder_is_not_a_hazard(scene):
    corridor, rsu, base, loc = scene
    det = detector(corridor, rsu, loc, base, **FAST)
    y = float(corridor.road.pose_at(230.0, -1.4)[1])  # on the shoulder, 1.4 m right of lane 0
    box = patch_box(rsu, 130.0, y, 1.0, 0.8, 0.3)
    rng = np.random.default_rng(3)
    events = run(det, [frame_with(base, [box], noise=rng) for _ in range(20)])
    assert events == [] and det.stats.off_lane > 0


def test_static_object_cut_by_the_bottom_edge_is_not_placed(scene):
    """An object whose image reaches the bottom border (a vehicle stopped half in view) has its ground contact out
    of view: not a hazard, however long it stands; the same object fully in view is one."""
    corridor, rsu, base, loc = scene
    h = rsu.camera.height_px
    rng = np.random.default_rng(5)
    events = {}
    lane_y = {x: float(corridor.road.pose_at(100.0 + x, corridor.road.lane_centre_offset_m(1))[1]) for x in (116, 118)}
    cut, in_view = patch_box(rsu, 116.0, lane_y[116]), patch_box(rsu, 118.0, lane_y[118])
    assert cut[1] < h < cut[3] and in_view[3] < h - 10  # 16 m and 18 m ahead of rsu3
    for name, box in (("cut", cut), ("in view", in_view)):
        det = detector(corridor, rsu, loc, base, **FAST)
        events[name] = run(det, [frame_with(base, [box], noise=rng) for _ in range(30)])
        if name == "cut":
            assert det.stats.cut_by_border > 0
    assert events["cut"] == []
    assert any(e.state == HazardState.APPEAR for _, e in events["in view"])


def test_ghost_of_an_object_that_left_is_absorbed(scene):
    corridor, rsu, base, loc = scene
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    box = patch_box(rsu, 125.0, y)
    learnt = frame_with(base, [box])  # the object was there when the background was learnt
    det = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(**FAST), camera=rsu.camera)
    det.prime(learnt)
    rng = np.random.default_rng(4)
    events = run(det, [frame_with(base, [], noise=rng) for _ in range(30)])
    assert events == [] and det.stats.ghosts >= 1


def test_initial_median_ignores_passing_traffic(scene):
    corridor, rsu, base, loc = scene
    cfg = HazardConfig(init_frames=5, init_interval_s=0.2, **FAST)
    det = HazardDetector(corridor.road, loc.mapper.to_ground, cfg, camera=rsu.camera)
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(0))[1])
    rng = np.random.default_rng(5)
    # a car passes during the learning phase (a different place in each sampled frame)
    frames = [frame_with(base, [patch_box(rsu, 110.0 + 1.0 * k, y, 4.5, 1.8, 1.5)], noise=rng) for k in range(15)]
    frames += [frame_with(base, [], noise=rng) for _ in range(20)]
    assert run(det, frames) == []
    assert det.fg.ready


def test_road_mask_covers_the_lanes_not_the_sky(scene):
    corridor, rsu, _base, _loc = scene
    m = road_mask(rsu.camera, corridor.road, 0.5)
    assert m.shape == (360, 640)
    u, v = project(rsu, 130.0, float(corridor.road.pose_at(230.0, 1.85)[1]))
    assert m[int(v / 2), int(u / 2)]
    assert not m[:20].any()  # the sky
    assert 0.05 < m.mean() < 0.5


def test_config_is_validated():
    with pytest.raises(ValueError):
        HazardConfig(off_s=2.0, on_s=1.0)
    with pytest.raises(ValueError):
        HazardConfig(scale=2.0)


class _NoDetector:
    name = "none"

    def detect(self, image):
        from rsu.perception import Detections

        return Detections.empty()


def test_service_publishes_hazard_alerts_appear_persist_clear(scene):
    from protocol.clock import SimClock
    from protocol.keys import rsu_key
    from protocol.local_bus import LocalBus
    from protocol.messages import HazardAlert
    from rsu.build import PipelineConfig, build_tracker
    from rsu.frames import ArraySource
    from rsu.pipeline import RsuPipeline
    from rsu.service import RsuService

    corridor, rsu, base, loc = scene
    y = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    box = patch_box(rsu, 125.0, y)
    rng = np.random.default_rng(6)
    images = [frame_with(base, [box], noise=rng) for _ in range(45)] + [frame_with(base, [], noise=rng)
                                                                         for _ in range(15)]
    clock = SimClock()

    class Source(ArraySource):
        def read(self, timeout_s=None):
            clock.advance(1 / 15)
            return super().read(timeout_s)

    bus = LocalBus()
    got: list[HazardAlert] = []
    bus.subscribe(rsu_key("rellis", RSU, "hazard"), lambda _k, m: got.append(m))
    hazards = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(**FAST), camera=rsu.camera)
    hazards.prime(base)
    pipe = RsuPipeline(_NoDetector(), build_tracker(PipelineConfig()), Localizer(corridor, rsu), hazards=hazards)
    svc = RsuService(corridor, RSU, Source(images, 15.0, "cam"), pipe, bus, clock)
    assert svc.run() == 0
    states = [m.state.value for m in got]
    assert states[0] == "appear" and states[-1] == "clear" and "persist" in states
    assert {m.hazard_id for m in got} == {f"{RSU}-hz-1"}
    assert [m.seq for m in got] == list(range(len(got)))
    first = got[0]
    assert first.rsu_id == RSU and first.lane == 1 and abs(first.pos_x_m - 125.0) < 1.0
    lat, lon = corridor.to_latlon(first.pos_x_m, first.pos_y_m)
    assert first.lat_deg == pytest.approx(lat) and first.lon_deg == pytest.approx(lon)
    assert svc.hazards_published["appear"] == 1 and svc.hazards_published["clear"] == 1


def test_slow_far_vehicle_is_masked_by_its_localised_speed(scene):
    corridor, rsu, base, loc = scene
    y = float(corridor.road.pose_at(240.0, corridor.road.lane_centre_offset_m(0))[1])
    rng = np.random.default_rng(7)
    # 60 m ahead, 1.5 m/s: its box centre moves ~5 px over the run (less than moved_px), its body looks static
    boxes = [patch_box(rsu, 160.0 + 1.5 * k / 15, y, 4.5, 1.8, 1.5) for k in range(30)]
    frames = [frame_with(base, [b], colour=(200, 200, 200), noise=rng) for b in boxes]
    cfg = dict(FAST, moving_speed_mps=1.0)
    det = detector(corridor, rsu, loc, base, **cfg)
    assert run(det, frames, tracks=lambda k: ([7], [boxes[k]])) != []  # pixels alone: it looks parked
    det = detector(corridor, rsu, loc, base, **cfg)
    events = []
    for k, img in enumerate(frames):
        events += det.update(img, k / 15, [7], [boxes[k]], {7: 1.5})
    assert events == []


def test_untimed_warm_up_frames_learn_the_background_at_the_detector_rate(scene):
    """``learn_background`` without times (``sim.warmup``: the camera's 15 fps) counts them at ``warmup_fps`` and
    learns from 2 a second: 6 s of warm-up make the initial median (9 frames 0.5 s apart), with no evidence."""
    corridor, rsu, base, loc = scene
    det = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(), camera=rsu.camera)
    rng = np.random.default_rng(12)
    looked = []
    for _ in range(90):
        det.learn_background(frame_with(base, [], noise=rng))
        looked.append(det._learn_t_s)
    assert det.fg.ready and not det.fg.evidence.any()
    assert len(set(looked)) == 12  # every eighth frame (7/15 s is under the 0.5 s period)


def test_median_of_frames_matches_numpy_median():
    """Paeth's network gives np.median's values on nine frames (ties and all), other counts fall back to it."""
    from rsu.hazard.background import median_of_frames

    rng = np.random.default_rng(5)
    for n in (9, 9, 9, 4, 5):
        frames = [rng.integers(0, 4 if n == 9 else 255, (11, 13, 3)).astype(np.uint8) for _ in range(n)]
        want = np.median(np.stack(frames), axis=0)
        np.testing.assert_array_equal(median_of_frames(frames).astype(np.float64), want)
    frames = [rng.normal(0, 50, (7, 5)).astype(np.float32) for _ in range(9)]
    np.testing.assert_array_equal(median_of_frames(frames), np.median(np.stack(frames), axis=0).astype(np.float32))


def test_channel_max_is_the_largest_channel():
    """The hazard look's per-pixel largest channel (strided numpy maxima) equals numpy's reduction, in both dtypes
    the background model uses, as a new contiguous image."""
    from rsu.hazard.background import _channel_max

    rng = np.random.default_rng(9)
    for img in (rng.normal(0, 40, (17, 23, 3)).astype(np.float32), rng.integers(0, 256, (17, 23, 3)).astype(np.uint8)):
        got = _channel_max(img)
        np.testing.assert_array_equal(got, img.max(axis=2))
        assert got.dtype == img.dtype and got.flags["C_CONTIGUOUS"] and not np.shares_memory(got, img)


def test_warm_up_leaves_no_ghost_of_a_vehicle_the_initial_median_kept(scene):
    """A vehicle over a patch of road in 5 of the initial median's 9 warm-up looks is in the median; the road
    the later warm-up looks show there, standing still, replaces it (rellis_ev_yield seeds 8 and 9: such a ghost far
    down rsu2's view, its outline too weak for the ghost test, was a hazard in lane 1 for the whole run)."""
    corridor, rsu, base, loc = scene
    det = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(), camera=rsu.camera)
    box = patch_box(rsu, 140.0, 5.5, length=4.5, width=1.8, height=1.5)
    rng = np.random.default_rng(3)
    for k in range(90):  # 6 s at 15 fps: looks every 0.5 s, the first 9 make the median
        covered = (k // 8) in (1, 2, 4, 5, 7)  # 5 of the 9 median looks see the vehicle there
        det.learn_background(frame_with(base, [box] if covered and k < 72 else [], noise=rng))
    x1, y1, x2, y2 = (int(round(v * det.cfg.scale)) for v in box)
    road = det.fg.roi[y1:y2, x1:x2]  # the watched pixels (the road) of the vehicle's box
    ghost = np.abs(det.fg.long_bg[y1:y2, x1:x2] - det.fg.small(base)[y1:y2, x1:x2]).max(axis=2) > 10
    assert road.sum() > 500 and (ghost & road).sum() < 0.2 * road.sum()  # its rim and a few pixels the look
    # opened away are left (the median alone leaves all of them)
    events = run(det, [frame_with(base, [], noise=rng) for _ in range(60)], t0=6.0)
    assert not events


def test_a_live_start_leaves_no_ghost_of_a_platoon_its_median_kept_and_still_sees_new_debris(scene):
    """Started on a live road (no warm-up, no primed empty road): red and blue cars take turns over a patch of lane 0
    in two of every three looks while the initial median is made, so the median holds a blend of them that no frame
    shows (a far platoon); the road that stands still there once they have gone replaces the median's guess and is no
    hazard (its soft outline passes no ghost test). Debris dropped afterwards on road already seen is reported."""
    corridor, rsu, base, loc = scene
    det = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(), camera=rsu.camera)
    y0 = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(0))[1])
    y1 = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    x1, ya, x2, yb = (int(round(v)) for v in patch_box(rsu, 150.0, y0, length=4.5, width=1.8, height=1.5))
    shape = np.zeros(base.shape[:2], np.float32)
    shape[ya:yb, x1:x2] = 1.0
    shape = cv2.GaussianBlur(shape, (0, 0), 4.0)[..., None]  # a soft outline

    def car(colour):
        return (base * (1.0 - shape) + np.float32(colour) * shape).astype(np.uint8)

    red, blue = car((20, 20, 200)), car((200, 20, 20))
    rng = np.random.default_rng(6)
    turns = [red, blue, base] * 4  # 8 frames each: one look of the detector's two a second
    frames = [frame_with(turns[k // 8], [], noise=rng) for k in range(8 * len(turns))]  # 6.4 s
    frames += [frame_with(base, [], noise=rng) for _ in range(60)]  # they have gone: the road for 4 s
    assert run(det, frames) == []
    assert det.fg.ready and det.stats.ghosts == 0  # not the ghost test's doing
    events = run(det, [frame_with(base, [patch_box(rsu, 125.0, y1)], noise=rng) for _ in range(45)], t0=11.0)
    assert [e.state for _, e in events][:1] == [HazardState.APPEAR] and events[0][1].lane == 1


def test_a_live_start_reports_debris_that_fell_while_its_median_was_made(scene):
    """Debris that falls on road the median's first looks showed (2.5 s in, before the median is made) is reported:
    the road there is no guess."""
    corridor, rsu, base, loc = scene
    det = HazardDetector(corridor.road, loc.mapper.to_ground, HazardConfig(), camera=rsu.camera)
    y1 = float(corridor.road.pose_at(225.0, corridor.road.lane_centre_offset_m(1))[1])
    debris = patch_box(rsu, 125.0, y1)
    rng = np.random.default_rng(7)
    frames = [frame_with(base, [debris] if k >= 38 else [], noise=rng) for k in range(135)]  # 9 s
    events = run(det, frames)
    assert [e.state for _, e in events][:1] == [HazardState.APPEAR] and events[0][1].lane == 1
