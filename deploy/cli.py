"""`iea`: the umbrella command. Each service also has its own command (iea-rsu, iea-ddm, ...).

    iea schema [--check]        write (or check) the message JSON Schemas in protocol/schema/
    iea router ...              start a Zenoh router (same as iea-router)
    iea corridor [FILE]         validate a corridor file and print a summary
    iea calibrate RSU ...       commission a camera: its pose from surveyed points, error table, check image
    iea keys new KEY_ID ...     create an Ed25519 signing key and print its trust-list entry
    iea rsu|ddm|vehicle|sim ... run a service (same as iea-rsu, iea-ddm, iea-vehicle, iea-sim)
    iea deploy compose|acl|keys generate docker-compose.yml / router ACL and credentials / signing keys
    iea health ROLE [ID]        wait for a service's Health (the containers' health check)
    iea status [--corridor-id]  every service of a running corridor as one table (tokens, health, state)
    iea demo                    run the main scenario end to end (what `make demo` runs)
    iea scenario run NAME       run any scenario end to end (--inprocess --fast: lockstep, faster than real time)
    iea up                      the compose topology as local processes around one router
    iea record --out run.mcap   every key of a running corridor into an MCAP file
    iea replay run.mcap         republish a recording (--speed X, --keys EXPR)
    iea view [--port 8080]      the corridor live in a browser (plan, health, timeline)
    iea foxglove [--port 8765]  the corridor live in Foxglove / Lichtblick (Foxglove WebSocket protocol)
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable

SERVICES = {
    "rsu": ("rsu.cli", "roadside unit: frames -> detections -> tracks -> ObjectList / EvAlert"),
    "ddm": ("ddm.cli", "driving-decision service: corridor picture -> path-switch commands"),
    "vehicle": ("vehicle.cli", "autonomous vehicle: command handling, lateral/longitudinal control"),
    "sim": ("sim.cli", "corridor simulator: world, traffic, EV, camera renders, dataset export"),
}


def _run_service(name: str, argv: list[str]) -> int:
    module_name, _ = SERVICES[name]
    try:
        module = importlib.import_module(module_name)
    except ModuleNotFoundError as exc:
        if exc.name and (exc.name == module_name or module_name.startswith(exc.name + ".")):
            print(f"error: the {name} service is not part of this build ({module_name} is missing)", file=sys.stderr)
            return 2
        raise
    return int(module.main(argv) or 0)


def _schema(argv: list[str]) -> int:
    from protocol.schema_export import SCHEMA_DIR, stale_schemas, write_schemas

    ap = argparse.ArgumentParser(prog="iea schema", description="Write the JSON Schema (draft 2020-12) of the "
                                 f"wire payload of every message kind to {SCHEMA_DIR} (or check that the committed "
                                 "files match the code).")
    ap.add_argument("--check", action="store_true",
                    help="exit 1, naming each stale file, if a committed schema differs from the message models")
    args = ap.parse_args(argv)
    if args.check:
        stale = stale_schemas()
        if stale:
            print(f"error: stale schema(s) in {SCHEMA_DIR}: {'; '.join(stale)}. Run `iea schema` (or `make schema`) "
                  "and commit protocol/schema/", file=sys.stderr)
            return 1
        print(f"schemas in {SCHEMA_DIR} match the message models")
        return 0
    for path in write_schemas():
        print(f"wrote {path}")
    return 0


def _corridor(argv: list[str]) -> int:
    from protocol.corridor import DEFAULT_CORRIDOR, CorridorError, load_corridor

    ap = argparse.ArgumentParser(prog="iea corridor", description="Validate a corridor TOML file and summarise it.")
    ap.add_argument("file", nargs="?", default=str(DEFAULT_CORRIDOR), help=f"corridor file (default {DEFAULT_CORRIDOR})")
    args = ap.parse_args(argv)
    try:
        c = load_corridor(args.file)
    except CorridorError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    road = c.road
    print(f"corridor {c.corridor_id!r} ({c.name}) origin {c.origin_lat_deg:.6f}, {c.origin_lon_deg:.6f}")
    print(f"road: {road.length_m:.0f} m in {len(road.segments)} segment(s), {road.lanes} lane(s) of "
          f"{road.lane_width_m} m, shoulder {road.shoulder_width_m} m, limit {road.speed_limit_mps} m/s")
    for r in c.rsus:
        cam = r.camera
        print(f"  {r.rsu_id}: at ({cam.x_m:.1f}, {cam.y_m:.1f}) h={cam.height_m} m, {cam.width_px}x{cam.height_px} "
              f"@ {cam.fps:g} fps, {len(r.calibration)} calibration pairs")
    for v in c.vehicles:
        print(f"  vehicle {v.vehicle_id}: lane {v.start_lane} from s={v.start_s_m} m at {v.cruise_speed_mps} m/s")
    return 0


def _keys(argv: list[str]) -> int:
    from deploy.signing import write_new_key

    ap = argparse.ArgumentParser(prog="iea keys", description="Manage the Ed25519 keys that sign commands and alerts.")
    sub = ap.add_subparsers(dest="action", required=True)
    new = sub.add_parser("new", help="create a key pair: KEY_ID.pem (private, mode 0600) and print its [[trust]] entry")
    new.add_argument("key_id", help="key id, e.g. ddm-1 or rsu1-key")
    new.add_argument("--role", choices=["ddm", "rsu"], required=True, help="what the key may sign")
    new.add_argument("--rsu-id", help="for an RSU key: the RSU it speaks for")
    new.add_argument("--vehicles", default="*", help="for a DDM key: comma-separated vehicle ids it may command")
    new.add_argument("--out", default=".", help="directory for the private key (default: current)")
    args = ap.parse_args(argv)
    if args.role == "rsu" and not args.rsu_id:
        ap.error("--rsu-id is required for an RSU key")
    try:
        path, entry = write_new_key(args.out, args.key_id, args.role, args.rsu_id, args.vehicles)
    except FileExistsError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    print(f"# private key written to {path}; add this to the corridor file:")
    print(entry)
    return 0


def _deploy(argv: list[str]) -> int:
    from pathlib import Path

    from protocol.corridor import DEFAULT_CORRIDOR, CorridorError, load_corridor

    ap = argparse.ArgumentParser(prog="iea deploy", description="Generate deployment files for a corridor.")
    sub = ap.add_subparsers(dest="action", required=True)
    acl = sub.add_parser("acl", help="Zenoh router config with per-service ACL, password dictionary and credentials")
    acl.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (default: rellis)")
    acl.add_argument("--out", required=True, help="output directory (keep it out of git: it holds passwords)")
    acl.add_argument("--listen", action="append", default=None, help="router endpoint(s) (default tcp/0.0.0.0:7447)")
    acl.add_argument("--dictionary-path", default=None,
                     help="path of users.txt as the router will see it (e.g. inside a container)")
    acl.add_argument("--mtls", action="store_true",
                     help="mutual TLS instead of passwords: a private CA and a certificate per service")
    acl.add_argument("--pki-path", default=None, help="with --mtls: where services will find the files")
    mesh = sub.add_parser("mesh", help="a router per corridor segment linked to a core router, ACL on each")
    mesh.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (default: rellis)")
    mesh.add_argument("--out", required=True, help="output directory (keep it out of git: it holds passwords)")
    mesh.add_argument("--core-listen", action="append", default=None, help="core router endpoint (default tcp/0.0.0.0:7447)")
    mesh.add_argument("--core-connect", action="append", default=None,
                      help="where the segment routers reach the core (default: --core-listen on 127.0.0.1)")
    mesh.add_argument("--segment-listen", action="append", required=True,
                      help="one per segment router (repeat; the RSUs are split among them in corridor order)")
    mesh.add_argument("--mtls", action="store_true", help="mutual TLS on every link (tls/ endpoints) instead of passwords")
    mesh.add_argument("--pki-path", default=None, help="with --mtls: where routers and services will find the files")
    mesh.add_argument("--no-pki", action="store_true", help="with --mtls: write the configs only, no keys")
    keys = sub.add_parser("keys", help="a signing key per service (DDM, each RSU) and the corridor file trusting them")
    keys.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (default: rellis)")
    keys.add_argument("--out", required=True, help="output directory (keep it out of git: it holds private keys)")
    keys.add_argument("--force", action="store_true", help="replace an existing bundle (redeploy every service)")
    comp = sub.add_parser("compose", help="docker-compose file: router, sim, RSUs, DDM and vehicles of a corridor")
    comp.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (default: rellis)")
    comp.add_argument("--rsus", type=int, default=None, help="number of RSUs to deploy (default: all of the corridor)")
    comp.add_argument("--scenario", default="rellis_ev_yield", help="scenario the simulator runs")
    comp.add_argument("--no-acl", action="store_true", help="open router, no credentials (closed lab network only)")
    comp.add_argument("--acl-dir", default="./secrets/acl", help="host folder of `iea deploy acl --out` (default ./secrets/acl)")
    comp.add_argument("--unsigned", action="store_true",
                      help="no signatures: vehicles accept any command the router lets through (default: signed, "
                           "with the `iea deploy keys --out secrets/keys` bundle)")
    comp.add_argument("--keys-dir", default="./secrets/keys", help="host folder of `iea deploy keys --out` "
                      "(default ./secrets/keys)")
    comp.add_argument("--zenoh-image", default=None, help="router image (default: eclipse/zenoh pinned to the binding)")
    comp.add_argument("--out", default="-", help="output file (default: standard output)")
    args = ap.parse_args(argv)
    try:
        corridor = load_corridor(args.corridor)
    except CorridorError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    if args.action == "compose":
        return _write_compose(args, corridor)
    if args.action == "keys":
        from datetime import date

        from deploy.signing import write_key_bundle

        try:
            target, paths = write_key_bundle(args.corridor, Path(args.out), key_id_suffix=date.today().strftime("%Y%m%d"),
                                             overwrite=args.force)
        except (FileExistsError, ValueError) as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        for name, path in paths.items():
            print(f"{name:<10} {path}")
        print(f"corridor   {target}  (trusts these keys: run every service on it; `iea deploy compose` mounts it)")
        return 0
    if args.action == "mesh":
        from deploy.mesh import write_mesh_bundle

        try:
            written = write_mesh_bundle(corridor, Path(args.out), args.core_listen or ["tcp/0.0.0.0:7447"],
                                        args.segment_listen, args.core_connect, mtls=args.mtls,
                                        pki_dir_in_services=args.pki_path, write_pki=not args.no_pki)
        except ValueError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
        for name, path in written.items():
            print(f"{name:<10} {path}")
        print(f"start each router with `iea router --config ROUTER`; {written['mesh']} says which router each "
              "service joins (`--connect` it with `--zenoh-config <its credentials file>`)")
        return 0
    from deploy.acl import write_acl_bundle, write_mtls_bundle

    if args.mtls:
        written = write_mtls_bundle(corridor, Path(args.out), args.listen, args.pki_path)
    else:
        written = write_acl_bundle(corridor, Path(args.out), args.listen, args.dictionary_path)
    for name, path in written.items():
        print(f"{name:<10} {path}")
    print("start the router with `iea router --config ROUTER` and each service with "
          "`--connect tcp/HOST:7447 --zenoh-config <its credentials file>`")
    return 0


def _write_compose(args: argparse.Namespace, corridor) -> int:
    from pathlib import Path

    from deploy.compose import HEADER, ZENOH_IMAGE, compose_for_scenario, compose_yaml
    from sim.scenario import ScenarioError

    try:
        doc = compose_for_scenario(corridor, args.corridor, args.scenario, rsus=args.rsus, acl=not args.no_acl,
                                   acl_dir=args.acl_dir, zenoh_image=args.zenoh_image or ZENOH_IMAGE,
                                   signed=not args.unsigned, keys_dir=args.keys_dir)
    except (ValueError, ScenarioError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    text = compose_yaml(doc, HEADER)
    if args.out == "-":
        sys.stdout.write(text)
    else:
        Path(args.out).write_text(text, encoding="utf-8")
        print(f"wrote {args.out} ({len(doc['services'])} services)")
    return 0


def _health(argv: list[str]) -> int:
    from deploy.status import check_health, health_key
    from protocol.corridor import DEFAULT_CORRIDOR, CorridorError, load_corridor
    from protocol.zenoh_transport import ZenohSettings

    ap = argparse.ArgumentParser(prog="iea health", description="Wait for a service's Health message and report it "
                                 "(exit 0: ok or degraded; 1: error status or none within the timeout). Used as the "
                                 "docker-compose health check.")
    ap.add_argument("role", choices=["rsu", "ddm", "vehicle", "sim"])
    ap.add_argument("node", nargs="?", default=None, help="RSU or vehicle id (rsu, vehicle)")
    ap.add_argument("--corridor", default=str(DEFAULT_CORRIDOR), help="corridor file (its id names the keys)")
    ap.add_argument("--corridor-id", default=None, help="override the corridor id")
    ap.add_argument("--timeout-s", type=float, default=5.0, help="how long to wait (Health comes at 1 Hz)")
    ZenohSettings.add_arguments(ap)
    args = ap.parse_args(argv)
    if args.role in ("rsu", "vehicle") and not args.node:
        ap.error(f"{args.role} needs its id, e.g. `iea health {args.role} {'rsu1' if args.role == 'rsu' else 'av1'}`")
    try:
        key = health_key(args.corridor_id or load_corridor(args.corridor).corridor_id, args.role, args.node)
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    return check_health(settings, key, args.timeout_s)


def _delegate(module_name: str, function: str = "main") -> Callable[[list[str]], int]:
    """A command run by another module's ``function(argv)`` (deployment commands in deploy/, experiments in
    scenario/), imported only when the command runs."""
    def run(argv: list[str]) -> int:
        return int(getattr(importlib.import_module(module_name), function)(argv) or 0)
    return run


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    commands = {
        "schema": ("write or check the message JSON Schemas", _schema),
        "router": ("start a Zenoh router (iea-router)", None),
        "corridor": ("validate and summarise a corridor file", _corridor),
        "calibrate": ("commission a camera from surveyed points (iea calibrate RSU --image F --points P.csv)",
                      _delegate("deploy.commission")),
        "keys": ("create signing keys (iea keys new KEY_ID --role ddm|rsu)", _keys),
        "deploy": ("generate deployment files (iea deploy acl|compose ...)", _deploy),
        "demo": ("run the main scenario end to end (make demo)", _delegate("deploy.demo")),
        "scenario": ("list scenarios, or run one end to end (processes, or --inprocess lockstep)",
                     _delegate("deploy.scenario_cli")),
        "health": ("check a running service's Health (docker-compose health check)", _health),
        "status": ("every service of a running corridor as one table (iea status --corridor-id ID)",
                   _delegate("deploy.status")),
        "up": ("router + every service as local processes (no Docker)", _delegate("deploy.up")),
        "record": ("record every key of a corridor to MCAP (iea record --out run.mcap)",
                   _delegate("deploy.record")),
        "replay": ("republish an MCAP recording (iea replay run.mcap [--speed X] [--keys EXPR])",
                   _delegate("deploy.replay")),
        "view": ("the corridor live in a browser (iea view --port 8080 --corridor-id ID)",
                 _delegate("deploy.view")),
        "foxglove": ("the corridor live in Foxglove / Lichtblick (iea foxglove --port 8765 --corridor-id ID)",
                     _delegate("deploy.foxglove_bridge")),
        "v2x": ("standard V2X (ETSI CAM / DENM / CPM): iea v2x dump [--hex FILE]", _delegate("deploy.v2x_dump")),
    }
    if not argv or argv[0] in ("-h", "--help"):
        lines = [__doc__.strip(), "", "commands:"]
        lines += [f"  {k:<10} {v[0]}" for k, v in commands.items()]
        lines += [f"  {k:<10} {v[1]}" for k, v in SERVICES.items()]
        lines += ["", "Run `iea COMMAND --help` for the options of a command."]
        print("\n".join(lines))
        return 0 if argv else 2
    cmd, rest = argv[0], argv[1:]
    if cmd in SERVICES:
        return _run_service(cmd, rest)
    if cmd == "router":
        from protocol.router import main as router_main

        return router_main(rest, prog="iea router")
    if cmd in commands:
        return commands[cmd][1](rest)
    print(f"error: unknown command {cmd!r}; run `iea --help`", file=sys.stderr)
    return 2


if __name__ == "__main__":
    raise SystemExit(main())
