"""docker-compose deployment of a corridor: one Zenoh router, the simulator, the RSUs, the DDM, the vehicles.

    iea deploy compose [--corridor FILE] [--rsus N] [--scenario NAME] [--out docker-compose.yml] [--no-acl]
                       [--unsigned]

Every IEA service runs from one image (the top-level ``Dockerfile``) with its own CLI, in Zenoh client
mode against the router (``eclipse/zenoh``, pinned to the version of the Python binding), with a health
check (``iea health ROLE ID``: a fresh ``Health`` message from that service within a few seconds) and a
restart policy. RSU cameras default to the simulator's view (``--source sim``); set ``RSU1_SOURCE`` (etc.)
to a camera URL or file for real cameras.

Access control: by default the router runs with the per-service ACL of ``deploy/acl.py`` and
each service authenticates with its own credentials, so only the DDM may publish vehicle commands.
Create the (secret, never committed) bundle once with::

    iea deploy acl --out secrets/acl --dictionary-path /etc/iea/acl/users.txt

``--no-acl`` writes an open deployment for a closed lab network.

Signatures: by default every service runs on the corridor file of an ``iea deploy keys``
bundle (``./secrets/keys/corridor.toml``, mounted read-only as ``/etc/iea/corridor.toml``), which trusts
one key per signing service; the DDM and each RSU get their own private key only (``/etc/iea/keys/``), so
vehicles follow only commands the DDM signed and the DDM acts only on alerts an RSU signed. Create the
bundle once with ``iea deploy keys --out secrets/keys``; ``--unsigned`` writes a deployment without them.

File format: the Compose Specification with neither a ``version`` nor a ``name`` key, which the
two tools users have both read with the same meaning: Docker Compose v2 (``docker compose``) and Debian 12's
``docker-compose`` 1.29.2, which since 1.27 validates every non-v1 file against its own early-2021 copy of
the specification (``deploy/compose_schema.py`` checks both schemas). Long-form ``depends_on`` with a
``condition`` (``service_started``/``service_healthy``), ``restart``, ``healthcheck`` with
``start_period`` and ``build`` all mean the same to both. Not used: the top-level ``name`` (added to the
specification later; 1.29.2 refuses the file), so the project name comes from the file's folder or
``COMPOSE_PROJECT_NAME`` / ``-p`` (the header suggests ``iea-<corridor>``); nor ``version``: optional for
both, 1.29.2 validates "2.x", "3.x" and no version alike, and Docker Compose v2 warns it is obsolete.

Metrics: every IEA service serves Prometheus metrics on port ``METRICS_PORT`` of its container
(``--metrics-port``; exposed to the compose network only), and the optional profile ``monitoring`` adds a
Prometheus server (the official ``prom/prometheus`` image, pinned) scraping them every 5 s, its UI on
host port 9090: ``docker compose --profile monitoring up``. Likewise the profile ``foxglove`` adds
``iea foxglove`` (the corridor live for Foxglove / Lichtblick on host port 8765, with credentials that
may only subscribe: ``deploy.acl.WATCHERS``): ``docker compose --profile foxglove up``. Its configuration is written by its own
command line (the image's shell), so the compose file stays the one file to deploy. Profiles are in both
schemas (docker-compose >= 1.28).
"""

from __future__ import annotations

from typing import Any

from deploy.host_tuning import HOST_SYSCTLS
from protocol.corridor import Corridor

ZENOH_IMAGE = "eclipse/zenoh:1.10.2"
"""The router image, pinned to the eclipse-zenoh Python binding the services use."""
IEA_IMAGE = "iea-corridor:latest"
ROUTER_ENDPOINT = "tcp/router:7447"
ACL_DIR_IN_CONTAINER = "/etc/iea/acl"
SIGNED_CORRIDOR_IN_CONTAINER = "/etc/iea/corridor.toml"
KEYS_DIR_IN_CONTAINER = "/etc/iea/keys"
METRICS_PORT = 9464
"""Every IEA container's Prometheus endpoint (each container has its own network namespace)."""
PROMETHEUS_IMAGE = "prom/prometheus:v2.53.0"
"""The official Prometheus image, pinned (2.53 is a long-term-support release)."""
MONITORING_PROFILE = "monitoring"
FOXGLOVE_PROFILE = "foxglove"
FOXGLOVE_PORT = 8765
"""``iea foxglove``'s Foxglove WebSocket port (published on the host: Foxglove / Lichtblick connect to it)."""


def _zenoh_args(user: str, acl: bool) -> list[str]:
    args = ["--mode", "client", "--connect", ROUTER_ENDPOINT]
    if acl:
        args += ["--zenoh-config", f"{ACL_DIR_IN_CONTAINER}/{user}.json5"]
    return args


