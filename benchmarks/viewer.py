"""How fast does the live viewer deliver frames, and how long from a gaze message to a frame rendered with it?

Frames per second delivered to a WebSocket client on the same machine and the gaze-to-frame latency, for
`foveawarp view` started as its own process.

The client sends gaze messages (a Lissajous path, ``--gaze-hz`` per second, each with a sequence number) and
reads every frame the server sends (header parsed; the JPEG of the first and last frame decoded and its size
checked). Reported per resolution:

- ``fps_delivered``: frames received per second over the timed window (after ``--warmup-s``);
- ``frame_ms``: the delivered frame time, 1000 / ``fps_delivered`` (the interval between frames as the client
  receives them: render, copy, encode and send of one frame, as the server runs one frame at a time);
- ``latency_server_p50/p95_ms``: from a gaze message's arrival at the server to the first frame rendered with it
  leaving the server (the server measures it; ``GET /stats.json`` after a ``reset_stats`` message). Only gazes
  that a frame used count: a gaze replaced by a newer one before the next frame started is never rendered;
- ``latency_p95_frames``: that server p95 in units of ``frame_ms`` (target <= 2);
- ``latency_msg_p50/p95_ms`` and ``latency_msg_p95_frames``: every gaze message, from its arrival to the first
  frame rendered with it or a newer gaze leaving the server (the stricter reading: the wait of a gaze that arrives
  just after a frame started counts in full even when a newer gaze replaces it);
- ``latency_client_p50/p95_ms``: from the client sending a gaze to receiving the first frame rendered with it
  (includes the client's own receive path and the server's wait to read the message);
- ``render_ms`` / ``encode_ms``: the server's median render + copy and JPEG encode times per frame;
  ``encoder``: the JPEG encoder the server used.

Targets: >= 60 fps at 1280x720 on CUDA with p95 latency <= 2 frame times; >= 5 fps at 480x270 on the CPU.
Writes viewer-<tag>.json / .md.

    python benchmarks/viewer.py --device cuda:0                 # 1280x720 and 1920x1080
    python benchmarks/viewer.py --device cpu                    # 480x270
    python benchmarks/viewer.py --device cuda:0 --encoder pillow # the Pillow fallback
    python benchmarks/viewer.py --device cpu --screenshot docs/images/viewer.png   # the README's image (chromium)
"""

from __future__ import annotations

import asyncio
import io
import json
import math
import os
import re
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import numpy as np

sys.path.append(str(Path(__file__).resolve().parent.parent))

from benchmarks._common import REPO, base_parser, md_table, parse_sizes, progress, write_results  # noqa: E402

CANONICAL = "python benchmarks/viewer.py --device cuda:0 --out benchmarks/results --tag h200"

URL_RE = re.compile(r"open (http://\S+/)")


class ViewerProcess:
    """`python -m foveawarp.cli view ...` on a free loopback port; the URL is read from its first line."""

    def __init__(self, device, width, height, scene="cornell", timing="off", quality=80, encoder="auto",
                 timeout=300.0, cmd=None):
        if cmd is None:
            cmd = [sys.executable, "-m", "foveawarp.cli", "view", "--device", device, "--width", str(width),
                   "--height", str(height), "--scene", scene, "--port", "0", "--timing", timing,
                   "--quality", str(quality), "--encoder", encoder]
        env = {**os.environ, "PYTHONUNBUFFERED": "1"}
        self.proc = subprocess.Popen(cmd, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                                     env=env)
        self.lines = []
        self.url = None
        found = threading.Event()

        def reader():
            for line in self.proc.stdout:
                self.lines.append(line.rstrip())
                m = URL_RE.search(line)
                if m and self.url is None:
                    self.url = m.group(1)
                    found.set()
            found.set()

        threading.Thread(target=reader, daemon=True).start()
        if not found.wait(timeout) or self.url is None:
            self.close()
            raise RuntimeError("viewer did not start:\n" + "\n".join(self.lines[-30:]))
        self.port = int(self.url.rsplit(":", 1)[1].strip("/"))

    def stats(self) -> dict:
        with urllib.request.urlopen(self.url + "stats.json", timeout=30) as r:
            return json.loads(r.read())

    def close(self):
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(30)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(10)


