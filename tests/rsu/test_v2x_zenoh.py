"""Over Zenoh, as processes: an RSU's V2X gateway turns the RSU's objects into CPMs and passes on a CAM its radio
hears, signed; `iea v2x dump` decodes both off the corridor's V2X keys."""

from __future__ import annotations

import json
import time

import pytest

from protocol.examples import object_list
from protocol.keys import rsu_key
from protocol.security import Signer, load_private_key, new_key_pair
from protocol.v2x.build import ev_cam
from protocol.v2x.codec import encode
from protocol.v2x.keys import v2x_obu_cam_key
from protocol.v2x.secure import seal
from protocol.zenoh_transport import ZenohSettings, ZenohTransport

pytestmark = pytest.mark.serial  # processes and Zenoh: make test runs it alone


def test_gateway_and_dump_over_zenoh(tmp_path, spawn, corridor_id):
    pem, _ = new_key_pair()
    key = tmp_path / "rsu1.pem"
    key.write_bytes(pem)
    key.chmod(0o600)
    ev = Signer("ev-key", load_private_key(key))
    gw = spawn("-m", "rsu.v2x_gateway", "--rsu-id", "rsu1", "--corridor-id", corridor_id, "--key", str(key), "--key-id", "rsu1-key",
               "--radio-loss", "0", "--duration-s", "40")
    dump = spawn("-m", "deploy.cli", "v2x", "dump", "--corridor-id", corridor_id, "--duration-s", "40")
    seen: set[str] = set()
    heard: set[str] = set()
    with ZenohTransport(ZenohSettings()) as zt:
        zt.subscribe_bytes(f"iea/{corridor_id}/v2x/rsu/rsu1/*", lambda k, _p: heard.add(k.rsplit("/", 1)[-1]))
        # the dump is subscribed (only it matches this key) before anything is sent
        assert zt.wait_for_subscribers(f"iea/{corridor_id}/v2x/probe", 25.0), dump.stderr.read() if dump.poll() else ""
        deadline = time.monotonic() + 25.0  # the gateway starts (asn1tools loads its schema), then hears
        done_at = None
        while time.monotonic() < deadline and gw.poll() is None:
            now = time.time()
            zt.publish(rsu_key(corridor_id, "rsu1", "objects"), object_list(3, now))
            cam = encode("CAM", ev_cam(42, now, 30.6329, -96.4789, 0.0, 20.0, True, True))
            k = v2x_obu_cam_key(corridor_id, "ev1")
            zt.publish_bytes(k, seal(ev, k, cam, now))
            time.sleep(0.25)
            if done_at is None and {"cpm", "rx"} <= heard:
                done_at = time.monotonic() + 1.5  # the dump, started at the same time, has had them too
            if done_at is not None and time.monotonic() > done_at:
                break
    dump.terminate()
    out, err = dump.communicate(timeout=20)
    for line in out.splitlines():
        doc = json.loads(line)
        if doc.get("kind") == "CPM":
            seen.add("cpm")
            assert doc["value"]["payload"]["cpmContainers"][1]["containerData"]["numberOfPerceivedObjects"] == 3
        if doc.get("key", "").endswith("/rsu1/rx"):
            seen.add("rx")
            assert doc["envelope"]["rsu_id"] == "rsu1" and doc["inner"]["envelope"]["signer"] == "ev-key"
            assert doc["inner"]["inner"]["kind"] == "CAM" and doc["inner"]["inner"]["stationId"] == 42
    assert seen == {"cpm", "rx"}, (out[-2000:], err[-2000:])


def test_iea_up_v2x_lays_out_a_gateway_per_rsu_and_an_ev_key(tmp_path):
    from deploy.up import Up
    from protocol.corridor import load_corridor
    from protocol.security import TrustList, load_private_key

    up = Up(scenario="ev_equipped_unseen", run_dir=tmp_path / "run", port=0, v2x=True)
    names = [s.name for s in up.specs]
    assert {f"rsu{i}-v2x" for i in range(1, 5)} <= set(names)
    gw = next(s for s in up.specs if s.name == "rsu2-v2x")
    assert gw.args[:4] == ["-m", "rsu.v2x_gateway", "--rsu-id", "rsu2"] and "--key" in gw.args
    sim = next(s for s in up.specs if s.name == "sim")
    ev_key = sim.args[sim.args.index("--ev-key") + 1]
    trust = TrustList.from_corridor(load_corridor(up.corridor_file))
    kid = trust.key_id_of(load_private_key(ev_key))
    assert kid == "ev1-up" and trust.keys[kid].role == "ev" and trust.has_role("rsu")
