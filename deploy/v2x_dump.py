"""`iea v2x dump`: what is said in standard V2X on a corridor, decoded for an operator.

    iea v2x dump [--corridor-id ID] [--duration-s S]   every message on iea/<corridor>/v2x/** as it arrives
    iea v2x dump --hex FILE                            one message held in FILE as hex (spaces, newlines allowed)

Each message is printed as one JSON line: its key (live), kind (CAM, DENM, CPM), header, and the decoded value
(open types decoded, BIT STRINGs as '0'/'1', bytes as hex); a V2X envelope (a signed CAM, a relay) is opened and
its signer shown with the CAM inside (not verified here: the DDM verifies). ``--hex`` exits 0 when the file
decodes and 2, saying why, when it does not.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from protocol.v2x.codec import V2xError, decode, to_plain
from protocol.v2x.secure import open_envelope


def describe(payload: bytes) -> dict[str, Any]:
    """A message (UPER, or a V2X envelope around one) as JSON-able data; raises ``V2xError`` when it is neither."""
    if payload[:1] and payload[0] & 0xF0 == 0x80:  # a msgpack map: an envelope
        env = open_envelope(payload)
        out: dict[str, Any] = {"envelope": {"signer": env.key_id, "not_before": env.not_before,
                                            "not_after": env.not_after}}
        if env.rsu_id is not None:
            out["envelope"].update(rsu_id=env.rsu_id, heard_on=env.heard_on, rx_time_s=env.rx_time_s)
        out["inner"] = describe(env.payload)
        return out
    msg = decode(payload)
    h = msg.header
    return {"kind": msg.kind, "protocolVersion": h.protocol_version, "stationId": h.station_id,
            "value": to_plain(msg.value)}


def read_hex(path: Path) -> bytes:
    text = path.read_text(encoding="utf-8", errors="strict")
    digits = "".join(text.split())
    if digits.lower().startswith("0x"):
        digits = digits[2:]
    try:
        return bytes.fromhex(digits)
    except ValueError as e:
        raise V2xError(f"{path}: not hexadecimal ({e})") from None


def dump_hex(path: Path, say: Callable[[str], None] = print) -> int:
    try:
        data = read_hex(path)
        say(json.dumps(describe(data)))
    except (OSError, UnicodeDecodeError) as e:
        print(f"iea v2x dump: cannot read {path}: {e}", file=sys.stderr)
        return 2
    except V2xError as e:
        print(f"iea v2x dump: {path}: {e}", file=sys.stderr)
        return 2
    return 0


def dump_live(corridor_id: str, settings: Any, duration_s: float | None, say: Callable[[str], None] = print) -> int:
    from protocol.v2x.keys import v2x_expr
    from protocol.zenoh_transport import ZenohTransport

    lock = threading.Lock()

    def on_bytes(key: str, payload: bytes) -> None:
        try:
            line = json.dumps({"key": key, **describe(payload)})
        except V2xError as e:
            line = json.dumps({"key": key, "error": str(e), "bytes": len(payload)})
        with lock:
            say(line)

    with ZenohTransport(settings) as zt:
        sub = zt.subscribe_bytes(v2x_expr(corridor_id), on_bytes)
        threading.Event().wait(duration_s)
        sub.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    ap = argparse.ArgumentParser(prog="iea v2x", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="action", required=True)
    d = sub.add_parser("dump", help="decode and print the corridor's V2X messages, or one message from a hex file")
    d.add_argument("--hex", type=Path, default=None, help="a file holding one message as hex")
    d.add_argument("--corridor", default=None, help="corridor file (its id names the keys; default rellis)")
    d.add_argument("--corridor-id", default=None)
    d.add_argument("--duration-s", type=float, default=None, help="stop after this long (default: Ctrl-C)")
    from protocol.zenoh_transport import ZenohSettings

    ZenohSettings.add_arguments(d)
    args = ap.parse_args(argv)
    if args.hex is not None:
        return dump_hex(args.hex)
    from protocol.corridor import CorridorError, load_corridor
    from protocol.runtime import stop_on_ctrl_c

    stop_on_ctrl_c()
    try:
        cid = args.corridor_id or load_corridor(args.corridor).corridor_id
        settings = ZenohSettings.from_args(args)
    except (CorridorError, ValueError) as exc:
        print(f"iea v2x dump: {exc}", file=sys.stderr)
        return 2
    return dump_live(cid, settings, args.duration_s)


if __name__ == "__main__":
    raise SystemExit(main())
