"""Signing keys of a corridor deployment (signed by default).

``iea deploy keys --out DIR`` writes one Ed25519 key per signing service (the DDM, each RSU) as
``DIR/<service>.pem`` (mode 0600) and ``DIR/corridor.toml``: the corridor file with a ``[[trust]]`` entry
per key (the DDM's may command every vehicle of the corridor; each RSU's speaks for that RSU only). Every
service runs on that corridor file: vehicles then accept only commands signed by the DDM's key, and the
DDM only EV/hazard alerts signed by an RSU's key (protocol/security.py). ``iea deploy compose`` mounts the
corridor file into every container and each key into its own service's container only; ``iea up`` and
``iea demo`` make throwaway keys in their run folder the same way. Running unsigned takes an explicit
``--unsigned``.

A bundle is never overwritten by accident: the deployed vehicles trust its public keys.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

CORRIDOR_FILE = "corridor.toml"


def signing_services(corridor: Any) -> list[tuple[str, str]]:
    """(service name, its trust-entry scope lines) of every service that signs: the DDM, then each RSU."""
    return [("ddm", 'role = "ddm"\nvehicles = ["*"]'),
            *[(r.rsu_id, f'role = "rsu"\nrsu_id = "{r.rsu_id}"') for r in corridor.rsus]]


def write_new_key(out_dir: str | Path, key_id: str, role: str, rsu_id: str | None = None,
                  vehicles: str = "*") -> tuple[Path, str]:
    """``iea keys new``: a key pair, its private key written to ``out_dir/KEY_ID.pem`` (mode 0600); returns that
    path and the key's ``[[trust]]`` entry (an RSU key speaks for ``rsu_id``; a DDM key may command ``vehicles``,
    comma-separated). Raises ``FileExistsError`` rather than overwrite a private key."""
    from protocol.security import new_key_pair

    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / f"{key_id}.pem"
    if path.exists():
        raise FileExistsError(f"{path} exists; refusing to overwrite a private key")
    pem, pub = new_key_pair()
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    with os.fdopen(fd, "wb") as f:
        f.write(pem)
    scope = (f'rsu_id = "{rsu_id}"' if role == "rsu" else
             "vehicles = [" + ", ".join(f'"{v.strip()}"' for v in vehicles.split(",")) + "]")
    return path, f'[[trust]]\nkey_id = "{key_id}"\nrole = "{role}"\npublic_key = "{pub}"\n{scope}'


def write_key_bundle(corridor_file: str | Path, out_dir: str | Path, *, key_id_suffix: str,
                     overwrite: bool = False, note: str = "iea deploy keys") -> tuple[Path, dict[str, Path]]:
    """Write a key per signing service and the trusting corridor file into ``out_dir``; returns (the corridor
    file, {service: key file}). Raises ``FileExistsError`` when a bundle is there and not ``overwrite``."""
    from protocol.corridor import load_corridor
    from protocol.security import new_key_pair

    corridor_file = Path(corridor_file)
    corridor = load_corridor(corridor_file)
    if corridor.trust:
        raise ValueError(f"{corridor_file} already has [[trust]] entries: use the key bundle written with it "
                         "(`--keys DIR`) or start from the corridor file without them")
    out = Path(out_dir)
    target = out / CORRIDOR_FILE
    if target.exists() and not overwrite:
        raise FileExistsError(f"{target} exists: the deployed services trust its keys; pass --force to replace "
                              "them (then redeploy every service)")
    out.mkdir(parents=True, exist_ok=True)
    entries, paths = [], {}
    for name, scope in signing_services(corridor):
        pem, public = new_key_pair()
        path = out / f"{name}.pem"
        fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
        with os.fdopen(fd, "wb") as f:
            f.write(pem)
        paths[name] = path
        entries.append(f'[[trust]]\nkey_id = "{name}-{key_id_suffix}"\n{scope}\npublic_key = "{public}"\n')
    target.write_text(corridor_file.read_text() + f"\n# signing keys ({note}): private keys beside this file\n"
                      + "\n".join(entries))
    load_corridor(target)  # the file we wrote must load
    return target, paths


def load_key_bundle(bundle_dir: str | Path, corridor: Any) -> tuple[Path, dict[str, Path]]:
    """(corridor file, {service: key file}) of a bundle written by ``write_key_bundle``, checked complete."""
    d = Path(bundle_dir)
    target = d / CORRIDOR_FILE
    missing = [str(p) for p in [target, *(d / f"{n}.pem" for n, _ in signing_services(corridor))] if not p.is_file()]
    if missing:
        raise FileNotFoundError(f"incomplete key bundle in {d}: missing {', '.join(missing)} "
                                "(write one with `iea deploy keys --out DIR`)")
    return target, {n: d / f"{n}.pem" for n, _ in signing_services(corridor)}


def key_args(paths: dict[str, Path]) -> dict[str, list[str]]:
    """Per service the arguments that make it sign (``corridor_services(keys=...)``)."""
    return {name: ["--key", str(path)] for name, path in paths.items()}
