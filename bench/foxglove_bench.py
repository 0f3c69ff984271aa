"""The cost of the robotics tools' view of the corridor: `iea foxglove` live during the demo, and recordings.

Runs `iea demo` (every service a process over Zenoh on loopback, the project's detector, signed, recording
to MCAP) under a corridor id of its own, with `iea foxglove` (a process of its own) joined to it and
Foxglove's own WebSocket client (@foxglove/ws-protocol, Node, tests/node) subscribed to every channel the
bridge advertises, as a Foxglove window showing every panel would be. Measured:

- ``bridge_cpu_percent``: the bridge process's CPU time (user + system, /proc/PID/stat) over the demo's
  wall time, in percent of one core; ``bridge_rss_mb`` its resident memory at the end;
- ``bridge_msgs_per_s`` / ``bridge_mb_per_s``: messages and bytes the client received per second over
  the demo (every key's JSON view, the cameras and the derived scene, map and log);
- ``client_ok``: every message the client got parsed as JSON and validated against its channel's schema;
- ``recording_mb_per_min``: the demo's recording (``run.mcap``, zstd chunks as `iea record` writes them)
  per minute of recording, and ``recording_mb_per_min_no_camera`` the same recording rewritten without
  the camera channels (``iea/<c>/rsu/<rsu>/camera/jpeg``); ``camera_share`` what the frames take.

    python bench/foxglove_bench.py [--quick] [--json]

With ``--json`` the last line of output is one JSON object holding the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.proc_stats import cpu_s, rss_mb  # noqa: E402
from deploy.procs import stop_process_group  # noqa: E402
from deploy.up import free_port  # noqa: E402

NODE_DIR = ROOT / "tests" / "node"




def without_topics(src: Path, dst: Path, drop: str) -> None:
    """Copy an MCAP recording leaving out the channels whose topic ends with ``drop`` (same writer settings
    as ``deploy.record``: zstd chunks)."""
    from mcap.reader import make_reader
    from mcap.writer import Writer

    with open(src, "rb") as f, open(dst, "wb") as g:
        reader = make_reader(f)
        header = reader.get_header()
        w = Writer(g)
        w.start(profile=header.profile, library=header.library)
        schemas: dict[int, int] = {}
        channels: dict[int, int] = {}
        for schema, channel, msg in reader.iter_messages(log_time_order=True):
            if channel.topic.endswith(drop):
                continue
            if channel.id not in channels:
                if schema is not None and schema.id not in schemas:
                    schemas[schema.id] = w.register_schema(schema.name, schema.encoding, schema.data)
                channels[channel.id] = w.register_channel(channel.topic, channel.message_encoding,
                                                          schemas.get(schema.id, 0) if schema else 0,
                                                          dict(channel.metadata))
            w.add_message(channels[channel.id], log_time=msg.log_time, data=msg.data,
                          publish_time=msg.publish_time, sequence=msg.sequence)
        w.finish()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a 12 s demo instead of 30 s")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--keep", default=None, help="copy the demo's recording here (e.g. for a screenshot)")
    args = ap.parse_args(argv)
    node = shutil.which("node")
    if node is None or not (NODE_DIR / "node_modules" / "@foxglove" / "ws-protocol").is_dir():
        print("foxglove_bench: needs Node.js and `npm ci` in tests/node", file=sys.stderr)
        return 2
    from deploy.demo import run_demo
    from deploy.record import check_recording

    duration_s = 12.0 if args.quick else 30.0
    cid = f"fox-{uuid.uuid4().hex[:6]}"
    port = free_port()
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    tmp = Path(tempfile.mkdtemp(prefix="foxglove_bench-"))
    bridge = subprocess.Popen([sys.executable, "-m", "deploy", "foxglove", "--port", str(port), "--corridor-id", cid],
                              stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env, cwd=ROOT,
                              start_new_session=True)
    client = None
    result: dict = {}
    try:
        print(bridge.stdout.readline().strip(), flush=True)
        client = subprocess.Popen([node, "ws_client.mjs", f"ws://127.0.0.1:{port}", str(duration_s + 120), "--stay",
                                   "^/scene/objects$", "^/map/", "/ev$", "^/log$", "camera/jpeg$", "."],
                                  cwd=NODE_DIR, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        time.sleep(2.0)  # the client connects and subscribes
        demo = threading.Thread(target=lambda: result.update(
            run_demo(duration_s=duration_s, corridor_id=cid, quiet=True, run_root=tmp / "runs")), daemon=True)
        cpu0, wall0 = cpu_s(bridge.pid), time.monotonic()
        demo.start()
        print(f"[foxglove_bench] demo of {duration_s:.0f} s on corridor {cid}, bridge ws://127.0.0.1:{port}",
              flush=True)
        demo.join()
        wall = time.monotonic() - wall0
        cpu = cpu_s(bridge.pid) - cpu0
        mem = rss_mb(bridge.pid)
        client.send_signal(signal.SIGTERM)
        out, err = client.communicate(timeout=30)
        lines = [ln for ln in out.splitlines() if ln.startswith("{")]
        seen = json.loads(lines[-1]) if lines else {"problems": [err[-500:]], "messages": 0, "bytes": 0}
        run = Path(result["run_dir"]) / "run.mcap"
        info = check_recording(run)
        minutes = info["duration_s"] / 60.0
        no_cam = tmp / "no_camera.mcap"
        without_topics(run, no_cam, "/camera/jpeg")
        size, size_no_cam = run.stat().st_size, no_cam.stat().st_size
        if args.keep:
            shutil.copy(run, args.keep)
    finally:
        for p in (client,):
            if p is not None and p.poll() is None:
                p.kill()
        stop_process_group(bridge, signal.SIGTERM)
        shutil.rmtree(tmp, ignore_errors=True)
    figures = {
        "demo_s": duration_s, "wall_s": round(wall, 1),
        "bridge_cpu_percent": round(100.0 * cpu / wall, 1), "bridge_rss_mb": round(mem, 1),
        "bridge_msgs_per_s": round(seen["messages"] / wall, 1),
        "bridge_mb_per_s": round(seen["bytes"] / wall / 1e6, 3),
        "client_topics": len(seen.get("perTopic", {})), "client_ok": not seen["problems"],
        "client_problems": seen["problems"][:3],
        "recording_s": info["duration_s"], "recording_messages": info["messages"],
        "recording_mb_per_min": round(size / 1e6 / minutes, 2),
        "recording_mb_per_min_no_camera": round(size_no_cam / 1e6 / minutes, 2),
        "camera_share": round(1.0 - size_no_cam / size, 3),
        "demo_commands": len(result.get("commands", [])), "host_cpus": os.cpu_count(),
    }
    print(f"[foxglove_bench] iea foxglove: {figures['bridge_cpu_percent']} % of a core, {figures['bridge_rss_mb']} MB, "
          f"{figures['bridge_msgs_per_s']} msg/s ({figures['bridge_mb_per_s']} MB/s) to one client; recording "
          f"{figures['recording_mb_per_min']} MB/min ({figures['recording_mb_per_min_no_camera']} without cameras)")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
