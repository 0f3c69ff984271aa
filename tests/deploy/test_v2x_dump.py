"""`iea v2x dump --hex FILE`: one message decoded (exit 0) or refused with the reason (exit 2)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from deploy.v2x_dump import describe, dump_hex
from protocol.security import Signer, load_private_key, new_key_pair
from protocol.v2x.build import ev_cam
from protocol.v2x.codec import encode
from protocol.v2x.secure import seal

ROOT = Path(__file__).resolve().parents[2]
CAM_HEX = "0202c792bfbc63a400fa49b2bfed49be160630a14000331a9680"  # veloce's signed CAM, as its payload
CAM_V1_HEX = "0102000f6954fb00405a75197750084bcdffffffe00031b51e72000fc0007ebfe7ea8003a9800fffc0009fffc00000"


def test_the_cli_decodes_a_hex_file_and_exits_0(tmp_path):
    f = tmp_path / "cam.hex"
    f.write_text(CAM_HEX[:20] + "\n  " + CAM_HEX[20:] + "\n")
    out = subprocess.run([sys.executable, "-m", "deploy.cli", "v2x", "dump", "--hex", str(f)], cwd=ROOT,
                         capture_output=True, text=True, timeout=60)
    assert out.returncode == 0, out.stderr
    doc = json.loads(out.stdout.strip().splitlines()[-1])
    assert doc["kind"] == "CAM" and doc["stationId"] == 3348283324
    assert "rsuContainerHighFrequency" in doc["value"]["cam"]["camParameters"]["highFrequencyContainer"]


def test_a_version_1_cam_bad_hex_or_a_missing_file_exit_2_saying_why(tmp_path, capsys):
    (tmp_path / "v1.hex").write_text(CAM_V1_HEX)
    assert dump_hex(tmp_path / "v1.hex") == 2
    assert "protocolVersion 1" in capsys.readouterr().err
    (tmp_path / "bad.hex").write_text("02 02 zz")
    assert dump_hex(tmp_path / "bad.hex") == 2
    assert "not hexadecimal" in capsys.readouterr().err
    assert dump_hex(tmp_path / "none.hex") == 2
    assert "cannot read" in capsys.readouterr().err


def test_an_envelope_is_opened_and_its_cam_shown(tmp_path):
    pem, _ = new_key_pair()
    (tmp_path / "k.pem").write_bytes(pem)
    signer = Signer("ev1-key", load_private_key(tmp_path / "k.pem"))
    cam = encode("CAM", ev_cam(42, 10.0, 30.6, -96.4, 0.0, 20.0, True, True))
    doc = describe(seal(signer, "iea/c/v2x/obu/ev1/cam", cam, 10.0))
    assert doc["envelope"]["signer"] == "ev1-key" and doc["inner"]["kind"] == "CAM" and doc["inner"]["stationId"] == 42
    sv = doc["inner"]["value"]["cam"]["camParameters"]["specialVehicleContainer"]
    assert sv["emergencyContainer"]["lightBarSirenInUse"] == "11"
