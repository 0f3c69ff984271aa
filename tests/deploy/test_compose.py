"""docker-compose deployment: the committed file is what `iea deploy compose`
generates, it matches the corridor file, every service command parses with that service's own CLI, it
satisfies both the Compose Specification's schema (Docker Compose v2) and the one docker-compose 1.29.2
applies (Debian 12) on every machine, and `docker-compose config` accepts it with the same meaning where
the tool is installed (.ci/run installs it; no Docker engine needed)."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from deploy.compose import METRICS_PORT, PROMETHEUS_IMAGE, ROUTER_ENDPOINT, ZENOH_IMAGE, compose_services
from deploy.compose_schema import COMPOSE_SPEC, DOCKER_COMPOSE_V1, compose_errors
from protocol.corridor import load_corridor

pytestmark = pytest.mark.serial  # processes, Zenoh or its own timing: make test runs it alone


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
    assert "name" not in doc and "version" not in doc  # neither key means the same to compose v1 and v2
    services = doc["services"]
    rsu_ids = [r.rsu_id for r in corridor.rsus]
    optional = {n for n, s in services.items() if s.get("profiles")}  # `--profile monitoring` / `foxglove` only
    assert optional == {"prometheus", "foxglove"}
    services = {n: s for n, s in services.items() if n not in optional}
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
        # signed by default: the `iea deploy keys` corridor file trusting the keys, and each signing
        # service its own private key, nobody else's
        assert args.corridor == "/etc/iea/corridor.toml"
        assert "./secrets/keys/corridor.toml:/etc/iea/corridor.toml:ro" in svc["volumes"]
        keys_mounted = [v for v in svc["volumes"] if v.endswith(".pem:ro") or ".pem:" in v]
        if name == "ddm" or name in rsu_ids:
            assert args.key == f"/etc/iea/keys/{name}.pem"
            assert keys_mounted == [f"./secrets/keys/{name}.pem:/etc/iea/keys/{name}.pem:ro"]
        else:
            assert keys_mounted == [] and getattr(args, "key", None) is None
        assert args.metrics_port == METRICS_PORT and svc["expose"] == [str(METRICS_PORT)]
        if cmd[0] == "rsu":  # camera source from the environment, the simulator's view by default
            assert args.rsu == name and args.source == f"${{{name.upper()}_SOURCE:-sim}}"
    # the vehicle starts where the scenario puts the AV
    v = vehicle_parser().parse_args(services["av1"]["command"][1:])
    assert (v.start_s, v.start_lane, v.speed) == (135.0, 1, 13.4)


def test_foxglove_profile_serves_the_corridor_to_robotics_tools():
    """`iea foxglove` as an optional service: its own CLI accepts the command, on the signed corridor file,
    with watcher credentials (subscribe only), its WebSocket port published on the host."""
    from deploy.acl import WATCHERS
    from deploy.foxglove_bridge import build_parser

    fox = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))["services"]["foxglove"]
    assert fox["profiles"] == ["foxglove"] and fox["ports"] == ["8765:8765"] and fox["image"] == "iea-corridor:latest"
    assert fox["command"][0] == "foxglove"
    args = build_parser().parse_args(fox["command"][1:])
    assert (args.host, args.port, args.corridor) == ("0.0.0.0", 8765, "/etc/iea/corridor.toml")
    assert args.connect == [ROUTER_ENDPOINT] and args.zenoh_config == "/etc/iea/acl/foxglove.json5"
    assert "foxglove" in WATCHERS and "./secrets/keys/corridor.toml:/etc/iea/corridor.toml:ro" in fox["volumes"]
    assert not any(".pem" in v for v in fox["volumes"])  # no signing key: it publishes nothing


def test_iea_up_offers_the_foxglove_bridge(tmp_path):
    from deploy.foxglove_bridge import build_parser
    from deploy.up import Up
    from deploy.up import build_parser as up_parser

    assert up_parser().parse_args(["--foxglove"]).foxglove == 8765 and up_parser().parse_args([]).foxglove is None
    up = Up(run_dir=tmp_path / "run", signed=False, record=False, foxglove_port=9876, port=7600)
    (spec,) = [s for s in up.specs if s.name == "foxglove"]
    assert spec.args[:3] == ["-m", "deploy", "foxglove"]
    args = build_parser().parse_args(spec.args[3:])
    assert (args.port, args.corridor_id, args.connect) == (9876, up.corridor_id, [up.endpoint])
    assert "foxglove" not in up.health_line()  # it sends no Health


def test_monitoring_profile_scrapes_every_service():
    """The optional Prometheus server: the official image pinned, its config listing every IEA
    service's metrics port, written by its own command line."""
    services = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))["services"]
    prom = services["prometheus"]
    assert prom["profiles"] == ["monitoring"] and prom["image"] == PROMETHEUS_IMAGE
    assert re.fullmatch(r"prom/prometheus:v\d+\.\d+\.\d+", prom["image"])
    script = prom["command"][0]
    lines = re.findall(r'"([^"]*)"', script.split(" > ")[0])
    config = yaml.safe_load("\n".join(lines))
    targets = config["scrape_configs"][0]["static_configs"][0]["targets"]
    iea = [n for n, s in services.items() if s.get("image") == "iea-corridor:latest" and not s.get("profiles")]
    assert sorted(targets) == sorted(f"{n}:{METRICS_PORT}" for n in iea)


