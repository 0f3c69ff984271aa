"""Camera commissioning: pose from surveyed points on a simulator render, flags, refusals, error
table, corridor write-back, the check image, and `iea calibrate` on a real frame (skips without ../shared)."""

from __future__ import annotations

import math
import tomllib
from pathlib import Path

import cv2
import numpy as np
import pytest

from protocol.corridor import load_corridor, parse_corridor
from rsu.calibration.camera_geometry import ground_points, project
from rsu.calibration.error import error_table
from rsu.calibration.overlay import CalibrationOverlay, OverlayPoint, check_image
from rsu.calibration.solve import CalibrationError, SurveyPoint, read_points_csv, solve_camera

ROOT = Path(__file__).resolve().parents[2]
FIXTURES = ROOT / "tests" / "fixtures" / "commission"
REAL_VIDEO = ROOT / ".." / "shared" / "data" / "real" / "traffic_videos" / "haarcascades_video2.avi"
SPREAD_PX = [(100, 660), (1180, 660), (250, 450), (1030, 450), (400, 300), (880, 300), (560, 230), (720, 230),
             (640, 560), (300, 360), (980, 360), (640, 260)]


@pytest.fixture(scope="module")
def sim():
    corridor = load_corridor()
    return corridor, corridor.rsu("rsu1").camera


def _survey(cam, n=8, seed=0, pixel_sigma_px=1.0):
    rng = np.random.default_rng(seed)
    xy = ground_points(cam, np.array(SPREAD_PX[:n], dtype=float))
    uv, _ = project(cam, np.column_stack([xy, np.zeros(n)]))
    uv = uv + rng.normal(0.0, pixel_sigma_px, uv.shape)
    return [SurveyPoint(f"p{i}", u, v, x, y, 0.0) for i, ((u, v), (x, y)) in enumerate(zip(uv, xy, strict=True))]


def _errors(got, cam):
    pos = float(np.linalg.norm(got.centre_world - cam.centre_world))
    ang = max(abs(math.degrees(a - b)) for a, b in ((got.yaw_rad, cam.yaw_rad), (got.pitch_rad, cam.pitch_rad),
                                                     (got.roll_rad, cam.roll_rad)))
    return pos, ang


