"""A corridor larger than one router: a router per corridor segment, linked to a core router.

    iea deploy mesh [--corridor FILE] --out DIR --core-listen tcp/0.0.0.0:7447 \\
        --segment-listen tcp/0.0.0.0:7448 [--segment-listen tcp/0.0.0.0:7449 ...] [--core-connect EP ...]
        [--mtls [--pki-path DIR] [--no-pki]]

The RSUs are split into contiguous groups in corridor order, one group per segment router (an RSU
talks to the router of its own stretch of road); the DDM, the simulator and the vehicles join the core
(vehicles move along the whole corridor: their cellular link reaches the core, not a roadside box).
Every router runs the same ACL (``deploy.acl.router_config``, deny by default) for the services that
join it; the segment routers authenticate to the core as ``router-<segment>`` and may carry any key of
the corridor there (routers are infrastructure: the service-level checks are made at the edge, where
the service joined). With passwords the link's other direction is not authenticated (the segment
opened it), so each router has a fixed Zenoh id and the segment routers admit the core's by that id;
with ``--mtls`` (``tls/`` endpoints) every router and service has a certificate from one private CA and
both ends of every link are authenticated by certificate common name (``router-core``, ``router-segN``,
the service ids). ``--no-pki`` writes the configs only (no keys: for templates such as
``deploy/zenoh/mesh/``). Writes ``router-core.json5``, ``router-<segment>.json5``, the password dictionary
(``users.txt``, 0600), a credentials file per service and ``mesh.json`` (which router each service joins).

``mesh_layout`` is pure; ``write_mesh_bundle`` writes the files.
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path
from typing import Any

from deploy.acl import router_config, service_publish_keys
from protocol.corridor import Corridor


def mesh_layout(corridor: Corridor, n_segments: int) -> dict[str, str]:
    """Service (ACL user) -> the router it joins: ``core`` or ``seg1``..``segN``."""
    rsus = [r.rsu_id for r in corridor.rsus]
    if not 1 <= n_segments <= len(rsus):
        raise ValueError(f"need 1..{len(rsus)} segment routers for {len(rsus)} RSUs, got {n_segments}")
    out = {user: "core" for user in service_publish_keys(corridor)}
    per = -(-len(rsus) // n_segments)
    for i, rsu in enumerate(rsus):
        out[rsu] = f"seg{i // per + 1}"
    return out


def _with_routers(cfg: dict[str, Any], corridor: Corridor, **who: list[str]) -> dict[str, Any]:
    """Let the linked routers (``usernames=``, ``zids=``, ``cert_common_names=``) carry every message of the
    corridor, both ways."""
    ac = cfg["access_control"]
    ac["rules"].append({"id": "router-link", "permission": "allow", "flows": ["ingress", "egress"],
                        "messages": ["put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                                     "liveliness_token", "declare_liveliness_subscriber", "liveliness_query"],
                        "key_exprs": [f"iea/{corridor.corridor_id}/**"]})
    subjects = []
    for field, values in who.items():
        if values:
            ac["subjects"].append({"id": f"routers-{field}", field: values})
            subjects.append(f"routers-{field}")
    ac["policies"].append({"id": "routers", "rules": ["router-link"], "subjects": subjects})
    return cfg


def write_mesh_bundle(corridor: Corridor, out_dir: Path, core_listen: list[str], segment_listen: list[str],
                      core_connect: list[str] | None = None, dictionary_path_in_router: str | None = None,
                      *, mtls: bool = False, pki_dir_in_services: str | None = None, write_pki: bool = True
                      ) -> dict[str, Path]:
    """Core and segment router configs with the ACL, one dictionary, credentials per service and router.
    ``core_connect``: where segment routers reach the core (default: ``core_listen`` with 0.0.0.0 -> 127.0.0.1)."""
    if not segment_listen:
        raise ValueError("a mesh needs at least one --segment-listen endpoint")
    layout = mesh_layout(corridor, len(segment_listen))
    out_dir.mkdir(parents=True, exist_ok=True)
    segments = [f"seg{i + 1}" for i in range(len(segment_listen))]
    if mtls:
        return _write_mtls_mesh(corridor, out_dir, core_listen, segment_listen, core_connect, layout, segments,
                                pki_dir_in_services, write_pki)
    users = {u: secrets.token_urlsafe(18) for u in [*service_publish_keys(corridor), *(f"router-{s}" for s in segments)]}
    dictionary = out_dir / "users.txt"
    dictionary.write_text("".join(f"{u}:{p}\n" for u, p in users.items()), encoding="utf-8")
    dictionary.chmod(0o600)
    dict_path = dictionary_path_in_router or str(dictionary.resolve())
    connect = core_connect or [ep.replace("0.0.0.0", "127.0.0.1") for ep in core_listen]
    written: dict[str, Path] = {"users": dictionary}
    # Zenoh ids are hex numbers: no leading zero, so the id the router reports is the one in its ACL
    zids = {name: f"{secrets.randbelow(15) + 1:x}{secrets.token_hex(8)[1:]}" for name in ["core", *segments]}
    core = _with_routers(router_config(corridor, dict_path, core_listen), corridor,
                         usernames=[f"router-{s}" for s in segments], zids=[zids[s] for s in segments])
    core["id"] = zids["core"]
    written["core"] = out_dir / "router-core.json5"
    written["core"].write_text(json.dumps(core, indent=2) + "\n", encoding="utf-8")
    for seg, listen in zip(segments, segment_listen, strict=True):
        cfg = router_config(corridor, dict_path, [listen])
        cfg["connect"] = {"endpoints": connect}
        cfg["transport"]["auth"]["usrpwd"].update({"user": f"router-{seg}", "password": users[f"router-{seg}"]})
        cfg = _with_routers(cfg, corridor, zids=[zids["core"]])
        cfg["id"] = zids[seg]
        written[seg] = out_dir / f"router-{seg}.json5"
        written[seg].write_text(json.dumps(cfg, indent=2) + "\n", encoding="utf-8")
        written[seg].chmod(0o600)  # it holds the segment router's password
    for user in service_publish_keys(corridor):
        cred = out_dir / f"{user}.json5"
        cred.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": user, "password": users[user]}}}},
                                   indent=2) + "\n", encoding="utf-8")
        cred.chmod(0o600)
        written[user] = cred
    written["mesh"] = _write_layout(out_dir, connect, segments, segment_listen, layout)
    return written


def _write_layout(out_dir: Path, connect: list[str], segments: list[str], segment_listen: list[str],
                  layout: dict[str, str]) -> Path:
    endpoints = {"core": connect, **{s: [ep.replace("0.0.0.0", "127.0.0.1")] for s, ep in
                                     zip(segments, segment_listen, strict=True)}}
    mesh = {"routers": endpoints, "services": {u: {"router": r, "connect": endpoints[r]} for u, r in layout.items()}}
    path = out_dir / "mesh.json"
    path.write_text(json.dumps(mesh, indent=2) + "\n", encoding="utf-8")
    return path


def _write_mtls_mesh(corridor: Corridor, out_dir: Path, core_listen: list[str], segment_listen: list[str],
                     core_connect: list[str] | None, layout: dict[str, str], segments: list[str],
                     pki_dir_in_services: str | None, write_pki: bool) -> dict[str, Path]:
    from deploy.acl import tls_link
    from deploy.certs import make_pki

    users = list(service_publish_keys(corridor))
    routers = ["router-core", *(f"router-{s}" for s in segments)]
    if write_pki:
        make_pki([*routers, *users], out_dir)
    where = pki_dir_in_services or str(out_dir.resolve())
    connect = core_connect or [ep.replace("0.0.0.0", "127.0.0.1") for ep in core_listen]
    written: dict[str, Path] = {}
    core = router_config(corridor, None, core_listen, tls=tls_link(where, "router-core"))
    core = _with_routers(core, corridor, cert_common_names=routers[1:])
    written["core"] = out_dir / "router-core.json5"
    written["core"].write_text(json.dumps(core, indent=2) + "\n", encoding="utf-8")
    for seg, listen in zip(segments, segment_listen, strict=True):
        cfg = router_config(corridor, None, [listen], tls=tls_link(where, f"router-{seg}"))
        cfg["connect"] = {"endpoints": connect}
        cfg = _with_routers(cfg, corridor, cert_common_names=["router-core"])
        written[seg] = out_dir / f"router-{seg}.json5"
        written[seg].write_text(json.dumps(cfg, indent=2) + "\n", encoding="utf-8")
    for user in users:
        client = out_dir / f"{user}.json5"  # as with passwords: one name per service whatever the auth
        client.write_text(json.dumps({"transport": {"link": {"tls": tls_link(where, user)}}}, indent=2) + "\n",
                          encoding="utf-8")
        written[user] = client
    written["mesh"] = _write_layout(out_dir, connect, segments, segment_listen, layout)
    return written
