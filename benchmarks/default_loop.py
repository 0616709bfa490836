"""What the API example's loop gives a user: ``FrameLoop(scene, w, h, config=cfg, device=dev)`` with every other
constructor argument left at its default (``timing=True``, ``policy`` None = "auto"), against ``render_reference``
of a loop built the same way, and against the foveated frame forced on (``policy="foveated"``: what the default
was with ``timing=True`` before session 14).

Per scene x size x shading, the three loops take turns frame by frame along the scene's camera path (1/30 s a
frame) with a moving gaze (``benchmarks/frame.py``'s Lissajous path), each frame synchronized, each loop with its
own camera objects, the order of the three cycling through all six permutations. The default
loop's first ``FrameLoop.policy_measurement_frames()`` frames (51) hold its policy's measurement (12 foveated, 12 full
resolution, 9 + 9 more when the two are close, and 9 more full ones when foveation still wins); then ``--warmup``
frames,
then ``--frames`` timed frames, whose medians are reported with the path the default loop took, the policy's
estimates and the median of the per-frame differences from the reference. Quality of the same timed frames
against the reference frame of the same camera, time and gaze: PSNR, foveal PSNR (eccentricity <= 5 deg) and (on
CUDA) SSIM, mean and min (identical frames count as 100 dB in the mean).

    python benchmarks/default_loop.py --device cuda:0 --sizes 1920x1080,3840x2160
    python benchmarks/default_loop.py --device cpu --sizes 640x360 --scenes cornell,bunny
"""

from __future__ import annotations

import itertools
import statistics
import sys
import time
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import (base_parser, checked_shadings_sizes, md_table, scenes_present,  # noqa: E402
                               shading_config, write_results)
from benchmarks.frame import ALL_SCENES, _fovea_key, _metric_fn, _summ, gaze_path  # noqa: E402

import foveawarp as fw  # noqa: E402


def _timed(fn, dev) -> tuple:
    wp.synchronize_device(dev)
    t0 = time.perf_counter()
    out = fn()
    wp.synchronize_device(dev)
    return (time.perf_counter() - t0) * 1e3, out