def test_rsus_option_and_open_deployment():
    doc = compose_services(load_corridor(), rsus=2, acl=False)
    assert [n for n in doc["services"] if n.startswith("rsu")] == ["rsu1", "rsu2"]
    assert all("--zenoh-config" not in s.get("command", []) for s in doc["services"].values())
    with pytest.raises(ValueError, match="between 1 and 4"):
        compose_services(load_corridor(), rsus=9)
    text = _generate("--rsus", "3", "--no-acl")
    assert "rsu3:" in text and "rsu4:" not in text and "router.json5" in text


def test_unsigned_takes_an_explicit_flag():
    doc = compose_services(load_corridor(), signed=False)
    for svc in doc["services"].values():
        assert "--key" not in svc.get("command", []) and "/etc/iea/corridor.toml" not in svc.get("command", [])
    assert "--key" in _generate()  # the default is signed
    assert "--key" not in _generate("--unsigned")


def test_compose_files_satisfy_both_compose_schemas():
    """No Docker needed: the committed file and an open 2-RSU one against the Compose Specification and
    docker-compose 1.29.2's schema (deploy/schema/)."""
    assert compose_errors(yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))) == {}
    assert compose_errors(yaml.safe_load(_generate("--rsus", "2", "--no-acl"))) == {}


def test_schema_check_refuses_what_the_tools_refuse():
    doc = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    # a top-level name is the Compose Specification's, but 1.29.2 refuses it
    named = {"name": "iea-rellis", **doc}
    errors = compose_errors(named)
    assert list(errors) == [DOCKER_COMPOSE_V1]
    assert errors[DOCKER_COMPOSE_V1] == ["(top level): 'name' does not match any of the regexes: '^x-'"]
    # a condition neither tool knows, and a service with neither image nor build
    bad = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    bad["services"]["ddm"]["depends_on"]["router"]["condition"] = "service_ready"
    assert set(compose_errors(bad)) == {COMPOSE_SPEC, DOCKER_COMPOSE_V1}
    del bad["services"]["ddm"]["depends_on"], bad["services"]["ddm"]["image"]
    assert any(e.startswith("services/ddm:") for e in compose_errors(bad)[DOCKER_COMPOSE_V1])
    # health-gated start means the same to both: a service_healthy condition is valid for both
    gated = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))
    gated["services"]["ddm"]["depends_on"]["rsu1"] = {"condition": "service_healthy"}
    assert compose_errors(gated) == {}


def _docker_compose_config(tool: str, text: str, tmp_path: Path) -> subprocess.CompletedProcess:
    (tmp_path / "secrets" / "acl").mkdir(parents=True, exist_ok=True)
    target = tmp_path / "docker-compose.yml"
    target.write_text(text, encoding="utf-8")
    (tmp_path / "Dockerfile").write_text((ROOT / "Dockerfile").read_text(encoding="utf-8"))
    env = {k: v for k, v in os.environ.items() if not k.startswith(("COMPOSE_", "RSU"))}
    return subprocess.run([tool, "-f", str(target), "config"], capture_output=True, text=True, timeout=60,
                          cwd=tmp_path, env=env)


def test_docker_compose_config_accepts_the_file(tmp_path):
    """The real docker-compose (Debian 12: 1.29.2) accepts the file, keeps its meaning (health checks,
    restart policies, start conditions) and refuses a file with a top-level name."""
    tool = shutil.which("docker-compose")
    if tool is None:
        pytest.skip("docker-compose is not installed (Debian package docker-compose; .ci/run installs it); "
                    "the schema checks above still ran")
    text = COMPOSE.read_text(encoding="utf-8")
    r = _docker_compose_config(tool, text, tmp_path)
    assert r.returncode == 0, r.stderr
    ours, theirs = yaml.safe_load(text)["services"], yaml.safe_load(r.stdout)["services"]
    assert set(theirs) == set(ours)
    for name, svc in ours.items():
        for key in ("image", "restart", "depends_on", "healthcheck"):
            assert theirs[name].get(key) == svc.get(key), (name, key)
    published = [dict(zip(("published", "target"), map(int, p.split(":")), strict=True))
                 for p in ours["router"]["ports"]]
    assert theirs["router"]["ports"] == published  # 1.29.2 prints ports in the long form
    assert theirs["rsu1"]["command"][4] == "sim"  # ${RSU1_SOURCE:-sim} with RSU1_SOURCE unset
    r = _docker_compose_config(tool, "name: iea-rellis\n" + text, tmp_path)
    assert r.returncode != 0 and "'name' does not match any of the regexes" in r.stderr


def test_every_corridor_host_gets_the_thin_stream_kernel_setting():
    import yaml

    from deploy.host_tuning import HOST_SYSCTLS

    services = yaml.safe_load(COMPOSE.read_text(encoding="utf-8"))["services"]
    hosts = [name for name in services if name not in ("prometheus", "foxglove")]
    assert "router" in hosts and "ddm" in hosts and "av1" in hosts
    for name in hosts:
        assert services[name]["sysctls"] == HOST_SYSCTLS, name
