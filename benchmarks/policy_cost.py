"""What a full-resolution frame costs through ``FrameLoop.render`` against ``render_reference`` (issues 14, 16).

Where the cost policy ("auto") picks full resolution, ``render`` draws the same image as ``render_reference``
but through the foveated frame's head (policy, history and stats bookkeeping in Python, the body's graph on CUDA).
This times the two frame by frame, taking turns along the scene's camera path (1/30 s per frame), after
warm-up: two loops of the same scene, size and shading, one rendering with ``policy="full"``, the other
calling ``render_reference``; each frame synchronized, the two taking turns at going first; medians, and the
median of the per-frame differences. ``--timing on`` builds both loops with ``timing=True`` (the constructor's
default: a synchronization around every stage, eager launches), ``off`` (default) with ``timing=False`` (CUDA
graph replay of ``render``'s body).

    python benchmarks/policy_cost.py --device cpu --threads 2 --scenes cornell,bunny
"""

from __future__ import annotations

import statistics
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

import warp as wp  # noqa: E402

from benchmarks._common import base_parser, md_table, write_results  # noqa: E402
from benchmarks.cpu import frame_ms  # noqa: E402

import foveawarp as fw  # noqa: E402


def main(argv=None) -> None:
    p = base_parser(__doc__.split("\n")[0])
    p.add_argument("--scenes", default="cornell,bunny")
    p.add_argument("--width", type=int, default=640)
    p.add_argument("--height", type=int, default=360)
    p.add_argument("--frames", type=int, default=60, help="timed frames per loop")
    p.add_argument("--threads", type=int, default=None, help="CPU threads (default: the usable cores)")
    p.add_argument("--shadings", default="default,ao8")
    p.add_argument("--timing", choices=("on", "off"), default="off", help="FrameLoop(timing=...) of both loops")
    p.add_argument("--name", default="policy-cost", help="results file stem")
    args = p.parse_args(argv)
    if args.frames < 1:
        p.error(f"--frames must be an integer >= 1, got {args.frames}")
    bad = [s for s in args.shadings.split(",") if s not in ("default", "ao8")]
    if bad:
        p.error(f"--shadings must be a comma list of 'default' and 'ao8', got {args.shadings!r}")
    dev = wp.get_device(args.device)
    w, h = (96, 54) if args.quick else (args.width, args.height)
    frames = 6 if args.quick else args.frames
    rows = []
    for sc in [s for s in args.scenes.split(",") if s]:
        for shading in args.shadings.split(","):
            cfg = fw.Config() if shading == "default" else fw.Config().with_(shading={"ao_samples": 8})
            timing = args.timing == "on"
            full = fw.FrameLoop(sc, w, h, config=cfg, device=dev, timing=timing, policy="full", cpu_threads=args.threads)
            ref = fw.FrameLoop(sc, w, h, config=cfg, device=dev, timing=timing, policy="full", cpu_threads=args.threads)
            t_full, t_ref = [], []
            for i in range(args.warmup + frames):  # the two loops take turns frame by frame, each first every other
                if i % 2:
                    b, a = frame_ms(ref, 1, True, start=i), frame_ms(full, 1, False, start=i)
                else:
                    a, b = frame_ms(full, 1, False, start=i), frame_ms(ref, 1, True, start=i)
                if i >= args.warmup:
                    t_full += a
                    t_ref += b
            diff = [a - b for a, b in zip(t_full, t_ref)]
            row = {"scene": sc, "width": w, "height": h, "shading": shading, "frames": frames, "timing": timing,
                   "threads": full.cpu_threads if dev.is_cpu else None,
                   "reference_ms": statistics.median(t_ref), "render_full_ms": statistics.median(t_full),
                   "median_diff_ms": statistics.median(diff)}
            row["ratio"] = row["render_full_ms"] / row["reference_ms"]
            rows.append(row)
            print(row, flush=True)
    cols = ["scene", "width", "height", "shading", "timing", "threads", "reference_ms", "render_full_ms", "ratio",
            "median_diff_ms"]
    md = (f"## render(policy='full') against render_reference, {dev.alias}, timing={args.timing}\n\n"
          + md_table(rows, cols))
    print(md)
    write_results(args.name, dev, {"rows": rows}, md, args.out)


if __name__ == "__main__":
    main()