def _healthcheck(role: str, node: str | None, user: str, acl: bool) -> dict[str, Any]:
    test = ["CMD", "iea", "health", role, *([node] if node else []), "--timeout-s", "5", *_zenoh_args(user, acl)]
    return {"test": test, "interval": "15s", "timeout": "10s", "retries": 3, "start_period": "20s"}


def compose_services(corridor: Corridor, *, rsus: int | None = None, scenario: str = "rellis_ev_yield",
                     acl: bool = True, acl_dir: str = "./secrets/acl", zenoh_image: str = ZENOH_IMAGE,
                     corridor_file: str = "deploy/corridors/rellis.toml",
                     av_start: dict[str, tuple[float, int, float]] | None = None, signed: bool = True,
                     keys_dir: str = "./secrets/keys") -> dict[str, Any]:
    """The compose document (a dict) for a corridor: router, sim, ``rsus`` RSUs (default all), DDM, vehicles.
    ``av_start``: vehicle id -> (start_s_m, lane, speed_mps) where the scenario puts it. ``signed``: every
    service on the ``iea deploy keys`` bundle in ``keys_dir`` (module docstring)."""
    chosen = list(corridor.rsus)
    if rsus is not None:
        if not 1 <= rsus <= len(chosen):
            raise ValueError(f"--rsus must be between 1 and {len(chosen)} (the corridor's RSUs), got {rsus}")
        chosen = chosen[:rsus]
    corridor_in_image = SIGNED_CORRIDOR_IN_CONTAINER if signed else f"/opt/iea/{corridor_file}"
    acl_volume = [f"{acl_dir}:{ACL_DIR_IN_CONTAINER}:ro"] if acl else []
    if signed:
        acl_volume.append(f"{keys_dir}/corridor.toml:{SIGNED_CORRIDOR_IN_CONTAINER}:ro")
    signs = {"ddm", *(r.rsu_id for r in chosen)}

    def iea_service(user: str, command: list[str], role: str, node: str | None) -> dict[str, Any]:
        volumes = list(acl_volume)
        if signed and user in signs:  # its own private key, nobody else's
            key = f"{KEYS_DIR_IN_CONTAINER}/{user}.pem"
            volumes.append(f"{keys_dir}/{user}.pem:{key}:ro")
            command = command + ["--key", key]
        svc: dict[str, Any] = {
            "image": IEA_IMAGE,
            "command": command + ["--corridor", corridor_in_image] + _zenoh_args(user, acl)
            + ["--metrics-port", str(METRICS_PORT)],
            "expose": [str(METRICS_PORT)],
            "depends_on": {"router": {"condition": "service_started"}},
            "restart": "unless-stopped",
            "healthcheck": _healthcheck(role, node, user, acl),
            "sysctls": dict(HOST_SYSCTLS),  # thin-stream retransmissions (deploy/host_tuning.py)
        }
        if volumes:
            svc["volumes"] = volumes
        return svc

    router_cfg = f"{ACL_DIR_IN_CONTAINER}/router-acl.json5" if acl else "/etc/zenoh/router.json5"
    services: dict[str, Any] = {
        "router": {
            "image": zenoh_image,
            "command": ["-c", router_cfg],
            "volumes": ([f"{acl_dir}:{ACL_DIR_IN_CONTAINER}:ro"] if acl
                        else ["./deploy/zenoh/router.json5:/etc/zenoh/router.json5:ro"]),
            "ports": ["7447:7447"],
            "restart": "unless-stopped",
            "sysctls": dict(HOST_SYSCTLS),
        },
    }
    # With a vehicle service the world waits for its first state: the two containers start in any order.
    sim_cmd = ["sim", "run", scenario] + (["--wait-for-av", "60"] if av_start else [])
    sim = iea_service("sim", sim_cmd, "sim", None)
    sim["build"] = {"context": ".", "dockerfile": "Dockerfile"}  # the one image all IEA services share
    services["sim"] = sim
    for r in chosen:
        env = f"{r.rsu_id.upper()}_SOURCE"
        services[r.rsu_id] = iea_service(r.rsu_id, ["rsu", "--rsu", r.rsu_id, "--source", f"${{{env}:-sim}}"],
                                         "rsu", r.rsu_id)
    services["ddm"] = iea_service("ddm", ["ddm", "run"], "ddm", None)
    for v in corridor.vehicles:
        cmd = ["vehicle", "run", "--vehicle", v.vehicle_id]
        if av_start and v.vehicle_id in av_start:
            s0, lane, speed = av_start[v.vehicle_id]
            cmd += ["--start-s", f"{s0:g}", "--start-lane", str(lane), "--speed", f"{speed:g}"]
        services[v.vehicle_id] = iea_service(v.vehicle_id, cmd, "vehicle", v.vehicle_id)
    services["prometheus"] = prometheus_service([n for n in services if n != "router"])
    services["foxglove"] = {  # the robotics tools' live view, off unless its profile is enabled
        "image": IEA_IMAGE, "profiles": [FOXGLOVE_PROFILE],
        "command": ["foxglove", "--host", "0.0.0.0", "--port", str(FOXGLOVE_PORT), "--corridor", corridor_in_image]
        + _zenoh_args("foxglove", acl),
        "ports": [f"{FOXGLOVE_PORT}:{FOXGLOVE_PORT}"],
        "depends_on": {"router": {"condition": "service_started"}}, "restart": "unless-stopped",
        **({"volumes": list(acl_volume)} if acl_volume else {}),
    }
    return {"services": services}  # no top-level `name`: docker-compose 1.29.2 refuses it (module docstring)


