"""Zenoh router access control for a corridor: who may publish what.

Every service authenticates to the router with its own user name (Zenoh user/password
authentication; over TLS in deployment) and the router's ACL (Zenoh 1.x ``access_control``) lets it
publish only under its own keys, denying everything else by default:

| user            | may publish (ingress ``put``)                                   |
|-----------------|-----------------------------------------------------------------|
| ``ddm``         | ``iea/{c}/vehicle/*/cmd``, ``iea/{c}/ddm/health``                 |
| ``{rsu_id}``    | ``iea/{c}/rsu/{rsu_id}/**``                                       |
| ``{vehicle_id}``| ``iea/{c}/vehicle/{vehicle_id}/state|ack|health``                 |
| ``sim``         | ``iea/{c}/sim/**``                                                |

Everyone may subscribe under ``iea/{c}/**`` and the router delivers (egress) everything it admitted;
``foxglove`` (``iea foxglove``, the robotics tools' live view) has credentials and may only do that.
Only the DDM may therefore send a ``PathSwitchCommand``; vehicles also verify its signature
(protocol/security.py).

Presence and state: everyone may watch and query liveliness tokens and query under
``iea/{c}/**``; a service may declare only its own token ``iea/{c}/alive/{role}/{user}`` and answer
queries (``declare_queryable``, ``reply``) only on its own keys (those it may publish, and the DDM's
``iea/{c}/ddm/state``): an RSU cannot pose as another in ``iea status`` or in a DDM's start-up catch-up.

    iea deploy acl [--corridor FILE] --out DIR [--mtls]
        router config, and per service either a user/password credentials file or (--mtls) a
        certificate from a private CA and a TLS client config
"""

from __future__ import annotations

import json
import secrets
from pathlib import Path
from typing import Any

from protocol.corridor import Corridor
from protocol.qos import ROUTER_NETWORK_QOS


def service_publish_keys(corridor: Corridor) -> dict[str, list[str]]:
    """User name -> the key expressions it may publish."""
    c = corridor.corridor_id
    out: dict[str, list[str]] = {
        "ddm": [f"iea/{c}/vehicle/*/cmd", f"iea/{c}/ddm/health"],
        "sim": [f"iea/{c}/sim/**"],
    }
    for rsu in corridor.rsus:
        out[rsu.rsu_id] = [f"iea/{c}/rsu/{rsu.rsu_id}/**"]
    for v in corridor.vehicles:
        out[v.vehicle_id] = [f"iea/{c}/vehicle/{v.vehicle_id}/{t}" for t in ("state", "ack", "health")]
    return out


WATCHERS = ("foxglove",)
"""Users that only watch the corridor (``iea foxglove``): credentials, and nothing to publish or serve."""


def service_serve_keys(corridor: Corridor) -> dict[str, list[str]]:
    """User name -> the key expressions it may answer queries on (its own keys)."""
    out = service_publish_keys(corridor)
    out["ddm"] = [*out["ddm"], f"iea/{corridor.corridor_id}/ddm/state"]
    return out


def service_token_keys(corridor: Corridor) -> dict[str, str]:
    """User name -> its liveliness token key."""
    c = corridor.corridor_id
    out = {"ddm": f"iea/{c}/alive/ddm/ddm", "sim": f"iea/{c}/alive/sim/sim"}
    out.update({r.rsu_id: f"iea/{c}/alive/rsu/{r.rsu_id}" for r in corridor.rsus})
    out.update({v.vehicle_id: f"iea/{c}/alive/vehicle/{v.vehicle_id}" for v in corridor.vehicles})
    return out


