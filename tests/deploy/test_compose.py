"""docker-compose deployment (issue 8 item 3): the committed file is what `iea deploy compose` generates,
it matches the corridor file, every service command parses with that service's own CLI, and
`docker-compose config` accepts it where the tool is installed (no Docker engine needed)."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from deploy.compose import ROUTER_ENDPOINT, ZENOH_IMAGE, compose_services
from protocol.corridor import load_corridor

ROOT = Path(__file__).resolve().parents[2]
COMPOSE = ROOT / "docker-compose.yml"


def _generate(*args: str) -> str:
    r = subprocess.run([sys.executable, "-m", "deploy", "deploy", "compose", *args], capture_output=True, text=True,
                       cwd=ROOT, timeout=60)
    assert r.returncode == 0, r.stderr
    return r.stdout


def test_committed_compose_is_the_generated_one():
    assert COMPOSE.read_text(encoding="utf-8") == _generate(), "run `iea deploy compose --out docker-compose.yml`"


def test_compose_matches_the_corridor_and_services_parse_their_commands():
    from importlib.metadata import version

    from ddm.cli import build_parser as ddm_parser
    from rsu.cli import build_parser as rsu_parser
    from sim.cli import build_parser as sim_parser
    from vehicle.cli import build_parser as vehicle_parser

    doc = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    corridor = load_corridor()
    services = doc["services"]
    rsu_ids = [r.rsu_id for r in corridor.rsus]
    assert set(services) == {"router", "sim", "ddm", *rsu_ids, *(v.vehicle_id for v in corridor.vehicles)}
    # the router image is pinned to the Python binding's version
    assert services["router"]["image"] == ZENOH_IMAGE and ZENOH_IMAGE.endswith(":" + version("eclipse-zenoh"))
    parsers = {"rsu": rsu_parser, "ddm": ddm_parser, "vehicle": vehicle_parser, "sim": sim_parser}
    for name, svc in services.items():
        if name == "router":
            continue
        assert svc["restart"] == "unless-stopped" and svc["healthcheck"]["test"][:3] == ["CMD", "iea", "health"]
        assert svc["depends_on"] == {"router": {"condition": "service_started"}}
        cmd = svc["command"]
        args = parsers[cmd[0]]().parse_args(cmd[1:])  # the service's own CLI accepts it
        assert args.connect == [ROUTER_ENDPOINT] and args.mode == "client"
        assert args.zenoh_config == f"/etc/iea/acl/{name}.json5"  # ACL credentials of that service
        assert args.corridor == "/opt/iea/deploy/corridors/rellis.toml"
        if cmd[0] == "rsu":  # camera source from the environment, the simulator's view by default
            assert args.rsu == name and args.source == f"${{{name.upper()}_SOURCE:-sim}}"
    # the vehicle starts where the scenario puts the AV
    v = vehicle_parser().parse_args(services["av1"]["command"][1:])
    assert (v.start_s, v.start_lane, v.speed) == (135.0, 1, 13.4)


def test_rsus_option_and_open_deployment():
    doc = compose_services(load_corridor(), rsus=2, acl=False)
    assert [n for n in doc["services"] if n.startswith("rsu")] == ["rsu1", "rsu2"]
    assert all("--zenoh-config" not in s.get("command", []) for s in doc["services"].values())
    with pytest.raises(ValueError, match="between 1 and 4"):
        compose_services(load_corridor(), rsus=9)
    text = _generate("--rsus", "3", "--no-acl")
    assert "rsu3:" in text and "rsu4:" not in text and "router.json5" in text


def test_docker_compose_config_accepts_the_file(tmp_path):
    tool = shutil.which("docker-compose")
    if tool is None:
        pytest.skip("docker-compose is not installed (Debian package docker-compose); the YAML checks above still ran")
    (tmp_path / "secrets" / "acl").mkdir(parents=True)
    target = tmp_path / "docker-compose.yml"
    target.write_text(COMPOSE.read_text(encoding="utf-8"), encoding="utf-8")
    (tmp_path / "Dockerfile").write_text((ROOT / "Dockerfile").read_text(encoding="utf-8"))
    r = subprocess.run([tool, "-f", str(target), "config", "-q"], capture_output=True, text=True, timeout=60,
                       cwd=tmp_path)
    assert r.returncode == 0, r.stderr
