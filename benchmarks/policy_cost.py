"""What a full-resolution frame costs through ``FrameLoop.render`` against ``render_reference`` (issues 14, 16).

Where the cost policy ("auto") picks full resolution, ``render`` draws the same image as ``render_reference``
but through the foveated frame's head (policy, history and stats bookkeeping in Python, the body's graph on CUDA).
This times the two frame by frame, taking turns along the scene's camera path (1/30 s per frame), after
warm-up: two loops of the same scene, size and shading, one rendering with ``policy="full"``, the other
calling ``render_reference``; each frame synchronized, the two taking turns at going first; medians, and the
median of the per-frame differences. ``--timing on`` builds both loops with ``timing=True`` (the constructor's
default: a synchronization around every stage, eager launches), ``off`` (default) with ``timing=False`` (CUDA
graph replay of ``render``'s body). ``--auto`` adds a third loop with the default policy ("auto"), timed after its
first measurement (so on the path it chose; ``auto_path`` says which), the three taking turns in a rotating
order: what the policy's bookkeeping costs a frame against the reference (``auto_ratio``).

    python benchmarks/policy_cost.py --device cpu --threads 2 --scenes cornell,bunny
    python benchmarks/policy_cost.py --device cuda:0 --auto --shadings default --sizes 1920x1080,3840x2160
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

sys.path.append(str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402
from benchmarks.cpu import frame_ms  # noqa: E402

import foveawarp as fw  # noqa: E402


def _one(sc, w, h, shading, frames, dev, args) -> dict:
    """One (scene, size, shading) row: the loops take turns frame by frame, the order rotating every frame."""
    cfg = fw.Config() if shading == "default" else fw.Config().with_(shading={"ao_samples": 8})
    timing = args.timing == "on"
    kw = dict(config=cfg, device=dev, timing=timing, cpu_threads=args.threads)
    loops = [("full", fw.FrameLoop(sc, w, h, policy="full", **kw), False),
             ("ref", fw.FrameLoop(sc, w, h, policy="full", **kw), True)]
    if args.auto:
        auto = fw.FrameLoop(sc, w, h, policy="auto", **kw)
        loops.append(("auto", auto, False))
        # its first measurement (both paths, warm-up and timed frames) happens before the timed frames
        frame_ms(auto, auto.policy_measurement_frames() + 2, False)
    times = {name: [] for name, _, _ in loops}
    for i in range(args.warmup + frames):
        k = i % len(loops)
        for name, loop, ref in loops[k:] + loops[:k]:
            t = frame_ms(loop, 1, ref, start=i)
            if i >= args.warmup:
                times[name] += t
    row = {"scene": sc, "width": w, "height": h, "shading": shading, "frames": frames, "timing": timing,
           "threads": loops[0][1].cpu_threads if dev.is_cpu else None,
           "reference_ms": statistics.median(times["ref"]), "render_full_ms": statistics.median(times["full"]),
           "median_diff_ms": statistics.median(a - b for a, b in zip(times["full"], times["ref"]))}
    row["ratio"] = row["render_full_ms"] / row["reference_ms"]
    if args.auto:
        row.update(auto_ms=statistics.median(times["auto"]), auto_path=auto._pol_choice,
                   auto_median_diff_ms=statistics.median(a - b for a, b in zip(times["auto"], times["ref"])))
        row["auto_ratio"] = row["auto_ms"] / row["reference_ms"]
    return row


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--scenes", default="cornell,bunny")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--frames", type=int, default=60, help="timed frames per loop")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: the usable cores)")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--timing", choices=("on", "off"), default="off", help="FrameLoop(timing=...) of both loops")
    p.add_argument("--auto", action="store_true", help="also time a loop with the default policy (auto)")
    p.add_argument("--sizes", default=None, help="comma list of WxH (default: --width x --height)")
    p.add_argument("--name", default="policy-cost", help="results file stem")
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error(f"--frames must be an integer >= 1, got {args.frames}")
    bad = [s for s in args.shadings.split(",") if s not in ("default", "ao8")]
    if bad:
        p.error(f"--shadings must be a comma list of 'default' and 'ao8', got {args.shadings!r}")
    dev = wp.get_device(args.device)
    if args.quick:
        sizes = [(96, 54)]
    elif args.sizes:
        try:
            sizes = [tuple(int(v) for v in z.split("x")) for z in args.sizes.split(",")]
        except ValueError:
            p.error(f"--sizes must be a comma list of WxH, got {args.sizes!r}")
    else:
        sizes = [(args.width, args.height)]
    frames = 6 if args.quick else args.frames
    rows = []
    for sc in [s for s in args.scenes.split(",") if s]:
        for (w, h) in sizes:
            for shading in args.shadings.split(","):
                rows.append(_one(sc, w, h, shading, frames, dev, args))
                print(rows[-1], flush=True)
    cols = ["scene", "width", "height", "shading", "timing", "threads", "reference_ms", "render_full_ms", "ratio",
            "median_diff_ms"] + (["auto_ms", "auto_path", "auto_ratio", "auto_median_diff_ms"] if args.auto else [])
    md = (f"## render(policy='full') against render_reference, {dev.alias}, timing={args.timing}\n\n"
          + md_table(rows, cols))
    print(md)
    write_results(args.name, dev, {"rows": rows}, md, args.out)


if __name__ == "__main__":
    main()