def router_config(corridor: Corridor, dictionary_file: str | None, listen: list[str] | None = None,
                  tls: dict[str, Any] | None = None) -> dict[str, Any]:
    """A Zenoh router config (JSON-compatible dict) enforcing the table in the module docstring.

    Services are identified by user name (``dictionary_file``, user/password authentication) or, with
    ``tls`` (mutual TLS), by the common name of their certificate (see ``deploy/certs.py``)."""
    c = corridor.corridor_id
    publish = service_publish_keys(corridor)
    serve, tokens = service_serve_keys(corridor), service_token_keys(corridor)
    rules: list[dict[str, Any]] = [
        {"id": "subscribe", "permission": "allow", "flows": ["ingress"],
         "messages": ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"],
         "key_exprs": [f"iea/{c}/**"]},
        {"id": "deliver", "permission": "allow", "flows": ["egress"],
         "messages": ["put", "declare_subscriber", "liveliness_token", "declare_liveliness_subscriber",
                      "liveliness_query", "declare_queryable", "query", "reply"],
         "key_exprs": [f"iea/{c}/**"]},
    ]
    subjects: list[dict[str, Any]] = [{"id": "everyone"}]
    policies: list[dict[str, Any]] = [{"id": "everyone", "rules": ["subscribe", "deliver"], "subjects": ["everyone"]}]
    for user, key_exprs in publish.items():
        rules.append({"id": f"publish-{user}", "permission": "allow", "flows": ["ingress"], "messages": ["put"],
                      "key_exprs": key_exprs})
        rules.append({"id": f"serve-{user}", "permission": "allow", "flows": ["ingress"],
                      "messages": ["declare_queryable", "reply"], "key_exprs": serve[user]})
        rules.append({"id": f"token-{user}", "permission": "allow", "flows": ["ingress"],
                      "messages": ["liveliness_token"], "key_exprs": [tokens[user]]})
        who = {"cert_common_names": [user]} if tls and tls.get("enable_mtls") else {"usernames": [user]}
        subjects.append({"id": f"user-{user}", **who})
        policies.append({"id": f"policy-{user}", "rules": [f"publish-{user}", f"serve-{user}", f"token-{user}"],
                         "subjects": [f"user-{user}"]})
    config: dict[str, Any] = {
        "mode": "router",
        "listen": {"endpoints": listen or ["tcp/0.0.0.0:7447"]},
        "scouting": {"multicast": {"enabled": False}},
        "qos": {"network": ROUTER_NETWORK_QOS},
        "transport": {"auth": {"usrpwd": {"dictionary_file": dictionary_file}}} if dictionary_file else {},
        "access_control": {"enabled": True, "default_permission": "deny", "rules": rules,
                           "subjects": subjects, "policies": policies},
    }
    if tls:
        config["transport"]["link"] = {"tls": tls}
    return config


def tls_link(pki_dir: str, name: str) -> dict[str, Any]:
    """The ``transport/link/tls`` section for service ``name`` with mutual TLS (certs from deploy/certs.py)."""
    return {
        "root_ca_certificate": f"{pki_dir}/ca.pem",
        "enable_mtls": True,
        "listen_private_key": f"{pki_dir}/{name}.key",
        "listen_certificate": f"{pki_dir}/{name}.pem",
        "connect_private_key": f"{pki_dir}/{name}.key",
        "connect_certificate": f"{pki_dir}/{name}.pem",
    }


def write_mtls_bundle(corridor: Corridor, out_dir: Path, listen: list[str] | None = None,
                      pki_dir_in_services: str | None = None, hosts: list[str] | None = None) -> dict[str, Path]:
    """A private CA, a certificate per service, the mTLS router config with the ACL, and per-service
    client configs (``--zenoh-config``). ``pki_dir_in_services`` is where the files are mounted
    (e.g. in containers); by default the absolute output path."""
    from deploy.certs import make_pki

    users = [*service_publish_keys(corridor), *WATCHERS]
    out_dir.mkdir(parents=True, exist_ok=True)
    make_pki(["router", *users], out_dir, hosts=hosts)
    where = pki_dir_in_services or str(out_dir.resolve())
    cfg = router_config(corridor, None, listen or ["tls/0.0.0.0:7447"], tls=tls_link(where, "router"))
    router = out_dir / "router-mtls.json5"
    router.write_text(json.dumps(cfg, indent=2) + "\n", encoding="utf-8")
    written = {"router": router}
    for user in users:
        client = out_dir / f"{user}-mtls.json5"
        client.write_text(json.dumps({"transport": {"link": {"tls": tls_link(where, user)}}}, indent=2) + "\n",
                          encoding="utf-8")
        written[user] = client
    return written


def write_acl_bundle(corridor: Corridor, out_dir: Path, listen: list[str] | None = None,
                     dictionary_path_in_router: str | None = None) -> dict[str, Path]:
    """Router config, password dictionary (mode 0600) and a credentials file per service."""
    out_dir.mkdir(parents=True, exist_ok=True)
    users = {u: secrets.token_urlsafe(18) for u in [*service_publish_keys(corridor), *WATCHERS]}
    dictionary = out_dir / "users.txt"
    dictionary.write_text("".join(f"{u}:{p}\n" for u, p in users.items()), encoding="utf-8")
    dictionary.chmod(0o600)
    cfg = router_config(corridor, dictionary_path_in_router or str(dictionary.resolve()), listen)
    router = out_dir / "router-acl.json5"
    router.write_text(json.dumps(cfg, indent=2) + "\n", encoding="utf-8")
    written = {"router": router, "users": dictionary}
    for user, password in users.items():
        cred = out_dir / f"{user}.json5"
        cred.write_text(json.dumps({"transport": {"auth": {"usrpwd": {"user": user, "password": password}}}},
                                   indent=2) + "\n", encoding="utf-8")
        cred.chmod(0o600)
        written[user] = cred
    return written