async def measure(vp: ViewerProcess, width, height, seconds, warmup_s, gaze_hz, first_frame_timeout=600.0):
    from websockets.asyncio.client import connect

    sent = {}                       # seq -> send time
    frames = []                     # (recv time, header)
    round_trips = []                # (recv time, ms) for the first frame of each seq
    seen_seq = 0
    first_jpeg = last_jpeg = None
    stop = asyncio.Event()
    got_first = asyncio.Event()

    async with connect(f"ws://127.0.0.1:{vp.port}/ws", max_size=2**27, open_timeout=60, compression=None) as ws:
        async def sender():
            seq = 0
            period = 1.0 / gaze_hz
            t0 = time.perf_counter()
            nxt = t0
            while not stop.is_set():
                seq += 1
                t = time.perf_counter() - t0
                x = width * (0.5 + 0.35 * math.sin(2 * math.pi * 0.5 * t))
                y = height * (0.5 + 0.3 * math.sin(2 * math.pi * 0.7 * t + 0.4))
                sent[seq] = time.perf_counter()
                await ws.send(json.dumps({"type": "gaze", "x": x, "y": y, "seq": seq}))
                nxt += period
                await asyncio.sleep(max(nxt - time.perf_counter(), 0.0))

        async def receiver():
            nonlocal seen_seq, first_jpeg, last_jpeg
            async for m in ws:
                now = time.perf_counter()
                if isinstance(m, str):
                    continue
                n = int.from_bytes(m[:4], "little")
                h = json.loads(m[4:4 + n])
                frames.append((now, h))
                if first_jpeg is None:
                    first_jpeg = m[4 + n:]
                last_jpeg = m[4 + n:]
                s = h.get("seq")
                if s is not None and s > seen_seq:
                    seen_seq = s
                    if s in sent:
                        round_trips.append((now, (now - sent[s]) * 1e3))
                got_first.set()
                if stop.is_set():
                    return

        await ws.recv()  # state
        rt = asyncio.create_task(receiver())
        st = asyncio.create_task(sender())
        await asyncio.wait_for(got_first.wait(), first_frame_timeout)   # kernels compile on a first run
        await asyncio.sleep(warmup_s)
        await ws.send(json.dumps({"type": "reset_stats"}))
        t_start = time.perf_counter()
        await asyncio.sleep(seconds)
        t_end = time.perf_counter()
        server = await asyncio.get_running_loop().run_in_executor(None, vp.stats)
        stop.set()
        await st
        try:
            await asyncio.wait_for(rt, 10)
        except (asyncio.TimeoutError, Exception):
            rt.cancel()
    window = [(t, h) for t, h in frames if t_start <= t <= t_end]
    rts = np.asarray([ms for t, ms in round_trips if t_start <= t <= t_end])
    fps = len(window) / (t_end - t_start)
    from PIL import Image

    sizes = {Image.open(io.BytesIO(j)).size for j in (first_jpeg, last_jpeg) if j is not None}

    def med(k):
        v = [h["stats"][k] for _, h in window if k in h["stats"]]
        return float(np.median(v)) if v else None

    p50 = server.get("latency_ms_p50")
    p95 = server.get("latency_ms_p95")
    m95 = server.get("latency_msg_ms_p95")
    frame_ms = 1e3 / fps if fps > 0 else float("inf")
    return {
        "resolution": f"{width}x{height}",
        "seconds": round(t_end - t_start, 3),
        "frames": len(window),
        "fps_delivered": fps,
        "frame_ms": frame_ms,
        "server_fps": server.get("fps"),
        "latency_server_p50_ms": p50,
        "latency_server_p95_ms": p95,
        "latency_samples": server.get("latency_samples"),
        "latency_p95_frames": (p95 / frame_ms) if p95 is not None and fps > 0 else None,
        "latency_msg_p50_ms": server.get("latency_msg_ms_p50"),
        "latency_msg_p95_ms": m95,
        "latency_msg_p95_frames": (m95 / frame_ms) if m95 is not None and fps > 0 else None,
        "latency_client_p50_ms": float(np.percentile(rts, 50)) if rts.size else None,
        "latency_client_p95_ms": float(np.percentile(rts, 95)) if rts.size else None,
        "render_ms": med("ms_frame"),
        "encode_ms": med("ms_encode"),
        "sampling_rate": med("sampling_rate"),
        "jpeg_kb": float(np.mean([h["stats"]["jpeg_bytes"] for _, h in window]) / 1024) if window else None,
        "encoder": server.get("encoder"),
        "decoded_sizes_ok": sizes == {(width, height)},
        "gaze_hz": gaze_hz,
    }


def screenshot(path: Path, device: str, width: int, height: int) -> None:
    """Open the page in headless Chromium (Playwright, executable_path) and save a PNG of the viewer."""
    from playwright.sync_api import sync_playwright

    sys.path.insert(0, str(REPO / "tests"))
    from test_viewer_browser import CHROMIUM_ARGS, chromium_path

    exe = chromium_path()
    if exe is None:
        raise SystemExit("no chromium found (apt-get install chromium)")
    vp = ViewerProcess(device, width, height, timing="on")
    try:
        with sync_playwright() as pw:
            b = pw.chromium.launch(executable_path=exe, headless=True, args=CHROMIUM_ARGS)
            page = b.new_page(viewport={"width": 1040, "height": 780})
            page.goto(vp.url)
            page.wait_for_function("document.getElementById('conn').textContent === 'live'", timeout=120_000)
            page.check("input[data-overlay=rings]")
            box = page.locator("#view").bounding_box()
            page.mouse.move(box["x"] + 0.62 * box["width"], box["y"] + 0.45 * box["height"])
            time.sleep(8.0)   # frames follow, temporal history settles, stats fill in
            page.mouse.move(box["x"] + 0.63 * box["width"], box["y"] + 0.46 * box["height"])
            time.sleep(4.0)
            path.parent.mkdir(parents=True, exist_ok=True)
            page.screenshot(path=str(path))
            b.close()
    finally:
        vp.close()
    if path.stat().st_size > 300 * 1024:  # keep the repository light: 256-colour PNG
        from PIL import Image

        Image.open(path).convert("RGB").quantize(256).save(path, optimize=True)
    print(f"screenshot: {path} ({path.stat().st_size / 1024:.0f} KB)")