def compose_for_scenario(corridor: Corridor, corridor_path: str, scenario: str, **options) -> dict[str, Any]:
    """``iea deploy compose``: ``compose_services`` for the corridor file at ``corridor_path`` (inside the
    repository, which the image copies: ValueError otherwise) with the AV where ``scenario`` starts it;
    ``options``: the rest of ``compose_services``'s. Raises ``ScenarioError`` for an unknown scenario."""
    from pathlib import Path

    from sim.scenario import load_scenario

    sc = load_scenario(scenario, corridor)
    av = {sc.av.vehicle_id: (sc.av.start_s_m, sc.av.lane, sc.av.speed_mps)} if sc.av is not None else None
    root = Path(__file__).resolve().parent.parent
    try:
        corridor_file = str(Path(corridor_path).resolve().relative_to(root))
    except ValueError:
        raise ValueError(f"the corridor file must be inside the repository (the image copies {root}); "
                         f"got {corridor_path}") from None
    return compose_services(corridor, scenario=scenario, corridor_file=corridor_file, av_start=av, **options)


def prometheus_config(targets: list[str]) -> list[str]:
    """The lines of prometheus.yml scraping ``targets`` (compose service names) on ``METRICS_PORT``."""
    return ["global: {scrape_interval: 5s, evaluation_interval: 5s}", "scrape_configs:", "  - job_name: iea",
            "    static_configs:", "      - targets: [" + ", ".join(f"'{t}:{METRICS_PORT}'" for t in targets) + "]"]


def prometheus_service(targets: list[str]) -> dict[str, Any]:
    """The optional Prometheus server (profile ``monitoring``): its config written by its own shell, then run."""
    write = "printf '%s\\n' " + " ".join(f'"{line}"' for line in prometheus_config(targets))
    run = "exec /bin/prometheus --config.file=/tmp/prometheus.yml --storage.tsdb.path=/prometheus"
    return {"image": PROMETHEUS_IMAGE, "profiles": [MONITORING_PROFILE], "entrypoint": ["/bin/sh", "-c"],
            "command": [f"{write} > /tmp/prometheus.yml && {run}"], "ports": ["9090:9090"],
            "depends_on": {t: {"condition": "service_started"} for t in targets}, "restart": "unless-stopped"}


def compose_yaml(doc: dict[str, Any], header: str = "") -> str:
    import yaml

    body = yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)
    return header + body


HEADER = """\
# IEA corridor deployment: one Zenoh router, the simulator, the RSUs, the DDM and the vehicle.
# Generated by `iea deploy compose` from deploy/corridors/rellis.toml: edit the corridor, not this file.
# Before the first `docker compose up`, create the router ACL and each service's credentials, and the
# signing keys with the corridor file trusting them (both secret, never committed):
#   iea deploy acl --out secrets/acl --dictionary-path /etc/iea/acl/users.txt
#   iea deploy keys --out secrets/keys
# Real cameras: RSU1_SOURCE=rtsp://... docker compose up   (default: each RSU renders the simulator's view)
# Monitoring: docker compose --profile monitoring up   (Prometheus on :9090 scraping every service's :9464/metrics)
# Foxglove / Lichtblick: docker compose --profile foxglove up   (iea foxglove on ws://<host>:8765)
# Valid for Docker Compose v2 (`docker compose`) and Debian 12's docker-compose 1.29.2 (`docker-compose`).
# Project name: this folder's name, or COMPOSE_PROJECT_NAME=iea-rellis (or `-p iea-rellis`).
"""
