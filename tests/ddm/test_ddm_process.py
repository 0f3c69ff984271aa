"""Process level: ``python -m ddm.cli run`` over real Zenoh (loopback peer mode), scripted RSU/vehicle input."""

from __future__ import annotations

import math
import os
import subprocess
import sys
import threading
import time
from pathlib import Path
from uuid import uuid4

import pytest
from ddm_rig import det, lane_y, object_list

from deploy.procs import stop_process
from protocol.corridor import load_corridor
from protocol.enums import AckStatus, AlertState, Manoeuvre, VehicleMode
from protocol.keys import ddm_health_key, rsu_key, vehicle_key
from protocol.messages import CommandAck, EvAlert, VehicleState

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


ROOT = Path(__file__).resolve().parents[2]
zenoh = pytest.importorskip("zenoh")


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_ddm_process_pulls_over_and_retransmits_until_acked():
    from protocol.zenoh_transport import ZenohSettings, ZenohTransport

    cid = f"t{uuid4().hex[:8]}"
    cor = load_corridor()
    env = dict(os.environ, PYTHONPATH=str(ROOT))
    proc = subprocess.Popen(
        [sys.executable, "-m", "ddm.cli", "run", "--corridor", str(ROOT / "deploy/corridors/rellis.toml"),
         "--corridor-id", cid, "--startup-listen-s", "0.5", "--log-level", "INFO"],
        cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    tr = ZenohTransport(ZenohSettings())
    cmds: list[tuple[float, object]] = []
    health = []
    lock = threading.Lock()

    def on_cmd(_k, m):
        with lock:
            cmds.append((time.time(), m))

    tr.subscribe(vehicle_key(cid, "av1", "cmd"), on_cmd)
    tr.subscribe(ddm_health_key(cid), lambda _k, m: health.append(m))
    try:
        deadline = time.time() + 15.0
        while not health and time.time() < deadline:  # the DDM is up and the peers found each other
            assert proc.poll() is None, proc.stdout.read()
            time.sleep(0.05)
        assert health, "no Health from the DDM process"
        t_start = time.time()
        av_x, ev_x, frame = 20.0, -30.0, 0
        acked_at = None
        pull_over = None
        while time.time() < deadline + 5.0:
            now = time.time()
            el = now - t_start
            ax, ex = av_x + 13.4 * el, ev_x + 20.0 * el
            frame += 1
            objs = [det(cor, 11, ax, lane_y(1), 13.4), det(cor, 12, ex, lane_y(1), 20.0)]
            tr.publish(rsu_key(cid, "rsu1", "objects"), object_list("rsu1", frame, now, objs))
            lat, lon = cor.to_latlon(ax, lane_y(1))
            tr.publish(vehicle_key(cid, "av1", "state"), VehicleState(
                src="av1", stamp=now, vehicle_id="av1", pos_x_m=ax, pos_y_m=lane_y(1), lat_deg=lat, lon_deg=lon,
                heading_rad=0.0, speed_mps=13.4, mode=VehicleMode.DRIVING))
            if frame % 5 == 1:
                lat, lon = cor.to_latlon(ex, lane_y(1))
                tr.publish(rsu_key(cid, "rsu1", "ev"), EvAlert(
                    src="rsu1", stamp=now, alert_id="rsu1-ev-1", state=AlertState.ACTIVE, rsu_id="rsu1", object_id=12,
                    pos_x_m=ex, pos_y_m=lane_y(1), lat_deg=lat, lon_deg=lon, vel_x_mps=20.0, speed_mps=20.0,
                    confidence=0.9, first_seen=t_start))
            with lock:
                got = list(cmds)
            if pull_over is None and got:
                pull_over = got[0][1]
            if pull_over is not None and acked_at is None:
                n_sends = sum(1 for _, m in got if m.command_id == pull_over.command_id)
                if n_sends >= 3:  # retransmitted while we stayed silent: now acknowledge it
                    tr.publish(vehicle_key(cid, "av1", "ack"), CommandAck(
                        src="av1", stamp=time.time(), command_id=pull_over.command_id, vehicle_id="av1",
                        status=AckStatus.ACCEPTED))
                    acked_at = time.time()
            if acked_at is not None and time.time() - acked_at > 1.5:
                break
            time.sleep(0.1)
        assert pull_over is not None, "no command from the DDM process"
        assert pull_over.manoeuvre == Manoeuvre.PULL_OVER and pull_over.target_lane == 0
        assert acked_at is not None, "the command was not retransmitted 3 times"
        with lock:
            same = [t for t, m in cmds if m.command_id == pull_over.command_id]
        assert len(same) >= 3
        assert all(b > a for a, b in zip(same, same[1:], strict=False))
        late = [t for t in same if t > acked_at + 0.3]
        assert late == [], f"still retransmitted {len(late)} times after the ack"
        assert not math.isnan(health[-1].uptime_s)
    finally:
        tr.close()
        stop_process(proc, timeout_s=5.0)


def test_cli_help_and_bad_arguments(capsys):
    from ddm.cli import main

    with pytest.raises(SystemExit) as ex:
        main(["run", "--help"])
    assert ex.value.code == 0 and "--corridor-id" in capsys.readouterr().out
    assert main(["run", "--corridor", "/nonexistent/corridor.toml"]) == 2
    assert "corridor file not found" in capsys.readouterr().err
    assert main(["run", "--corridor-id", "bad/id"]) == 2
    assert "not a valid key chunk" in capsys.readouterr().err