def run_case(scene, w, h, shading, dev, frames, warmup, threads, metric, timing=None) -> dict:
    cfg = shading_config(fw, shading)
    kw = {} if threads is None else {"cpu_threads": threads}
    if timing is not None:
        kw["timing"] = timing
    dflt = fw.FrameLoop(scene, w, h, config=cfg, device=dev, **kw)  # the defaults under test
    fov = fw.FrameLoop(scene, w, h, config=cfg, device=dev, policy="foveated", **kw)
    ref = fw.FrameLoop(scene, w, h, config=cfg, device=dev, **kw)
    n_pol = dflt.policy_measurement_frames() if dflt.policy == "auto" else 0
    total = n_pol + warmup + frames
    t = {"reference": [], "default": [], "foveated": []}
    q = {"default": [], "foveated": []}
    paths = []
    orders = list(itertools.permutations(("reference", "default", "foveated")))
    for i in range(total):
        ts = i / 30.0
        g = gaze_path(i, total, w, h)
        # each loop its own camera object (a camera caches its kernel parameters: a shared one would charge
        # whichever loop runs first), and the order of the three cycles through all six permutations, so that
        # every loop follows every other equally often (a frame right after a heavier one meets other clocks)
        cams = {name: scene.camera_at(ts) for name in orders[0]}
        run = {"reference": lambda: ref.render_reference(cams["reference"], time=ts, gaze_px=g),
               "default": lambda: dflt.render(cams["default"], gaze_px=g, time=ts),
               "foveated": lambda: fov.render(cams["foveated"], gaze_px=g, time=ts)}
        got = {}
        for name in orders[i % 6]:
            ms, frame = _timed(run[name], dev)
            got[name] = frame
            if i >= n_pol + warmup:
                t[name].append(ms)
        if i >= n_pol + warmup:
            paths.append(got["default"].stats["policy"]["path"])
            for name in q:
                q[name].append(metric(got[name].image, got["reference"].image, g, cams["reference"].fov_y_deg))
    pol = got["default"].stats["policy"]
    row = {"scene": scene.name, "width": w, "height": h, "shading": shading, "frames": frames,
           "threads": dflt.cpu_threads if dev.is_cpu else None, "timing": dflt.timing, "policy": dflt.policy,
           "default_paths": {p: paths.count(p) for p in sorted(set(paths))}, "default_path_series": paths,
           "policy_foveated_ms": pol.get("foveated_ms"), "policy_full_ms": pol.get("full_ms"),
           "policy_stats": {k: v for k, v in pol.items() if k != "path"},
           "reference_ms": statistics.median(t["reference"]), "default_ms": statistics.median(t["default"]),
           "foveated_ms": statistics.median(t["foveated"]), "frame_ms": t}
    row["default_over_reference"] = row["default_ms"] / row["reference_ms"]
    row["foveated_over_reference"] = row["foveated_ms"] / row["reference_ms"]
    # the median of the per-frame differences (the frames of one step share camera, time and gaze)
    for name in ("default", "foveated"):
        row[f"{name}_minus_reference_ms"] = statistics.median(a - b for a, b in zip(t[name], t["reference"]))
    for name, ms in q.items():
        ps = [m["psnr"] for m in ms]
        fp = [_fovea_key(m) for m in ms]
        row[f"{name}_psnr"] = _summ(ps)
        row[f"{name}_ssim"] = _summ([m["ssim"] for m in ms])
        row[f"{name}_fovea_psnr"] = _summ(fp)
        row[f"{name}_psnr_series"] = ps
    return row


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--scenes", default=ALL_SCENES)
    p.add_argument("--sizes", default="1920x1080,3840x2160")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--frames", type=int, default=30, help="timed frames per loop (after the policy's measurement)")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: the usable cores)")
    p.add_argument("--name", default="default-loop")
    p.add_argument("--timing", choices=("default", "on", "off"), default="default",
                   help="FrameLoop(timing=...) of all three loops (default: the constructor's, on)")
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error(f"--frames must be an integer >= 1, got {args.frames}")
    shadings, sizes = checked_shadings_sizes(p, args)
    dev = wp.get_device(args.device)
    if args.quick:
        sizes, frames, warmup = [(64, 36)], 3, 1
    else:
        frames, warmup = args.frames, args.warmup
    metric, metric_kind = _metric_fn(fast=not dev.is_cuda)  # CUDA: PSNR and SSIM on the device
    rows = []
    for scene in scenes_present(fw, args.scenes):
        for w, h in sizes:
            for shading in shadings:
                row = run_case(scene, w, h, shading, dev, frames, warmup, args.threads, metric,
                               timing=None if args.timing == "default" else args.timing == "on")
                rows.append(row)
                print({k: v for k, v in row.items() if not k.endswith("_series") and k != "frame_ms"}, flush=True)
    cols = ["scene", "width", "height", "shading", "reference_ms", "default_ms", "default_over_reference",
            "default_minus_reference_ms", "default_paths", "foveated_ms", "foveated_over_reference",
            "default_psnr_mean", "default_psnr_min", "foveated_psnr_mean", "foveated_psnr_min"]
    flat = [{**r, "default_psnr_mean": r["default_psnr"]["mean"], "default_psnr_min": r["default_psnr"]["min"],
             "foveated_psnr_mean": r["foveated_psnr"]["mean"], "foveated_psnr_min": r["foveated_psnr"]["min"]}
            for r in rows]
    what = ("every FrameLoop default: timing=True, policy 'auto'" if args.timing == "default" else
            f"FrameLoop defaults but timing={args.timing == 'on'}: policy 'auto'")
    md = (f"## The API example's loop ({what}), {dev.alias}\n\n"
          f"Medians of {frames} synchronized frames after the policy's measurement, the three loops taking turns; PSNR in "
          f"dB against the reference frame of the same camera, time and gaze ({metric_kind}).\n\n"
          + md_table(flat, cols))
    print(md)
    write_results(args.name, dev, {"rows": rows, "metric": metric_kind}, md, args.out)


if __name__ == "__main__":
    main()
