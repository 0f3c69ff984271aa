"""Simulated RTK survey of calibration pairs (pixel -> road-plane world point) for a corridor's cameras.

The location-reference localiser (thesis App. B) interpolates between surveyed pairs. On the real
road these come from an RTK rover placed at marked points; for a simulated corridor this tool plays
the surveyor: it places markers on a grid over the lanes and shoulder, projects them through each
camera and adds the RTK error (default sigma 2 cm). Output: TOML ``calibration = [...]`` lines.

    python -m sim.survey deploy/corridors/rellis.toml
"""

from __future__ import annotations

import argparse

import numpy as np

from protocol.corridor import Corridor, RsuConfig, load_corridor


def project_points(rsu: RsuConfig, xyz: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pixel coordinates (N, 2) of world points (N, 3) and a mask of those in front of the camera."""
    cam = rsu.camera
    pc = (cam.rotation_world_to_camera @ (xyz - cam.centre_world).T).T
    in_front = pc[:, 2] > 0.1
    uv = (cam.intrinsic_matrix @ pc.T).T
    uv = uv[:, :2] / np.where(in_front, pc[:, 2], 1.0)[:, None]
    return uv, in_front


def survey(corridor: Corridor, rsu: RsuConfig, step_m: float = 5.0, rtk_sigma_m: float = 0.02,
           seed: int = 0) -> list[tuple[float, float, float, float]]:
    road = corridor.road
    rng = np.random.default_rng(seed)
    s = np.arange(0.0, road.length_m + 1e-9, step_m)
    d = np.arange(-road.shoulder_width_m, road.width_m + 1e-9, road.lane_width_m / 2.0)
    ss, dd = np.meshgrid(s, d)
    x, y, _ = road.pose_at(ss.ravel(), dd.ravel())
    xyz = np.stack([x, y, np.zeros_like(x)], axis=1)
    uv, ok = project_points(rsu, xyz)
    cam = rsu.camera
    ok &= (uv[:, 0] >= 0) & (uv[:, 0] < cam.width_px) & (uv[:, 1] >= 0) & (uv[:, 1] < cam.height_px)
    dist = np.hypot(x - cam.x_m, y - cam.y_m)
    ok &= dist < 130.0
    noisy = xyz[ok, :2] + rng.normal(0.0, rtk_sigma_m, size=(int(ok.sum()), 2))
    return [(round(float(u), 1), round(float(v), 1), round(float(px), 3), round(float(py), 3))
            for (u, v), (px, py) in zip(uv[ok], noisy, strict=True)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("corridor", help="corridor TOML file")
    ap.add_argument("--step-m", type=float, default=5.0, help="marker spacing along the road (m)")
    ap.add_argument("--rtk-sigma-m", type=float, default=0.02, help="RTK position error (m, 1 sigma)")
    args = ap.parse_args(argv)
    corridor = load_corridor(args.corridor)
    for i, rsu in enumerate(corridor.rsus):
        pairs = survey(corridor, rsu, args.step_m, args.rtk_sigma_m, seed=i)
        print(f"# {rsu.rsu_id}: {len(pairs)} pairs")
        print("calibration = [\n" + "".join(f"  {list(p)},\n" for p in pairs) + "]")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
