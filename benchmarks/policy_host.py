"""Study (issue 14, session 35): the host time of the default policy's full-resolution frame against the reference's.

The default policy renders full resolution on every scene with default shading, with the reference's kernels, yet
its frames measured 1.00-1.035x the reference's time in ``frame.py``'s runs, most at 1080p on the cheapest scenes
(0.35 ms frames). ``frame.py`` synchronizes every frame, so the host's work per frame adds to it. Per scene and
size, three loops along the camera path, taking turns frame by frame: ``render_reference``, ``render`` with
``policy="full"`` and ``render`` with the default policy once it has chosen full resolution. Per frame: the host
time of the call (until it returns, the GPU's work queued) and the frame's time (until the GPU is done), medians
over ``--frames`` frames. ``--profile``: the calls' Python profile (cProfile, cumulative) for each loop.

    python benchmarks/policy_host.py --device cuda:0 [--specs cornell:1920x1080,eyechart:1920x1080] [--profile]
"""

from __future__ import annotations

import cProfile
import io
import pstats
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, git_commit, md_table, write_results  # noqa: E402
from benchmarks.frame import gaze_path  # noqa: E402

LOOPS = ("reference", "full", "auto")


def study(fw, scene, w, h, dev, frames: int, profile: bool) -> dict:
    loops = {"reference": fw.FrameLoop(scene, w, h, device=dev, timing=False, policy="full"),
             "full": fw.FrameLoop(scene, w, h, device=dev, timing=False, policy="full"),
             "auto": fw.FrameLoop(scene, w, h, device=dev, timing=False)}
    warm = loops["auto"].policy_measurement_frames() + 8

    def call(name, i):
        t = i / 30.0
        cam, gaze = scene.camera_at(t), gaze_path(i, frames, w, h)
        if name == "reference":
            return loops[name].render_reference(cam, time=t, gaze_px=gaze)
        return loops[name].render(cam, gaze_px=gaze, time=t)

    for name in LOOPS:
        for i in range(warm):
            call(name, i)
    wp.synchronize_device(dev)
    path = loops["auto"]._pol_choice
    host = {n: [] for n in LOOPS}
    total = {n: [] for n in LOOPS}
    order = np.random.default_rng(0)
    for i in range(warm, warm + frames):
        for j in order.permutation(len(LOOPS)):
            n = LOOPS[j]
            wp.synchronize_device(dev)
            t0 = time.perf_counter()
            call(n, i)
            t1 = time.perf_counter()
            wp.synchronize_device(dev)
            t2 = time.perf_counter()
            host[n].append((t1 - t0) * 1e6)
            total[n].append((t2 - t0) * 1e6)
    res = {"auto_path": path, "auto_blocks": loops["auto"]._pol_est.get("blocks")}
    for n in LOOPS:
        res[f"{n}_host_us"] = float(np.median(host[n]))
        res[f"{n}_frame_us"] = float(np.median(total[n]))
    if profile:
        for n in LOOPS:
            pr = cProfile.Profile()
            pr.enable()
            for i in range(warm + frames, warm + frames + 200):
                call(n, i)
                wp.synchronize_device(dev)
            pr.disable()
            s = io.StringIO()
            pstats.Stats(pr, stream=s).strip_dirs().sort_stats("tottime").print_stats(25)
            res[f"{n}_profile"] = s.getvalue()
    return res


def main(argv=None):
    p = base_parser(__doc__)
    p.add_argument("--specs", default="cornell:1920x1080,eyechart:1920x1080,bunny:1920x1080,bunny:3840x2160")
    p.add_argument("--frames", type=int, default=200)
    p.add_argument("--profile", action="store_true")
    p.add_argument("--name", default="policy-host")
    args = p.parse_args(argv)
    import foveawarp as fw

    wp.config.quiet = True
    dev = wp.get_device(args.device)
    specs = []
    for spec in args.specs.split(","):
        name, _, size = spec.partition(":")
        wh = size.split("x")
        if not name or len(wh) != 2 or not all(v.isdigit() and int(v) > 0 for v in wh):
            p.error(f"--specs items must be SCENE:WIDTHxHEIGHT (e.g. cornell:1920x1080), got {spec!r}")
        specs.append((name, size, int(wh[0]), int(wh[1])))
    records, rows = [], []
    for name, size, w, h in specs:
        r = {"device": dev.alias, "scene": name, "width": w, "height": h, "commit": git_commit(),
             **study(fw, fw.load_scene(name), w, h, dev, args.frames, args.profile)}
        records.append(r)
        row = {"scene": name, "size": size, "auto path": r["auto_path"]}
        for n in LOOPS:
            row[f"{n} host us"] = r[f"{n}_host_us"]
            row[f"{n} frame us"] = r[f"{n}_frame_us"]
        rows.append(row)
        print(row, flush=True)
        for n in LOOPS:
            if f"{n}_profile" in r:
                print(f"--- {name} {size} {n}\n{r[n + '_profile']}", flush=True)
    md = md_table(rows, list(rows[0]))
    write_results(args.name, dev, {"records": records}, md, args.out)
    print(md)


if __name__ == "__main__":
    main()