def test_pose_from_8_points_with_1px_noise_on_a_render(sim, tmp_path):
    from sim.render.renderer import Renderer

    corridor, cam = sim
    frame = Renderer(cam, corridor.road, seed=0).background("day")
    for seed in (0, 1, 2):
        sol = solve_camera(_survey(cam, seed=seed), cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no")
        pos, ang = _errors(sol.camera, cam)
        assert pos < 0.2 and ang < 0.2, (seed, pos, ang)
        assert sol.flagged == [] and sol.rms_px < 2.0
    pts = [OverlayPoint(r.name, r.measured_uv, r.reprojected_uv, r.flagged) for r in sol.residuals]
    img = check_image(frame, sol.camera, corridor.road, max_range_m=85.0, points=pts, title="rsu1")
    assert img.shape == frame.shape
    assert np.count_nonzero(np.any(img != frame, axis=2)) > 5000  # lanes, grid, limit, points drawn
    assert cv2.imwrite(str(tmp_path / "check.jpg"), img)


def test_the_focal_length_is_solved_when_the_points_fix_it(sim):
    _, cam = sim
    sol = solve_camera(_survey(cam, n=12, seed=3), cam.width_px, cam.height_px, fx_px=None)
    assert sol.focal_solved
    assert abs(sol.camera.fx_px - cam.fx_px) < 0.02 * cam.fx_px
    assert _errors(sol.camera, cam)[0] < 0.5


def test_a_wrong_pair_is_flagged_by_name_and_left_out(sim):
    _, cam = sim
    pts = _survey(cam, n=10, seed=4) + [SurveyPoint("swapped_marker", 640.0, 500.0, 30.0, -20.0, 0.0)]
    sol = solve_camera(pts, cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no")
    assert sol.flagged == ["swapped_marker"]
    assert _errors(sol.camera, cam)[0] < 0.2
    assert next(r for r in sol.residuals if r.name == "swapped_marker").error_px > 50


def test_too_few_collinear_and_inconsistent_points_are_refused_with_reasons(sim):
    _, cam = sim
    pts = _survey(cam, n=12, seed=5)
    with pytest.raises(CalibrationError, match="too few points"):
        solve_camera(pts[:5], cam.width_px, cam.height_px, fx_px=cam.fx_px)
    line = [SurveyPoint(f"l{i}", *project(cam, np.array([[20.0 + 8 * i, 0.0, 0.0]]))[0][0], 20.0 + 8 * i, 0.0)
            for i in range(8)]
    with pytest.raises(CalibrationError, match="collinear"):
        solve_camera(line, cam.width_px, cam.height_px, fx_px=cam.fx_px)
    rng = np.random.default_rng(0)
    order = rng.permutation(len(pts))
    shuffled = [SurveyPoint(p.name, p.u_px, p.v_px, pts[j].x_m, pts[j].y_m) for p, j in zip(pts, order, strict=True)]
    with pytest.raises(CalibrationError, match="inconsistent"):
        solve_camera(shuffled, cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no")
    with pytest.raises(CalibrationError, match="outside the 1280x720 image"):
        solve_camera([SurveyPoint("far", 2000.0, 10.0, 1.0, 1.0)] + pts, cam.width_px, cam.height_px)


def test_error_table_predicts_the_ground_error_and_compares_both_methods(sim):
    corridor, cam = sim
    sol = solve_camera(_survey(cam, n=12, seed=6), cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no")
    rows = error_table(sol, corridor.road, 100.0, pixel_sigma_px=1.0, draws=100)
    by = {r.centre_m: r for r in rows}
    assert by[20.0].predicted_median_m < by[60.0].predicted_median_m < by[100.0].predicted_median_m
    assert 0.1 < by[60.0].predicted_median_m < 0.4  # ~0.3 m per pixel along the road at 60 m
    assert any(r.reference_cv_median_m is not None for r in rows)
    assert all(r.use.startswith(("transform", "reference")) for r in rows if r.n_lane_points)


def test_points_csv_reads_corridor_and_latlon_columns(sim):
    corridor, _ = sim
    lat, lon = corridor.to_latlon(30.0, 5.0)
    pts = read_points_csv(f"# surveyed 2026-11-25\nname,u_px,v_px,lat_deg,lon_deg,height_m\nsign,10,20,{lat!r},{lon!r},2.5\n",
                          corridor.from_latlon)
    assert pts[0].name == "sign" and abs(pts[0].x_m - 30.0) < 1e-6 and abs(pts[0].y_m - 5.0) < 1e-6
    assert pts[0].z_m == 2.5
    with pytest.raises(CalibrationError, match="needs u_px, v_px"):
        read_points_csv("a,b,c\n1,2,3\n")
    with pytest.raises(CalibrationError, match="used twice"):
        read_points_csv("name,u_px,v_px,x_m,y_m\na,1,2,3,4\na,5,6,7,8\n")


def test_corridor_write_back_keeps_the_file_and_loads(sim, tmp_path):
    from deploy.commission import corridor_text_with_camera

    corridor, cam = sim
    sol = solve_camera(_survey(cam, seed=7), cam.width_px, cam.height_px, fx_px=cam.fx_px, solve_focal="no")
    text = Path(corridor.source).read_text(encoding="utf-8")
    new = corridor_text_with_camera(text, "rsu1", sol.camera, list(sol.kept))
    got = parse_corridor(tomllib.loads(new), "new")
    assert len(got.rsu("rsu1").calibration) == 8 and got.rsu("rsu2").calibration == corridor.rsu("rsu2").calibration
    assert abs(got.rsu("rsu1").camera.height_m - sol.camera.height_m) < 1e-3
    assert "# RELLIS test corridor" in new and "# p0" in new
    added = parse_corridor(tomllib.loads(corridor_text_with_camera(text, "rsu9", sol.camera, list(sol.kept))), "x")
    assert abs(added.rsu("rsu9").camera.pitch_rad - sol.camera.pitch_rad) < 1e-5


def test_annotate_overlay_draws_on_frames_of_the_camera_size_only(sim):
    corridor, cam = sim
    rsu = corridor.rsu("rsu1")
    overlay = CalibrationOverlay(cam, corridor.road, max_range_m=rsu.max_range_m, calibration=rsu.calibration)
    frame = np.full((cam.height_px, cam.width_px, 3), 90, np.uint8)
    assert np.count_nonzero(np.any(overlay.apply(frame) != frame, axis=2)) > 5000
    small = np.zeros((240, 320, 3), np.uint8)
    assert overlay.apply(small) is small


def test_iea_calibrate_on_a_real_frame_writes_pose_pairs_and_check_image(tmp_path, capsys):
    if not REAL_VIDEO.is_file():
        pytest.skip(f"{REAL_VIDEO} absent (../shared/data/real not beside the repository)")
    from deploy.commission import main

    corridor_file = tmp_path / "real_corridor.toml"
    corridor_file.write_text((FIXTURES / "real_corridor.toml").read_text(encoding="utf-8"), encoding="utf-8")
    check = tmp_path / "check.jpg"
    rc = main(["real1", "--image", str(REAL_VIDEO), "--points", str(FIXTURES / "haarcascades_video2_pairs.csv"),
               "--corridor", str(corridor_file), "--check-image", str(check), "--write"])
    out = capsys.readouterr().out
    assert rc == 0, out
    assert "reprojection error" in out and "leave-one-out" in out and "+++ " in out
    cam = load_corridor(corridor_file).rsu("real1")
    assert 8.0 < cam.camera.height_m < 12.0 and len(cam.calibration) == 31
    img = cv2.imread(str(check))
    assert img is not None and img.shape[1] >= 960