def main(argv=None):
    p = base_parser(__doc__, CANONICAL)
    p.add_argument("--sizes", default=None, help="WxH list, e.g. 1280x720,1920x1080 (default: those on CUDA, "
                                                  "480x270 on the CPU)")
    p.add_argument("--scene", default="cornell")
    p.add_argument("--seconds", type=float, default=None, help="timed window per size (default 10; quick 3)")
    p.add_argument("--warmup-s", type=float, default=None, help="untimed seconds after the first frame (default 3)")
    p.add_argument("--gaze-hz", type=float, default=250.0, help="gaze messages per second (an eye tracker's rate)")
    p.add_argument("--quality", type=int, default=80, help="JPEG quality (default 80)")
    p.add_argument("--encoder", default="auto", choices=("auto", "simplejpeg", "pillow"),
                   help="the server's JPEG encoder (default auto: simplejpeg when installed)")
    p.add_argument("--screenshot", default=None, help="instead of measuring, save the README's viewer image here")
    args = p.parse_args(argv)
    if (args.seconds is not None and args.seconds <= 0) or args.gaze_hz <= 0:
        p.error(f"--seconds and --gaze-hz must be > 0, got {args.seconds} and {args.gaze_hz}")
    import warp as wp

    from foveawarp._util import init_warp

    init_warp()
    device = args.device or ("cuda:0" if wp.is_cuda_available() else "cpu")
    cuda = wp.get_device(device).is_cuda
    if args.screenshot:
        screenshot(Path(args.screenshot), device, 480, 270)
        return 0
    if args.quick:
        sizes = [(96, 54)]
    elif args.sizes:
        sizes = parse_sizes(p, args.sizes)
    else:
        sizes = [(1280, 720), (1920, 1080)] if cuda else [(480, 270)]
    seconds = args.seconds or (3.0 if args.quick else 10.0)
    warmup_s = args.warmup_s if args.warmup_s is not None else (1.0 if args.quick else 3.0)
    rows = []
    for w, h in progress(sizes, "viewer"):
        vp = ViewerProcess(device, w, h, scene=args.scene, quality=args.quality, encoder=args.encoder)
        try:
            r = asyncio.run(measure(vp, w, h, seconds, warmup_s, args.gaze_hz))
        finally:
            vp.close()
        rows.append({"scene": args.scene, "width": w, "height": h, **r})
    targets = []
    for r in rows:
        if cuda and r["resolution"] == "1280x720":
            targets.append({"target": ">= 60 fps at 1280x720 (CUDA)", "value": r["fps_delivered"],
                            "met": r["fps_delivered"] >= 60.0})
            lp = r["latency_p95_frames"]
            targets.append({"target": "gaze-to-frame p95 <= 2 frame times at 1280x720", "value": lp,
                            "met": lp is not None and lp <= 2.0})
        if not cuda and r["resolution"] == "480x270":
            targets.append({"target": ">= 5 fps at 480x270 (CPU)", "value": r["fps_delivered"],
                            "met": r["fps_delivered"] >= 5.0})
    table = md_table(rows, COLS)
    if targets:
        table += "\n" + md_table(targets, ["target", "value", "met"])
    load = os.getloadavg() if hasattr(os, "getloadavg") else None
    write_results("viewer", device, rows, table, args.out, args.tag, extra={
        "targets": targets, "cpu_count": os.cpu_count(), "load_average": load, "quality": args.quality,
        "encoder": args.encoder, "seconds": seconds, "warmup_s": warmup_s, "gaze_hz": args.gaze_hz})
    print(table)
    return 0


COLS = ["resolution", "fps_delivered", "frame_ms", "latency_server_p50_ms", "latency_server_p95_ms",
        "latency_p95_frames", "latency_msg_p50_ms", "latency_msg_p95_ms", "latency_msg_p95_frames",
        "latency_client_p50_ms", "latency_client_p95_ms", "render_ms", "encode_ms",
        "sampling_rate", "jpeg_kb", "decoded_sizes_ok"]

if __name__ == "__main__":
    sys.exit(main())
