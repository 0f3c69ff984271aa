"""The cost of `iea view` during the demo: its CPU, and the page's update rate in a real browser.

Runs `iea demo` (every service a process over Zenoh on loopback, the project's detector, signed) under a
corridor id of its own, with `iea view` (a process of its own) subscribed to that corridor and Debian's
chromium, headless, showing the page (live, server-sent events). Measured:

- ``view_cpu_percent``: the view process's CPU time (user + system, /proc/PID/stat) over the demo's wall
  time, in percent of one core; ``view_rss_mb`` its resident memory at the end;
- ``page_update_hz``: the updates per second the page itself counts (pictures received and drawn over its
  last 2 s, reported by the page to ``/api/seen`` once a second), median and minimum over the demo;
- ``page_saw_ev`` / ``page_saw_av`` / ``page_saw_alert``: whether the page drew the EV and the AV and
  showed the EV alert at some point.

``--screenshot FILE.jpg`` also saves the page (1400x820, JPEG) while it shows the EV alert, drawn by a second
headless chromium (polling mode: no open stream, so it can finish); taken again while the live page shows
the alert until the screenshot's own page reports that it showed it.

    python bench/view_bench.py [--quick] [--json] [--screenshot docs/view.jpg]

With ``--json`` the last line of output is one JSON object holding the figures.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import signal
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import urllib.request
import uuid
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from bench.proc_stats import cpu_s, rss_mb  # noqa: E402
from deploy.procs import stop_process_group  # noqa: E402
from deploy.up import free_port  # noqa: E402


def get_json(url: str) -> dict:
    with urllib.request.urlopen(url, timeout=2.0) as r:
        return json.loads(r.read())


def screenshot(browser: str, url: str, out: Path, profile: Path) -> None:
    png = out.with_suffix(".png")
    subprocess.run([browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
                    f"--user-data-dir={profile}", "--window-size=1400,820", "--virtual-time-budget=1500",
                    f"--screenshot={png}", url + "?poll"], capture_output=True, timeout=60)
    if out.suffix.lower() in (".jpg", ".jpeg"):
        import cv2

        cv2.imwrite(str(out), cv2.imread(str(png)), [cv2.IMWRITE_JPEG_QUALITY, 80])
        png.unlink()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="a 12 s demo instead of 30 s")
    ap.add_argument("--json", action="store_true", help="end with one JSON line of the figures")
    ap.add_argument("--screenshot", default=None, help="save the page showing the EV alert here (.jpg or .png)")
    ap.add_argument("--rate-hz", type=float, default=15.0, help="the view's update rate (default 15, as iea view)")
    args = ap.parse_args(argv)
    browser = shutil.which("chromium") or shutil.which("chromium-browser")
    if browser is None:
        print("view_bench: Debian's chromium is needed (apt-get install chromium)", file=sys.stderr)
        return 2
    from deploy.demo import run_demo

    duration_s = 12.0 if args.quick else 30.0
    cid = f"view-{uuid.uuid4().hex[:6]}"
    port = free_port()
    url = f"http://127.0.0.1:{port}/"
    env = dict(os.environ, PYTHONPATH=str(ROOT), PYTHONUNBUFFERED="1")
    tmp = Path(tempfile.mkdtemp(prefix="view_bench-"))
    view = subprocess.Popen([sys.executable, "-m", "deploy", "view", "--port", str(port), "--corridor-id", cid,
                             "--rate-hz", str(args.rate_hz)], stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                            text=True, env=env, cwd=ROOT, start_new_session=True)
    page = None
    rates: list[float] = []
    saw = {"ev": False, "av": False, "alert": False}
    shot_taken = False
    try:
        print(view.stdout.readline().strip(), flush=True)
        page = subprocess.Popen([browser, "--headless=new", "--no-sandbox", "--disable-gpu", "--no-first-run",
                                 f"--user-data-dir={tmp / 'page'}", "--window-size=1400,820", url],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)
        result: dict = {}
        demo = threading.Thread(target=lambda: result.update(
            run_demo(duration_s=duration_s, corridor_id=cid, quiet=True, run_root=tmp / "runs")), daemon=True)
        cpu0, wall0 = cpu_s(view.pid), time.monotonic()
        demo.start()
        print(f"[view_bench] demo of {duration_s:.0f} s on corridor {cid}, view {url}", flush=True)
        while demo.is_alive():
            demo.join(1.0)
            try:
                seen = get_json(url + "api/seen")
            except OSError:
                continue
            if seen.get("received", 0) > time.time() - 2.0 and seen.get("updates", 0) > 20:
                rates.append(float(seen.get("rate_hz", 0.0)))
            saw["ev"] |= bool(seen.get("ev_drawn"))
            saw["av"] |= bool(seen.get("av_drawn"))
            saw["alert"] |= bool(seen.get("alert_text"))
            if args.screenshot and seen.get("alert_text") and seen.get("ev_drawn") and not shot_taken:
                t_shot = time.time()
                screenshot(browser, url, Path(args.screenshot), tmp / "shot")
                shot = get_json(url + "api/seen?mode=poll")
                shot_taken = shot.get("received", 0) > t_shot and bool(shot.get("alert_text"))
                print(f"[view_bench] screenshot {args.screenshot}: "
                      f"{'shows the alert' if shot_taken else 'missed the alert, again'}", flush=True)
            print(f"  page {rates[-1] if rates else 0:.1f} updates/s  ev={saw['ev']} av={saw['av']} "
                  f"alert={saw['alert']}", flush=True)
        wall = time.monotonic() - wall0
        cpu = cpu_s(view.pid) - cpu0
        mem = rss_mb(view.pid)
    finally:
        for p in (page, view):
            if p is not None:
                stop_process_group(p, signal.SIGTERM)
        shutil.rmtree(tmp, ignore_errors=True)
    figures = {
        "demo_s": duration_s, "wall_s": round(wall, 1),
        "view_cpu_percent": round(100.0 * cpu / wall, 1), "view_rss_mb": round(mem, 1),
        "page_update_hz": round(statistics.median(rates), 1) if rates else None,
        "page_update_hz_min": round(min(rates), 1) if rates else None, "page_samples": len(rates),
        "view_rate_hz": args.rate_hz,
        "page_saw_ev": saw["ev"], "page_saw_av": saw["av"], "page_saw_alert": saw["alert"],
        "demo_commands": len(result.get("commands", [])), "host_cpus": os.cpu_count(),
    }
    print(f"[view_bench] iea view: {figures['view_cpu_percent']} % of a core, {figures['view_rss_mb']} MB; "
          f"page {figures['page_update_hz']} updates/s (min {figures['page_update_hz_min']})")
    if args.json:
        print(json.dumps(figures))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
